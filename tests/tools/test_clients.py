"""The real ground stations end to end: MAVProxy, MAVSDK 3.x (gRPC, the wheel's mavsdk_server) and MAVSDK 4.x (the
ctypes binding), each as its users run it, against a real SITL and autopilot on loopback UDP.

Each client must connect, download all parameters, get CLSAC_LV, set it, be refused CLSAC_AM = 3 with the whole
reason (a chunked STATUSTEXT, longer than one 50-byte message), switch mode, disarm and arm, and fly a roll
setpoint; MAVProxy also joins a signed launch with a passphrase key.  The clients are not product dependencies: they
live in virtual environments of their own, found through CLSAC_CLIENTS_VENV (MAVProxy 1.8.75 and mavsdk<4) and
CLSAC_MAVSDK4_VENV (mavsdk>=4), by default .venv-clients and .venv-mavsdk4 at the repository root (``bash .ci/run``
creates them; README, "Real ground stations").  A client is skipped only when it is not installed there, and the
skip reason says where it was looked for and how to install it.
"""

from __future__ import annotations

import json
import math
import os
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from autopilot.params import PARAMS
from tests._mavlink_procs import Proc, free_ports, load_json

pytestmark = pytest.mark.e2e
ROOT = Path(__file__).resolve().parents[2]
SESSIONS = Path(__file__).resolve().parents[1] / "clients"
CLIENTS_VENV = Path(os.environ.get("CLSAC_CLIENTS_VENV", ROOT / ".venv-clients"))
MAVSDK4_VENV = Path(os.environ.get("CLSAC_MAVSDK4_VENV", ROOT / ".venv-mavsdk4"))
ROLL_SETPOINT_DEG = 15.0
LV_SET = 12.5  # exactly representable in float32: the value read back is the value set


def _client_python(venv: Path, module: str, requirement: str, env_var: str) -> str:
    """The venv's python if ``module`` imports there; else skip, saying where it was looked for and how to install."""
    py = venv / "bin" / "python"
    ok = py.exists() and (
        subprocess.run([str(py), "-c", f"import {module}"], capture_output=True, timeout=60).returncode == 0
    )
    if not ok:
        pytest.skip(
            f"{requirement} is not installed in {venv} ({env_var}): python3 -m venv {venv} && "
            f"{venv}/bin/pip install {requirement!r} (bash .ci/run does this; it could not be installed here)"
        )
    return str(py)


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Vehicle:
    """A real SITL (real time) and a real autopilot streaming to ``gcs_port``: unsigned, so the first ground station
    that talks is admitted."""

    def __init__(self, tmp_path: Path, gcs_port: int, *extra: str):
        sitl_port = free_ports(1)[0]
        self.stats = tmp_path / "autopilot.json"
        self.sitl = Proc("sitl", ["--listen", f"127.0.0.1:{sitl_port}", "--quiet"], tmp_path / "sitl.log")
        assert self.sitl.wait_for("sitl: listening", 30), self.sitl.output()
        args = ["--sitl", f"127.0.0.1:{sitl_port}", "--gcs", f"127.0.0.1:{gcs_port}", "--stats-json", str(self.stats)]
        self.ap = Proc("autopilot", [*args, *extra], tmp_path / "autopilot.log")
        assert self.ap.wait_for("autopilot:", 30), self.ap.output()

    def log_line(self, prefix: str) -> str:
        """The autopilot's own log line that starts with ``prefix`` (what it printed, not what it sent)."""
        for line in self.ap.output().splitlines():
            if line.startswith(f"autopilot: {prefix}"):
                return line[len("autopilot: ") :]
        raise AssertionError(f"no 'autopilot: {prefix}' line in\n{self.ap.output()}")

    def stop(self) -> dict:
        self.ap.stop()
        self.sitl.stop()
        return load_json(self.stats)


def _vehicle(tmp_path, *extra):
    port = free_ports(1)[0]
    v = Vehicle(tmp_path, port, *extra)
    v.port = port
    return v


@pytest.fixture
def vehicle(tmp_path):
    v = _vehicle(tmp_path)
    yield v
    v.ap.stop()
    v.sitl.stop()


@pytest.fixture
def mavsdk_vehicle(tmp_path):
    """MAVSDK stamps SET_ATTITUDE_TARGET.time_boot_ms with its host's uptime, not the vehicle's sim time: the
    autopilot flies its setpoints on arrival with --setpoint-time now (README, "MAVSDK")."""
    v = _vehicle(tmp_path, "--setpoint-time", "now")
    yield v
    v.ap.stop()
    v.sitl.stop()


def _check_refusal_reason(vehicle: Vehicle, shown: list[str]) -> str:
    """The whole refusal reason, as the autopilot logged it, is among the texts the client shows."""
    reason = vehicle.log_line("CLSAC_AM=3 rejected")
    assert len(reason) > 50 and re.search(r"\bgot 3(\.0)?\b", reason), reason  # over one STATUSTEXT: chunked
    assert reason in shown, (reason, shown)
    return reason


def _check_mavsdk_session(out: dict, vehicle: Vehicle) -> None:
    steps = ("connect", "all_params", "get_lv", "set_lv", "get_lv_after", "mode_manual", "mode_clsac", "arm")
    for name in (*steps, "set_failure_en", "get_failure_en", "reset_failure_en"):
        assert not (isinstance(out[name], dict) and "error" in out[name]), (name, out[name])
    # SYS_FAILURE_EN is an INT32 as PX4's (MAVSDK reads it bytewise and sets it with set_param_int), the rest REAL32
    assert out["all_params"]["int"] == {"SYS_FAILURE_EN": 0}
    assert sorted(out["all_params"]["float"]) == sorted(p.name for p in PARAMS if p.name != "SYS_FAILURE_EN")
    assert out["get_failure_en"] == 1
    assert out["all_params"]["float"]["CLSAC_LV"] == 20.0 and out["get_lv"] == 20.0  # the paper's L_v (sec. 5)
    assert out["get_lv_after"] == LV_SET
    assert "VALUE_OUT_OF_RANGE" in out["set_am_refused"]["error"]  # PARAM_ERROR's code, as MAVSDK reports it
    _check_refusal_reason(vehicle, out["statustexts"])
    assert (out["mode_manual"], out["mode_clsac"]) == (0, 101)  # HEARTBEAT.custom_mode: MANUAL, CLSAC
    assert "disarm" in out and not (isinstance(out["disarm"], dict) and "error" in out["disarm"]), out["disarm"]
    assert "DISARMED: rudder neutral" in out["statustexts"] and "ARMED" in out["statustexts"]
    assert abs(out["fly"]["roll_deg"] - ROLL_SETPOINT_DEG) < 2.0, out["fly"]  # 5 s after the step, CL-SAC tracks it
    stats = vehicle.stop()
    gcs = stats["links"]["gcs"]
    assert "wrong_id" not in gcs["rejected"], gcs["rejected"]  # 245:190 is a ground station by default
    assert gcs["rx_by_type"].get("SET_ATTITUDE_TARGET", 0) > 50  # Offboard.set_attitude's setpoints were flown
    assert "future_setpoint" not in gcs["rejected"]
    assert stats["events"]["param_sets"] == 3  # CLSAC_LV, SYS_FAILURE_EN 1 and back to 0


def _run_session(py: str, script: str, args: list, tmp_path: Path, timeout: float = 120) -> dict:
    out_path = tmp_path / "session.json"
    log = tmp_path / "session.log"
    with open(log, "w") as f:
        r = subprocess.run(
            [py, "-W", "ignore", str(SESSIONS / script), *map(str, args), str(out_path)],
            stdout=f,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            timeout=timeout,
            cwd=tmp_path,
        )
    assert r.returncode == 0 and out_path.exists(), log.read_text()[-3000:]
    return json.loads(out_path.read_text())


def test_mavsdk3_default_ids_full_session(mavsdk_vehicle, tmp_path):
    py = _client_python(CLIENTS_VENV, "mavsdk", "mavsdk<4", "CLSAC_CLIENTS_VENV")
    out = _run_session(py, "mavsdk3_session.py", [mavsdk_vehicle.port, _free_tcp_port()], tmp_path)
    _check_mavsdk_session(out, mavsdk_vehicle)


def test_mavsdk4_default_ids_full_session(mavsdk_vehicle, tmp_path):
    py = _client_python(MAVSDK4_VENV, "mavsdk.plugins.param", "mavsdk>=4", "CLSAC_MAVSDK4_VENV")
    out = _run_session(py, "mavsdk4_session.py", [mavsdk_vehicle.port], tmp_path)
    assert out["connect"]["system_id"] == 1
    _check_mavsdk_session(out, mavsdk_vehicle)


# ------------------------------------------------------------------------------------------------------ MAVProxy
class MavProxy:
    """MAVProxy as a user runs it: ``mavproxy.py --master udpin:...``, commands typed on stdin (without
    --non-interactive, which ignores stdin), its console read from stdout."""

    def __init__(self, py: str, port: int, cwd: Path, **env: str):
        self.lines: list[str] = []
        self.p = subprocess.Popen(
            [py, str(Path(py).parent / "mavproxy.py"), "--master", f"udpin:127.0.0.1:{port}", "--nowait"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            cwd=cwd,
            # its console line by line, as on a terminal: on a pipe Python buffers it, and without this (an
            # environment without PYTHONUNBUFFERED) the parameter count never reached the test in time
            env=dict(os.environ, PYTHONUNBUFFERED="1", **env),
        )
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.p.stdout:
            self.lines.append(line.rstrip("\n"))

    def send(self, command: str) -> None:
        self.p.stdin.write(command + "\n")
        self.p.stdin.flush()

    def wait_for(self, pattern: str, timeout: float = 15.0, start: int = 0) -> re.Match:
        rx = re.compile(pattern)
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            for line in self.lines[start:]:
                if m := rx.search(line):
                    return m
            time.sleep(0.05)
        raise AssertionError(f"MAVProxy never printed {pattern!r}:\n" + "\n".join(self.lines[-60:]))

    def mark(self) -> int:
        return len(self.lines)

    def close(self) -> None:
        if self.p.poll() is None:
            try:
                self.send("exit")
                self.p.wait(10)
            except (OSError, subprocess.TimeoutExpired):
                self.p.kill()
                self.p.wait()


@pytest.fixture
def mavproxy_python():
    return _client_python(CLIENTS_VENV, "MAVProxy", "MAVProxy==1.8.75", "CLSAC_CLIENTS_VENV")


def _quaternion_arg(roll_deg: float) -> str:
    """SET_ATTITUDE_TARGET.q of a pure roll (docs/spec.md, section 3), as MAVProxy's ``message`` command evals it."""
    h = math.radians(roll_deg) / 2
    return f"[{math.cos(h):.6f},{math.sin(h):.6f},0,0]"


def test_mavproxy_full_session(vehicle, tmp_path, mavproxy_python):
    mp = MavProxy(mavproxy_python, vehicle.port, tmp_path)
    try:
        mp.wait_for(r"Detected vehicle 1:1", 20)
        mp.send("param fetch")
        mp.wait_for(rf"Received {len(PARAMS)} parameters", 20)
        mark = mp.mark()
        mp.send("param show CLSAC_LV")
        mp.wait_for(r"CLSAC_LV\s+20\.0\b", start=mark)
        mp.send(f"param set CLSAC_LV {LV_SET}")
        mark = mp.mark()
        time.sleep(0.5)
        mp.send("param show CLSAC_LV")
        mp.wait_for(rf"CLSAC_LV\s+{LV_SET}\b", start=mark)
        mark = mp.mark()
        mp.send("param set CLSAC_AM 3")
        shown = mp.wait_for(r"AP: (CLSAC_AM=3 rejected: .*)$", start=mark).group(1)
        _check_refusal_reason(vehicle, [shown])  # reassembled by MAVProxy's own PendingText from our chunks
        mp.send("mode MANUAL")
        mp.wait_for(r"AP: mode MANUAL", start=mark)
        mp.send("mode 101")  # CLSAC: not in ArduPlane's mode table, so by number
        mp.wait_for(r"AP: mode CLSAC", start=mark)
        mp.send("disarm")
        mp.wait_for(r"AP: DISARMED: rudder neutral", start=mark)
        mp.send("arm throttle")
        mp.wait_for(r"AP: ARMED", start=mark)
        mp.send("module load message")
        mp.wait_for(r"Loaded module message", start=mark)
        q = _quaternion_arg(ROLL_SETPOINT_DEG)
        for _ in range(50):  # 5 s at 10 Hz (the setpoint timeout is 1 s)
            mp.send(f"message SET_ATTITUDE_TARGET 0 1 1 71 {q} 0 0 0 0")
            time.sleep(0.1)
        mark = mp.mark()
        mp.send("status ATTITUDE")
        roll = float(mp.wait_for(r"ATTITUDE \{.*roll : (-?[0-9.e-]+)", start=mark).group(1))
        assert abs(math.degrees(roll) - ROLL_SETPOINT_DEG) < 2.0, roll
    finally:
        mp.close()
    stats = vehicle.stop()
    assert stats["events"]["param_sets"] == 1 and stats["events"]["param_rejected"] >= 1
    assert stats["links"]["gcs"]["rx_by_type"]["SET_ATTITUDE_TARGET"] >= 40


def _keygen_passphrase(path: Path, passphrase: str) -> None:
    r = subprocess.run(
        [sys.executable, "-m", "tools.flight.keygen", "--passphrase", str(path)],
        input=passphrase + "\n",
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert r.returncode == 0, r.stderr


def test_mavproxy_signed_launch_with_passphrase(tmp_path, mavproxy_python):
    """A signed launch (tools.launch, real time) keyed with ``tools.flight.keygen --passphrase``; MAVProxy joins with
    ``signing key PASSPHRASE`` (no key file on its side), is admitted by its signature, downloads the parameters and
    sets CLSAC_LV while the launcher's own ground station flies the profile."""
    passphrase = "correct-horse-battery-staple"
    key = tmp_path / "flight.key"
    _keygen_passphrase(key, passphrase)
    port = free_ports(1)[0]
    mp = MavProxy(mavproxy_python, port, tmp_path)
    out = tmp_path / "run"
    launch = subprocess.Popen(
        [sys.executable, "-m", "tools.launch", "--duration", "10", "--signing-key", str(key), "--gcs-peer"]
        + [f"127.0.0.1:{port}", "--out", str(out), "--no-rrd", "--no-png", "--quiet"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        stdin=subprocess.DEVNULL,
    )
    try:
        mp.send(f"signing key {passphrase}")
        mp.wait_for(r"Detected vehicle 1:1", 30)
        mp.send("param fetch")
        mp.wait_for(rf"Received {len(PARAMS)} parameters", 20)
        mp.send(f"param set CLSAC_LV {LV_SET}")
        mark = mp.mark()
        time.sleep(0.5)
        mp.send("param show CLSAC_LV")
        mp.wait_for(rf"CLSAC_LV\s+{LV_SET}\b", start=mark)
    finally:
        mp.close()
        code = launch.wait(60)
    assert code == 0, (out / "autopilot.log").read_text()[-2000:]
    ap = load_json(out / "autopilot.json")
    gcs = ap["links"]["gcs"]
    assert ap["events"]["param_sets"] == 1  # MAVProxy's PARAM_SET passed the signature check (unsigned: refused)
    assert not {"unsigned", "bad_signature"} & set(gcs["rejected"]), gcs["rejected"]
    assert load_json(out / "summary.json")["ok"] is True


def test_mavproxy_sees_two_vehicles_with_sysid_1_and_2(tmp_path, mavproxy_python):
    """Two launches (lockstep) with --sysid 1 and 2 streaming to MAVProxy's one port: MAVProxy detects two vehicles
    (tests/autopilot/test_sysid.py checks each one's HEARTBEAT and ATTITUDE stream on such a port)."""
    port = free_ports(1)[0]
    mp = MavProxy(mavproxy_python, port, tmp_path)
    # its port bound before the launches fly: a lockstep launch lasts about 1.5 s, and a MAVProxy still starting
    # (4 s cold) missed both vehicles once by hand; what they send after the bind waits in the socket
    mp.wait_for(r"Telemetry log:", 60)
    launches = [
        subprocess.Popen(
            [sys.executable, "-m", "tools.launch", "--lockstep", "--duration", "10", "--sysid", str(n), "--gcs-peer"]
            + [f"127.0.0.1:{port}", "--out", str(tmp_path / f"v{n}"), "--no-rrd", "--no-png", "--quiet"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            stdin=subprocess.DEVNULL,
        )
        for n in (1, 2)
    ]
    try:
        mp.wait_for(r"Detected vehicle 1:1", 30)
        mp.wait_for(r"Detected vehicle 2:1", 30)
    finally:
        mp.close()
        codes = [p.wait(120) for p in launches]
    assert codes == [0, 0]


def test_mavproxy_names_this_vehicles_modes_with_its_module(vehicle, tmp_path, mavproxy_python):
    """Plain MAVProxy lists ArduPlane's modes for this fixed wing (none of them this vehicle's but MANUAL) and shows
    Mode(101); with ``tools.flight.mavproxy_modes`` loaded (the checkout on its PYTHONPATH, as the docs say) it lists
    this vehicle's modes, switches by name (DO_SET_MODE, answered by the autopilot's own "AP: mode ..."), names the
    mode in its prompt, and a FAILSAFE asked for is DENIED (the vehicle enters and leaves it by itself).  The
    module's table is ``autopilot.vehicle.Mode``."""
    from autopilot.vehicle import Mode
    from tools.flight.mavproxy_modes import MODES

    assert MODES == {m.value: m.name for m in Mode}
    mp = MavProxy(mavproxy_python, vehicle.port, tmp_path, PYTHONPATH=str(ROOT))  # the checkout, as the docs say
    try:
        mp.wait_for(r"Detected vehicle 1:1", 20)
        mark = mp.mark()
        mp.send("mode")
        listed = mp.wait_for(r"Available modes:\s+(.*)$", start=mark).group(1)
        assert "FBWA" in listed and "CLSAC" not in listed  # ArduPlane's, without the module
        mark = mp.mark()
        mp.send("module load tools.flight.mavproxy_modes")
        mp.wait_for(r"Loaded module tools.flight.mavproxy_modes", start=mark)
        mp.wait_for(r"clsac_modes: this vehicle's modes: MANUAL SAC CLSAC FAILSAFE BASELINE", start=mark)
        mark = mp.mark()
        mp.send("mode")
        listed = mp.wait_for(r"Available modes:\s+(.*)$", start=mark).group(1)
        assert sorted(s.strip() for s in listed.split(",")) == sorted(MODES.values()), listed
        mp.send("mode SAC")
        mp.wait_for(r"AP: mode SAC", start=mark)
        mp.send("mode CLSAC")
        mp.wait_for(r"AP: mode CLSAC", start=mark)
        mp.send("mode MANUAL")
        mp.wait_for(r"AP: mode MANUAL", start=mark)
        mp.wait_for(r"^MANUAL> ", start=mark, timeout=10)  # the prompt names the mode (MAVProxy's flightmode)
        mark = mp.mark()
        mp.send("mode FAILSAFE")
        mp.wait_for(r"Got COMMAND_ACK: DO_SET_MODE: DENIED", start=mark)
        mp.send("mode CLSAC")
        mp.wait_for(r"^CLSAC> ", start=mp.mark(), timeout=10)
    finally:
        mp.close()
