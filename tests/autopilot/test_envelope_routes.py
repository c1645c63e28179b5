"""One verdict on every route (autopilot.envelope.verdict; issue 36 item 3): the same flight judged by the
in-process loop, the robustness study's flight, the damage study's flight and the launcher (lockstep, e2e) comes
out the same, a square MIMO plant's rudder and sideslip included; every route clips every law at the surface's
stop."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

MIMO = "jsbsim:c172x:surface=aileron+rudder"
AILERON_STOP = math.radians(17.5)  # the c172x's aileron (sitl.plant.surface_limit_rad)


@pytest.fixture(scope="module")
def mimo_flight():
    """The MIMO baseline in light turbulence, seed 1, 30 s: in process, in the robustness study, in the damage study."""
    from tools.experiment.damage.flight import fly_record
    from tools.experiment.damage.grid import NONE, DamageFlight
    from tools.experiment.mimo_inprocess import run_mimo
    from tools.experiment.study.flights import StudyFlight, fly_study_flight

    r = run_mimo(MIMO, "baseline", disturbances=(("seed", 1), ("turbulence", "light")))
    study = fly_study_flight(StudyFlight("baseline", MIMO, "light", 1))
    damage = fly_record(DamageFlight(MIMO, "baseline", NONE, None, 10.0, 1, 30.0, "light"))
    return r, study, damage


def test_the_mimo_rudder_saturation_is_out_on_every_route(mimo_flight):
    """The rudder saturated in about half the steps (a hand count on the series), past the 20 % the aileron may:
    out of the envelope in the in-process verdict, the robustness study and the damage study alike."""
    from autopilot.envelope import verdict

    r, study, damage = mimo_flight
    s = r["series"]
    rudder_lim = math.radians(r["sideslip"]["channels"][1]["limit_deg"])
    share = r["sideslip"]["saturated_fraction"]["rudder"]
    assert share == pytest.approx(np.mean(np.abs(s["u2"]) >= rudder_lim * (1 - 1e-6)), abs=0.01) and share > 0.2
    c = verdict(s["t"], s["phi"], s["u"], AILERON_STOP, ref=s["ym_ol"], sideslip=r["sideslip"])
    assert c["ok"] is False and f"rudder saturated {100 * share:.1f} % of the flight (limit 20 %)" in c["reason"]
    assert study["bounded"] is False and damage["controlled"] is False
    assert damage["reason"] == c["reason"]
    # the roll channel alone is inside: only the second channel puts it out
    assert verdict(s["t"], s["phi"], s["u"], AILERON_STOP, ref=s["ym_ol"])["ok"] is True


def test_in_process_every_law_clips_at_the_surfaces_stop():
    """run_inprocess flies SAC and CL-SAC at the c172x aileron's 17.5 deg as the launcher and the studies do (it
    flew them at the scenario's 30 deg)."""
    from tools.experiment.scenario import PAPER, run_inprocess, run_of

    sc = replace(PAPER, plant="jsbsim:c172x", faults=("delay=0.1@10",))
    for controller in ("sac", "clsac"):
        u = run_inprocess(sc, run_of(controller)).series["u"]
        assert np.max(np.abs(u)) <= AILERON_STOP + 1e-12, controller


def test_the_siso_oscillation_is_out_in_process_and_in_the_damage_study():
    """The c172x SAC flight with a 60 ms delay from 10 s, still air, 60 s: the same verdict and reason in process
    (run_inprocess at the stop, ``verdict``) and in the damage study's flight."""
    from autopilot.envelope import Envelope, verdict
    from tools.experiment.damage.flight import fly_record
    from tools.experiment.damage.grid import DamageFlight
    from tools.experiment.scenario import PAPER, run_inprocess, run_of

    sc = replace(PAPER, plant="jsbsim:c172x", duration_s=60.0, faults=("delay=0.06@10",), disturbances=(("seed", 1),))
    s = run_inprocess(sc, run_of("sac"), atmosphere=True).series
    c = verdict(s["t"], s["phi"], s["u"], AILERON_STOP, Envelope(surface="aileron"), ref=s["ym_ol"])
    damage = fly_record(DamageFlight("jsbsim:c172x", "sac", "delay", 0.06, 10.0, 1, 60.0, "none"))
    assert c["ok"] is False and damage["controlled"] is False and damage["oscillating"] is True
    assert damage["reason"] == c["reason"] and "regular 4 deg swings" in c["reason"]


@pytest.mark.e2e
def test_the_launcher_and_the_damage_study_agree_on_the_mimo_baseline(mimo_flight, tmp_path):
    """Issue 36's must-show: ``tools.launch --lockstep --plant jsbsim:c172x:surface=aileron+rudder --controller
    baseline --turbulence light --seed 1`` and the damage study's same cell: neither is controlled, for the same
    reason (the launcher's lockstep flight is bit for bit run_mimo's)."""
    _, study, damage = mimo_flight
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "tools.launch", "--lockstep", "--plant", MIMO, "--controller", "baseline"]
    cmd += ["--turbulence", "light", "--seed", "1", "--out", str(out), "--no-png"]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert p.returncode == 3, p.stdout + p.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["controlled"]["ok"] is False and study["bounded"] is False and damage["controlled"] is False
    assert "rudder saturated" in s["controlled"]["reason"] and "rudder saturated" in damage["reason"]
