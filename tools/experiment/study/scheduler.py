"""A Dask scheduler reached with every wait bounded (``connect``), after a probe of its handshake (``probe``).

Dask's own handshake read has no timeout (``distributed.comm.core.connect``), and it trusts the first 8 bytes it
reads as a length: a server that accepts and stays silent hangs the client, an HTTP server's "HTTP/1.1" makes it
allocate 3 EiB.  So before the client connects, ``probe`` does the handshake itself, with a deadline: it sends the
client's handshake (a Dask frame), reads 8 bytes of length (at most ``MAX_HANDSHAKE``) and the frame, and checks
that it is the scheduler's handshake (a dict with ``pickle-protocol``).  Every failure is one line naming the
address (``StudyError``).
"""

from __future__ import annotations

import pickle
import socket
import struct
import sys
import time

from tools.experiment.study.sampling import StudyError

TIMEOUT_S = 10.0  # connecting, the handshake, the client, waiting for a worker: each at most this
MAX_HANDSHAKE = 1 << 16  # bytes: a scheduler's handshake is about 60


def _address(address: str) -> tuple[str, int]:
    rest = address.split("://", 1)[1]
    host, sep, port = rest.rpartition(":")
    if not sep or not port.isdigit() or not 0 < int(port) < 65536:
        raise StudyError(f"--scheduler must look like tcp://HOST:PORT, got {address!r}")
    return host.strip("[]") or "127.0.0.1", int(port)


def _handshake() -> bytes:
    """The client's handshake as Dask frames it (``distributed.comm.tcp.TCP.write``): 8 bytes of length, then the
    frames packed with their lengths (``distributed.protocol.utils.pack_frames``)."""
    from distributed.protocol import dumps
    from distributed.protocol.utils import pack_frames

    info = {"compression": None, "python": tuple(sys.version_info)[:3], "pickle-protocol": pickle.HIGHEST_PROTOCOL}
    body = pack_frames([bytes(f) for f in dumps(info)])
    return struct.pack("Q", len(body)) + body


def _recv(sock: socket.socket, n: int, deadline: float, address: str, timeout: float) -> bytes:
    data = b""
    while len(data) < n:
        left = deadline - time.monotonic()
        if left <= 0:
            raise StudyError(
                f"--scheduler {address}: no answer in {timeout:g} s"
                + (" (not a Dask scheduler: it accepted the connection and said nothing)" if not data else "")
            )
        sock.settimeout(left)
        try:
            chunk = sock.recv(min(n - len(data), 65536))
        except TimeoutError:
            continue
        except OSError as exc:
            raise StudyError(f"--scheduler {address}: not a Dask scheduler ({exc.strerror or exc})") from None
        if not chunk:
            raise StudyError(f"--scheduler {address}: not a Dask scheduler (it closed the connection)")
        data += chunk
    return data


def probe(address: str, timeout: float = TIMEOUT_S) -> None:
    """Raise ``StudyError`` unless a Dask scheduler answers the handshake at ``address`` (tcp://) within
    ``timeout`` seconds.  Other schemes (tls://, inproc://) are left to ``connect``'s bounded wait."""
    if not address.startswith("tcp://"):
        return
    host, port = _address(address)
    deadline = time.monotonic() + timeout
    try:
        sock = socket.create_connection((host, port), timeout=timeout)
    except TimeoutError:
        raise StudyError(f"--scheduler {address}: no answer in {timeout:g} s (cannot connect)") from None
    except OSError as exc:
        raise StudyError(f"cannot connect to the Dask scheduler at {address}: {exc.strerror or exc}") from None
    with sock:
        try:
            sock.sendall(_handshake())
        except OSError as exc:
            raise StudyError(f"--scheduler {address}: not a Dask scheduler ({exc.strerror or exc})") from None
        (length,) = struct.unpack("Q", _recv(sock, 8, deadline, address, timeout))
        if not 16 <= length <= MAX_HANDSHAKE:
            raise StudyError(f"--scheduler {address}: not a Dask scheduler (its first bytes are not a Dask handshake)")
        body = _recv(sock, length, deadline, address, timeout)
        try:
            from distributed.protocol import loads
            from distributed.protocol.utils import unpack_frames

            msg = loads(unpack_frames(body), deserialize=False)
        except Exception:  # noqa: BLE001 - whatever does not decode is not what a scheduler sends
            msg = None
        if not (isinstance(msg, dict) and "pickle-protocol" in msg):
            raise StudyError(f"--scheduler {address}: not a Dask scheduler (its answer is not a Dask handshake)")


def connect(address: str, timeout: float = TIMEOUT_S):
    """A ``distributed.Client`` of the scheduler at ``address`` with at least one worker, every wait bounded by
    ``timeout``; ``StudyError`` (one line) otherwise."""
    try:
        from distributed import Client
    except ImportError as exc:
        raise StudyError(f"--scheduler needs dask.distributed (pip install 'dask[distributed]'): {exc}") from None
    probe(address, timeout)
    try:
        client = Client(address, timeout=f"{timeout:g}s")
    except Exception as exc:  # noqa: BLE001 - whatever the client meets, one line naming the address
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise StudyError(f"cannot connect to the Dask scheduler at {address}: {first}") from None
    try:
        client.wait_for_workers(1, timeout=timeout)
    except Exception:  # noqa: BLE001
        client.close(timeout=timeout)
        raise StudyError(f"the Dask scheduler at {address} has no worker (none joined in {timeout:g} s)") from None
    return client


def threads(client) -> int:
    """The cluster's worker threads."""
    try:
        return max(1, sum(client.nthreads().values()))
    except Exception:  # noqa: BLE001
        return 1
