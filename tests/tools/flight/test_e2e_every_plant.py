"""Every plant a first-class aircraft (issue 30), flown: lockstep launches of the designs ``tools.pfc design`` writes
(pa28, J3Cub at 60 kt), the c172x's outputs naming it and its aileron, a parameter changed in flight recorded with
its time, and every controller given the plant's surface stop.  The fast checks are tests/sitl/test_every_plant.py."""

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

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

from tests._mavlink_procs import free_ports  # noqa: E402

pytestmark = pytest.mark.e2e
ROOT = Path(__file__).resolve().parents[3]
ENV = dict(os.environ, PYTHONPATH=str(ROOT))


def _run(*args: str, cwd=None, timeout: float = 300.0) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", *args], capture_output=True, text=True, timeout=timeout, cwd=cwd, env=ENV
    )


def _launch(*args: str, cwd=None) -> tuple[subprocess.CompletedProcess, dict]:
    r = _run("tools.launch", "--lockstep", "--quiet", *args, cwd=cwd)
    out = re.search(r"files: (\S+)/flight\.tlog", r.stdout)
    assert out is not None, r.stdout[-2000:] + r.stderr[-2000:]
    return r, json.loads((Path(cwd or ".") / out.group(1) / "summary.json").read_text())


@pytest.fixture(scope="module")
def pa28(tmp_path_factory):
    """``python -m tools.pfc design jsbsim:pa28 --out F``: the design and what it printed."""
    out = tmp_path_factory.mktemp("pa28") / "pa28.params"
    r = _run("tools.pfc", "design", "jsbsim:pa28", "--out", str(out))
    assert r.returncode == 0, r.stderr
    return out, r.stdout


def test_the_design_s_last_line_is_the_command_that_flies_it(pa28):
    path, stdout = pa28
    last = stdout.strip().splitlines()[-1]
    assert last == f"python -m tools.launch --lockstep --plant jsbsim:pa28 --params {path}"
    text = path.read_text()
    assert "PID_KP" in text and "CLSAC_PID" not in text  # the PID's own names (issue 37), not their aliases
    assert "# baseline_gains" not in text and "CLSAC_U_LIMIT" not in text
    assert "rate_limit" not in path.with_suffix(".toml").read_text()  # pa28's ailerons have no actuator


@pytest.mark.parametrize("controller", ["baseline", "clsac"])
def test_the_design_flies_every_controller_and_the_outputs_name_pa28(tmp_path, pa28, controller):
    """Must show (M-every-plant): after tools.pfc design jsbsim:pa28 --out F, --controller baseline --params F flies
    (exit 0 or 3; before, FAILED: unknown parameter 'CLSAC_PFC_NUM'), and so do SAC and CL-SAC; the header, the
    verdict and summary.json name pa28 and its aileron."""
    path, _ = pa28
    out = tmp_path / "f"
    r, s = _launch("--plant", "jsbsim:pa28", "--params", str(path), "--controller", controller, "--out", str(out))
    assert r.returncode in (0, 3), r.stdout[-2000:]
    assert f"flight, {controller} (" in r.stdout and " on pa28 (aileron), " in r.stdout
    last = r.stdout.strip().splitlines()[-1]
    assert "aileron saturated" in last and "rudder" not in last
    assert (s["plant_name"], s["surface"], s["params"]) == ("pa28", "aileron", str(path))
    from autopilot.params import load_file

    start, design = s["parameters"]["start"], load_file(path)
    names = ("PID_KP", "PID_KI", "PID_KD") if controller == "baseline" else ("CLSAC_PFC_NUM",)
    assert all(start[n] == pytest.approx(design[n], rel=1e-6) for n in names)  # the design's values flew (REAL32)
    assert (out / "flight.png").is_file()


def test_a_c172x_flight_names_c172x_and_its_aileron_everywhere(tmp_path):
    """Must show: a c172x flight's output names c172x, and its verdict says aileron, not rudder; its run folder
    (the default one, under runs/ of the working folder: here a temporary one) is named after it too, and every
    file it leaves is one docs/flying.md lists."""
    r, s = _launch("--plant", "jsbsim:c172x", "--duration", "10", cwd=tmp_path)
    assert r.returncode == 0, r.stdout[-2000:]
    (folder,) = (tmp_path / "runs").iterdir()
    assert folder.name.endswith("-lockstep-clsac-c172x"), folder.name
    assert "== lockstep flight, clsac (Lv=20) on c172x (aileron), " in r.stdout
    last = r.stdout.strip().splitlines()[-1]
    assert last.startswith("OK: flown to the end; controlled: ") and "aileron saturated" in last
    assert "rudder" not in last and "rudder" not in s["controlled"]["reason"]
    assert (s["plant"], s["plant_name"], s["surface"]) == ("jsbsim:c172x", "c172x", "aileron")
    listed = (ROOT / "docs" / "flying.md").read_text()
    files = sorted(p.name for p in folder.iterdir())
    assert len(files) == 14 and all(f"`{name}`" in listed for name in files), files


def test_the_j3cub_at_60_kt_is_designed_and_flies(tmp_path):
    """Must show: tools.pfc design jsbsim:J3Cub:airspeed_kt=60 designs (its slow spiral mode, a pole at +0.0046 1/s,
    is stabilised by C = g (s + a) above a small gain) and the design flies."""
    out = tmp_path / "j3.params"
    r = _run("tools.pfc", "design", "jsbsim:J3Cub:airspeed_kt=60", "--out", str(out))
    assert r.returncode == 0, r.stderr
    poles = re.search(r"poles (.*)", r.stdout).group(1)
    assert re.search(r"\b0\.004[56]\d*\+0j", poles), poles  # the unstable spiral, reported
    assert "unstable Ke bands of 1 + Ke F: continuous [0, 0.001" in r.stdout  # the plant's own, left at once
    f, s = _launch("--plant", "jsbsim:J3Cub:airspeed_kt=60", "--params", str(out), "--out", str(tmp_path / "f"))
    assert f.returncode in (0, 3), f.stdout[-2000:]
    assert s["plant_name"] == "J3Cub" and s["runs"][0]["metrics"]["ise_ref"] < 0.5


class _Station:
    """A ground station on one UDP port: it hears the vehicle's HEARTBEAT, then sends one PARAM_SET."""

    def __init__(self, port: int):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.2)
        self.mav = mavlink.MAVLink(None, 255, 200)
        self.vehicle = None
        self.sim_ms = 0  # the vehicle's clock, from its ATTITUDE stream
        self.values: list[float] = []
        self.stop = False
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop:
            try:
                data, addr = self.sock.recvfrom(65536)
            except TimeoutError:
                continue
            for m in self.mav.parse_buffer(data) or []:
                if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1:
                    self.vehicle = addr
                if m.get_type() == "ATTITUDE":
                    self.sim_ms = max(self.sim_ms, m.time_boot_ms)
                if m.get_type() == "PARAM_VALUE" and m.param_id == "CLSAC_LV":
                    self.values.append(m.param_value)

    def param_set(self, name: str, value: float) -> None:
        msg = mavlink.MAVLink_param_set_message(1, 1, name.encode(), value, mavlink.MAV_PARAM_TYPE_REAL32)
        self.sock.sendto(msg.pack(self.mav), self.vehicle)


def test_a_parameter_changed_in_flight_is_an_event_with_its_time(tmp_path):
    """A ground station's CLSAC_LV 20 -> 50 in a lockstep flight: summary.json has the change with its sim time, the
    first and the last value (Lv, Lv_end), the header says both, and the autopilot flew the new one from then on."""
    import numpy as np

    port = free_ports(1)[0]
    gcs = _Station(port)
    out = tmp_path / "f"
    argv = [sys.executable, "-m", "tools.launch", "--lockstep", "--duration", "60", "--quiet", "--no-signing"]
    argv += ["--gcs-peer", f"127.0.0.1:{port}", "--out", str(out)]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    try:
        t0 = time.monotonic()
        while (gcs.vehicle is None or gcs.sim_ms < 5000) and time.monotonic() - t0 < 60:
            time.sleep(0.005)  # flying for 5 s of sim time: the change comes mid-flight
        assert gcs.vehicle is not None and gcs.sim_ms >= 5000, "the vehicle was not heard flying"
        gcs.param_set("CLSAC_LV", 50.0)
        stdout, _ = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            proc.kill()
        gcs.stop = True
        gcs.thread.join(5)
        gcs.sock.close()
    s = json.loads((out / "summary.json").read_text())
    (change,) = s["parameters"]["changes"]
    assert (change["name"], change["from"], change["to"]) == ("CLSAC_LV", 20.0, 50.0)
    assert 5.0 <= change["t_s"] < 60.0
    assert (s["Lv"], s["Lv_end"]) == (20.0, 50.0) and s["parameters"]["end"]["CLSAC_LV"] == 50.0
    assert "clsac (Lv=20 -> 50) on KH2013A (rudder)" in stdout
    assert f"parameter changed in flight: CLSAC_LV 20 -> 50 at {change['t_s']:.2f} s" in stdout
    # what flew: the closed-loop reference model, paper eqs. (18)-(19) discretised exactly (A_m = -5, B_m = 5,
    # C_m = 1): y_m[k+1] = e^{(A_m - Lv) T} y_m[k] + (e^{(A_m - Lv) T} - 1)/(A_m - Lv) (B_m u_m[k] + Lv y_a[k]),
    # with Lv = 20 before the change and 50 after it, from the series alone
    series = np.load(out / "autopilot_series.npz")
    assert 50.0 in gcs.values and (out / "flight.png").is_file()
    t, ym, um, ya = (series[k].astype(float) for k in ("t", "ym", "um", "ya"))

    def predicted(lv):
        a = -5.0 - lv
        phi = math.exp(a * 0.01)
        return phi * ym[:-1] + (phi - 1.0) / a * (5.0 * um[:-1] + lv * ya[:-1])

    fits = {lv: np.abs(predicted(lv) - ym[1:]) < 1e-9 for lv in (20.0, 50.0)}
    before, after = t[:-1] < change["t_s"] - 0.015, t[:-1] > change["t_s"] + 0.015
    assert before.sum() > 100 and after.sum() > 100
    assert fits[20.0][before].all() and not fits[20.0][after].any()
    assert fits[50.0][after].all()


@pytest.mark.parametrize("controller", ["sac", "clsac", "baseline"])
def test_every_controller_gets_the_plant_s_surface_stop(tmp_path, controller):
    """jsbsim:c172x:surface_max_deg=25: the PID was clipped at the surface's 25 deg, SAC and CL-SAC at the design
    file's 17.5 deg (its CLSAC_U_LIMIT); now every controller flies the plant's stop (and the design sets none)."""
    from sitl.plant import surface_limit_rad
    from tools.experiment.scenario import PAPER, RunSpec, controller_config

    plant = "jsbsim:c172x:surface_max_deg=25"
    r, s = _launch("--plant", plant, "--controller", controller, "--duration", "3", "--out", str(tmp_path / "f"))
    assert r.returncode in (0, 3), r.stdout[-2000:]
    ap = json.loads((tmp_path / "f" / "autopilot.json").read_text())
    assert ap["u_limit_rad"] == surface_limit_rad(plant) == math.radians(25.0)
    # the in-process runner (tools.experiment, the study) the same
    from dataclasses import replace

    lv = {"sac": 0.0, "clsac": 20.0, "baseline": 0.0}[controller]
    run = RunSpec(controller, lv, controller=None if controller != "baseline" else "baseline")
    cfg = controller_config(replace(PAPER, plant=plant, u_limit_rad=math.radians(25.0)), run)
    assert cfg.u_limit_rad == math.radians(25.0)
