"""Long STATUSTEXTs in MAVLink 2 chunks (autopilot.shared.events): the wire fields, checked by decoding the real
packed bytes with pymavlink, and the reassembly on the receiving side.  (MAVProxy's own reassembly of the chunks
is exercised by tests/tools/test_clients.py with the real MAVProxy.)"""

from __future__ import annotations

from collections import Counter

import pytest

from autopilot.shared.events import (
    STATUSTEXT_LEN,
    STATUSTEXT_MAX_CHUNKS,
    StatusEvents,
    StatusTextAssembler,
    statustext_chunks,
)
from autopilot.shared.mavlink import mavlink

REASON = "CLSAC_AM=3 rejected: am must be Hurwitz (all eigenvalues in the open left half plane), got 3.0"


class WireLink:
    """Stands in for a UdpLink's ``send``: packs each message with pymavlink, as the link does, and decodes the bytes
    back, so the test sees what a receiver sees."""

    def __init__(self):
        self.mav = mavlink.MAVLink(None, 1, 1)
        self.decoder = mavlink.MAVLink(None, 255, 190)
        self.got = []

    def send(self, msg):
        self.got.append(self.decoder.decode(bytearray(msg.pack(self.mav))))


def _events() -> tuple[StatusEvents, WireLink]:
    link = WireLink()
    return StatusEvents("test", link, Counter(), verbose=False), link


@pytest.mark.parametrize("n", [0, 1, 49, 50])
def test_a_text_that_fits_is_one_statustext_with_id_0(n):
    ev, link = _events()
    ev(mavlink.MAV_SEVERITY_INFO, "x" * n)
    assert [(m.text, m.id, m.chunk_seq) for m in link.got] == [("x" * n, 0, 0)]


@pytest.mark.parametrize("n, chunks", [(51, 2), (99, 2), (100, 3), (101, 3), (150, 4), (200, 5)])
def test_a_long_text_is_chunked_with_one_id_and_a_short_last_chunk(n, chunks):
    text = "".join(chr(ord("a") + i % 26) for i in range(n))
    ev, link = _events()
    ev(mavlink.MAV_SEVERITY_WARNING, text)
    got = link.got
    assert len(got) == chunks  # ceil(n / 50), plus an empty end chunk when n is a multiple of 50
    assert {m.id for m in got} == {1} and [m.chunk_seq for m in got] == list(range(chunks))
    assert all(len(m.text) == STATUSTEXT_LEN for m in got[:-1]) and len(got[-1].text) < STATUSTEXT_LEN
    assert "".join(m.text for m in got) == text
    assert {m.severity for m in got} == {mavlink.MAV_SEVERITY_WARNING}


def test_each_chunked_text_has_its_own_non_zero_id():
    ev, link = _events()
    for _ in range(3):
        ev(mavlink.MAV_SEVERITY_WARNING, REASON)
    ev(mavlink.MAV_SEVERITY_INFO, "short")
    ids = [m.id for m in link.got]
    assert ids == [1, 1, 2, 2, 3, 3, 0]
    ev._last_id = 65535  # the uint16 wraps to 1, never to 0 ("the only chunk")
    ev(mavlink.MAV_SEVERITY_WARNING, REASON)
    assert link.got[-1].id == 1


def test_non_ascii_is_escaped_so_chunks_stay_50_characters():
    chunks = statustext_chunks("é" * 30, 7)  # 30 characters, 120 ASCII bytes as \xe9 escapes
    assert b"".join(c for c, _, _ in chunks) == b"\\xe9" * 30
    assert [len(c) for c, _, _ in chunks] == [50, 50, 20]


def test_a_text_beyond_the_chunk_limit_is_cut_with_its_end_marked():
    chunks = statustext_chunks("y" * 1000, 9)
    assert len(chunks) == STATUSTEXT_MAX_CHUNKS and len(chunks[-1][0]) == STATUSTEXT_LEN - 1


def test_assembler_reassembles_in_any_order_and_per_sender():
    ev, link = _events()
    ev(mavlink.MAV_SEVERITY_WARNING, REASON)
    first, last = link.got
    asm = StatusTextAssembler()
    assert asm.add(last) is None  # the end arrived first: the first chunk is still missing
    assert asm.add(first) == REASON
    assert asm.add(first) is None  # a new text with the same id starts over, it is not the old one again


def test_assembler_passes_id_0_texts_and_marks_a_lost_chunk():
    ev, link = _events()
    ev(mavlink.MAV_SEVERITY_INFO, "mode CLSAC")
    asm = StatusTextAssembler(max_pending=1)
    assert asm.add(link.got[0]) == "mode CLSAC"
    ev(mavlink.MAV_SEVERITY_WARNING, "z" * 120)  # 3 chunks: lose the middle one
    a, _, c = link.got[1:]
    ev(mavlink.MAV_SEVERITY_WARNING, REASON)
    d, e = link.got[4:]
    assert asm.add(a) is None and asm.add(c) is None
    assert asm.add(d) == "z" * 50 + " ... " + "z" * 20  # the abandoned text, its gap shown as MAVProxy shows it
    assert asm.add(e) == REASON
