"""Core benchmarks: controller step, physics step, the whole ``paper`` experiment in-process.

    python -m tools.bench core [--quick]          (or: python -m tools.bench.core [--quick] [--json PATH])

Targets (per call, median): controller step (SISO path) <= 10 us, physics step (Aircraft.step) <= 5 us;
the whole paper experiment in-process (5 runs, summary.json, no figure) <= 3 s wall, median of several.
Per-call times are batch time / calls, from time.perf_counter_ns, over many batches; median and p90 are
over the batches.  The inputs are a recorded closed-loop run, so the controller sees realistic signals.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from autopilot.clsac import ClSac
from autopilot.config import ClSacConfig
from autopilot.shared.process import standard_json
from sitl.aircraft import Aircraft, AircraftConfig
from tools.bench import figure, report, summarise_us, timed_batches
from tools.experiment.scenario import PAPER, PAPER_RUNS, controller_config, run_inprocess

TARGET_CONTROLLER_US = 10.0
TARGET_PHYSICS_US = 5.0
TARGET_EXPERIMENT_S = 3.0
BATCH = 1000  # calls per timed batch
QUICK_ARGV = ["--quick"]  # what `python -m tools.bench --quick` passes to main()


def _recorded():
    """(phi, um, u) of the paper's CL-SAC run as Python floats, for replay."""
    s = run_inprocess(PAPER, PAPER_RUNS[1]).series
    return s["phi"].tolist(), s["um"].tolist(), s["u"].tolist()


def bench_controller(batches: int, fast: bool = True) -> dict:
    phi, um, _ = _recorded()
    pairs = list(zip(phi[:BATCH], um[:BATCH]))  # the first 10 s of flight, replayed from the start
    ctrl = ClSac(controller_config(PAPER, PAPER_RUNS[1], ClSacConfig()), fast=fast)
    if fast and not ctrl._fast:  # noqa: SLF001 - make sure the figure is the SISO path it claims to be
        raise RuntimeError("ClSac did not take its SISO fast path")

    def batch():
        for y, m in pairs:
            ctrl(y, m)

    return summarise_us(timed_batches(batch, len(pairs), batches, setup=ctrl.reset))


def bench_physics_step(batches: int) -> dict:
    _, _, u = _recorded()
    # 10 physics steps per control sample, as in the scenario (1 kHz physics, 100 Hz control)
    cmds = [c for c in u[: BATCH // 10] for _ in range(10)]
    ac = Aircraft(AircraftConfig(physics_rate_hz=PAPER.physics_rate_hz))
    step = ac.step

    def batch():
        for c in cmds:
            step(c)

    return summarise_us(timed_batches(batch, len(cmds), batches, setup=ac.reset))


def bench_physics_advance(batches: int) -> dict:
    _, _, u = _recorded()
    cmds = u[:BATCH]
    n = PAPER.physics_per_control
    ac = Aircraft(AircraftConfig(physics_rate_hz=PAPER.physics_rate_hz))
    advance = ac.advance

    def batch():
        for c in cmds:
            advance(c, n)

    return summarise_us(timed_batches(batch, len(cmds), batches, setup=ac.reset))


def bench_experiment(repeats: int) -> dict:
    from tools.experiment.runs import run_experiment

    times = []
    with tempfile.TemporaryDirectory(prefix="bench-exp-") as tmp:
        run_experiment(tmp, plot=False)  # warm-up (caches, first-call imports)
        for _ in range(repeats):
            t0 = time.perf_counter()
            run_experiment(tmp, plot=False)
            times.append(time.perf_counter() - t0)
    return {"median": statistics.median(times), "min": min(times), "max": max(times), "n": repeats}


def bench_cli_cold() -> float:
    """``python -m tools.experiment paper --no-plot`` as a fresh process (interpreter start and imports included)."""
    root = Path(__file__).resolve().parents[2]
    with tempfile.TemporaryDirectory(prefix="bench-cli-") as tmp:
        t0 = time.perf_counter()
        proc = subprocess.run(
            [sys.executable, "-m", "tools.experiment", "paper", "--no-plot", "--out", tmp],
            cwd=root,
            capture_output=True,
            text=True,
        )
        dt = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"tools.experiment failed: {proc.stderr.strip()}")
    return dt


TARGET_BAD_PLANT_FILE_S = 1.0  # docs/plants.md: a bad plant file is refused in one line, exit 2, within a second


def bench_bad_plant_file(repeats: int) -> float:
    """Median seconds of ``python -m tools.pfc --plant FILE`` refusing a 100 MB plant file (sparse) from its size
    alone, one line, exit 2 (the interpreter's start included).  tests/sitl/test_plant_files.py checks only that it is
    not read (no speed asserted in a test)."""
    root = Path(__file__).resolve().parents[2]
    times = []
    with tempfile.TemporaryDirectory(prefix="bench-plant-") as tmp:
        f = Path(tmp) / "big.toml"
        with open(f, "wb") as fh:
            fh.truncate(100 * 1024 * 1024)
        for _ in range(repeats):
            t0 = time.perf_counter()
            proc = subprocess.run(
                [sys.executable, "-m", "tools.pfc", "--plant", str(f)], cwd=root, capture_output=True, text=True
            )
            times.append(time.perf_counter() - t0)
            if proc.returncode != 2 or len(proc.stderr.strip().splitlines()) != 1:
                raise RuntimeError(f"the 100 MB plant file was not refused in one line: {proc.stderr[-300:]!r}")
    return sorted(times)[len(times) // 2]


def bench_figure() -> float:
    from tools.view.plots import save_paper_figure

    results = [run_inprocess(PAPER, r) for r in PAPER_RUNS]
    with tempfile.TemporaryDirectory(prefix="bench-fig-") as tmp:
        t0 = time.perf_counter()
        save_paper_figure(results, Path(tmp) / "paper.png")
        return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m tools.bench core", description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="fewer repetitions")
    p.add_argument("--json", metavar="PATH", help="also write the figures to this JSON file")
    p.add_argument("--no-extras", action="store_true", help="skip the informational figures (cold CLI, figure)")
    args = p.parse_args(argv)
    batches = 30 if args.quick else 300
    repeats = 2 if args.quick else 7

    figs: dict[str, dict] = {}
    c = bench_controller(batches)
    figs["controller_step_siso"] = figure(
        c["median"], "us", TARGET_CONTROLLER_US, p90=c["p90"], min=c["min"], batches=c["n"], calls=BATCH
    )
    cm = bench_controller(max(batches // 30, 5), fast=False)
    figs["controller_step_matrix"] = figure(
        cm["median"], "us", None, p90=cm["p90"], min=cm["min"], batches=cm["n"], calls=BATCH
    )
    ph = bench_physics_step(batches)
    figs["physics_step"] = figure(
        ph["median"], "us", TARGET_PHYSICS_US, p90=ph["p90"], min=ph["min"], batches=ph["n"], calls=BATCH
    )
    pa = bench_physics_advance(max(batches // 3, 5))
    figs["physics_advance_10_steps"] = figure(
        pa["median"], "us", None, p90=pa["p90"], min=pa["min"], batches=pa["n"], calls=BATCH
    )
    ex = bench_experiment(repeats)
    figs["paper_experiment_inprocess"] = figure(
        ex["median"], "s", TARGET_EXPERIMENT_S, min=ex["min"], max=ex["max"], runs=ex["n"]
    )
    if not args.no_extras:
        figs["paper_experiment_cli_cold"] = figure(bench_cli_cold(), "s", None, note="fresh process, --no-plot")
        figs["paper_figure"] = figure(bench_figure(), "s", None, note="save paper.png")
        figs["bad_plant_file_refused"] = figure(
            bench_bad_plant_file(repeats), "s", TARGET_BAD_PLANT_FILE_S, note="100 MB file, python -m tools.pfc"
        )

    report("core benchmarks (per-call times: median, p90 and min over batches of calls)", figs)
    if args.json:
        Path(args.json).write_text(standard_json({"core": figs}, indent=2) + "\n", encoding="utf-8")
        print(f"wrote {Path(args.json).resolve()}")
    return figs


if __name__ == "__main__":
    main()
