"""Faults from the real ground stations, as their users send them, into a launched real-time flight (issue 29).

MAVSDK 4.x's and 3.x's Failure plugin (``inject(SYSTEM_SERVO, STUCK, 4)``: MAV_CMD_INJECT_FAILURE 102/2/4, NaN in
param4..7; neither reads SYS_FAILURE_EN first) and MAVProxy 1.8.75's ``long INJECT_FAILURE 102 2 4`` (its cmdlong
module, typed on stdin), each against ``python -m tools.launch --failure-injection`` (or, for MAVProxy, a flight that
enables it with ``param set SYS_FAILURE_EN 1``): the stuck servo is accepted and lands in summary.json, a failure
type not implemented is UNSUPPORTED.  The clients live in their own virtual environments (tests/tools/test_clients.py).
"""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from autopilot.params import PARAMS
from tests._mavlink_procs import free_ports, load_json
from tests.tools.test_clients import CLIENTS_VENV, MAVSDK4_VENV, MavProxy, _client_python, _free_tcp_port, _run_session

pytestmark = pytest.mark.e2e


class Launch:
    """A real-time launched flight, unsigned, streaming to one more ground station on ``port``."""

    def __init__(self, tmp_path, port: int, *flags: str, duration: float = 15.0):
        self.out = tmp_path / "run"
        self.p = subprocess.Popen(
            [sys.executable, "-m", "tools.launch", "--duration", repr(duration), "--no-signing", "--gcs-peer"]
            + [f"127.0.0.1:{port}", "--out", str(self.out), "--no-rrd", "--no-png", "--quiet", *flags],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            stdin=subprocess.DEVNULL,
        )

    def summary(self) -> dict:
        code = self.p.wait(120)
        summary = load_json(self.out / "summary.json")
        assert code in (0, 3), (code, summary.get("error"))  # 3: the stuck rudder rolled it out of its envelope
        return summary


def _ground_station_faults(summary: dict) -> list[dict]:
    return [f for f in summary["faults"] if f["source"] == "ground station"]


def _check_mavsdk(out: dict, launch: Launch) -> None:
    assert out["stuck"] == "SUCCESS" and out["stuck_s"] < 1.0, out
    assert out["garbage"] == "UNSUPPORTED", out
    assert any(t.startswith("failure injected by GCS 245:190") for t in out["statustexts"]), out["statustexts"]
    faults = _ground_station_faults(launch.summary())
    assert [f["kind"] for f in faults] == ["stuck"], faults


def test_mavsdk4_failure_plugin_injects_a_stuck_servo(tmp_path):
    py = _client_python(MAVSDK4_VENV, "mavsdk.plugins.failure", "mavsdk>=4", "CLSAC_MAVSDK4_VENV")
    port = free_ports(1)[0]
    launch = Launch(tmp_path, port, "--failure-injection")
    try:
        out = _run_session(py, "mavsdk4_failure.py", [port], tmp_path)
    finally:
        launch.p.wait(120)
    _check_mavsdk(out, launch)


def test_mavsdk3_failure_plugin_injects_a_stuck_servo(tmp_path):
    py = _client_python(CLIENTS_VENV, "mavsdk.failure", "mavsdk<4", "CLSAC_CLIENTS_VENV")
    port = free_ports(1)[0]
    launch = Launch(tmp_path, port, "--failure-injection")
    try:
        out = _run_session(py, "mavsdk3_failure.py", [port, _free_tcp_port()], tmp_path)
    finally:
        launch.p.wait(120)
    _check_mavsdk(out, launch)


def test_mavproxy_long_inject_failure_denied_until_sys_failure_en_then_accepted(tmp_path):
    py = _client_python(CLIENTS_VENV, "MAVProxy", "MAVProxy==1.8.75", "CLSAC_CLIENTS_VENV")
    port = free_ports(1)[0]
    mp = MavProxy(py, port, tmp_path)
    launch = Launch(tmp_path, port)  # without --failure-injection
    try:
        mp.wait_for(r"Detected vehicle 1:1", 30)
        mark = mp.mark()
        mp.send("long INJECT_FAILURE 102 2 4")
        mp.wait_for(r"Got COMMAND_ACK: INJECT_FAILURE: DENIED", start=mark)
        mp.wait_for(r"AP: INJECT_FAILURE from GCS 255:230 refused: failure injection is off", start=mark)
        mp.send("param fetch")
        mp.wait_for(rf"Received {len(PARAMS)} parameters", 20)
        mp.send("param set SYS_FAILURE_EN 1")
        time.sleep(0.5)
        mark = mp.mark()
        mp.send("param show SYS_FAILURE_EN")
        mp.wait_for(r"SYS_FAILURE_EN\s+1(\.0)?\b", start=mark)
        mark = mp.mark()
        mp.send("long INJECT_FAILURE 102 3 4")  # GARBAGE: not implemented
        mp.wait_for(r"Got COMMAND_ACK: INJECT_FAILURE: UNSUPPORTED", start=mark)
        mark = mp.mark()
        mp.send("long INJECT_FAILURE 102 2 4 0 5")  # stuck at 5 deg (param5)
        mp.wait_for(r"Got COMMAND_ACK: INJECT_FAILURE: ACCEPTED", start=mark)
        mp.wait_for(r"AP: failure injected by GCS 255:230 at [0-9.]+ s: servo stuck=5 deg", start=mark)
    finally:
        mp.close()
    faults = _ground_station_faults(launch.summary())
    assert [f["kind"] for f in faults] == ["stuck"], faults
