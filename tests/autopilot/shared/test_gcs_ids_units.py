"""The GCS link's id rules in-process (autopilot.shared.link.UdpLink.feed with real pymavlink-packed bytes): which
systems a MAV_TYPE_GCS heartbeat adds, the bounds on learning, counting and reporting, and the heartbeat type read
from a MAVLink 2 payload whose trailing zeros are trimmed."""

from __future__ import annotations

import os
import socket
import time

import pytest

from autopilot.shared.link import (
    ANY_COMPONENT,
    REFUSED_GCS_KEYS,
    REFUSED_GCS_REPORTS,
    UdpLink,
    heartbeat_type,
    looks_like_gcs,
)
from autopilot.shared.mavlink import GCS_SYSTEMS, mavlink

M = mavlink
ADDR = ("127.0.0.1", 40000)


def _link(learn: int = 8) -> UdpLink:
    return UdpLink(
        "gcs",
        (1, 1),
        ("127.0.0.1", 0),
        ("127.0.0.1", 9),
        peers=[(s, ANY_COMPONENT) for s in GCS_SYSTEMS],
        msgids=[M.MAVLINK_MSG_ID_HEARTBEAT, M.MAVLINK_MSG_ID_PARAM_REQUEST_READ],
        admit=8,
        learn_gcs=learn,
        gcs_systems=GCS_SYSTEMS,
    )


def _hb(sysid: int, compid: int = 190, mav_type: int = M.MAV_TYPE_GCS) -> bytes:
    msg = M.MAVLink_heartbeat_message(mav_type, M.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)
    return msg.pack(M.MAVLink(None, sysid, compid))


def _read(sysid: int, compid: int = 190) -> bytes:
    return M.MAVLink_param_request_read_message(1, 1, b"CLSAC_LV", -1).pack(M.MAVLink(None, sysid, compid))


def _feed(link: UdpLink, data: bytes, addr=ADDR) -> list:
    got = []
    link.feed(data, addr, lambda m, t: got.append(m))
    return got


def test_heartbeat_type_from_a_trimmed_payload():
    assert heartbeat_type(_hb(7, mav_type=M.MAV_TYPE_GCS)) == 6
    # custom_mode 0 and every field after type 0: MAVLink 2 trims the payload to its last non-zero byte
    trimmed = M.MAVLink_heartbeat_message(0, 0, 0, 0, 0, 0).pack(M.MAVLink(None, 7, 190))
    assert trimmed[1] < 5 and heartbeat_type(trimmed) == 0


def test_looks_like_gcs():
    assert looks_like_gcs(_hb(9, 1), 9, 1)  # a GCS heartbeat, whatever its ids
    assert looks_like_gcs(_read(245, 1), 245, 1, GCS_SYSTEMS) and looks_like_gcs(_read(9, 190), 9, 190)
    assert not looks_like_gcs(_hb(9, 191, M.MAV_TYPE_ONBOARD_CONTROLLER), 9, 191, GCS_SYSTEMS)


def test_a_gcs_heartbeat_adds_its_system_with_any_component_up_to_the_bound():
    link = _link(learn=2)
    assert _feed(link, _read(42)) == [] and link.rejected["wrong_id"] == 1
    assert len(_feed(link, _hb(42))) == 1 and link.learned_systems == [42]
    assert len(_feed(link, _read(42, 7))) == 1  # any component of a learned system
    assert _feed(link, _hb(1)) == [] and _feed(link, _hb(0)) == []  # never the vehicle's own system or broadcast
    assert _feed(link, _hb(43, mav_type=M.MAV_TYPE_ONBOARD_CONTROLLER)) == []  # only a GCS heartbeat
    assert len(_feed(link, _hb(43))) == 1
    assert _feed(link, _hb(44)) == [] and link.learned_systems == [42, 43]  # the third is over learn_gcs=2
    c = link.counters()
    assert c["rx_datagrams"] == c["rx_accepted"] + sum(c["rejected"].values())  # still one count per datagram


def test_learning_off_without_learn_gcs():
    link = _link(learn=0)
    assert _feed(link, _hb(42)) == [] and link.learned_systems == []
    assert "learned_gcs_systems" not in link.counters()


def test_refusals_are_counted_by_source_in_bounded_memory_and_reported_a_bounded_number_of_times():
    link = _link(learn=0)
    calls = []
    link.on_refused_gcs = lambda *a: calls.append(a)
    for s in range(2, 2 + 2 * REFUSED_GCS_KEYS):
        for _ in range(3):
            _feed(link, _read(s))
    assert len(link.refused_gcs) == REFUSED_GCS_KEYS + 1  # the first 64 sources, then one shared counter
    assert link.refused_gcs[("wrong_id", -1, -1)] == 3 * REFUSED_GCS_KEYS
    assert sum(link.refused_gcs.values()) == link.rejected["wrong_id"] == 6 * REFUSED_GCS_KEYS
    assert len(calls) == REFUSED_GCS_REPORTS and calls[0] == ("wrong_id", 2, 190, ADDR)


def test_refusal_text_names_the_reason_and_the_way_in():
    from autopilot.loop import AutopilotOptions, refusal_text

    default, narrowed = AutopilotOptions(), AutopilotOptions(gcs_ids=((255, 190),), learn_gcs=False)
    signed = AutopilotOptions(signing_key=b"k" * 32)
    head = "GCS 42:190 at 127.0.0.1:40000 refused: "
    cases = [
        ("wrong_id", default, "system 42 is not a ground station's (255, 245) and sent no MAV_TYPE_GCS HEARTBEAT"),
        ("wrong_id", narrowed, "not one of the accepted --gcs-id 255:190"),
        ("not_peer", default, "its address is not admitted (add it with --gcs-peer, or sign"),
        ("not_peer", signed, "its address is not admitted: 8 ground stations are already"),
        ("unsigned", signed, "unsigned; this vehicle takes only packets signed with its key"),
        ("bad_signature", signed, "signed with another key"),
    ]
    for reason, opts, why in cases:
        text = refusal_text(reason, 42, 190, ADDR, opts)
        assert text.startswith(head + why), text


# ------------------------------------------------------------------------------------ the admission cap (8)
def _signed_packet(key: bytes, port: int) -> tuple[socket.socket, bytes]:
    m = M.MAVLink(None, 255, 230)
    m.signing.secret_key, m.signing.link_id, m.signing.sign_outgoing = key, 1, True
    m.signing.timestamp = int((time.time() - 1420070400) * 1e5)
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    return s, M.MAVLink_heartbeat_message(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3).pack(m)


@pytest.mark.parametrize("fixed", [0, 1])
def test_exactly_eight_ground_stations_are_admitted_the_ninth_is_not_peer(fixed):
    """Real sockets, real MAVLink 2 signatures: with ``admit=8`` (``fixed`` of them listed peers), the eighth
    address is admitted, the ninth is refused ``not_peer`` (mutation: ``>=`` -> ``>`` in the cap, which admits 9)."""
    from autopilot.shared.link import UdpLink
    from autopilot.shared.signing import SIGNING_LINK_GCS, Signing

    key = os.urandom(32)
    socks = [_signed_packet(key, 0) for _ in range(9)]
    listed = [s.getsockname() for s, _ in socks[:fixed]]
    link = UdpLink(
        "gcs",
        (1, 1),
        ("127.0.0.1", 0),
        ("127.0.0.1", 9),
        peers=[(255, None)],
        msgids=[M.MAVLINK_MSG_ID_HEARTBEAT],
        admit=8,
        peer_addrs=listed,
        signing=Signing(key, SIGNING_LINK_GCS),
    )
    try:
        for s, pkt in socks:
            s.sendto(pkt, link.local)
        got = 0
        t0 = time.monotonic()
        while link.rx_datagrams < 9 and time.monotonic() - t0 < 5:
            got += link.poll(lambda msg, t: None)
        assert len(link.admitted) == 8 and socks[8][0].getsockname() not in link.admitted
        assert link.rejected == {"not_peer": 1} and link.rx_accepted == 8
    finally:
        link.close()
        for s, _ in socks:
            s.close()
