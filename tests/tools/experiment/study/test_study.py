"""The Monte Carlo study: summary.json, replay, the command line, and a real local Dask cluster."""

from __future__ import annotations

import json
import math
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from autopilot.controllers import ROBUSTNESS
from tools.experiment.study import (
    CONDITIONS,
    StudyError,
    StudyOptions,
    Task,
    replay,
    run_study,
    simulate,
)

ROOT = Path(__file__).resolve().parents[4]
SMALL = dict(runs=6, seed=5, controllers=("clsac", "baseline"), sweep_runs=0, long_runs=0, chunk=100)


def _results(summary: dict) -> dict:
    return summary["results"]


@pytest.mark.e2e  # slow: matplotlib and rerun imports, the figure and the Rerun recording of the worst runs
def test_study_writes_its_files(tmp_path):
    summary = run_study(StudyOptions(**SMALL), tmp_path, log=lambda _m: None, progress=False)
    doc = json.loads((tmp_path / "summary.json").read_text())
    assert doc["results"] == json.loads(json.dumps(summary["results"]))
    assert (tmp_path / "table.md").read_text().startswith("| controller |")
    assert (tmp_path / "robustness.png").stat().st_size > 1000
    assert (tmp_path / "worst.rrd").stat().st_size > 1000


def test_summary_holds_shares_percentiles_and_a_replayable_worst_run():
    summary = run_study(StudyOptions(**SMALL), None, log=lambda _m: None, progress=False)
    doc = json.loads(json.dumps(summary, allow_nan=False))
    for ctrl in SMALL["controllers"]:
        for cond in CONDITIONS:
            agg = doc["results"][ctrl][cond]
            assert agg["runs"] == 6 and 0.0 <= agg["bounded_share"] <= 1.0
            assert set(agg["p50"]) == set(agg["p95"]) >= {"ise_ref", "energy", "max_abs_roll", "sat_fraction"}
            w = agg["worst"]
            assert w["seed"] == 5 and w["replay_inprocess"].startswith("python -m tools.experiment replay")
            assert "--lockstep" in w["replay_mavlink"] and f"--seed {5 * 1_000_000 + w['run']}" in w["replay_mavlink"]
            if cond != "severe":
                continue
            # the share and the percentiles against the per-run numbers of the same runs flown in one batch
            runs = simulate(Task(ctrl, tuple((cond, i) for i in range(6)), 5))
            assert agg["bounded_share"] == pytest.approx(float(np.mean(runs["bounded"])))
            assert agg["p95"]["energy"] == float(np.sort(runs["energy"])[5])  # nearest rank: the 6th of 6
            if not runs["bounded"].all():  # the worst run is the unbounded one that rolled furthest
                worst_roll = float(np.max(runs["max_abs_roll"][~runs["bounded"]]))
                assert w["metrics"]["max_abs_roll"] == (worst_roll if np.isfinite(worst_roll) else None)
            # the replay is the same run: bit for bit the same numbers
            r = replay(ctrl, cond, 5, w["run"], record=False)
            assert float(r["ise_ref"][0]) == (
                w["metrics"]["ise_ref"] if w["metrics"]["ise_ref"] is not None else np.inf
            )
            # p50 <= p95, and the worst run is at least as bad as the p95 when it is unbounded
            if agg["p95"]["ise_ref"] is not None:
                assert agg["p50"]["ise_ref"] <= agg["p95"]["ise_ref"]


def test_results_do_not_depend_on_the_chunk_size():
    one = {**SMALL, "controllers": ("clsac",)}
    a = run_study(StudyOptions(**{**one, "chunk": 7}), None, log=lambda _m: None, progress=False)
    b = run_study(StudyOptions(**{**one, "chunk": 100}), None, log=lambda _m: None, progress=False)
    c = run_study(StudyOptions(**{**one, "chunk": 5, "workers": 2}), None, log=lambda _m: None, progress=False)
    assert _results(c) == _results(a)
    assert _results(a) == _results(b)


@pytest.mark.e2e  # a subprocess
def test_replay_command_line_prints_the_study_numbers():
    r = replay("clsac", "moderate", 2, 3, record=False)
    out = subprocess.run(
        [sys.executable, "-m", "tools.experiment", "replay", "--controller", "clsac", "--condition", "moderate"]
        + ["--seed", "2", "--run", "3"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    assert f"ise_ref       {float(r['ise_ref'][0]):.10g}" in out.stdout


@pytest.mark.e2e  # subprocesses
@pytest.mark.parametrize(
    "argv, message",
    [
        (["--runs", "0"], "--runs: must be in [1, 10000000], got '0'"),
        (["--controllers", "nope"], "unknown controller 'nope'"),
        (["--conditions", "calm"], "unknown condition 'calm'"),
        (["--chunk", "0"], "--chunk: must be in [1, 1000000], got '0'"),
        (["--scheduler", "localhost:8786"], "--scheduler must look like tcp://HOST:PORT"),
    ],
)
def test_bad_study_flags_exit_2_with_one_line(argv, message, tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "tools.experiment", "robustness", "--out", str(tmp_path / "x"), *argv],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], out.stderr


def test_options_reject_unknown_names():
    with pytest.raises(StudyError, match="unknown controller"):
        StudyOptions(controllers=("pid",))
    assert "baseline" in ROBUSTNESS and "clsac_freeze" in ROBUSTNESS


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.e2e
def test_dask_cluster_of_two_workers_gives_the_local_results(tmp_path):
    """A real cluster on loopback: ``dask scheduler`` and two ``dask worker`` processes started here."""
    pytest.importorskip("distributed")
    from distributed import Client

    dask = shutil.which("dask", path=os.path.dirname(sys.executable)) or shutil.which("dask")
    if dask is None:
        pytest.skip("the dask command is not installed")
    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "DASK_DISTRIBUTED__WORKER__DAEMON": "False"}
    procs = []
    logs = []
    try:
        sched_log = open(tmp_path / "scheduler.log", "w")  # noqa: SIM115
        logs.append(sched_log)
        procs.append(
            subprocess.Popen(
                [dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                stdout=sched_log,
                stderr=subprocess.STDOUT,
                cwd=ROOT,
                env=env,
            )
        )
        for i in range(2):
            wlog = open(tmp_path / f"worker{i}.log", "w")  # noqa: SIM115
            logs.append(wlog)
            procs.append(
                subprocess.Popen(
                    [dask, "worker", addr, "--nthreads", "1", "--no-dashboard", "--host", "127.0.0.1"],
                    stdout=wlog,
                    stderr=subprocess.STDOUT,
                    cwd=ROOT,
                    env=env,
                )
            )
        deadline = time.monotonic() + 60
        client = None
        while client is None:
            try:
                client = Client(addr, timeout="5s")
            except (OSError, TimeoutError):
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.5)
        with client:
            client.wait_for_workers(2, timeout=60)
            assert len(client.scheduler_info()["workers"]) == 2
            # each worker steps the study's batches in C as this process does (tools/experiment/study/native.py)
            from tools.experiment.study import native

            engines = client.run(lambda: __import__("tools.experiment.study.native", fromlist=["engine"]).engine())
            assert sorted(engines.values()) == [native.engine()] * 2
        opts = dict(SMALL, chunk=3, long_runs=1)  # the 600 s flights go to the cluster too
        local = run_study(StudyOptions(**opts), None, log=lambda _m: None, progress=False)
        remote = run_study(StudyOptions(**opts, scheduler=addr), None, log=lambda _m: None, progress=False)
        assert remote["scheduler"] == addr
        assert _results(remote) == _results(local)
        assert remote["long_flight"] == local["long_flight"] and remote["timing"]["runs"] == 6 * 2 * 3 + 2 * 2
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=5)
        for f in logs:
            f.close()


_MATRICES = """
import json, sys
import numpy as np
from autopilot import ClSac, ClSacConfig
from tools.experiment.study.inputs import dryden, zoh_plant, zoh_plants
rng = np.random.default_rng(5)
out = [m.ravel() for _ in range(20) for m in zoh_plant(1 + 0.4 * (2 * rng.random(6) - 1), 0.01)]
out += [m.ravel() for m in zoh_plants(1 + 0.4 * (2 * rng.random((20, 6)) - 1), 0.01)]  # the study's: all at once
out += [getattr(dryden(0.01), k).ravel() for k in ("ad", "ld", "c", "l0")]
law = ClSac(ClSacConfig())._s
out += [np.ravel(np.asarray(law[k], dtype=float)) for k in sorted(law)]
print(json.dumps([float(v).hex() for m in out for v in m]))
"""


def test_study_matrices_are_the_same_bits_under_every_blas_kernel():
    """The plant's and the law's discretisation and the Dryden filter do not depend on the BLAS kernel OpenBLAS
    picks for the CPU (before: 29 entries of a plant's [Phi, Gamma] differed between its SkylakeX and Haswell
    kernels, and the long flight's median moved from 63.1 to 70.7 deg)."""
    import json
    import os
    import subprocess
    import sys

    def bits(coretype):
        env = dict(os.environ)
        env.pop("OPENBLAS_CORETYPE", None)
        if coretype:
            env["OPENBLAS_CORETYPE"] = coretype
        r = subprocess.run([sys.executable, "-c", _MATRICES], env=env, capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        return json.loads(r.stdout)

    native = bits(None)
    assert len(native) > 2 * 20 * 60  # 2 x 20 plants [Phi (6x6), Gamma (6x4)], the Dryden filter, the law
    for coretype in ("Haswell", "Sandybridge", "Prescott"):
        assert bits(coretype) == native, coretype


def test_the_figure_of_a_study_whose_runs_all_diverged_is_drawn_and_never_loses_the_summary(tmp_path):
    """Every run diverged (``robustness --fault effectiveness=1e308@10``): no metric has a value above zero, which a
    log scale cannot show (matplotlib: "Data cannot be log-scaled"), and the study exited 2 without summary.json.
    The figure is drawn (those rows on a linear scale), and a figure that fails anyway is one line, never an error:
    the summary is written first (issue 35, item 7)."""
    from tools.experiment.study.accumulate import Cell, Tally
    from tools.experiment.study.report import save_figure
    from tools.experiment.study.runner import write_study_files
    from tools.experiment.study.sampling import StudyOptions

    opts = StudyOptions(runs=2, controllers=("clsac", "baseline"), conditions=("nominal",), sweep_runs=0, long_runs=0)
    tally = Tally(exact=True)
    for ctrl in opts.controllers:
        cell = tally.cells.setdefault(ctrl, {})["nominal"] = Cell(True)
        for sample in cell.samples.values():
            sample.add(np.array([np.inf, np.nan]))
    png = save_figure(tally, opts, tmp_path / "robustness.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    lines = []
    tally.cells["clsac"]["nominal"] = object()  # a cell the figure cannot read: its own error, not the study's
    summary = {"partial": False, "sweep_runs": 0, "results": {c: {"nominal": {}} for c in opts.controllers}}
    assert write_study_files(summary, tally, opts, tmp_path, log=lines.append, table=False) == []
    assert len(lines) == 1 and lines[0].startswith("no figure: ") and not (tmp_path / "robustness.png").exists()


def test_an_error_after_the_first_runs_keeps_them_in_a_partial_summary():
    """A batch that fails after two batches of 2 runs were flown: the 4 runs are kept (partial, 4 of 8, the error's
    line); a batch that fails first is the error, as before (issue 35, item 7)."""
    from tools.experiment.study.runner import fly_study
    from tools.experiment.study.sampling import StudyOptions
    from tools.experiment.study.simulation import simulate

    opts = StudyOptions(runs=4, chunk=2, controllers=("clsac", "baseline"), conditions=("nominal",), sweep_runs=0,
                        long_runs=0)  # fmt: skip
    calls = []

    def third_fails(task):
        calls.append(task)
        if len(calls) == 3:
            raise ValueError("the third batch failed")
        return simulate(task)

    summary, tally, _ = fly_study(opts, log=lambda *_: None, progress=False, simulate=third_fails)
    assert summary["partial"] and summary["done"] == {"runs": 4, "of": 2 * 4} and tally.runs == 4
    assert summary["error"] == "ValueError: the third batch failed"
    assert summary["results"]["clsac"]["nominal"]["runs"] == 4 and not summary["results"]["baseline"]["nominal"]

    def fails(task):
        raise ValueError("no batch flies")

    with pytest.raises(ValueError, match="no batch flies"):
        fly_study(opts, log=lambda *_: None, progress=False, simulate=fails)


# ------------------------------------------------------------------------------------ the study's bounded share
def test_study_bounded_is_roll_below_60_deg_and_saturation_below_20_percent():
    """README "Robustness": a run is bounded when |roll| < 60 deg over the whole flight, the rudder is saturated
    less than 20 % of the steps and no 20 s window oscillates or fails to follow (autopilot.envelope; the flags
    themselves against the monitor in tests/autopilot/test_tracking.py); the share is the bounded runs over all."""
    from tools.experiment.study import Task, aggregate, merge, simulate

    task = Task("clsac", tuple(("severe", i) for i in range(16)), 5)
    runs = simulate(task)
    roll, sat = runs["max_abs_roll"], runs["sat_fraction"]
    inside = (roll < math.radians(60.0)) & (sat < 0.2)
    bounded = inside & ~runs["oscillating"] & ~runs["not_following"]
    assert runs["bounded"].tolist() == bounded.tolist()
    assert 0 < bounded.sum() < 16  # both kinds among these runs
    assert np.any((roll >= math.radians(60.0)) & (sat < 0.2))  # one fails on the roll alone
    assert np.any(inside & runs["oscillating"])  # and one on its limit cycle alone
    share = aggregate(merge([task], [runs])["clsac"], "severe", "clsac", 5)["bounded_share"]
    assert share == pytest.approx(bounded.sum() / 16, abs=1e-15)


def test_study_saturated_share_is_the_share_of_steps_at_the_limit():
    from tools.experiment.study import Task, simulate

    r = simulate(Task("clsac", (("severe", 9),), 5, 30.0, True))
    u = np.array(r["series"]["u"])[:, 0]
    at_limit = float(np.mean(np.abs(u) >= math.radians(30.0) - 1e-12))
    assert float(r["sat_fraction"][0]) == pytest.approx(at_limit, abs=1e-12) and at_limit > 0


@pytest.mark.parametrize("engine", ["numpy", "kernel"])
def test_the_study_counts_the_steps_its_command_was_clipped_at_the_limit(engine):
    """Four CL-SAC runs under severe turbulence, 10 s, in both engines: the saturated share is the number of steps
    whose recorded command is exactly +-30 deg (the laws clip to the limit) over the steps, counted here, and
    ``bounded`` is max |roll| < 60 deg and that share < 20 % (mutation: the kernel's or numpy's saturation test
    inverted or its bound moved past the limit)."""
    from tools.experiment.study import Task, native, simulate

    if engine == "kernel" and native.load() is None:
        pytest.skip(f"no C kernel here: {native.reason()}")
    r = simulate(Task("clsac", tuple(("severe", i) for i in range(4)), 3, 10.0, record=True), engine)
    u = r["series"]["u"]
    clipped = (np.abs(u) == math.radians(30.0)).sum(axis=0) / u.shape[0]
    assert np.array_equal(r["sat_fraction"], clipped) and clipped.max() > 0 and clipped.min() < 0.2
    # and tracking in every 20 s window (autopilot.envelope: neither oscillating nor not following)
    tracked = ~(np.asarray(r["oscillating"]) | np.asarray(r["not_following"]))
    want = [bool(m < math.radians(60.0) and s < 0.2 and k) for m, s, k in zip(r["max_abs_roll"], clipped, tracked)]
    assert r["bounded"].tolist() == want
