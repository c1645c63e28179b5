"""The lockstep floor of ``python -m tools.bench mavlink``: a bare ATTITUDE -> SERVO_OUTPUT_RAW ping-pong
between two real processes really exchanges decodable packets and measures a positive rate (a few seconds)."""

from __future__ import annotations

import pytest

from tools.bench.mavlink import lockstep_floor

pytestmark = pytest.mark.e2e  # real processes over loopback UDP


def test_floor_ping_pong_between_two_processes():
    r = lockstep_floor(seconds=0.3, runs=2, warmup_s=0.1)
    assert r["round_trips_per_s"] > 0 and len(r["runs"]) == 2 and all(x > 0 for x in r["runs"])
    assert r["rtf_100hz"] == r["round_trips_per_s"] / 100.0 and r["rtf_400hz"] == r["round_trips_per_s"] / 400.0
    n = r["frames"]
    assert n > 10
    sitl, ap = r["sitl_link"], r["autopilot_link"]
    # both packets decoded on the other side, nothing rejected (a resend after a loss is allowed, not expected)
    assert sitl["tx_by_type"]["ATTITUDE"] == n + r["resends"] >= ap["rx_by_type"]["ATTITUDE"] >= n
    assert ap["tx_by_type"]["SERVO_OUTPUT_RAW"] >= sitl["rx_by_type"]["SERVO_OUTPUT_RAW"] >= n
    assert sitl["rejected"] == {} and ap["rejected"] == {}
    # each answer carried its frame's time_usec and the neutral pulse on the rudder channel
    assert r["stale"] <= r["resends"] and r["wrong_value"] == 0
