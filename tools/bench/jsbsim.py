"""JSBSim benchmarks: the plant's physics step, and a lockstep flight over MAVLink on ``jsbsim:c172x``.

    python -m tools.bench jsbsim [--quick]          (or: python -m tools.bench.jsbsim [--quick] [--runs N])

Targets: the lockstep flight at 100 Hz control and 1 kHz physics, MAVLink signing on and the .rrd written
(the launcher's defaults), at least 20x real time: <= 50 ms of wall time per simulated second (median of the
runs).  The physics step (``JsbsimPlant.advance``: the servo, the safety pilot every 10 steps and one
``FGFDMExec.run``) is reported per step, without a target (JSBSim's own step is about 11 us).  The JSBSim Monte
Carlo (``python -m tools.experiment robustness --plant jsbsim:c172x``'s flights, ``tools.experiment.study.flights``:
in-process 30 s flights on ``tools.experiment.study.execute``) in flights per second for 1 and 2 local workers,
without a target.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from tools.bench import figure, flights_per_s, machine_load, report

QUICK_ARGV = ["--quick"]
TARGET_MS_PER_SIM_S = 50.0  # 20x real time


def bench_physics(seconds: float) -> dict:
    from sitl.plant import build

    plant = build("jsbsim:c172x", 1000.0)
    per_step = []
    for _ in range(int(seconds)):
        t0 = time.perf_counter_ns()
        for _k in range(100):
            plant.advance(0.01, 10)
        per_step.append((time.perf_counter_ns() - t0) / 1000.0 / 1000.0)  # us per physics step
    return {"median": statistics.median(per_step), "min": min(per_step), "n": len(per_step)}


def bench_lockstep(runs: int, duration: float) -> list[float]:
    """Real-time factors of lockstep flights on jsbsim:c172x (signing and .rrd on, as the launcher flies)."""
    from tools.flight import Flight

    rtf = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(runs):
            res = Flight(
                lockstep=True, plant="jsbsim:c172x", duration=duration, out=Path(tmp) / f"f{i}", quiet=True, png=False
            ).run()
            if not res.ok:
                raise RuntimeError(f"jsbsim lockstep flight {i}: {res.reason} (see {res.out})")
            rtf.append(res.summary["rtf"])
    return rtf


def bench_monte_carlo(workers: int, seeds: int) -> float:
    """Flights per second of the JSBSim Monte Carlo with ``workers`` local processes."""
    from tools.experiment.study.flights import fly_study_flight, make_flights

    flights = make_flights("c172x", ["clsac"], [63.0, 117.0], ["none", "moderate"], seeds)
    return flights_per_s(flights, workers, fly_study_flight)


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m tools.bench.jsbsim", description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="fewer, shorter runs")
    p.add_argument("--runs", type=int, default=None, help="lockstep flights (default 3, quick 1)")
    args = p.parse_args(argv or [])
    runs = args.runs or (1 if args.quick else 3)
    duration = 10.0 if args.quick else 30.0
    load = machine_load()
    phys = bench_physics(5 if args.quick else 20)
    rtf = bench_lockstep(runs, duration)
    m = statistics.median(rtf)
    figs = {
        "jsbsim_physics_step": figure(phys["median"], "us", min=round(phys["min"], 2), n=phys["n"]),
        "jsbsim_lockstep_100hz_with_rrd": figure(
            1000.0 / m,
            "ms",
            TARGET_MS_PER_SIM_S,
            rtf=round(m, 1),
            rtf_runs=[round(x, 1) for x in rtf],
            note="wall ms per sim s, 1 kHz physics, signing, .rrd",
        ),
    }
    for workers in (1, 2):
        figs[f"jsbsim_monte_carlo_{workers}_worker{'s' if workers > 1 else ''}"] = figure(
            bench_monte_carlo(workers, 1 if args.quick else 6), "1/s", note="30 s flights per wall second"
        )
    report(f"JSBSim (c172x), load {load['load1']} on {load['cpus']} CPU(s)", figs)
    return figs


if __name__ == "__main__":
    main()
