"""The launcher's web viewer (``--web``): one ``rerun --serve-web`` of its own, bound to loopback by default.

``rerun --serve-web`` serves the Rerun web viewer over HTTP (``--web-viewer-port``) and a gRPC proxy (``--port``) that
the processes stream to and the browser reads from.  It has no authentication: whoever reaches the gRPC port can read
the whole recording and write rows and texts into it.  So:

* it binds ``127.0.0.1`` unless the caller asks for another address (``--web-host``); a remote browser watches through
  an SSH tunnel (``ssh -L 9090:127.0.0.1:9090 -L 9877:127.0.0.1:9877 HOST``), and any other address prints a warning;
* it is the launcher's own: a port already taken (by another server, or anything) is an error, never a server to reuse;
* it ends with the launcher: ``WebServer.stop`` ends its process group (the flight calls it however it ends), and the
  kernel sends it SIGTERM if the launcher dies without stopping it (``PR_SET_PDEATHSIG``), so it is never left running
  reparented to pid 1.  (The kernel watches the thread that started it: start it from a thread that lives as long
  as the flight, as ``Flight.start`` in the launcher's main thread does.)
"""

from __future__ import annotations

import argparse
import ctypes
import ipaddress
import os
import signal
import socket
import subprocess
import time
from pathlib import Path
from urllib.parse import quote

DEFAULT_HOST = "127.0.0.1"
DEFAULT_HTTP_PORT = 9090  # the web viewer (HTML + wasm)
DEFAULT_GRPC_PORT = 9877  # the gRPC proxy the processes stream to and the browser reads from
START_TIMEOUT_S = 20.0
STOP_GRACE_S = 5.0
_PR_SET_PDEATHSIG = 1  # linux/prctl.h


class WebServerError(RuntimeError):
    """The web viewer could not be started (a port taken, rerun exited); the message is one line."""


def bind_host(text: str) -> str:
    """``--web-host``: an IP address to bind (``127.0.0.1``, ``0.0.0.0``, ``::``...), for argparse."""
    try:
        return str(ipaddress.ip_address(str(text).strip("[]")))
    except ValueError:
        msg = f"expected an IP address to bind, e.g. 127.0.0.1 or 0.0.0.0, got {text!r}"
        raise argparse.ArgumentTypeError(msg) from None


def tcp_port(text) -> int:
    """A TCP port 1..65535, for argparse."""
    try:
        port = int(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f"expected a TCP port (an integer), got {text!r}") from None
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"expected a TCP port in 1..65535, got {port}")
    return port


def is_loopback(host: str) -> bool:
    return ipaddress.ip_address(host).is_loopback


def connect_host(host: str) -> str:
    """The address a local process connects to for a server bound to ``host`` (loopback for 0.0.0.0 / ::)."""
    ip = ipaddress.ip_address(host)
    if ip.is_unspecified:
        return "127.0.0.1" if ip.version == 4 else "::1"
    return host


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


def port_taken(host: str, port: int) -> OSError | None:
    """Why a TCP listener cannot bind ``host:port`` (something listens there, on it or on all interfaces); None if
    it can.  ``SO_REUSEADDR`` as servers set it: a closed connection's TIME_WAIT does not count, a listener does."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
            s.listen(1)
        except OSError as exc:
            return exc
    return None


def _accepts(host: str, port: int, timeout_s: float = 0.3) -> bool:
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            return True
    except OSError:
        return False


def _die_with_parent_fn():
    """A ``preexec_fn`` asking the kernel for SIGTERM when the launcher dies (libc loaded before the fork)."""
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):  # not Linux: the process group and stop() still end it
        return None
    parent = os.getpid()

    def preexec() -> None:
        prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        if os.getppid() != parent:  # the launcher died before the request took effect
            os.kill(os.getpid(), signal.SIGTERM)

    return preexec


class WebServer:
    """``rerun --serve-web`` on ``host`` (HTTP ``http_port``, gRPC ``grpc_port``), started by ``start`` and ended by
    ``stop`` (idempotent; also a context manager).  Its output goes to ``log_path`` (or nowhere)."""

    def __init__(
        self,
        host: str = DEFAULT_HOST,
        http_port: int = DEFAULT_HTTP_PORT,
        grpc_port: int = DEFAULT_GRPC_PORT,
        *,
        log_path: str | os.PathLike | None = None,
        memory_limit: str = "25%",
        source: str | os.PathLike | None = None,
    ):
        self.host = bind_host(host)
        self.http_port = tcp_port(http_port)
        self.grpc_port = tcp_port(grpc_port)
        if self.http_port == self.grpc_port:
            raise WebServerError(f"--web-port and --web-grpc-port must differ, both are {self.http_port}")
        self.log_path = Path(log_path) if log_path is not None else None
        self.memory_limit = memory_limit
        self.source = source  # an .rrd to serve instead of a live proxy only
        self.proc: subprocess.Popen | None = None

    # ---------------------------------------------------------------- addresses
    @property
    def grpc_url(self) -> str:
        """Where the processes stream: ``rerun+http://HOST:PORT/proxy`` (loopback for an all-interfaces bind)."""
        return f"rerun+http://{_url_host(connect_host(self.host))}:{self.grpc_port}/proxy"

    def browser_url(self, host: str | None = None) -> str:
        """The page a browser opens, reading the gRPC proxy at the same ``host`` (default: the connect host)."""
        h = _url_host(host or connect_host(self.host))
        proxy = quote(f"rerun+http://{h}:{self.grpc_port}/proxy", safe="")
        return f"http://{h}:{self.http_port}/?url={proxy}"

    def notice(self) -> list[str]:
        """What the launcher prints: the page to open, and how to reach it (SSH tunnel or the exposure warning)."""
        ports = f"{self.http_port} and {self.grpc_port}"
        if is_loopback(self.host):
            return [
                f"launch: web viewer on loopback only: open {self.browser_url()}",
                f"launch: from another machine, tunnel both ports first: ssh -L {self.http_port}:127.0.0.1:"
                f"{self.http_port} -L {self.grpc_port}:127.0.0.1:{self.grpc_port} <this host>",
            ]
        return [
            f"launch: web viewer on {self.host}: open {self.browser_url('<this host>')}",
            f"launch: WARNING: anyone who reaches ports {ports} of this host can read the whole recording and "
            "write into it (no authentication); bind 127.0.0.1 and use ssh -L unless the network is yours alone",
        ]

    # ---------------------------------------------------------------- lifecycle
    def argv(self, exe: str) -> list[str]:
        cmd = [exe, "--serve-web", "--bind", self.host, "--port", str(self.grpc_port)]
        cmd += ["--web-viewer-port", str(self.http_port), "--server-memory-limit", self.memory_limit]
        return cmd + ([str(self.source)] if self.source is not None else [])

    def start(self, timeout_s: float = START_TIMEOUT_S) -> str:
        """Start the server and wait until both ports accept connections; returns ``grpc_url``.  WebServerError
        if a port is taken (checked first: nothing of someone else's is ever reused) or rerun does not come up."""
        if self.proc is not None:
            raise RuntimeError("this web server was already started")
        for what, port in (("--web-grpc-port", self.grpc_port), ("--web-port", self.http_port)):
            err = port_taken(self.host, port)
            if err is not None:
                raise WebServerError(
                    f"--web: TCP port {port} ({what}) on {self.host} is not free ({err.strerror or err}): another "
                    f"Rerun server or program holds it; stop it or choose other ports with --web-port/--web-grpc-port"
                )
        from autopilot.shared.telemetry.viewer import rerun_cli_path

        log = open(self.log_path, "w") if self.log_path is not None else subprocess.DEVNULL
        try:
            self.proc = subprocess.Popen(
                self.argv(rerun_cli_path()),
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                process_group=0,  # its own process group: Ctrl-C goes to the launcher, stop() ends the group
                preexec_fn=_die_with_parent_fn(),
                env=dict(os.environ, RUST_LOG=os.environ.get("RUST_LOG", "warn")),
            )
        finally:
            if log is not subprocess.DEVNULL:
                log.close()
        try:
            self._await_listening(timeout_s)
        except BaseException:  # Ctrl-C while waiting included: never leave it behind
            self.stop()
            raise
        return self.grpc_url

    def _await_listening(self, timeout_s: float) -> None:
        host = connect_host(self.host)
        deadline = time.monotonic() + timeout_s
        while not (_accepts(host, self.grpc_port) and _accepts(host, self.http_port)):
            if self.proc.poll() is not None:
                code = self.proc.returncode
                self.stop()
                why = self._last_line()
                raise WebServerError(f"--web: rerun --serve-web exited with code {code} at start-up: {why}")
            if time.monotonic() > deadline:
                self.stop()
                raise WebServerError(f"--web: rerun --serve-web did not listen on {self.host} within {timeout_s:g} s")
            time.sleep(0.05)
        if self.proc.poll() is not None:  # what answered is not ours (it exited): never reuse it
            code = self.proc.returncode
            self.stop()
            raise WebServerError(f"--web: rerun --serve-web exited with code {code}: {self._last_line()}")

    def _last_line(self) -> str:
        if self.log_path is None or not self.log_path.is_file():
            return "(no log)"
        lines = [ln.strip() for ln in self.log_path.read_text(errors="replace").splitlines() if ln.strip()]
        return lines[-1] if lines else "(no output)"

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def stop(self) -> None:
        """End the server's process group: SIGTERM, SIGKILL after ``STOP_GRACE_S``; reaps it.  Idempotent."""
        proc = self.proc
        if proc is None:
            return
        for sig, grace in ((signal.SIGTERM, STOP_GRACE_S), (signal.SIGKILL, STOP_GRACE_S)):
            try:
                os.killpg(proc.pid, sig)  # its group: process_group=0 made its pid the group id
            except ProcessLookupError:
                break
            try:
                proc.wait(grace)
                break
            except subprocess.TimeoutExpired:
                continue
        if proc.poll() is None:
            proc.wait()

    def __enter__(self) -> WebServer:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
