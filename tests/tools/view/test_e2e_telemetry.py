"""Telemetry of real flights: ``python -m tools.launch`` and ``python -m tools.experiment`` read back from their .rrd.

The SITL and the autopilot are the real processes over loopback UDP; the recording is what the user opens.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from autopilot.shared.pwm import PwmMap
from autopilot.telemetry import layout as L
from sitl import telemetry as S
from tests._mavlink_procs import load_json, run_cli
from tools.view import rrd_files as rrd

pytestmark = pytest.mark.e2e  # real processes over loopback UDP

ROOT = Path(__file__).resolve().parents[3]
DURATION = 5.0
RATE = 100.0


@pytest.fixture(scope="module", params=["merged", "concatenated"])
def lockstep_flight(tmp_path_factory, request):
    """A short flight whose parts are merged (indexed, the default), and one whose parts are concatenated, as a
    flight longer than ``--rrd-merge-max-mb`` is: the same recording either way."""
    out = tmp_path_factory.mktemp("rrd_flight")
    join = ["--rrd-merge-max-mb", "0"] if request.param == "concatenated" else []
    argv = ["--lockstep", "--quiet", "--duration", str(DURATION), "--out", str(out), *join]
    r = run_cli("tools.launch", *argv, timeout=180)
    assert r.returncode == 0, r.stdout + r.stderr
    return out, load_json(out / "summary.json"), r.stdout, request.param


def test_launch_leaves_one_recording_of_both_processes(lockstep_flight):
    out, summary, stdout, join = lockstep_flight
    path = out / "flight.rrd"
    assert summary["files"]["rrd"] == str(path) and path.stat().st_size > 10_000
    assert f"rerun {path}" in stdout  # the user is told how to open it
    assert not (out / ".parts").exists()  # the per-process parts were merged and removed
    assert len(rrd.recordings(path)) == 1
    paths = set(rrd.entity_paths(path))
    for ep in (
        L.AP_ROLL,
        L.AP_GAIN_KE,
        L.AP_GAIN_KX,
        L.AP_GAIN_KU,
        "/autopilot/timing/loop",
        "/autopilot/link/sitl",
        "/autopilot/link/gcs",
        "/autopilot/status/mode",
        "/autopilot/status/failsafe",
        S.SITL_ROLL,
        S.SITL_RUDDER,
    ):
        assert ep in paths, ep
    assert rrd.has_blueprint(path)
    assert len(rrd.blueprint_components(path, "ViewportBlueprint:root_container")) == 1  # one layout
    indexed = summary["files"]["rrd_indexed"]
    assert indexed is (join == "merged")
    ok, text = rrd.verify(path, check_footers=False)  # a complete, valid stream either way
    assert ok, text
    ok, text = rrd.verify(path)  # the footer (index) is there exactly when summary.json says so
    assert ok is indexed, text


def test_sample_counts_match_duration_and_rate(lockstep_flight):
    out, _, _, _ = lockstep_flight
    data = rrd.load(out / "flight.rrd")
    n = int(DURATION * RATE)
    ap = data[L.AP_ROLL]
    assert len(ap.t) == n
    np.testing.assert_array_equal(ap.t_ns, np.round(np.arange(n) * 1e9 / RATE).astype(np.int64))
    assert len(data[S.SITL_ROLL].t) == n  # one truth row per frame (state after each advance)
    assert len(data["/autopilot/link/sitl"].t) == n // 10  # link counters at 10 Hz of sim time


def test_truth_and_measured_roll_agree_to_float32_at_the_same_sim_time(lockstep_flight):
    out, _, _, _ = lockstep_flight
    data = rrd.load(out / "flight.rrd")
    truth, seen = data[S.SITL_ROLL], data[L.AP_ROLL]
    common, i_truth, i_seen = np.intersect1d(truth.t_ns, seen.t_ns, return_indices=True)
    assert len(common) == len(seen.t) - 1  # every frame but t = 0 (the SITL logs after advancing)
    # shown in degrees (the rows in rad times 180/pi); back in rad the roll seen is the float32 of the truth
    phi_truth = np.radians(truth.values[i_truth, 0])
    phi_seen = np.radians(seen.values[i_seen, 3])  # "y": the roll the controller received in ATTITUDE (float32)
    assert np.max(np.abs(phi_truth)) > math.radians(8)
    np.testing.assert_allclose(phi_seen, phi_truth.astype(np.float32).astype(np.float64), rtol=1e-14, atol=0)
    # The PWM the autopilot sent at frame k is the PWM the SITL applied over frame k (logged at t_k+1).
    pwm_sent = data["/autopilot/rudder_pwm"]
    pwm_applied = data["/sitl/servo_pwm"]
    np.testing.assert_array_equal(pwm_sent.values[:-1, 0], pwm_applied.values[: len(pwm_sent.t) - 1, 0])
    # ... and the applied command (shown in degrees) is that PWM through the calibration.
    pwm = PwmMap()
    applied = data[S.SITL_RUDDER].values[:, 1]
    expect_deg = [math.degrees(pwm.to_rad(int(p))) for p in pwm_applied.values[:, 0]]
    np.testing.assert_allclose(applied, expect_deg, rtol=0, atol=1e-10)


def test_flight_metrics_can_be_recomputed_from_the_recording(lockstep_flight):
    """summary.json's ise_crm equals sum(e^2) dt over the logged error: the recording is the flight."""
    out, summary, _, _ = lockstep_flight
    data = rrd.load(out / "flight.rrd")
    e = np.radians(data["/autopilot/error"].values[:, 0])  # shown in degrees; the metric is in rad^2 s
    assert summary["runs"][0]["metrics"]["ise_crm"] == pytest.approx(float(np.sum(e**2) / RATE), rel=1e-9)


def test_realtime_flight_ended_with_sigint_leaves_a_readable_recording(tmp_path):
    out = tmp_path / "rt"
    env = dict(os.environ)
    env.pop("DISPLAY", None)
    proc = subprocess.Popen(
        [sys.executable, "-m", "tools.launch", "--duration", "30", "--quiet", "--out", str(out)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        stdin=subprocess.DEVNULL,
    )
    try:
        # Wait until the autopilot is flying (its log names the links), then fly ~2.5 s more.
        deadline = time.time() + 60
        while time.time() < deadline:
            log = out / "autopilot.log"
            if log.exists() and "SITL link" in log.read_text():
                break
            time.sleep(0.1)
        time.sleep(2.5)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, stdout + stderr
    path = out / "flight.rrd"
    assert path.exists(), stdout + stderr
    ok, text = rrd.verify(path)
    assert ok, text
    data = rrd.load(path)
    n = len(data[L.AP_ROLL].t)
    assert 100 <= n <= 30 * RATE  # ~2.5 s at 100 Hz flown before Ctrl-C
    assert len(data[S.SITL_ROLL].t) > 100
    assert load_json(out / "summary.json")["files"]["rrd"] == str(path)


def test_experiment_writes_every_run_side_by_side(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "tools.experiment", "paper", "--out", str(tmp_path), "--no-plot"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    data = rrd.load(tmp_path / "paper.rrd")
    for name in ("sac", "clsac", "clsac_lv10", "clsac_lv50", "clsac_lv100"):
        roll = data[f"/runs/{name}/roll"]
        assert len(roll.t) == 3000, name
    assert rrd.has_blueprint(tmp_path / "paper.rrd")
