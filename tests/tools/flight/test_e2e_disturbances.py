"""Disturbances end to end: real SITL, autopilot and GCS processes over UDP, in lockstep (tools.flight.Flight)."""

from __future__ import annotations

import numpy as np
import pytest

from autopilot.shared.pwm import PwmMap
from tools.flight import Flight

pytestmark = pytest.mark.e2e

FAULTS = dict(loss=0.1, delay=0.03, duplicate=0.1, reorder=0.1, turbulence="light", roll_noise=0.2, gust="1.5,8,1")


def _fly(tmp_path, name, **kw):
    res = Flight(lockstep=True, duration=4.0, rrd=False, quiet=True, out=tmp_path / name, **kw).run()
    assert res.ok, res.reason
    with np.load(res.out / "sitl_series.npz") as s, np.load(res.out / "autopilot_series.npz") as a:
        return res, {k: s[k] for k in s.files}, {k: a[k] for k in a.files}


def test_fault_injected_lockstep_flight_repeats_bit_for_bit_per_seed(tmp_path):
    r1, s1, a1 = _fly(tmp_path, "a", seed=5, **FAULTS)
    r2, s2, a2 = _fly(tmp_path, "b", seed=5, **FAULTS)
    r3, s3, a3 = _fly(tmp_path, "c", seed=6, **FAULTS)
    for key in ("phi", "p", "r", "v", "delta_r", "u"):
        assert np.array_equal(s1[key], s2[key]), key
    for key in ("phi", "p", "u", "kie", "kx"):
        assert np.array_equal(a1[key], a2[key]), key
    assert not np.array_equal(s1["phi"], s3["phi"])
    inj1 = r1.summary["disturbances"]["injected"]
    assert inj1 == r2.summary["disturbances"]["injected"] != r3.summary["disturbances"]["injected"]
    # Every kind of fault happened, in both directions, and summary.json says how often.
    for direction in ("uplink", "downlink"):
        c = inj1[direction]
        assert c["sent"] >= 400 and c["lost"] > 0 and c["duplicated"] > 0 and c["reordered"] > 0
    assert r1.summary["disturbances"]["delay_frames"] == 3


def test_sensor_delay_and_bias_reach_the_autopilot_exactly(tmp_path):
    delay, bias_deg, rate_bias_deg = 3, 2.0, -5.0
    _res, s, a = _fly(tmp_path, "s", sensor_delay=delay, roll_bias=bias_deg, rate_bias=rate_bias_deg, profile="square")
    # Truth at frame j (t_j): the SITL's row j-1 is the state after frame j-1; the state at t_0 is zero.
    phi = np.concatenate([[0.0], s["phi"]])
    p = np.concatenate([[0.0], s["p"]])
    n = len(a["phi"])
    j = np.maximum(np.arange(n) - delay, 0)
    want_phi = (phi[j] + np.radians(bias_deg)).astype(np.float32).astype(float)  # float32 on the wire
    want_p = (p[j] + np.radians(rate_bias_deg)).astype(np.float32).astype(float)
    assert np.array_equal(a["phi"], want_phi)
    assert np.array_equal(a["p"], want_p)
    assert np.abs(phi[:n]).max() > 0.05  # the aircraft did move, so the delay is visible


def test_link_delay_is_whole_frames_of_sim_time_both_ways(tmp_path):
    """--delay 0.03 at 100 Hz: the autopilot sees the state of 3 frames ago, the SITL applies the command the
    autopilot sent 3 frames ago (neutral before the first one arrives)."""
    res, s, a = _fly(tmp_path, "d", delay=0.03)
    assert res.summary["disturbances"]["delay_frames"] == 3
    phi = np.concatenate([[0.0], s["phi"]])
    n = len(a["phi"])
    j = np.maximum(np.arange(n) - 3, 0)
    assert np.array_equal(a["phi"], phi[j].astype(np.float32).astype(float))
    pwm_map = PwmMap()  # the flight's servo calibration: 30 deg at full PWM, the default
    applied = np.array([pwm_map.to_rad(int(p)) for p in a["pwm"]])
    assert np.array_equal(s["u"][:3], np.zeros(3))
    assert np.array_equal(s["u"][3:], applied[: len(s["u"]) - 3])
    assert not np.array_equal(s["u"][2:], applied[: len(s["u"]) - 2])  # a 2-frame shift does not fit
    c = res.summary["disturbances"]["injected"]
    assert c["uplink"]["lost"] == c["downlink"]["lost"] == 0


def test_realtime_flight_with_link_faults(tmp_path):
    """Real time: the datagrams themselves are dropped, delayed (wall time), doubled and reordered; the flight
    still flies and summary.json counts what was injected."""
    res = Flight(
        duration=3.0, rrd=False, quiet=True, out=tmp_path / "rt", loss=0.1, delay=0.004, duplicate=0.1, reorder=0.1
    ).run()
    assert res.ok, res.reason
    inj = res.summary["disturbances"]["injected"]
    for direction in ("uplink", "downlink"):
        c = inj[direction]
        assert c["sent"] > 200 and c["lost"] > 0 and c["duplicated"] > 0 and c["reordered"] > 0
        assert c["delivered"] <= c["sent"] - c["lost"] + c["duplicated"]
    # The SITL sends only what the channel delivered (a send fails before the autopilot is known and after it
    # has gone), and the duplicated and overtaken ATTITUDEs reach the autopilot, which rejects them as stale.
    sitl_tx = res.summary["counters"]["sitl"]["tx_by_type"]["ATTITUDE"]
    assert 0 < sitl_tx <= inj["uplink"]["delivered"]
    assert sum(res.summary["counters"]["autopilot"]["sitl"]["rejected"].values()) > 0  # stale or replayed
    # Every servo command the channel delivered reached the SITL's loop: applied, or refused as stale (a duplicate,
    # or overtaken) or ahead of the autopilot's clock.
    ev = res.summary["events"]["sitl"]
    taken = ev.get("servo_applied", 0) + ev.get("stale_servo", 0) + ev.get("future_servo", 0)
    assert taken == inj["downlink"]["delivered"] and ev["servo_applied"] > 200, (ev, inj["downlink"])


@pytest.mark.parametrize("faults", [{"loss": 0.05}, {"duplicate": 0.05}])
def test_realtime_link_faults_without_a_delay_still_fly_every_delivered_command(tmp_path, faults):
    """With no ``--delay`` the channel delivers a servo command the moment it arrives: it was taken from the
    channel and dropped, so the SITL flew with the rudder at neutral, never moved, and the verdict said OK."""
    res = Flight(duration=3.0, rrd=False, quiet=True, out=tmp_path / "rt", seed=2, **faults).run()
    assert res.ok, res.reason
    ev, down = res.summary["events"]["sitl"], res.summary["disturbances"]["injected"]["downlink"]
    assert ev.get("servo_applied", 0) + ev.get("stale_servo", 0) == down["delivered"] > 250, (ev, down)
    assert np.max(np.abs(res.series["phi"])) > np.radians(5.0)  # the +10 deg step of the square wave was flown
