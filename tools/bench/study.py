"""Study benchmarks: the vectorised Monte Carlo (tools.experiment.study) against the plain one-run-at-a-time loop, and
Dask.

    python -m tools.bench study [--quick]      (or: python -m tools.bench study -- --runs N --no-dask)

Figures, all measured in this one benchmark run:

* ``batch_10k_runs_30s`` (target <= 20 s): 10,000 runs of the paper's 30 s square wave for one controller
  (CL-SAC, L_v = 20) under the "moderate" condition (turbulence, gust, crosswind, noise, bias, delay, loss,
  +-20 % plant), on the machine's 2 cores (``--workers 2``: two local processes, 4 chunks); and
  ``..._one_process``, the same in this process alone (chunks of 2500);
* ``batch_runs_per_s`` (one process) and ``plain_loop_runs_per_s``: the same work per run, batched, against
  ``tools.experiment.scenario.run_inprocess`` (ControlStep + sitl.Aircraft, one run after the other, nominal condition:
  the plain loop has no disturbances, so it is the cheaper case), and their ratio ``speedup_vs_plain_loop``;
* ``dask_2_over_1_worker_wall`` (target <= 0.75): the wall time of the same study on a local Dask cluster of 2
  worker processes divided by that of 1 worker (1.0 = no scaling, 0.5 = perfect), best of two alternating
  measurements each;
* the study as a user runs it, ``python -m tools.experiment robustness --runs 50 --sweep-runs 5 --long-runs 2``
  (2,205 runs of 30 s and 24 of 600 s, with its progress bar), ``--study-repeats`` times (default 3), medians:
  ``study_command_wall_s`` (from the command to its exit), ``study_summary_s`` (its last line's "N runs (...) in
  S s"), ``study_wall_over_summary`` (target <= 1.2: the line says what the user waited for, within 20 %; the rest
  is Python's start-up and the imports before the study starts) and ``study_long_over_30s_cost`` (target <= 1.0:
  the cost of a simulated second of one aircraft in the 600 s flights over that in the 30 s runs, from
  summary.json's ``timing.phases``; both are the same steps in C, and a long flight has less set-up per simulated
  second, so above 1 means a per-step overhead is back).  ``--with-numpy`` adds the same command with the numpy
  steps (``CLSAC_STUDY_KERNEL=numpy``, the study before the C kernel; about a minute) for comparison.
* ``faults_KIND_runs_per_s`` and ``faults_KIND_over_fault_free``: the C kernel's 30 s runs per second (one
  process, CL-SAC, "moderate", batches of ``--fault-runs`` runs, default 1000) with each KH2013A fault of
  ``FAULT_SPECS`` flown from 10 s (tools.experiment.study.faults; the faulted plants' ZOH included), medians of
  ``--fault-repeats`` (default 5) batches alternated with fault-free ones, and the median ratio to the fault-free
  rate measured in the same run (``faults_fault_free_runs_per_s``).  ``--faults-only``: just these.
* ``sigint_stop_s_one_process`` and ``sigint_stop_s_two_processes`` (target <= 1 s, docs/experiments.md promises
  0.1 s to stop and 0.15-0.2 s to the exit): from SIGINT to the study's exit, the documented maximum ``--runs
  10000000`` on this process and ``--runs 1000 --workers 2 --long-runs 0``, each signalled once its progress bar
  shows and half a second more, medians of ``--sigint-repeats`` (default 3).  The tests check only that the study
  stops and keeps what it did (tests/tools/experiment/study/test_study_never_hangs.py), bounded by a generous
  timeout: a load of 10 on 2 cores took 2.08 s once.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tools.bench import figure, print_table, report

TARGET_10K_S = 20.0
TARGET_DASK_RATIO = 0.75
TARGET_WALL_OVER_SUMMARY = 1.2  # the summary's "in S s" within 20 % of the command's wall time
TARGET_LONG_OVER_30S = 1.0  # a long flight's simulated second per aircraft costs no more than a 30 s run's
STUDY_ARGV = ["--runs", "50", "--sweep-runs", "5", "--long-runs", "2"]
_SUMMARY_LINE = re.compile(r"^(\d+) runs \((.*)\) in ([0-9.]+) s ", re.M)
QUICK_ARGV = ["--quick"]
FAULT_SPECS = ("effectiveness=0.3@10", "damping=0.3@10", "stuck@10", "off@10", "delay=0.05@10", "rate=20@10")


def _pairs(n: int, condition: str = "moderate"):
    return [(condition, i) for i in range(n)]


def bench_batch(runs: int, chunk: int = 2500, workers: int = 1) -> float:
    from tools.experiment.study import execute, make_tasks

    tasks = make_tasks(["clsac"], _pairs(runs), seed=0, chunk=chunk)
    t0 = time.perf_counter()
    execute(tasks, workers=workers)
    return time.perf_counter() - t0


def bench_plain(runs: int) -> float:
    from tools.experiment.scenario import PAPER, PAPER_RUNS, run_inprocess

    run_inprocess(PAPER, PAPER_RUNS[1])  # warm-up
    t0 = time.perf_counter()
    for _ in range(runs):
        run_inprocess(PAPER, PAPER_RUNS[1])
    return time.perf_counter() - t0


def bench_dask(runs: int, workers: int, chunk: int) -> float:
    from distributed import Client, LocalCluster

    from tools.experiment.study import execute, make_tasks

    tasks = make_tasks(["clsac"], _pairs(runs), seed=0, chunk=chunk)
    with LocalCluster(
        n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None, host="127.0.0.1"
    ) as cluster:
        with Client(cluster) as client:
            # imports and the C kernel's loading outside the timed region
            client.run(lambda: __import__("tools.experiment.study.native", fromlist=["load"]).load() and None)
            addr = cluster.scheduler_address
        t0 = time.perf_counter()
        execute(tasks, addr)
        return time.perf_counter() - t0


def bench_study_command(numpy: bool = False) -> dict:
    """``python -m tools.experiment robustness STUDY_ARGV`` in a subprocess, its progress bar on this terminal:
    the wall time from the command to its exit, its last line's N and S, and summary.json's phases."""
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    if numpy:
        env["CLSAC_STUDY_KERNEL"] = "numpy"
    with tempfile.TemporaryDirectory(prefix="bench-study-") as tmp:
        out = Path(tmp) / "study"
        argv = [sys.executable, "-m", "tools.experiment", "robustness", *STUDY_ARGV, "--out", str(out)]
        t0 = time.perf_counter()
        r = subprocess.run(argv, env=env, cwd=root, stdout=subprocess.PIPE, text=True, timeout=900)
        wall = time.perf_counter() - t0
        if r.returncode != 0:
            raise RuntimeError(f"the study exited {r.returncode}: {r.stdout.strip().splitlines()[-1:]}")
        m = _SUMMARY_LINE.search(r.stdout)
        if m is None:
            raise RuntimeError("the study printed no 'N runs (...) in S s' line")
        timing = json.loads((out / "summary.json").read_text(encoding="utf-8"))["timing"]
    print(m.group(0).strip())
    phases = timing["phases"]
    return {
        "wall": wall,
        "runs": int(m.group(1)),
        "summary": float(m.group(3)),
        "us_30s": phases["runs_30s"]["us_per_aircraft_s"],
        "us_600s": phases["runs_600s"]["us_per_aircraft_s"],
    }


def study_figures(repeats: int, numpy: bool = False) -> dict[str, dict]:
    """The study command's figures, medians of ``repeats`` runs (``numpy``: with the numpy steps)."""
    runs = [bench_study_command(numpy) for _ in range(repeats)]
    med = {k: statistics.median(r[k] for r in runs) for k in ("wall", "summary", "us_30s", "us_600s")}
    ratio = statistics.median(r["wall"] / r["summary"] for r in runs)
    cost = statistics.median(r["us_600s"] / r["us_30s"] for r in runs)
    tag = "_numpy" if numpy else ""
    cmd = "python -m tools.experiment robustness " + " ".join(STUDY_ARGV)
    return {
        f"study_command_wall_s{tag}": figure(med["wall"], "s", None, command=cmd, repeats=repeats),
        f"study_summary_s{tag}": figure(med["summary"], "s", None, runs=runs[0]["runs"]),
        f"study_wall_over_summary{tag}": figure(ratio, "1", None if numpy else TARGET_WALL_OVER_SUMMARY),
        f"us_per_aircraft_s_30s{tag}": figure(med["us_30s"], "us", None),
        f"us_per_aircraft_s_600s{tag}": figure(med["us_600s"], "us", None),
        f"study_long_over_30s_cost{tag}": figure(cost, "1", None if numpy else TARGET_LONG_OVER_30S),
    }


def fault_figures(runs: int, repeats: int) -> dict[str, dict]:
    """The kernel's runs per second with each fault of ``FAULT_SPECS`` against fault-free, alternated batch by
    batch in this process (medians, and the median of the per-round ratios)."""
    from sitl import damage
    from tools.experiment.study import Task, native, simulate

    if native.load() is None:
        print(f"no fault figures: no C kernel ({native.reason()})")
        return {}
    pairs = tuple(_pairs(runs))
    tasks = {"fault_free": Task("clsac", pairs, 0, 30.0)}
    tasks.update(
        {s.split("=")[0].split("@")[0]: Task("clsac", pairs, 0, 30.0, faults=(damage.parse(s),)) for s in FAULT_SPECS}
    )
    simulate(Task("clsac", pairs[:1], 0, 1.0), "kernel")  # the kernel's loading outside the timing
    rates: dict[str, list[float]] = {k: [] for k in tasks}
    for _ in range(repeats):
        for k, t in tasks.items():
            t0 = time.perf_counter()
            simulate(t, "kernel")
            rates[k].append(runs / (time.perf_counter() - t0))
    free = statistics.median(rates["fault_free"])
    figs = {"faults_fault_free_runs_per_s": figure(free, "run/s", None, runs=runs, repeats=repeats)}
    for spec, k in zip(FAULT_SPECS, list(tasks)[1:], strict=True):
        ratio = statistics.median(a / b for a, b in zip(rates[k], rates["fault_free"], strict=True))
        figs[f"faults_{k}_runs_per_s"] = figure(statistics.median(rates[k]), "run/s", None, fault=spec)
        figs[f"faults_{k}_over_fault_free"] = figure(ratio, "1", None)
    return figs


SIGINT_CASES = {
    "one_process": (["--runs", "10000000"], b"/270017100 runs"),
    "two_processes": (["--runs", "1000", "--workers", "2", "--long-runs", "0"], b"/44100 runs"),
}
TARGET_SIGINT_S = 1.0


def bench_sigint(argv: list[str], shows: bytes, after: float = 0.5) -> float:
    """Seconds from SIGINT to the exit of ``python -m tools.experiment robustness ARGV``, signalled once its stderr
    shows ``shows`` (the progress bar) and ``after`` seconds more; raises if it does not exit 130."""
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    with tempfile.TemporaryDirectory(prefix="bench-sigint-") as tmp:
        cmd = [sys.executable, "-m", "tools.experiment", "robustness", *argv, "--out", str(Path(tmp) / "s")]
        p = subprocess.Popen(cmd, env=env, cwd=root, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        try:
            seen, deadline = b"", time.monotonic() + 300
            os.set_blocking(p.stderr.fileno(), False)
            while shows not in seen:
                if time.monotonic() > deadline or p.poll() is not None:
                    raise RuntimeError(f"the study never showed {shows!r}: {seen[-300:]!r}")
                seen += p.stderr.read() or b""
                time.sleep(0.02)
            t_signal = time.monotonic() + after
            while time.monotonic() < t_signal:  # the pipe drained, so that the study never blocks writing to it
                p.stderr.read()
                time.sleep(0.02)
            t0 = time.perf_counter()
            p.send_signal(signal.SIGINT)
            while (code := p.poll()) is None:
                p.stderr.read()
                if time.perf_counter() - t0 > 120:
                    raise RuntimeError("the study did not stop within 120 s of SIGINT")
                time.sleep(0.005)
            took = time.perf_counter() - t0
        finally:
            if p.poll() is None:
                p.kill()
                p.wait()
    if code != 130:
        raise RuntimeError(f"the study exited {code} on SIGINT, not 130")
    return took


def sigint_figures(repeats: int) -> dict[str, dict]:
    """``sigint_stop_s_*``: medians of ``repeats`` SIGINTs of each ``SIGINT_CASES`` study."""
    figs = {}
    for name, (argv, shows) in SIGINT_CASES.items():
        took = [bench_sigint(argv, shows) for _ in range(repeats)]
        cmd = "python -m tools.experiment robustness " + " ".join(argv)
        figs[f"sigint_stop_s_{name}"] = figure(
            statistics.median(took), "s", TARGET_SIGINT_S, command=cmd, repeats=repeats, max=max(took)
        )
    return figs


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m tools.bench study", description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="2,000 runs instead of 10,000 (target scaled)")
    p.add_argument("--runs", type=int, default=None, help="runs of the batch figure (default 10000)")
    p.add_argument("--plain-runs", type=int, default=None, help="runs of the plain loop (default 20)")
    p.add_argument("--no-dask", action="store_true", help="skip the Dask figure")
    p.add_argument("--study-repeats", type=int, default=None, help="runs of the study command (default 3)")
    p.add_argument("--no-study", action="store_true", help="skip the study command's figures")
    p.add_argument("--with-numpy", action="store_true", help="also the study command with the numpy steps")
    p.add_argument("--fault-runs", type=int, default=None, help="runs per batch of the fault figures (default 1000)")
    p.add_argument("--fault-repeats", type=int, default=None, help="batches per fault figure (default 5)")
    p.add_argument("--faults-only", action="store_true", help="only the KH2013A fault figures")
    p.add_argument("--sigint-repeats", type=int, default=None, help="SIGINTs per stop figure (default 3)")
    p.add_argument("--sigint-only", action="store_true", help="only the SIGINT stop figures")
    args = p.parse_args(argv)
    if args.faults_only:
        figs = fault_figures(args.fault_runs or (200 if args.quick else 1000), args.fault_repeats or 5)
        print_table("study benchmarks: KH2013A faults in the C kernel (tools.experiment.study.faults)", figs)
        return figs
    if args.sigint_only:
        figs = sigint_figures(args.sigint_repeats or (1 if args.quick else 3))
        print_table("study benchmarks: from SIGINT to the exit", figs)
        return figs
    runs = args.runs or (2000 if args.quick else 10_000)
    plain_runs = args.plain_runs or (5 if args.quick else 20)
    figs: dict[str, dict] = {}
    target = TARGET_10K_S * runs / 10_000
    name = "batch_10k_runs_30s" if runs == 10_000 else f"batch_{runs}_runs_30s"
    wall1 = bench_batch(runs)
    wall = bench_batch(runs, chunk=max(runs // 4, 1), workers=2)
    figs[name] = figure(wall, "s", target, runs=runs, controller="clsac", condition="moderate", processes=2)
    figs[name + "_one_process"] = figure(wall1, "s", None, runs=runs)
    batch_rate = runs / wall1
    plain_rate = plain_runs / bench_plain(plain_runs)
    figs["batch_runs_per_s"] = figure(batch_rate, "run/s", None)
    figs["plain_loop_runs_per_s"] = figure(plain_rate, "run/s", None, runs=plain_runs, condition="nominal")
    figs["speedup_vs_plain_loop"] = figure(batch_rate / plain_rate, "x", None)
    if not args.no_dask:
        try:
            dask_runs = max(runs // 2, 1000)
            chunk = max(dask_runs // 4, 1)  # two chunks per worker
            # alternate, best of two each: other processes on a shared 2-core machine take whole cores at random
            one, two = math.inf, math.inf
            for _ in range(2):
                one = min(one, bench_dask(dask_runs, 1, chunk))
                two = min(two, bench_dask(dask_runs, 2, chunk))
            figs["dask_1_worker_runs_per_s"] = figure(dask_runs / one, "run/s", None, runs=dask_runs, chunk=chunk)
            figs["dask_2_workers_runs_per_s"] = figure(dask_runs / two, "run/s", None, runs=dask_runs, chunk=chunk)
            figs["dask_2_over_1_worker_wall"] = figure(two / one, "1", TARGET_DASK_RATIO)
        except ImportError as exc:
            print(f"no Dask figures: {exc}")
    if not args.no_study:
        figs.update(study_figures(args.study_repeats or (1 if args.quick else 3)))
        if args.with_numpy:
            figs.update(study_figures(1, numpy=True))
    figs.update(fault_figures(args.fault_runs or (200 if args.quick else 1000), args.fault_repeats or 5))
    figs.update(sigint_figures(args.sigint_repeats or (1 if args.quick else 3)))
    report("study benchmarks (vectorised Monte Carlo, tools.experiment.study)", figs)
    return figs


if __name__ == "__main__":
    main()
