"""The study's steps in C (tools/experiment/study/kernel.c): the numpy loop's numbers bit for bit, a numpy fallback
when the
kernel cannot be built, and the study's accounting of what the user waits for."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from autopilot.controllers import ROBUSTNESS
from tools.experiment.study import (
    CONDITIONS,
    LONG_CONTROLLERS,
    StudyOptions,
    Task,
    native,
    run_study,
    simulate,
)

ROOT = Path(__file__).resolve().parents[4]
# the three conditions, and the sweeps' extremes (32 samples of delay, 90 % loss, 8 x severe turbulence)
MIX = ("nominal", "moderate", "severe", "delay=32", "loss=0.9", "turbulence=8")


@pytest.fixture(scope="module")
def kernel():
    """The kernel; on a machine with a C compiler it must build (a skip only where there is none)."""
    if native._compiler() is None and native.load() is None:
        pytest.skip(f"no C kernel here: {native.reason()}")
    lib = native.load()
    assert lib is not None, native.reason()
    return lib


def _same(a: dict, b: dict) -> list[str]:
    """The keys whose arrays differ in any bit (NaN payloads included), series key by key."""
    bad = []
    for key in a:
        if key == "series":
            bad += [f"series.{k}" for k in a[key] if a[key][k].tobytes() != b[key][k].tobytes()]
        elif key == "draws":
            bad += [f"draws.{k}" for k in a[key] if np.asarray(a[key][k]).tobytes() != np.asarray(b[key][k]).tobytes()]
        else:
            x, y = np.asarray(a[key]), np.asarray(b[key])
            if x.shape != y.shape or x.dtype != y.dtype or x.tobytes() != y.tobytes():
                bad.append(key)
    return bad


@pytest.mark.parametrize("controller", ROBUSTNESS)
def test_the_kernel_flies_every_controller_bit_for_bit_as_the_numpy_loop(kernel, controller):
    """Every metric, the window peaks, and every series of every step, under the three conditions and the sweeps'
    extremes (delay, loss, turbulence), the PFC drawn per run."""
    task = Task(controller, tuple((c, i) for c in MIX for i in range(2)), 7, 10.0, record=True)
    ref, fast = simulate(task, "numpy"), simulate(task, "kernel")
    assert _same(ref, fast) == []
    assert ref["series"]["u"].shape == (1000, len(task.runs))
    assert set(ref["pfc_paper"].tolist()) == {True, False}  # a batch of both PFCs (per-run coefficients)


@pytest.mark.parametrize("controller", ["sac", "clsac", "baseline"])
def test_the_kernel_judges_tracking_bit_for_bit_as_the_numpy_loop(kernel, controller):
    """30 s: the 20 s windows of autopilot.envelope.window_flags are judged (11 of them), under the three
    conditions and the sweeps' extremes; both flags come out True in some runs and False in others (the batch
    holds both, so the comparison can fail)."""
    task = Task(controller, tuple((c, i) for c in MIX for i in range(2)), 1, 30.0)
    ref, fast = simulate(task, "numpy"), simulate(task, "kernel")
    assert _same(ref, fast) == []
    for key in ("oscillating", "not_following", "bounded"):
        assert ref[key].dtype == bool and 0 < ref[key].sum() < len(task.runs), (key, ref[key])


def test_the_kernel_keeps_the_peak_of_every_30_s_window(kernel):
    """61 s: two full windows and a partial one (not reported), under nominal and moderate (the long flight's)."""
    task = Task("clsac_projection", (("nominal", 0), ("moderate", 1)), 3, 61.0)
    ref, fast = simulate(task, "numpy"), simulate(task, "kernel")
    assert _same(ref, fast) == []
    assert ref["window_peak_roll"].shape == (2, 2) and np.all(ref["window_peak_roll"] > 0)


def test_a_diverging_run_diverges_the_same_way(kernel, monkeypatch):
    """Infinite crosswind or bias: infinities and NaNs through the plant, the law's clip and the projection's
    min/max, with numpy's NaN rules (the metrics score +inf, the series hold the very NaNs)."""
    inf = float("inf")
    monkeypatch.setitem(CONDITIONS, "t_wind", dataclasses.replace(CONDITIONS["moderate"], name="t_wind", crosswind=inf))
    monkeypatch.setitem(CONDITIONS, "t_bias", dataclasses.replace(CONDITIONS["severe"], name="t_bias", roll_bias=inf))
    for controller in ("clsac_projection", "clsac_freeze", "baseline"):
        task = Task(controller, (("t_wind", 0), ("t_bias", 1), ("moderate", 2)), 1, 5.0, record=True)
        ref, fast = simulate(task, "numpy"), simulate(task, "kernel")
        assert _same(ref, fast) == [], controller
        assert np.isnan(ref["series"]["u"][:, :2]).any() and np.isinf(ref["ise_ref"][:2]).all()
        assert np.isfinite(ref["ise_ref"][2])


@pytest.mark.e2e  # slow: 20,000 steps of the numpy loop (about 3 s)
def test_the_kernel_flies_a_long_flight_as_the_numpy_loop(kernel):
    """200 s under moderate, CL-SAC: into the drift that amplifies any last bit (the published median peak
    |roll| passes 60 deg by 180-210 s, docs/experiments.md).  The whole 600 s table is
    tests/project/test_readme_robustness.py's: the kernel's numbers against those the numpy loop published."""
    task = Task(LONG_CONTROLLERS[0], (("moderate", 0),), 1, 200.0)
    ref, fast = simulate(task, "numpy"), simulate(task, "kernel")
    assert _same(ref, fast) == []
    assert ref["window_peak_roll"].shape == (1, 6)


_HEX = """
import json, sys
from tools.experiment.study import Task, native, simulate
r = simulate(Task("clsac", (("moderate", 0), ("severe", 1)), 4, 5.0))
print(json.dumps({"engine": native.engine(), "ise_ref": [float(v).hex() for v in r["ise_ref"]]}))
"""


@pytest.mark.parametrize(
    "env, why",
    [({"CLSAC_STUDY_KERNEL": "numpy"}, "numpy (CLSAC_STUDY_KERNEL=numpy)"), ({"CC": "false"}, "did not build")],
)
def test_without_the_kernel_the_study_steps_in_numpy_with_the_same_numbers(kernel, env, why):
    """Told so, or with a compiler that fails: the study says so on its first line and flies the numpy loop."""
    r = subprocess.run(
        [sys.executable, "-c", _HEX], env={**os.environ, **env}, cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["engine"].startswith("numpy (") and why in doc["engine"], doc["engine"]
    here = simulate(Task("clsac", (("moderate", 0), ("severe", 1)), 4, 5.0), "kernel")
    assert doc["ise_ref"] == [float(v).hex() for v in here["ise_ref"]]


def test_the_timing_counts_every_run_and_each_phase(capsys):
    """N is the 30 s runs and the 600 s runs; S covers both phases; the progress bars count both."""
    opts = StudyOptions(runs=2, seed=5, controllers=("clsac", "baseline"), sweep_runs=0, long_runs=1, chunk=100)
    lines = []
    summary = run_study(opts, None, log=lines.append, progress=True)
    t = summary["timing"]
    assert t["runs"] == 2 * 3 * 2 + 2 * 2 * 1  # 2 controllers x 3 conditions x 2 runs, then 2 x 2 conditions x 1
    p30, p600 = t["phases"]["runs_30s"], t["phases"]["runs_600s"]
    assert (p30["runs"], p30["duration_s"], p600["runs"], p600["duration_s"]) == (12, 30.0, 4, 600.0)
    assert t["wall_s"] >= p30["wall_s"] + p600["wall_s"] > 0
    assert p600["us_per_aircraft_s"] == pytest.approx(1e6 * p600["wall_s"] / (4 * 600.0))
    assert t["runs_per_s"] == pytest.approx(16 / t["wall_s"])
    err = capsys.readouterr().err
    assert "12/12 runs" in err and "600 s runs [" in err and "4/4 runs" in err
    assert re.search(r"\(steps: (C kernel|numpy \(.+\))\)$", lines[0]), lines[0]


@pytest.mark.e2e  # a subprocess that draws the figure and records the worst runs
def test_the_study_line_says_what_the_user_waited_for(tmp_path):
    out = tmp_path / "study"
    r = subprocess.run(
        [sys.executable, "-m", "tools.experiment", "robustness", "--runs", "2", "--controllers", "clsac,baseline"]
        + ["--sweep-runs", "0", "--long-runs", "1", "--no-progress", "--out", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    m = re.search(r"^16 runs \(12 of 30 s, 4 of 600 s\) in ([0-9.]+) s \(", r.stdout, re.M)
    assert m, r.stdout
    doc = json.loads((out / "summary.json").read_text())
    assert m.group(1) == f"{doc['timing']['wall_s']:.1f}"
    # summary.json is written last, so its time covers the table, the figure and the recording
    last = (out / "summary.json").stat().st_mtime_ns
    assert all((out / f).stat().st_mtime_ns <= last for f in ("table.md", "robustness.png", "worst.rrd"))


def test_the_plants_of_a_batch_are_discretised_at_once_bit_for_bit():
    """``zoh_many`` (the study's per-run plants, all at once) is ``zoh`` of each, bit for bit: repeated scale
    vectors, the nominal plant, and matrices of very different norms (each its own number of squarings)."""
    from autopilot.shared.numerics import expm, expm_many
    from tools.experiment.study.inputs import zoh_plant, zoh_plants

    rng = np.random.default_rng(11)
    scales = 1.0 + 0.4 * (2.0 * rng.random((40, 6)) - 1.0)
    scales[3] = scales[17]
    scales[20:25] = 1.0
    phi, gam = zoh_plants(scales, 0.01)
    for i, s in enumerate(scales):
        p, g = zoh_plant(s, 0.01)
        assert phi[i].tobytes() == p.tobytes() and gam[i].tobytes() == g.tobytes(), i
    ms = rng.standard_normal((30, 7, 7)) * np.logspace(-4, 2, 30)[:, None, None]
    ms[0] = 0.0
    many = expm_many(ms)
    assert all(many[i].tobytes() == expm(ms[i]).tobytes() for i in range(30))


def test_the_study_reads_the_laws_batch_and_kernel_forms_from_its_record(monkeypatch):
    """No list of names: a controller flies the batched study by its law's batch form (``Law.batch``, one that
    accepts its configuration), in C by its kernel form (``Law.kernel``), else the generic loop; taking a law's forms
    away sends it there (its record only changed), and a batch form without a kernel form steps in numpy."""
    from autopilot import controllers
    from autopilot.batch import BatchBaseline, BatchClSac
    from tools.experiment.study.cli import GENERIC, build_parser, plan_from_args
    from tools.experiment.study.sampling import StudyError

    assert {n for n, law in controllers.LAWS.items() if law.batch} == {"clsac", "baseline"}
    assert (
        controllers.get("clsac").batch_form() is BatchClSac
        and controllers.get("baseline").batch_form() is BatchBaseline
    )
    assert controllers.get("pid-ff").batch_form() is None  # the baseline's batch form flies no feed-forward
    assert all(controllers.get(n).batch_form() is None for n in ("mrac", "crm-mrac", "l1", "indi"))

    def plan():
        args = build_parser().parse_args(["--controllers", "baseline,clsac", "--runs", "2"])
        return [(text, tuple(opts.controllers)) for text, opts in plan_from_args(args)]

    assert plan() == [("kh2013a", ("baseline", "clsac"))]
    task = Task("baseline", (("moderate", 0), ("nominal", 1)), 2, 2.0)
    numpy_ = simulate(task, "numpy")
    monkeypatch.setitem(controllers.LAWS, "baseline", dataclasses.replace(controllers.LAWS["baseline"], kernel=""))
    assert _same(simulate(task), numpy_) == []  # no kernel form: the numpy loop, whatever the machine
    with pytest.raises(StudyError, match="no C kernel: baseline has no kernel form"):
        simulate(task, "kernel")
    monkeypatch.setitem(controllers.LAWS, "baseline", dataclasses.replace(controllers.LAWS["baseline"], batch=""))
    assert plan() == [("kh2013a", ("clsac",)), (GENERIC, ("baseline",))]
    with pytest.raises(StudyError, match="its law baseline has no batch form"):
        simulate(task)
