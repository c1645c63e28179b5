"""Status events: whatever text reaches a process's event reporter is printed, logged and sent printable."""

from __future__ import annotations

import io
import socket
from collections import Counter

from autopilot.shared.events import StatusEvents, printable
from autopilot.shared.link import UdpLink
from autopilot.shared.mavlink import mavlink


def test_a_quoted_peer_text_cannot_inject_escape_codes_or_lines():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(2.0)
    link = UdpLink("gcs", (1, 1), ("127.0.0.1", 0), rx.getsockname(), peers=[(255, 190)], msgids=[])
    out, seen = io.StringIO(), []
    events = StatusEvents("autopilot", link, Counter(), out=out)
    events.hooks.append(lambda sev, text: seen.append(text))
    evil = "CLSAC_\x1b[2J\x1b[31mX\nautopilot: FAKE LINE\x00"
    events(mavlink.MAV_SEVERITY_WARNING, f"{evil}=3 rejected")
    printed = out.getvalue()
    assert printed.count("\n") == 1 and "\x1b" not in printed and "\x00" not in printed
    assert "\\x1b[2J" in printed and "\\nautopilot: FAKE LINE" in printed
    assert seen == [printable(f"{evil}=3 rejected")] and seen[0].isprintable()
    data = rx.recv(4096)
    mav = mavlink.MAVLink(None)
    msg = mav.decode(bytearray(data))
    assert msg.get_type() == "STATUSTEXT" and "\x1b" not in msg.text and "\n" not in msg.text
    link.close()
    rx.close()
