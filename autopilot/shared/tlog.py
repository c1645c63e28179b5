"""Telemetry log (.tlog) in the standard format that pymavlink's mavlogdump.py and MAVExplorer read.

Each record is an 8-byte big-endian uint64 (microseconds since the Unix epoch) followed by the raw
MAVLink packet, exactly what ``mavutil.mavlogfile`` writes.  pymavlink's ``setup_logfile`` writes
nothing for UDP links driven by hand, so the links call :meth:`TlogWriter.write` with the bytes they
sent or accepted.  A write only stamps the record (the time it was sent or accepted) and queues it; the
owner moves the queue into the file's buffer with :meth:`TlogWriter.drain` once the lockstep answer is out
(off the critical path: docs/spec.md, "Lockstep"), and ``flush``/``close`` drain first, so every record
reaches the file in the order written with the stamp of its moment.  The buffer is flushed by the owner's
housekeeping (``maybe_flush``), so the control step never waits on the disk and a killed run leaves a
file that ends at a record boundary or inside the last record (readers stop there).  A write that fails (a full
disk) never stops the flight: the writer keeps what reached the file, drops the rest (``lost`` records) and says
why in ``error`` (one line naming the path), which the autopilot reports at its exit.
"""

from __future__ import annotations

import struct
import time

_TS = struct.Struct(">Q")
_time_ns = time.time_ns


class TlogWriter:
    def __init__(self, path: str, flush_interval_s: float = 0.5):
        self.path = path
        self._f = open(path, "wb", buffering=1 << 16)
        self._pack = _TS.pack
        self._queue: list = []  # (t_us, raw) written but not yet in the file's buffer (``drain``)
        self.records = 0  # records written (queued ones included)
        self.flush_interval_s = flush_interval_s
        self._next_flush = time.monotonic() + flush_interval_s
        self.error: str | None = None  # why the file stopped growing (a failed write), once it did
        self.lost = 0  # records not written because of it

    def write(self, raw, t_us: int | None = None) -> None:
        """Queue one record stamped now (or ``t_us``): a list append, cheap enough for the critical path."""
        self._queue.append((_time_ns() // 1000 if t_us is None else t_us, raw if type(raw) is bytes else bytes(raw)))
        self.records += 1

    def drain(self) -> None:
        """Move the queued records into the file's buffer, in the order written (no system call until the
        buffer fills)."""
        q = self._queue
        if q:
            if self.error is None:
                pack, w = self._pack, self._f.write
                try:
                    for t_us, raw in q:
                        w(pack(t_us) + raw)
                except OSError as exc:
                    self._failed(exc, len(q))
            else:
                self.lost += len(q)
            q.clear()

    def _failed(self, exc: OSError, pending: int) -> None:
        """A write failed: keep what is in the file, write nothing more (a buffer the disk refused is dropped)."""
        self.error = f"{self.path}: {exc.strerror or exc}"
        self.lost += pending
        try:
            self._f.close()
        except OSError:  # the buffer it could not write: dropped
            pass

    def maybe_flush(self, now_monotonic: float | None = None) -> None:
        now = time.monotonic() if now_monotonic is None else now_monotonic
        if now >= self._next_flush:
            self.flush()
            self._next_flush = now + self.flush_interval_s

    def flush(self) -> None:
        self.drain()
        if self.error is None:
            try:
                self._f.flush()
            except OSError as exc:
                self._failed(exc, 0)

    def close(self) -> None:
        if not self._f.closed:
            self.flush()
            if self.error is None:
                try:
                    self._f.close()
                except OSError as exc:
                    self._failed(exc, 0)


def packet_length(buf, i: int = 0) -> int:
    """Length of the MAVLink packet starting at ``buf[i]`` from its header, or 0 if there is no valid start."""
    n = len(buf) - i
    if n < 3:
        return 0
    magic = buf[i]
    if magic == 0xFD:
        return 12 + buf[i + 1] + (13 if buf[i + 2] & 1 else 0)
    if magic == 0xFE:
        return 8 + buf[i + 1]
    return 0


def read_tlog(path: str):
    """Yield ``(t_us, raw_packet_bytes)`` for each complete record of a tlog; stops at a truncated tail."""
    with open(path, "rb") as f:
        data = f.read()
    i = 0
    n = len(data)
    while i + 8 + 3 <= n:
        (t_us,) = _TS.unpack_from(data, i)
        plen = packet_length(data, i + 8)
        if plen == 0 or i + 8 + plen > n:
            break
        yield t_us, data[i + 8 : i + 8 + plen]
        i += 8 + plen


def packet_ids(raw) -> tuple[int, int, int]:
    """(sysid, compid, msgid) from a raw packet's header."""
    if raw[0] == 0xFD:
        return raw[5], raw[6], raw[7] | (raw[8] << 8) | (raw[9] << 16)
    return raw[3], raw[4], raw[5]


def packet_payload(raw) -> bytes:
    """The message content without header sequence number, CRC or signature: msgid + payload bytes."""
    if raw[0] == 0xFD:
        plen = raw[1]
        return bytes(raw[7:10]) + bytes(raw[10 : 10 + plen])
    plen = raw[1]
    return bytes(raw[5:6]) + bytes(raw[6 : 6 + plen])


# Messages whose emission is driven by wall-clock timers (1 Hz heartbeats, status texts, sim-time
# announcements while waiting): their number and position depend on speed, so determinism
# comparisons leave them out.  Everything else in a lockstep run is driven by the frames.
# HEARTBEAT, SYS_STATUS, SYSTEM_TIME, STATUSTEXT, CURRENT_MODE (1 Hz to the ground stations)
WALL_CLOCK_MSG_IDS = frozenset({0, 1, 2, 253, 436})


def payload_streams(path: str, exclude=WALL_CLOCK_MSG_IDS) -> dict[tuple[int, int, int], list[bytes]]:
    """Per (sysid, compid, msgid): the ordered list of payloads (msgid + payload, no sequence number) in the
    tlog, consecutive equal payloads collapsed into one.  Every frame-driven message carries its frame's time,
    so equal neighbours are copies of one message: a lockstep resend, or the GCS copy of a SERVO_OUTPUT_RAW
    sent to the SITL.  Two deterministic lockstep runs give equal dicts."""
    streams: dict[tuple[int, int, int], list[bytes]] = {}
    for _t, raw in read_tlog(path):
        key = packet_ids(raw)
        if key[2] in exclude:
            continue
        payload = packet_payload(raw)
        lst = streams.setdefault(key, [])
        if not lst or lst[-1] != payload:
            lst.append(payload)
    return streams
