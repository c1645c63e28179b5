"""A plant that diverges (a +200 1/s pole) is flown, then stopped OUT OF ENVELOPE (exit 3) by the SITL, naming the
plant, the flight time and the state, never a crash of the SITL; the bound at its edge; who is blamed when."""

from __future__ import annotations

import json
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from sitl import model
from sitl import plant as plants
from tools.flight.outcome import diverged_verdict

SERVO = f"[servo]\nwn2 = {model.SERVO_WN2!r}\ntwo_zeta_wn = {model.SERVO_2ZETA_WN!r}\n"
# p' = 200 p + 30 delta, phi' = p: a roll mode with a +200 1/s pole, far faster than the servo can hold
POLE_200 = (
    """name = "pole-200"
[input]
surface = "aileron"
[airframe]
states = ["p", "phi"]
A = [[200.0, 0.0], [1.0, 0.0]]
B = [[30.0], [0.0]]
C = [[0.0, 1.0]]
roll = "phi"
roll_rate = "p"
"""
    + SERVO
)


def test_the_state_bound_at_its_edge():
    assert plants.STATE_LIMIT == 1e6
    x = np.zeros(6)
    x[1] = 1e6
    assert plants.divergence(x) is None  # at the bound: still flown
    x[:] = 0.99e6  # sum of squares above the bound, no entry beyond it
    assert plants.divergence(x) is None
    x[:] = 0.0
    x[1] = np.nextafter(1e6, 2e6)
    assert plants.divergence(x).startswith("|p| reached 1e+06 rad/s, beyond the 1e+06")
    x[1], x[3] = 0.0, np.nan
    assert plants.divergence(x) == "phi became nan (not a finite number)"
    x[3], x[4] = 0.0, -np.inf
    assert plants.divergence(x) == "delta became -inf (not a finite number)"


def _child(name, code, exited_at):
    return SimpleNamespace(name=name, code=code, exited_at=exited_at, started=0.0)


def _stats(gaps: dict, mono: float = 10.0) -> dict:
    div = {"t_s": 0.16, "reason": "|p| reached 5e+06 rad/s, beyond the 1e+06 the SITL flies", "plant": "p.toml"}
    out = {n: {"sent": {"longest_gap_from_mono": t, "longest_gap_s": s}} for n, (t, s) in gaps.items()}
    out["sitl"]["diverged"] = {**div, "mono": mono}
    return out


FLOWN = {"fraction": 0.032, "steps": 16, "steps_asked": 500, "sim_time_s": 0.16, "duration_s": 5.0}


@pytest.mark.parametrize(
    "case, gaps, codes, expect",
    [
        ("nobody stalled", {"autopilot": (1, 0.1), "sitl": (1, 0.1), "gcs": (1, 0.1)}, {}, 3),
        ("the autopilot stalled before", {"autopilot": (8.0, 2.5), "sitl": (1, 0.1), "gcs": (1, 0.1)}, {}, None),
        ("a stall after the divergence", {"autopilot": (10.5, 2.5), "sitl": (1, 0.1), "gcs": (1, 0.1)}, {}, 3),
        ("the gcs failed before", {"autopilot": (1, 0.1), "sitl": (1, 0.1), "gcs": (1, 0.1)}, {"gcs": (1, 9.0)}, None),
        ("the gcs failed after", {"autopilot": (1, 0.1), "sitl": (1, 0.1), "gcs": (1, 0.1)}, {"gcs": (1, 11.0)}, 3),
    ],
)
def test_the_divergence_is_the_verdict_unless_a_process_failed_or_stalled_first(case, gaps, codes, expect):
    children = {n: _child(n, *codes.get(n, (None, None))) for n in ("autopilot", "gcs")}
    children["sitl"] = _child("sitl", 3, 10.01)
    got = diverged_verdict(children, _stats(gaps), FLOWN, t_end=12.0)
    if expect is None:
        assert got is None, case
        return
    code, failed, why = got
    assert (code, failed) == (3, None)
    assert why == (
        "out of envelope: the plant p.toml diverged at 0.160 s of flight: |p| reached 5e+06 rad/s, beyond the 1e+06 "
        "the SITL flies; the SITL stopped the flight; flown 3.2 % (16 of 500 steps, 0.16 of 5 s)"
    )
    children["sitl"].code = 1  # a SITL that crashed, whatever its stats say, is not a divergence
    assert diverged_verdict(children, _stats(gaps), FLOWN, t_end=12.0) is None


@pytest.mark.e2e
@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_a_plus_200_pole_is_out_of_envelope_not_a_crash(tmp_path, mode):
    f = tmp_path / "pole200.toml"
    f.write_text(POLE_200)
    # a plant with no design is refused (issue 30): the default gains are flown, from a parameter file of the user's own
    params = tmp_path / "defaults.params"
    params.write_text("# the default gains, flown on a plant they were not designed for\n")
    out = tmp_path / "run"
    argv = [sys.executable, "-m", "tools.launch", "--duration", "5", "--plant", str(f), "--params", str(params)]
    argv += ["--out", str(out), "--no-rrd"]
    r = subprocess.run(
        argv + (["--lockstep"] if mode == "lockstep" else []), capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 3, (r.returncode, r.stdout[-2000:], r.stderr[-2000:])
    assert "Traceback" not in r.stderr and "OverflowError" not in r.stdout + r.stderr
    last = r.stdout.strip().splitlines()[-1]
    assert last.startswith(f"OUT OF ENVELOPE: the plant {f} diverged at ") and "the SITL stopped the flight" in last
    s = json.loads((out / "summary.json").read_text())
    assert (s["ok"], s["outcome"], s["exit_code"], s["completed"], s["failed"]) == (
        False,
        "OUT OF ENVELOPE",
        3,
        False,
        None,
    )
    div = s["diverged"]
    assert div["plant"] == str(f) and 0 < div["t_s"] < 2.0 and s["flown"]["fraction"] < 0.4
    # what it flew stayed within the bound up to the last frame recorded; the frame that left it is named
    series = np.load(out / "sitl_series.npz")
    last_state = np.array([series[k][-1] for k in ("v", "p", "r", "phi", "delta_r", "delta_r_dot")])
    assert np.all(np.isfinite(last_state)) and np.max(np.abs(last_state)) <= plants.STATE_LIMIT
    value = float(div["reason"].split(" reached ")[1].split(" ")[0])
    assert value > plants.STATE_LIMIT
    sitl = json.loads((out / "sitl.json").read_text())
    assert sitl["diverged"]["t_s"] == div["t_s"] and sitl["exit_reason"].startswith("the plant diverged at")
