"""Mid-flight faults in the KH2013A study (tools/experiment/study/faults.py): the C kernel flies each kind bit for bit
as the numpy loop; the numpy loop's plant under each fault equals a continuous-time solver's (scipy solve_ivp) of
the faulted linear system driven by the same commands; the command line refuses what it cannot fly exactly."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from sitl import damage
from tools.experiment.study import Task, native, simulate

ROOT = Path(__file__).resolve().parents[4]
DEG = np.pi / 180.0
DT = 0.01
SPECS = (
    "effectiveness=0.3@10",
    "effectiveness=2.5@3.005:12",  # an onset between control steps: the first step at or after it
    "damping=0.3@5:20",
    "stuck@10",
    "stuck=5@7.5:20",
    "off@10",
    "delay=0.05@10",
    "delay=0.03@3:12",
    "rate=5@10",
    "rate=20@3:12",
)


@pytest.fixture(scope="module")
def kernel():
    if native._compiler() is None and native.load() is None:
        pytest.skip(f"no C kernel here: {native.reason()}")
    lib = native.load()
    assert lib is not None, native.reason()
    return lib


def _faults(*specs) -> tuple:
    return tuple(damage.parse(s) for s in specs)


def _bits(a: dict, b: dict) -> list[str]:
    bad = [k for k in ("ise_ref", "ise_crm", "energy", "tv", "max_abs_u", "max_abs_roll", "sat_fraction", "bounded")]
    bad = [k for k in bad if np.asarray(a[k]).tobytes() != np.asarray(b[k]).tobytes()]
    bad += [f"series.{k}" for k in a["series"] if a["series"][k].tobytes() != b["series"][k].tobytes()]
    return bad


# runs of moderate (noise, loss, turbulence, gusts, scaled plants) and nominal, across blocks of noise draws
RUNS = tuple(("moderate", i) for i in range(4)) + (("nominal", 0), ("severe", 1))


@pytest.mark.parametrize(
    "spec",
    [
        *SPECS,
        "effectiveness=0.5@4 damping=0.5@6:14 stuck@9:11 delay=0.02@8",
        "rate=10@5 effectiveness=0.5@8 stuck@12:13 delay=0.02@9",
    ],
)
@pytest.mark.parametrize("controller", ["clsac", "baseline"])
def test_the_kernel_flies_each_fault_bit_for_bit_as_the_numpy_loop(kernel, controller, spec):
    task = Task(controller, RUNS, 7, 20.0, True, _faults(*spec.split()))
    a, b = simulate(task, "kernel"), simulate(task, "numpy")
    assert _bits(a, b) == []


def test_every_kind_the_study_flies_is_flown_bit_for_bit_above():
    """A kind whose record gives it a study path (sitl.fault_kinds.FaultKind.study) is in SPECS: the C kernel is held
    to the numpy loop for it (docs/adding-a-fault-kind.md)."""
    from sitl.fault_kinds import STUDY_KINDS

    assert {damage.parse(s).kind for s in SPECS} == set(STUDY_KINDS)


def test_a_fault_changes_nothing_before_its_onset_and_something_after(kernel):
    clean = simulate(Task("clsac", RUNS, 7, 20.0, True), "kernel")
    hit = simulate(Task("clsac", RUNS, 7, 20.0, True, _faults("effectiveness=0.3@10")), "kernel")
    k = 1000  # step 1000 is t = 10 s: the first step flown with the fault; its roll is still the clean one's
    for key in ("phi", "u", "p", "delta_r"):
        assert clean["series"][key][: k + 1].tobytes() == hit["series"][key][: k + 1].tobytes(), key
    assert np.all(np.abs(clean["series"]["phi"][k + 50 :] - hit["series"]["phi"][k + 50 :]).max(axis=0) > 1e-6)


# ------------------------------------------------------------------------------------ against solve_ivp
def _nominal():
    from sitl.uncertainty import PlantScales

    a, b = PlantScales(*np.ones(6)).matrices()
    return np.asarray(a, dtype=float), np.asarray(b, dtype=float).ravel()


def _reference(series: dict, fault: damage.Fault, duration: float) -> np.ndarray:
    """The truth states [v, p, r, phi, delta, delta_dot] at every control step, from solve_ivp (DOP853) of the
    continuous plant, with the fault written here from docs/faults.md: from the first step k0 at or after START
    (to the first at or after END) effectiveness F scales the airframe rows' column of delta, damping F scales
    L_p; stuck freezes delta (at DEG, or where it is) and delta_dot = 0; off drives the servo with 0; delay D
    steps drives it with the command of D steps before (the command held at k0 before that).  The command is
    the law's, held over each period (the nominal condition loses no message)."""
    a0, b0 = _nominal()
    u = series["u"][:, 0]
    steps = int(round(duration / DT))
    k0 = int(np.ceil(round(fault.start / DT, 6)))
    k1 = steps if fault.end is None else int(np.ceil(round(fault.end / DT, 6)))
    af = a0.copy()
    if fault.kind == "effectiveness":
        af[:4, 4] *= fault.value
    if fault.kind == "damping":
        af[1, 1] *= fault.value
    frozen = np.eye(6)[:4]
    x = np.zeros(6)
    out = np.zeros((steps, 6))
    for k in range(steps):
        on = k0 <= k < k1
        if fault.kind == "stuck" and k == k0:  # the surface jams at step k0 (the state recorded there)
            x = x.copy()
            x[4] = x[4] if fault.value is None else fault.value
            x[5] = 0.0
        out[k] = x
        us = u[k]
        if on and fault.kind == "off":
            us = 0.0
        if on and fault.kind == "delay":
            d = int(round(fault.value / DT))
            us = u[k - d] if k - d >= k0 else u[k0 - 1]
        a = af if on else a0
        if on and fault.kind == "stuck":

            def f(_t, s, a=a):
                return np.concatenate([frozen @ (a @ s), [0.0, 0.0]])
        else:

            def f(_t, s, a=a, us=us):
                return a @ s + b0 * us

        x = solve_ivp(f, (0.0, DT), x, method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]
    return out


@pytest.mark.parametrize("spec", ["effectiveness=0.3@5", "damping=0.3@5:12", "stuck@5", "stuck=5@5:10", "off@5"])
def test_the_numpy_plant_under_a_fault_equals_a_continuous_time_solver(spec):
    fault = damage.parse(spec)
    duration = 15.0
    r = simulate(Task("baseline", (("nominal", 0),), 0, duration, True, (fault,)), "numpy")
    ref = _reference(r["series"], fault, duration)
    got = np.column_stack([r["series"][k][:, 0] for k in ("v", "p", "r", "phi", "delta_r")])
    err = np.abs(got - ref[:, :5]).max(axis=0)
    # 1e-9 of the states' scale (the study's roll reaches ~0.2 rad): a ZOH of the same system within the solver's
    # own tolerance; a fault a step late, or the wrong matrix, is off by 1e-4 or more
    assert err.max() < 1e-8, (spec, err)
    if fault.kind == "stuck":
        k0 = 500
        k1 = 1000 if fault.end is not None else len(got)
        held = got[k0:k1, 4]
        assert np.all(held == held[0]), "the surface moved while stuck"
        if fault.value is not None:
            assert held[0] == fault.value


def test_a_delay_of_whole_periods_equals_a_continuous_time_solver():
    fault = damage.parse("delay=0.05@5")
    r = simulate(Task("baseline", (("nominal", 0),), 0, 15.0, True, (fault,)), "numpy")
    ref = _reference(r["series"], fault, 15.0)
    got = np.column_stack([r["series"][k][:, 0] for k in ("v", "p", "r", "phi", "delta_r")])
    assert np.abs(got - ref[:, :5]).max() < 1e-8


# ------------------------------------------------------------------------------------ the command line
def _cli(*argv, cwd=ROOT):
    return subprocess.run(
        [sys.executable, "-m", "tools.experiment", *argv], capture_output=True, text=True, cwd=cwd, timeout=300
    )


@pytest.mark.parametrize(
    ("spec", "says"),
    [
        ("rate=0@1", "must be > 0"),
        ("delay=0.015@10", "whole control periods"),
        ("bogus@1", "unknown kind"),
        ("effectiveness=0.3", "missing @START"),
        ("effectiveness=-1@10", "must be > 0"),
        ("effectiveness=0.3@nan", "finite"),
        ("stuck@-5", "START must be >= 0"),
        ("inertia=2@1", "the KH2013A study flies"),
    ],
)
def test_a_fault_the_study_cannot_fly_is_one_line_and_exit_2(spec, says, tmp_path):
    r = _cli("robustness", "--fault", spec, "--runs", "2", "--out", str(tmp_path / "o"))
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and says in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "o").exists()


def test_the_study_with_a_fault_records_it_and_its_replays_fly_it(tmp_path):
    out = tmp_path / "o"
    argv = ["--fault", "effectiveness=0.3@10", "--runs", "8", "--sweep-runs", "0", "--long-runs", "0"]
    r = _cli("robustness", *argv, "--controllers", "clsac,baseline", "--out", str(out), "--no-progress")
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert [(f["kind"], f["value"], f["start"], f["end"]) for f in s["faults"]] == [("effectiveness", 0.3, 10.0, None)]
    w = s["results"]["clsac"]["severe"]["worst"]
    assert w["replay_inprocess"].endswith("--fault effectiveness=0.3@10")
    rep = _cli(*w["replay_inprocess"].split()[3:])
    assert rep.returncode == 0, rep.stderr
    ise = float(next(line.split()[1] for line in rep.stdout.splitlines() if line.strip().startswith("ise_ref")))
    assert ise == pytest.approx(w["metrics"]["ise_ref"], rel=1e-9)


# ------------------------------------------------------------------------------------ against the SITL's own plant
@pytest.mark.parametrize(
    "spec",
    [
        "effectiveness=0.3@10",
        "damping=0.3@10",
        "stuck@10",
        "stuck=5@10:20",
        "off@10:15",
        "delay=0.05@10",
        "delay=0.03@4:12",
        "rate=5@10",
        "rate=20@10",
        "rate=5@5:15",
        "rate=10@5 effectiveness=0.5@8",
        "rate=5@5 delay=0.03@7 off@20:22",
    ],
)
@pytest.mark.parametrize("controller", ["clsac", "baseline"])
def test_the_study_under_a_fault_is_the_in_process_sitl_flight_with_it(controller, spec):
    """The same fault flown by ``run_inprocess`` (the SITL's sitl.Aircraft at 1 kHz, ``set_effect`` and
    ``damage.Actuator`` one physics step at a time, in still air): the same linear system and the same fault
    semantics computed another way, so equal to rounding (measured: 2e-12 relative at most, 1e-10 under a rate
    limit, whose coast-or-not branch can flip on a last bit), not bit for bit.  A rate limit is the check that the
    study's SUBSTEPS physics steps are the SITL's."""
    import dataclasses

    from tools.experiment.scenario import BASELINE_RUN, PAPER, PAPER_RUNS, run_inprocess

    faults = _faults(*spec.split())
    ref = run_inprocess(
        dataclasses.replace(PAPER, faults=faults), PAPER_RUNS[1] if controller == "clsac" else BASELINE_RUN
    ).metrics
    r = simulate(Task(controller, tuple(("nominal", i) for i in range(8)), 0, 30.0, False, faults))
    i = int(np.flatnonzero(r["pfc_paper"])[0]) if controller == "clsac" else 0  # run_inprocess: the paper's PFC
    clean = simulate(Task(controller, (("nominal", i),), 0, 30.0))
    assert r["ise_ref"][i] != pytest.approx(clean["ise_ref"][0], rel=1e-3)  # the fault does change the flight
    for key in ("ise_ref", "ise_crm", "energy", "tv", "max_abs_u"):
        assert r[key][i] == pytest.approx(ref[key], rel=1e-8), key
