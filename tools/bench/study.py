"""Study benchmarks: the vectorised Monte Carlo (tools.study) against the plain one-run-at-a-time loop, and Dask.

    python -m tools.bench study [--quick]      (or: python -m tools.bench study -- --runs N --no-dask)

Figures, all measured in this one benchmark run:

* ``batch_10k_runs_30s`` (target <= 20 s): 10,000 runs of the paper's 30 s square wave for one controller
  (CL-SAC, L_v = 20) under the "moderate" condition (turbulence, gust, crosswind, noise, bias, delay, loss,
  +-20 % plant), on the machine's 2 cores (``--workers 2``: two local processes, 4 chunks); and
  ``..._one_process``, the same in this process alone (chunks of 2500);
* ``batch_runs_per_s`` (one process) and ``plain_loop_runs_per_s``: the same work per run, batched, against
  ``tools.scenario.run_inprocess`` (ControlStep + sitl.Aircraft, one run after the other, nominal condition:
  the plain loop has no disturbances, so it is the cheaper case), and their ratio ``speedup_vs_plain_loop``;
* ``dask_2_over_1_worker_wall`` (target <= 0.75): the wall time of the same study on a local Dask cluster of 2
  worker processes divided by that of 1 worker (1.0 = no scaling, 0.5 = perfect), best of two alternating
  measurements each.
"""

from __future__ import annotations

import argparse
import math
import time

from tools.bench import figure, load_warning, print_table

TARGET_10K_S = 20.0
TARGET_DASK_RATIO = 0.75
QUICK_ARGV = ["--quick"]


def _pairs(n: int, condition: str = "moderate"):
    return [(condition, i) for i in range(n)]


def bench_batch(runs: int, chunk: int = 2500, workers: int = 1) -> float:
    from tools.study import execute, make_tasks

    tasks = make_tasks(["clsac"], _pairs(runs), seed=0, chunk=chunk)
    t0 = time.perf_counter()
    execute(tasks, workers=workers)
    return time.perf_counter() - t0


def bench_plain(runs: int) -> float:
    from tools.scenario import PAPER, PAPER_RUNS, run_inprocess

    run_inprocess(PAPER, PAPER_RUNS[1])  # warm-up
    t0 = time.perf_counter()
    for _ in range(runs):
        run_inprocess(PAPER, PAPER_RUNS[1])
    return time.perf_counter() - t0


def bench_dask(runs: int, workers: int, chunk: int) -> float:
    from distributed import Client, LocalCluster

    from tools.study import execute, make_tasks

    tasks = make_tasks(["clsac"], _pairs(runs), seed=0, chunk=chunk)
    with LocalCluster(
        n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None, host="127.0.0.1"
    ) as cluster:
        with Client(cluster) as client:
            client.run(lambda: __import__("tools.study"))  # imports outside the timed region
            addr = cluster.scheduler_address
        t0 = time.perf_counter()
        execute(tasks, addr)
        return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m tools.bench study", description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="2,000 runs instead of 10,000 (target scaled)")
    p.add_argument("--runs", type=int, default=None, help="runs of the batch figure (default 10000)")
    p.add_argument("--plain-runs", type=int, default=None, help="runs of the plain loop (default 20)")
    p.add_argument("--no-dask", action="store_true", help="skip the Dask figure")
    args = p.parse_args(argv)
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
    print_table("study benchmarks (vectorised Monte Carlo, tools.study)", figs)
    warning = load_warning()
    if warning:
        print(warning)
    return figs


if __name__ == "__main__":
    main()
