"""Status events of a process: counted, printed, sent to a peer as STATUSTEXT and handed to hooks.

A text longer than one STATUSTEXT (50 bytes) goes out in chunks, as MAVLink 2 specifies (common.xml, STATUSTEXT
``id`` and ``chunk_seq``): 50-byte chunks sharing one non-zero ``id``, ``chunk_seq`` 0..n-1, the end marked by a
chunk shorter than 50 bytes (an empty one after a last chunk of exactly 50).  A text that fits is one STATUSTEXT
with ``id`` 0, "the only chunk".  This is what MAVProxy's reassembly (``mavproxy_link.PendingText``) and
QGroundControl expect; :class:`StatusTextAssembler` reassembles on the receiving side.
"""

from __future__ import annotations

import sys
import time
from collections import Counter

from autopilot.shared.mavlink import mavlink

STATUSTEXT_LEN = 50  # STATUSTEXT.text is char[50]
STATUSTEXT_MAX_CHUNKS = 8  # a text is sent as at most this many chunks (400 bytes; printable() caps at 200 chars)
# Events of one kind that a peer can cause at will (a refused PARAM_SET, a mode change): the first EVENT_BURST are
# said one by one, the rest counted and said as one summary line per EVENT_SUMMARY_S; a kind quiet for a whole
# EVENT_SUMMARY_S is said one by one again.
EVENT_BURST = 5
EVENT_SUMMARY_S = 10.0
_ID_WRAP = 1 << 16  # STATUSTEXT.id is uint16; 0 means "the only chunk"


def printable(text) -> str:
    """A peer's text (STATUSTEXT, bytes or str) made safe to log, print and forward: every control or
    non-printable character (escape codes, newlines, NUL) becomes ``\\xNN`` / ``\\uNNNN``, at most 200 characters."""
    if isinstance(text, (bytes, bytearray)):
        text = bytes(text).split(b"\0", 1)[0].decode("utf-8", "replace")
    text = str(text)[:200]
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else ascii(c)[1:-1] for c in text)


def statustext_chunks(text: str, text_id: int) -> list[tuple[bytes, int, int]]:
    """The (text bytes, id, chunk_seq) of each STATUSTEXT that carries ``text``.

    The wire text is ASCII (anything else as ``\\xNN`` escapes), so every chunk but the last is exactly 50
    characters for a receiver that counts characters (MAVProxy: ``len(m.text) != 50`` ends a text).  A text of at
    most 50 bytes is one chunk with id 0; a longer one is chunked under ``text_id`` (1..65535), ending with a chunk
    shorter than 50 bytes: an empty one when the text is a whole number of chunks.  At most STATUSTEXT_MAX_CHUNKS
    chunks: the rest of a longer text is cut."""
    data = text.encode("ascii", "backslashreplace")
    n = STATUSTEXT_LEN
    if len(data) <= n:
        return [(data, 0, 0)]
    if not 0 < text_id < _ID_WRAP:
        raise ValueError(f"a chunked STATUSTEXT needs an id 1..65535, got {text_id}")
    data = data[: n * STATUSTEXT_MAX_CHUNKS - 1]  # the last chunk is then shorter than 50: the end is marked
    parts = [data[i : i + n] for i in range(0, len(data), n)]
    if len(parts[-1]) == n:
        parts.append(b"")
    return [(p, text_id, seq) for seq, p in enumerate(parts)]


class StatusTextAssembler:
    """Reassembles chunked STATUSTEXTs: ``add(msg)`` returns the whole text when ``msg`` completes one, else None.

    Chunks are keyed by the sender's (system, component) and ``id``; ``id`` 0 is a whole text.  A text is complete
    when a chunk shorter than 50 bytes has arrived and every chunk before it; a missing chunk shows as `` ... ``
    (as MAVProxy shows it) once a later text from the same sender completes or ``max_pending`` texts are open."""

    def __init__(self, max_pending: int = 16):
        self.max_pending = max_pending
        self._pending: dict = {}  # (sysid, compid, id) -> {chunk_seq: bytes, "end": last seq or None}

    def add(self, msg) -> str | None:
        text = msg.text.encode("utf-8") if isinstance(msg.text, str) else bytes(msg.text).split(b"\0", 1)[0]
        text_id = getattr(msg, "id", 0) if hasattr(msg, "chunk_seq") else 0  # MAVLink 1 has no extensions
        if text_id == 0:
            return printable(text)
        key = (msg.get_srcSystem(), msg.get_srcComponent(), text_id)
        parts = self._pending.setdefault(key, {})
        parts[msg.chunk_seq] = text
        if len(text) < STATUSTEXT_LEN:
            parts["end"] = msg.chunk_seq
        end = parts.get("end")
        if end is not None and all(k in parts for k in range(end + 1)):
            del self._pending[key]
            return printable(b"".join(parts[k] for k in range(end + 1)))
        if len(self._pending) > self.max_pending:  # an abandoned text: emit what arrived, gaps marked
            old = next(iter(self._pending))
            got = self._pending.pop(old)
            seqs = sorted(k for k in got if k != "end")
            return " ... ".join(printable(got[k]) for k in seqs)
        return None


class StatusEvents:
    """``events(severity, text)``: one status event of process ``who``.

    The text is made printable first (``printable``).  Counted in ``counter["statustext"]``, printed as
    ``who: text`` when ``verbose``, sent through ``link`` (an ``autopilot.shared.link.UdpLink``) as STATUSTEXT
    (chunked when longer than 50 bytes: ``statustext_chunks``) unless ``send=False``, and handed to every ``hooks``
    callable as ``(severity, text)``.

    ``kind`` names events a peer can cause as often as it likes (``"param_rejected"``): of those, the first
    ``EVENT_BURST`` go out one by one, the rest are counted (``counter["events_summarised"]``) and said as one line
    per ``EVENT_SUMMARY_S``, ``N more <kind> events in the last 10 s (the last: ...)``, by the next event of the kind
    or by ``tick(now)`` (the owner's housekeeping), so a ground station flooding refused requests costs a line
    every ten seconds, not one per request.  A kind quiet for ``EVENT_SUMMARY_S`` starts again one by one.
    """

    def __init__(self, who: str, link, counter: Counter, *, verbose: bool = True, out=None):
        self.who = who
        self.link = link
        self.counter = counter
        self.verbose = verbose
        self.out = out or sys.stdout
        self.hooks: list = []
        self._last_id = 0  # the id of the last chunked text (1..65535, then round again)
        self._kinds: dict = {}  # kind -> [shown, last event time, held back, first held back time, severity, text]

    def __call__(self, severity: int, text: str, send: bool = True, kind: str | None = None) -> None:
        # Texts may quote a peer (a parameter name, a relayed STATUSTEXT): made printable here, once, for every path.
        text = printable(text)
        if kind is not None and not self._one_by_one(kind, severity, text, time.monotonic()):
            return
        self._say(severity, text, send)

    def _say(self, severity: int, text: str, send: bool = True) -> None:
        self.counter["statustext"] += 1
        if self.verbose:
            print(f"{self.who}: {text}", file=self.out, flush=True)
        if send:
            self._send(severity, text)
        for h in self.hooks:
            h(severity, text)

    def _one_by_one(self, kind: str, severity: int, text: str, now: float) -> bool:
        """Whether this event of ``kind`` is said by itself (else it is held back for the kind's summary)."""
        k = self._kinds.get(kind)
        if k is None:
            k = self._kinds[kind] = [0, now, 0, now, severity, text]
        elif now - k[1] >= EVENT_SUMMARY_S and not k[2]:
            k[0] = 0  # quiet for a whole interval: one by one again
        k[1] = now
        if k[0] < EVENT_BURST:
            k[0] += 1
            return True
        if not k[2]:
            k[3] = now
        k[2] += 1
        k[4], k[5] = severity, text
        self.counter["events_summarised"] += 1
        self.tick(now, kind)
        return False

    def tick(self, now: float | None = None, only: str | None = None, *, flush: bool = False) -> None:
        """Say the summary of every kind (or of ``only``) whose held-back events are ``EVENT_SUMMARY_S`` old
        (``flush``: whatever their age, at the end of the run)."""
        now = time.monotonic() if now is None else now
        for kind, k in self._kinds.items():
            if k[2] and (flush or now - k[3] >= EVENT_SUMMARY_S) and (only is None or kind == only):
                n, severity, text = k[2], k[4], k[5]
                k[2] = 0
                self._say(severity, f"{n} more {kind} events in the last {now - k[3]:.0f} s (the last: {text})")

    def _send(self, severity: int, text: str) -> None:
        candidate = self._last_id % (_ID_WRAP - 1) + 1  # 1..65535, never 0; taken only by a chunked text
        chunks = statustext_chunks(text, candidate)
        if chunks[0][1]:
            self._last_id = candidate
        for data, text_id, seq in chunks:
            self.link.send(mavlink.MAVLink_statustext_message(severity, data, text_id, seq))
