"""The autopilot as a MAVLink vehicle in lockstep flights: a CLSAC_LV change mid-flight, bit for bit, and a launch
with MAVProxy's set-up (a second ground station on a --gcs-peer port).  Lockstep numbers do not depend on the wall
clock, so these run in the parallel phase; the real-time vehicle is in test_vehicle.py (its ground station and
helpers are used here), which runs alone (tests/conftest.py).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_vehicle import A, Gcs, _start_autopilot

from autopilot.shared.tlog import payload_streams
from autopilot.vehicle import Mode
from tests._mavlink_procs import Proc, free_ports

pytestmark = pytest.mark.e2e


def test_lockstep_lv_change_mid_flight_is_deterministic(tmp_path):
    """CLSAC_LV 20 -> 50 at t = 10 s of a lockstep flight: lower rudder energy afterwards than keeping 20;
    the same flight twice gives the same command sequence bit for bit."""
    a = _lockstep_flight(tmp_path / "a", change=True)
    b = _lockstep_flight(tmp_path / "b", change=True)
    c = _lockstep_flight(tmp_path / "c", change=False)
    assert np.array_equal(a["u"], b["u"])
    k = 1000
    # identical until the change, and the first step after it flies the very same command (no jump: the law keeps
    # its states, a new Lv acts through the reference model from the next step on); different from then on
    assert np.array_equal(a["u"][: k + 1], c["u"][: k + 1])
    assert not np.array_equal(a["u"][k + 1 :], c["u"][k + 1 :])
    energy = lambda s: float(np.sum(s["u"][k:] ** 2) * 0.01)  # noqa: E731
    assert energy(a) < 0.9 * energy(c), (energy(a), energy(c))


def _lockstep_flight(d, change: bool) -> dict:
    """Lockstep: the test is the ground station and schedules the setpoints (a +-10 deg square, period 4 s), so
    the autopilot waits at t = 10 s until the parameter is set: the change lands on frame 1000 every time."""
    d.mkdir()
    sitl_port, port = free_ports(2)
    sitl = Proc("sitl", ["--listen", f"127.0.0.1:{sitl_port}", "--lockstep", "--duration", "20"], d / "sitl.log")
    assert sitl.wait_for("sitl: listening", 30)
    gcs = Gcs(port)
    series = d / "series.npz"
    ap = _start_autopilot(
        d, "autopilot", port, "--lockstep", "--duration", "20", "--series", str(series), sitl_port=sitl_port
    )
    try:
        gcs.connect()

        def schedule(t0, t1):  # a point every 100 ms and one at t1 - 10 ms: the horizon reaches the last frame
            for ms in [*range(t0, t1, 100), t1 - 10]:
                deg = 10.0 if (ms // 2000) % 2 == 0 else -10.0
                q = [math.cos(math.radians(deg) / 2), math.sin(math.radians(deg) / 2), 0.0, 0.0]
                gcs.mav.set_attitude_target_send(ms, 1, 1, 71, q, 0, 0, 0, 0)

        gcs.wait("SYSTEM_TIME", timeout=30)  # the first frame waits for a schedule: sim time is known
        schedule(0, 10000)  # up to 9.99 s: frame 1000 (t = 10 s) waits for the schedule
        gcs.wait("SYSTEM_TIME", timeout=30, cond=lambda m: m.time_boot_ms == 10000)
        if change:
            gcs.mav.param_set_send(1, 1, b"CLSAC_LV", 50.0, A.MAV_PARAM_TYPE_REAL32)
            assert gcs.wait("PARAM_VALUE", cond=lambda m: m.param_id == "CLSAC_LV").param_value == 50.0
        schedule(10000, 20000)  # (at most 10 s ahead of sim time)
        assert ap.p.wait(60) == 0
    finally:
        gcs.close()
        ap.stop()
        sitl.stop()
    return dict(np.load(series))


def test_launcher_png_events_and_a_second_ground_station(tmp_path):
    """A launch (lockstep) with MAVProxy's set-up: unsigned, a ground station on a --gcs-peer port gets the
    stream and its answers; flight.png is drawn; the rrd summary lists the event log."""
    from tools import rrd
    from tools.flight import Flight, FlightConfigError

    with pytest.raises(FlightConfigError, match="gcs_peer"):
        Flight(gcs_peer=("nowhere",))
    port = free_ports(1)[0]
    gcs = Gcs(port)
    out = tmp_path / "flight"
    try:
        with Flight(lockstep=True, duration=20, out=out, signing=False, gcs_peer=(f"127.0.0.1:{port}",)) as flight:
            hb = gcs.wait("HEARTBEAT", timeout=30)
            assert hb.custom_mode == Mode.CLSAC and gcs.wait("ATTITUDE")
            gcs.mav.param_request_read_send(1, 1, b"CLSAC_LV", -1)
            assert gcs.wait("PARAM_VALUE", cond=lambda m: m.param_id == "CLSAC_LV").param_value == 20.0
            res = flight.wait(timeout=120)
    finally:
        gcs.close()
    assert res is not None and res.ok, res
    png = out / "flight.png"
    assert res.summary["files"]["png"] == str(png) and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = rrd.summary(out / "flight.rrd")
    assert "/autopilot/events" in text and "events:" in text
    # the autopilot's two links have their own component: the servo stream to the SITL (1:140) and its copy to the
    # ground stations (1:1) are told apart in the tlog
    streams = payload_streams(str(out / "flight.tlog"))
    servo = A.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW
    assert len(streams[(1, 140, servo)]) == 2000 and 0 < len(streams[(1, 1, servo)]) < 2000
