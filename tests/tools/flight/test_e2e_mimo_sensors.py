"""A square MIMO plant's sideslip (AOA_SSA) through the sensor errors and link faults of the SITL (issue 32): the
attitude's sensor delay and the link's delay and loss act on it as on ATTITUDE.  Lockstep flights of three real
processes (``python -m tools.launch``) on the JSBSim c172x; facts checked against the SITL's own truth series,
not against what the autopilot computes: the autopilot's sideslip lags the aircraft's by exactly the frames its
roll lags the aircraft's, and with packet loss it holds its last sideslip on exactly the frames it holds its last
roll."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.e2e
ROOT = Path(__file__).resolve().parents[3]
PLANT = "jsbsim:c172x:surface=aileron+rudder"


def _fly(tmp_path: Path, name: str, *flags: str) -> dict:
    argv = [sys.executable, "-m", "tools.launch", "--lockstep", "--quiet", "--duration", "12", "--plant", PLANT,
            "--out", str(tmp_path / name), "--no-png", "--no-rrd", *flags]  # fmt: skip
    r = subprocess.run(argv, capture_output=True, text=True, timeout=300, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    out = Path(re.search(r"files: (\S+)/flight\.tlog", r.stdout).group(1))
    ap, sitl = np.load(out / "autopilot_series.npz"), np.load(out / "sitl_series.npz")
    return {"ap": {k: ap[k].copy() for k in ap.files}, "sitl": {k: sitl[k].copy() for k in sitl.files},
            "summary": json.loads((out / "summary.json").read_text())}  # fmt: skip


def _lag(measured: np.ndarray, truth: np.ndarray, most: int = 15) -> int:
    """The lag (frames) at which the truth best explains what was measured (least squares over the flight)."""
    n = min(len(measured), len(truth)) - most
    err = [float(np.mean((measured[most : most + n - 1] - truth[most - d : most - d + n - 1]) ** 2)) for d in
           range(most)]  # fmt: skip
    return int(np.argmin(err))


def _lags(f: dict) -> tuple[int, int]:
    """(roll lag, sideslip lag) of the autopilot's measurements behind the SITL's truth.  The truth's sideslip is
    asin(v / V) of its side velocity v (still air: JSBSim's beta), V its mean speed over the flight."""
    ap, sitl = f["ap"], f["sitl"]
    speed = float(np.sqrt(np.mean(sitl["v"] ** 2)) / np.sin(np.sqrt(np.mean(ap["beta"] ** 2))))
    beta_truth = np.arcsin(np.clip(sitl["v"] / speed, -1, 1))
    return _lag(ap["phi"], sitl["phi"]), _lag(ap["beta"], beta_truth)


def test_the_sideslip_takes_the_attitudes_sensor_delay_and_link_delay(tmp_path):
    clean = _fly(tmp_path, "clean")
    base_roll, base_side = _lags(clean)
    assert base_roll == base_side
    for flags, frames in ((("--delay", "0.05"), 5), (("--sensor-delay", "3"), 3)):
        roll, side = _lags(_fly(tmp_path, flags[0].strip("-"), *flags))
        assert roll == base_roll + frames, (flags, roll, base_roll)
        assert side == roll, (flags, side, roll)  # the sideslip arrives exactly as late as the roll


def test_a_lost_attitude_datagram_holds_the_sideslip_too(tmp_path):
    f = _fly(tmp_path, "loss", "--loss", "0.3", "--seed", "3")
    phi, beta = f["ap"]["phi"][5:], f["ap"]["beta"][5:]  # from trim the first frames' roll is the same float32
    held_roll = phi[1:] == phi[:-1]
    held_side = beta[1:] == beta[:-1]
    assert held_roll.sum() > 100  # 30 % of the frames lost: the autopilot holds the last roll it got
    assert (held_roll == held_side).all()  # and the last sideslip, on exactly those frames
    assert f["summary"]["sideslip"]["max_abs_sideslip_deg"] > 0.5


def test_real_time_link_faults_carry_the_sideslip_with_the_attitude(tmp_path):
    """Real time: AOA_SSA and ATTITUDE in one datagram, delayed or lost together (before, ATTITUDE delayed behind a
    newer-signed AOA_SSA was refused as a replay, and the flight flew no step)."""
    out = tmp_path / "rt"
    argv = [sys.executable, "-m", "tools.launch", "--duration", "6", "--plant", PLANT, "--loss", "0.1", "--delay",
            "0.02", "--out", str(out), "--no-png", "--no-rrd", "--quiet"]  # fmt: skip
    r = subprocess.run(argv, capture_output=True, text=True, timeout=120, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    got = json.loads((out / "autopilot.json").read_text())["links"]["sitl"]["rx_by_type"]
    assert got["ATTITUDE"] == got["AOA_SSA"] > 300  # paired: the 200 Hz sensor for 6 s, less the 10 % lost


def test_a_delayed_servo_message_delays_the_rudder_with_the_aileron(tmp_path):
    """Lockstep link delay on the servo message (SERVO_OUTPUT_RAW, servo1 the aileron, servo4 the rudder): the
    SITL applies each surface's command exactly as many frames after the autopilot sent it."""

    def lags(f):
        ap, sitl = f["ap"], f["sitl"]
        return _lag(sitl["u"], ap["u"]), _lag(sitl["u2"], ap["u2"])

    base_ail, base_rud = lags(_fly(tmp_path, "clean"))
    assert base_ail == base_rud
    ail, rud = lags(_fly(tmp_path, "delay", "--delay", "0.05"))
    assert ail == base_ail + 5 and rud == ail, (base_ail, ail, rud)
