"""A flood from one local address never makes the link drop a real peer's datagram (``UdpLink.poll``).

Real loopback sockets and real pymavlink packets: a hostile socket sends well-formed MAVLink 2 packets with the
peer's IDs (so they fail only on their address: ``not_peer``) and some garbage, queued ahead of the real peer's
datagrams.  The admitted peer's datagrams are always fed; the others share the per-poll budget (``budget`` fed,
the rest ``over_budget``); a poll reads at most ``16 * budget`` and leaves the rest queued; and the counters add
up exactly: ``rx_datagrams == rx_accepted + sum(rejected)``.
"""

from __future__ import annotations

import socket
import time

import pytest

from autopilot.shared.link import UdpLink
from tests._mavlink_procs import mav, mavlink, pack, udp

PEER_IDS = (1, 200)
BUDGET = 64  # small, so the boundary is tight


def _link(kind: str, peer_addr) -> UdpLink:
    kw = {"pinned": {}, "learned": {"learn_remote": True}, "admitted": {"admit": 4}}[kind]
    remote = {"pinned": peer_addr, "learned": None, "admitted": ("127.0.0.1", 9)}[kind]  # admitted: a default
    return UdpLink(
        "t", (1, 1), ("127.0.0.1", 0), remote, peers=[PEER_IDS], msgids=[mavlink.MAVLINK_MSG_ID_ATTITUDE], **kw
    )


def _attitude(m, k: int) -> bytes:
    return pack(m, mavlink.MAVLink_attitude_message(k, 0.001 * k, 0, 0, 0, 0, 0))


def _garbage(valid: bytes) -> list[bytes]:
    """One datagram per reason checked before the address: empty, bad_magic, mavlink1, truncated, bad_crc."""
    flipped = bytearray(valid)
    flipped[12] ^= 0x01  # a payload bit: the CRC no longer matches
    return [b"", b"\x00garbage", b"\xfe\x05" + bytes(10), valid[:-3], bytes(flipped)]


GARBAGE_REASONS = ("empty", "bad_magic", "mavlink1", "truncated", "bad_crc")


def _drain(link: UdpLink, got: list, until: int, budget: int = BUDGET) -> list[int]:
    """Poll until ``until`` datagrams have been read in all (5 s at most); the number read by each poll."""
    reads = []
    t0 = time.monotonic()
    while link.rx_datagrams < until and time.monotonic() - t0 < 5:
        n = link.poll(lambda msg, t: got.append(msg.time_boot_ms), budget)
        if n:
            reads.append(n)
    return reads


def _adds_up(link: UdpLink) -> bool:
    return link.rx_datagrams == link.rx_accepted + sum(link.rejected.values())


@pytest.mark.parametrize("kind", ["pinned", "learned", "admitted"])
def test_flood_queued_ahead_of_the_peer_never_drops_its_datagrams(kind):
    """2,100 hostile datagrams in 14 rounds of 150, each queued ahead of 10 of the peer's: all 140 handled."""
    peer, hostile = udp(), udp()
    link = _link(kind, peer.getsockname())
    pm, hm = mav(*PEER_IDS), mav(*PEER_IDS)  # the hostile one spoofs the peer's IDs
    got: list = []
    sent, expected = 0, []
    if kind != "pinned":  # the peer talks first and becomes the (learned / admitted) peer
        peer.sendto(_attitude(pm, 0), link.local)
        sent, expected = 1, [0]
        _drain(link, got, sent)
        assert link.admitted == [peer.getsockname()]
    rounds, flood, real = 14, 150, 10
    for r in range(rounds):
        valid = [_attitude(hm, 10_000 + r * flood + i) for i in range(flood - len(GARBAGE_REASONS))]
        for d in _garbage(valid[0]) + valid:  # the garbage first, so it is within the budget and counted by reason
            hostile.sendto(d, link.local)
        for i in range(real):
            k = 1 + r * real + i
            peer.sendto(_attitude(pm, k), link.local)
            expected.append(k)
        sent += flood + real
        reads = _drain(link, got, sent)
        assert reads == [flood + real], reads  # one poll read the round: the flood was ahead of the peer in it
    assert got == expected  # every real datagram accepted and handled, in order; nothing from the hostile
    assert link.rx_datagrams == sent and link.rx_accepted == len(expected) and link.rx_packets == len(expected)
    fed = BUDGET - len(GARBAGE_REASONS)  # the hostile's valid packets fed per round
    assert link.rejected == {
        **{r: rounds for r in GARBAGE_REASONS},
        "not_peer": rounds * fed,
        "over_budget": rounds * (flood - BUDGET),
    }
    assert _adds_up(link)
    for s in (link, peer, hostile):
        s.close()


def test_budget_still_bounds_non_peers_and_the_read_cap_leaves_the_rest_queued():
    peer, hostile = udp(), udp()
    link = _link("pinned", peer.getsockname())
    pm, hm = mav(*PEER_IDS), mav(*PEER_IDS)
    got: list = []
    # exactly `budget` non-peer datagrams fed per poll, the rest over_budget; the peer's interleaved ones all fed
    for k in range(2):
        for i in range(100):
            hostile.sendto(_attitude(hm, 1000 + 100 * k + i), link.local)
        for i in range(5):
            peer.sendto(_attitude(pm, 5 * k + i), link.local)
    assert link.poll(lambda msg, t: got.append(msg.time_boot_ms), BUDGET) == 210
    assert got == list(range(10))
    assert link.rejected == {"not_peer": BUDGET, "over_budget": 200 - BUDGET} and _adds_up(link)
    assert link.poll(lambda msg, t: got.append(msg), BUDGET) == 0

    # the read cap: budget 8 reads at most 128 per poll; what is beyond waits in the socket, it is not lost
    for i in range(200):
        hostile.sendto(_attitude(hm, 2000 + i), link.local)
    for i in range(5):
        peer.sendto(_attitude(pm, 10 + i), link.local)
    before = dict(link.rejected)
    assert link.poll(lambda msg, t: got.append(msg.time_boot_ms), 8) == 128
    assert len(got) == 10 and link.rejected["not_peer"] - before["not_peer"] == 8
    assert link.rejected["over_budget"] - before["over_budget"] == 120 and _adds_up(link)
    assert link.poll(lambda msg, t: got.append(msg.time_boot_ms), 8) == 77  # 72 hostile (8 fed) + the 5 real
    assert got == list(range(15))
    assert link.rejected["not_peer"] - before["not_peer"] == 16
    assert link.rejected["over_budget"] - before["over_budget"] == 184
    assert link.rx_datagrams == 415 and link.rx_accepted == 15 and _adds_up(link)
    for s in (link, peer, hostile):
        s.close()


def test_one_burst_of_4000_ahead_of_the_peer_is_held_by_the_socket_and_read_over_several_polls():
    """The socket's 4 MiB receive buffer holds a burst a 1 MiB one could not (about 830 bytes of kernel memory
    per small datagram on loopback), so the kernel does not drop the peer's datagrams queued behind it."""
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
    granted = probe.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)  # Linux reports twice what it grants
    probe.close()
    if granted < 8 << 20:
        pytest.skip(f"net.core.rmem_max below 4 MiB (granted {granted // 2} B): the kernel caps the buffer")
    peer, hostile = udp(), udp()
    link = _link("pinned", peer.getsockname())
    pm, hm = mav(*PEER_IDS), mav(*PEER_IDS)
    hostile_bufs = [_attitude(hm, 10_000 + i) for i in range(4000)]
    for d in hostile_bufs:
        hostile.sendto(d, link.local)
    for i in range(20):
        peer.sendto(_attitude(pm, i), link.local)
    got: list = []
    reads = _drain(link, got, 4020)
    assert reads == [1024, 1024, 1024, 948]  # the read cap (16 * 64) per poll; the rest stayed queued
    assert got == list(range(20)) and link.rx_accepted == 20
    assert link.rejected == {"not_peer": 4 * BUDGET, "over_budget": 4000 - 4 * BUDGET} and _adds_up(link)
    for s in (link, peer, hostile):
        s.close()
