"""Status events of a process: counted, printed, sent to a peer as STATUSTEXT and handed to hooks."""

from __future__ import annotations

import sys
from collections import Counter

from autopilot.shared.mavlink import mavlink

STATUSTEXT_LEN = 50  # STATUSTEXT.text is char[50]


def printable(text) -> str:
    """A peer's text (STATUSTEXT, bytes or str) made safe to log, print and forward: every control or
    non-printable character (escape codes, newlines, NUL) becomes ``\\xNN`` / ``\\uNNNN``, at most 200 characters."""
    if isinstance(text, (bytes, bytearray)):
        text = bytes(text).split(b"\0", 1)[0].decode("utf-8", "replace")
    text = str(text)[:200]
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else ascii(c)[1:-1] for c in text)


class StatusEvents:
    """``events(severity, text)``: one status event of process ``who``.

    The text is made printable first (``printable``).  Counted in ``counter["statustext"]``, printed as
    ``who: text`` when ``verbose``, sent through ``link`` (an ``autopilot.shared.link.UdpLink``) as STATUSTEXT
    truncated to 50 bytes unless ``send=False``, and handed to every ``hooks`` callable as ``(severity, text)``.
    """

    def __init__(self, who: str, link, counter: Counter, *, verbose: bool = True, out=None):
        self.who = who
        self.link = link
        self.counter = counter
        self.verbose = verbose
        self.out = out or sys.stdout
        self.hooks: list = []

    def __call__(self, severity: int, text: str, send: bool = True) -> None:
        # Texts may quote a peer (a parameter name, a relayed STATUSTEXT): made printable here, once, for every path.
        text = printable(text)
        self.counter["statustext"] += 1
        if self.verbose:
            print(f"{self.who}: {text}", file=self.out, flush=True)
        if send:
            self.link.send(mavlink.MAVLink_statustext_message(severity, text.encode("utf-8")[:STATUSTEXT_LEN], 0, 0))
        for h in self.hooks:
            h(severity, text)
