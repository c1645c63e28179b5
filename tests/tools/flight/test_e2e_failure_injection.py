"""Faults from a ground station in a launched flight (issue 29's must-show), the real processes end to end.

A pymavlink ground station on ``--gcs-peer`` sends MAV_CMD_INJECT_FAILURE (servo, stuck) while the flight flies: with
``--failure-injection`` it gets MAV_RESULT_ACCEPTED and the fault is in summary.json (source "ground station", the
time the SITL applied it); without, MAV_RESULT_DENIED and no fault.  The same in a lockstep flight, which a ground
station joins as it flies, and the rudder the SITL flew stands still from the fault on.
"""

from __future__ import annotations

import math
import os
import struct
import subprocess
import sys
import time

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import common as M  # noqa: E402

from autopilot.shared.events import StatusTextAssembler  # noqa: E402
from tests._mavlink_procs import free_ports, load_json  # noqa: E402

pytestmark = pytest.mark.e2e
NAN = float("nan")


def _inject_during_flight(tmp_path, *flags, wait_s: float = 3.0, param5: float = NAN):
    """Launch a flight streaming to a pymavlink ground station (255:230), send INJECT_FAILURE servo stuck once the
    vehicle has flown ``wait_s`` s of its own clock, return (COMMAND_ACK result, its wall delay, summary, out)."""
    port = free_ports(1)[0]
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255, source_component=230)
    out = tmp_path / "run"
    launch = subprocess.Popen(
        [sys.executable, "-m", "tools.launch", "--no-signing", "--gcs-peer", f"127.0.0.1:{port}", "--out", str(out)]
        + ["--no-rrd", "--no-png", "--quiet", *flags],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        stdin=subprocess.DEVNULL,
    )
    result = delay = None
    try:
        t_end = time.monotonic() + 60
        while time.monotonic() < t_end:  # the vehicle's clock (ATTITUDE.time_boot_ms = sim time) past wait_s
            m = gcs.recv_match(type="ATTITUDE", blocking=True, timeout=0.5)
            if m is not None and m.get_srcSystem() == 1 and m.time_boot_ms >= wait_s * 1000:
                break
        gcs.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        t0 = time.monotonic()
        gcs.mav.command_long_send(
            1, 1, M.MAV_CMD_INJECT_FAILURE, 0, 102, M.FAILURE_TYPE_STUCK, 4, NAN, param5, NAN, NAN
        )
        while time.monotonic() < t0 + 5:
            m = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.5)
            if m is not None and m.command == M.MAV_CMD_INJECT_FAILURE and m.target_component == 230:
                result, delay = m.result, time.monotonic() - t0
                break
    finally:
        code = launch.wait(120)
        gcs.close()
    summary = load_json(out / "summary.json")
    # 3: a stuck rudder rolls the airframe out of its envelope; 1 on a loaded machine: a few real-time steps came late
    # (a plain flight fails the same way there), the flight still flew to its end
    assert code in (0, 1, 3) and summary["flown"]["fraction"] > 0.95, (code, summary.get("error"))
    return result, delay, summary, out


def test_real_time_with_failure_injection_the_stuck_servo_is_accepted_and_recorded(tmp_path):
    result, delay, summary, out = _inject_during_flight(tmp_path, "--duration", "15", "--failure-injection")
    assert result == M.MAV_RESULT_ACCEPTED and delay < 1.0, (result, delay)
    faults = [f for f in summary["faults"] if f["source"] == "ground station"]
    assert len(faults) == 1, summary["faults"]
    f = faults[0]
    assert f["kind"] == "stuck" and f["end"] is None
    assert 3.0 <= f["start"] < 6.0, f  # sim time: after the 3 s the station waited, within a couple of seconds
    assert summary["failure_injection"] is True
    ap = load_json(out / "autopilot.json")
    assert [r["result"] for r in ap["failure_injections"]] == ["ACCEPTED"]


def test_real_time_without_failure_injection_the_command_is_denied_and_nothing_recorded(tmp_path):
    result, _delay, summary, out = _inject_during_flight(tmp_path, "--duration", "15")
    assert result == M.MAV_RESULT_DENIED
    assert not [f for f in summary.get("faults") or [] if f["source"] == "ground station"], summary["faults"]
    assert summary["controlled"]["ok"] is True and summary["failure_injection"] is False  # flown as without it
    assert load_json(out / "autopilot.json")["failure_injections"] == []


def test_lockstep_a_ground_station_joins_and_the_rudder_stays_where_it_jammed(tmp_path):
    result, _delay, summary, out = _inject_during_flight(
        tmp_path, "--lockstep", "--duration", "60", "--failure-injection", wait_s=5.0, param5=5.0
    )
    assert result == M.MAV_RESULT_ACCEPTED
    faults = [f for f in summary["faults"] if f["source"] == "ground station"]
    assert len(faults) == 1 and faults[0]["kind"] == "stuck", summary["faults"]
    start = faults[0]["start"]
    assert faults[0]["value"] == pytest.approx(math.radians(5.0))
    s = np.load(out / "sitl_series.npz")
    after = s["t"] > start + 0.1
    assert after.sum() > 100
    # the surface the SITL flew (delta_r, its state) sits at 5 deg from the fault on, whatever the law commands
    assert np.allclose(s["delta_r"][after], math.radians(5.0), atol=1e-6), s["delta_r"][after][:5]
    assert np.ptp(s["u"][after]) > math.radians(1.0)  # the law did go on commanding it


def _set_failure_en(gcs, value: int) -> None:
    """SYS_FAILURE_EN as MAVSDK's set_param_int sends it: INT32, the integer's bytes in the float (bytewise)."""
    raw = struct.unpack("<f", struct.pack("<i", value))[0]
    gcs.mav.param_set_send(1, 1, b"SYS_FAILURE_EN", raw, M.MAV_PARAM_TYPE_INT32)
    t_end = time.monotonic() + 5
    while time.monotonic() < t_end:
        m = gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
        if m is not None and m.param_id == "SYS_FAILURE_EN" and m.param_value == raw:
            assert m.param_type == M.MAV_PARAM_TYPE_INT32
            return
    raise AssertionError(f"no PARAM_VALUE SYS_FAILURE_EN {value}")


def test_a_ground_station_out_of_bounds_is_denied_and_it_clears_its_faults_with_injection_off(tmp_path):
    """Issue 35's must-show: STUCK at 1e30, at NaN (params 6 and 7 set) and at 45 deg on the KH2013A's +-30 deg rudder
    are DENIED (the SITL says why); after SYS_FAILURE_EN goes back to 0, a clear is accepted on instance 0 and 4, and no
    fault is left."""
    port = free_ports(1)[0]
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255, source_component=230)
    out = tmp_path / "run"
    launch = subprocess.Popen(
        [sys.executable, "-m", "tools.launch", "--no-signing", "--gcs-peer", f"127.0.0.1:{port}", "--out", str(out)]
        + ["--no-rrd", "--no-png", "--quiet", "--lockstep", "--duration", "40"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        stdin=subprocess.DEVNULL,
    )
    texts: list[str] = []
    chunks = StatusTextAssembler()

    def text(m) -> None:
        whole = chunks.add(m)
        if whole is not None:
            texts.append(whole)

    def ask(ftype, instance, p5):
        gcs.mav.command_long_send(1, 1, M.MAV_CMD_INJECT_FAILURE, 0, 102, ftype, instance, NAN, p5, 0, 0)
        t_end = time.monotonic() + 5
        while time.monotonic() < t_end:
            m = gcs.recv_match(type=["COMMAND_ACK", "STATUSTEXT"], blocking=True, timeout=0.5)
            if m is None or m.get_srcSystem() != 1:
                continue
            if m.get_type() == "STATUSTEXT":
                text(m)
            elif m.command == M.MAV_CMD_INJECT_FAILURE and m.target_component == 230:
                return m.result
        return None

    try:
        assert gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=30) is not None
        gcs.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        _set_failure_en(gcs, 1)
        assert ask(M.FAILURE_TYPE_STUCK, 4, 3.0) == M.MAV_RESULT_ACCEPTED
        assert ask(M.FAILURE_TYPE_STUCK, 4, 1e30) == M.MAV_RESULT_DENIED  # beyond any surface: the autopilot's table
        assert ask(M.FAILURE_TYPE_STUCK, 4, 45.0) == M.MAV_RESULT_DENIED  # beyond this rudder: the SITL's bound
        assert ask(M.FAILURE_TYPE_STUCK, 0, -31.0) == M.MAV_RESULT_DENIED
        assert ask(M.FAILURE_TYPE_STUCK, 4, NAN) == M.MAV_RESULT_DENIED  # NaN beside set params 6, 7: no position
        _set_failure_en(gcs, 0)
        assert ask(M.FAILURE_TYPE_OK, 0, NAN) == M.MAV_RESULT_ACCEPTED
        assert ask(M.FAILURE_TYPE_OK, 4, NAN) == M.MAV_RESULT_ACCEPTED
        assert ask(M.FAILURE_TYPE_STUCK, 4, 2.0) == M.MAV_RESULT_DENIED  # off: no new fault
        time.sleep(1.0)
        while (m := gcs.recv_match(type="STATUSTEXT", blocking=False)) is not None:
            if m.get_srcSystem() == 1:
                text(m)
    finally:
        code = launch.wait(180)
        gcs.close()
    summary = load_json(out / "summary.json")
    assert code in (0, 1, 3) and summary["flown"]["fraction"] > 0.95, (code, summary.get("error"))
    faults = [f for f in summary["faults"] if f["source"] == "ground station"]
    assert [(f["kind"], f["surface"], f["started"]) for f in faults] == [("stuck", "rudder", True)], faults
    # cleared: none left at the end.  The station's whole exchange can come before the lockstep flight's first frame
    # (one run with nothing else on the machine: stuck and cleared both at t = 0.0), so the end is not after the start.
    assert faults[0]["end"] is not None and faults[0]["end"] >= faults[0]["start"]
    said = " ".join(texts)
    assert "STUCK: the position (param5) must be within +-90 deg" in said, texts
    assert "SITL: INJECT_FAILURE refused: stuck=45: 45 deg is beyond the rudder's travel" in said, texts
