"""One MAVLink link over a plain non-blocking UDP socket (no mavutil polling in the hot path).

Receiving: each datagram is framed by hand (MAVLink 1 or 2 header, length, signature), the source
system/component and message id are checked from the header *before* decoding, and only the
packets the owner wants are decoded, by a ``pymavlink`` ``MAVLink`` instance (``decode`` checks the
CRC).  Everything that is not accepted is counted by reason in ``rejected``:

    bad_magic     the datagram (or its remainder) does not start with a MAVLink start byte
    truncated     a packet shorter than its header says
    bad_crc       CRC mismatch (pymavlink decode)
    decode_error  any other pymavlink decode error
    wrong_id      source (sysid, compid) not one this link talks to
    unknown_msg   message id not in the common dialect
    ignored_msg   a valid message this link does not use
    over_budget   datagrams left in the socket buffer beyond the per-poll budget are still read and
                  dropped (counted) when a flood exceeds it, so the loop keeps its rate

Sending: ``send(msg)`` packs with this link's own sequence counter and source IDs.  Every packet sent
or accepted is written to the tlog (if one is attached) with the raw bytes.
"""

from __future__ import annotations

import errno
import socket
import time
from collections import Counter

from autopilot.shared.fastmav import FAST_DECODERS, FastPacker
from autopilot.shared.mavlink import mavlink

_MAVLINK_MAP = mavlink.mavlink_map
REJECT_REASONS = (
    "bad_magic",
    "truncated",
    "bad_crc",
    "decode_error",
    "wrong_id",
    "unknown_msg",
    "ignored_msg",
    "over_budget",
)


class UdpLink:
    """A MAVLink endpoint on one UDP socket.

    ``bind``: local (host, port), port 0 for an ephemeral one.  ``remote``: where to send (None until a
    peer talks to us when ``learn_remote``).  ``peers``: accepted source (sysid, compid) pairs.
    ``msgids``: accepted message ids (others are counted as ``ignored_msg`` without decoding).
    """

    def __init__(
        self,
        name: str,
        src: tuple[int, int],
        bind: tuple[str, int],
        remote: tuple[str, int] | None,
        peers,
        msgids,
        *,
        learn_remote: bool = False,
        tlog=None,
        rcvbuf: int = 1 << 20,
    ):
        self.name = name
        self.mav = mavlink.MAVLink(None, src[0], src[1])
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        except OSError:
            pass
        self.sock.bind(bind)
        self.sock.setblocking(False)
        self.local = self.sock.getsockname()
        self.remote = remote
        self.learn_remote = learn_remote
        self.peers = frozenset(tuple(p) for p in peers)
        self.msgids = frozenset(msgids)
        self.tlog = tlog
        self.rx_datagrams = 0
        self.rx_packets = 0  # accepted and decoded
        self.tx_packets = 0
        self.tx_errors = 0
        self.rx_by_type: Counter = Counter()
        self.tx_by_type: Counter = Counter()
        self.rejected: Counter = Counter()
        self.last_rx_wall = 0.0  # perf_counter of the last accepted packet
        self.peer_addr = None  # address of the last accepted packet

    # ------------------------------------------------------------------ send
    def pack(self, msg) -> bytes:
        mav = self.mav
        buf = msg.pack(mav)
        mav.seq = (mav.seq + 1) & 0xFF
        return buf

    def send(self, msg) -> bytes | None:
        """Pack and send one message to ``remote``; returns the raw bytes (None if there is no peer yet)."""
        if self.remote is None:
            return None
        buf = self.pack(msg)
        self.send_raw(buf, msg.get_msgId())
        return buf

    def fast_packer(self, cls) -> FastPacker:
        """A byte-identical fast encoder for a hot message class (see ``autopilot.shared.fastmav``)."""
        return FastPacker(cls, self.mav.srcSystem, self.mav.srcComponent)

    def pack_fast(self, packer: FastPacker, *wire_values) -> bytes:
        """Encode with a fast packer and this link's sequence number (``wire_values`` in struct order)."""
        mav = self.mav
        buf = packer(mav.seq, *wire_values)
        mav.seq = (mav.seq + 1) & 0xFF
        return buf

    def send_batch(self, bufs: list, msgids: list) -> bool:
        """Send several packets in one datagram (a UDP MAVLink stream may carry several); tlog each one."""
        if self.remote is None:
            return False
        try:
            self.sock.sendto(b"".join(bufs), self.remote)
        except OSError:
            self.tx_errors += len(bufs)
            return False
        self.tx_packets += len(bufs)
        for mid in msgids:
            self.tx_by_type[mid] += 1
        if self.tlog is not None:
            for b in bufs:
                self.tlog.write(b)
        return True

    def send_raw(self, buf: bytes, msgid: int | None = None) -> bool:
        if self.remote is None:
            return False
        try:
            self.sock.sendto(buf, self.remote)
        except OSError:
            # ECONNREFUSED from a previous ICMP port-unreachable, ENOBUFS under load: count, go on.
            self.tx_errors += 1
            return False
        self.tx_packets += 1
        if msgid is not None:
            self.tx_by_type[msgid] += 1
        if self.tlog is not None:
            self.tlog.write(buf)
        return True

    # --------------------------------------------------------------- receive
    def poll(self, handler, budget: int = 256) -> int:
        """Read every datagram waiting (up to ``budget`` processed; the rest read and dropped as over_budget),
        calling ``handler(msg, t_rx)`` for each accepted message.  Returns the number of datagrams read."""
        sock = self.sock
        n = 0
        while True:
            try:
                data, addr = sock.recvfrom(4096)
            except BlockingIOError:
                return n
            except OSError as exc:  # ECONNREFUSED after an ICMP error on a sendto: not data, keep going
                if exc.errno in (errno.ECONNREFUSED, errno.ECONNRESET, errno.EHOSTUNREACH, errno.ENETUNREACH):
                    continue
                raise
            n += 1
            self.rx_datagrams += 1
            if n > budget:
                self.rejected["over_budget"] += 1
                if n > 16 * budget:
                    return n
                continue
            self.feed(data, addr, handler)

    def feed(self, data: bytes, addr, handler) -> None:
        """Frame, filter and decode one datagram."""
        t_rx = time.perf_counter()
        i = 0
        end = len(data)
        rejected = self.rejected
        while i < end:
            magic = data[i]
            if magic == 0xFD:
                if end - i < 12:
                    rejected["truncated"] += 1
                    return
                total = 12 + data[i + 1] + (13 if data[i + 2] & 1 else 0)
                sysid = data[i + 5]
                compid = data[i + 6]
                msgid = data[i + 7] | (data[i + 8] << 8) | (data[i + 9] << 16)
            elif magic == 0xFE:
                if end - i < 8:
                    rejected["truncated"] += 1
                    return
                total = 8 + data[i + 1]
                sysid = data[i + 3]
                compid = data[i + 4]
                msgid = data[i + 5]
            else:
                rejected["bad_magic"] += 1
                return
            if end - i < total:
                rejected["truncated"] += 1
                return
            j = i
            i += total
            if (sysid, compid) not in self.peers:
                rejected["wrong_id"] += 1
                continue
            if msgid not in self.msgids:
                rejected["unknown_msg" if msgid not in _MAVLINK_MAP else "ignored_msg"] += 1
                continue
            raw = data[j:i]
            try:
                fast = FAST_DECODERS.get(msgid) if magic == 0xFD and not data[j + 2] & 1 else None
                msg = fast(raw) if fast is not None else self.mav.decode(bytearray(raw))
            except mavlink.MAVError as exc:
                rejected["bad_crc" if "CRC" in str(exc) else "decode_error"] += 1
                continue
            except Exception:  # noqa: BLE001  (any decoder failure is a rejected packet, never a crash)
                rejected["decode_error"] += 1
                continue
            self.rx_packets += 1
            self.rx_by_type[msgid] += 1
            self.last_rx_wall = t_rx
            self.peer_addr = addr
            if self.learn_remote and addr != self.remote:
                self.remote = addr
            if self.tlog is not None:
                self.tlog.write(raw)
            handler(msg, t_rx)

    # ----------------------------------------------------------------- misc
    def fileno(self) -> int:
        return self.sock.fileno()

    def close(self) -> None:
        self.sock.close()

    def counters(self) -> dict:
        return {
            "rx_datagrams": self.rx_datagrams,
            "rx_packets": self.rx_packets,
            "tx_packets": self.tx_packets,
            "tx_errors": self.tx_errors,
            "rx_by_type": {_name(k): v for k, v in sorted(self.rx_by_type.items())},
            "tx_by_type": {_name(k): v for k, v in sorted(self.tx_by_type.items())},
            # the link's own reasons first, then those the owner adds (nonfinite_attitude, bad_pwm, ...)
            "rejected": {
                **{r: self.rejected[r] for r in REJECT_REASONS if self.rejected.get(r)},
                **{r: v for r, v in sorted(self.rejected.items()) if r not in REJECT_REASONS and v},
            },
        }


def _name(msgid: int) -> str:
    cls = _MAVLINK_MAP.get(msgid)
    return cls.msgname if cls is not None else str(msgid)


def format_counters(name: str, c: dict, extra: dict | None = None) -> str:
    """One line: ``name: rx N (ATTITUDE=.., ...) tx N rejected {reason: n}``."""
    rx = ", ".join(f"{k}={v}" for k, v in c["rx_by_type"].items())
    tx = ", ".join(f"{k}={v}" for k, v in c["tx_by_type"].items())
    rej = ", ".join(f"{k}={v}" for k, v in c["rejected"].items()) or "none"
    s = (
        f"{name}: received {c['rx_packets']} ({rx}) of {c['rx_datagrams']} datagrams; sent {c['tx_packets']} ({tx})"
        f"{'; send errors ' + str(c['tx_errors']) if c['tx_errors'] else ''}; rejected: {rej}"
    )
    if extra:
        s += "; " + ", ".join(f"{k}={v}" for k, v in extra.items())
    return s
