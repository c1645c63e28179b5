"""The damage study's speed against its plant's step floor (issue 29, item 5).

    python -m tools.bench damage [--quick]          (or: python -m tools.bench.damage [--quick] [--seeds N])

The floor of a flight is its plant alone: the same plant (JSBSim's model copy when the fault needs it), the same
fault schedule (``sitl.damage.ScheduledEffects``), 3000 control periods of 10 physics steps with a held command,
nothing else (no law, no series, no verdict): the least a flight of the study can cost.  On W workers the
floor's wall clock also holds what every flight must do before its first step, build its plant (load and trim
the model), and ``damage_*_floor`` the loop alone.  The study's flights are
``tools.experiment.damage`` tasks (CL-SAC, 30 s, light turbulence, the fault at 10 s: none, effectiveness 0.3,
stuck at 0, rate 20 deg/s, delay 50 ms) run by ``tools.experiment.study.execute`` on 1 and 2 local processes.
The floor on W workers is measured the same way, not assumed: the same tasks, each the plant alone, on the same
pool of W processes (two processes flying at once share the machine's memory and caches, so the floor's
flights/s on 2 workers is less than twice its 1-worker figure).  Figure: the study's flights/s over the floor's
on as many workers; target >= 0.85 on JSBSim, reported without a target on the KH2013A (whose step is
microseconds: the law and the verdict dominate).

Each law against the PID (issue 38, item 7): every law of the registry (``autopilot.controllers``) flies the same
tasks (the faults above, ``--law-seeds`` seeds) one after the other in this process, each flight timed alone;
``damage_<plant>_<law>_of_pid`` is the law's flights per second (one over its median seconds per flight) over the
PID's (``baseline``) on the same plant, target >= 0.5 for a law flown through the generic loop (no batch form).
"""

from __future__ import annotations

import argparse
import statistics
import time

from tools.bench import figure, flights_per_s, machine_load, report

QUICK_ARGV = ["--quick"]
TARGET_OF_FLOOR = 0.85
TARGET_OF_PID = 0.5  # a law without a batch form flies at least half as fast as the PID in the same loop
FAULTS = (("none", None), ("effectiveness", 0.3), ("stuck", 0.0), ("rate", 20.0), ("delay", 0.05))


def floor_s(plant: str, kind: str, value, reps: int) -> float:
    """Seconds per 30 s flight of the plant alone with the fault (median of ``reps``)."""
    from tools.experiment.damage.flight import disturbances
    from tools.experiment.damage.grid import NONE, fault_of
    from tools.experiment.scenario import Scenario, aircraft

    faults = () if kind == NONE else (fault_of(kind, value, 10.0),)
    scen = Scenario(plant=plant, disturbances=disturbances("light", 1), faults=faults)  # 1000 Hz physics
    times = []
    for _ in range(reps):
        _ac, adv = aircraft(scen, atmosphere=True)
        t0 = time.perf_counter()
        for _k in range(3000):
            adv(0.01, 10)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _floor_task(task) -> dict:
    """A study task's floor (picklable, for ``execute``): one flight of its plant alone with its fault."""
    return {"s": floor_s(task.plant, task.kind, task.value, 1)}


def floor_rate(plant: str, workers: int, seeds: int) -> float:
    """Flights per second of the plant alone, the study's tasks on ``workers`` local processes."""
    from tools.experiment.damage.grid import DamageFlight

    tasks = [DamageFlight(plant, "clsac", k, v, 10.0, s) for s in range(1, seeds + 1) for k, v in FAULTS]
    return flights_per_s(tasks, workers, _floor_task)


def study_rate(plant: str, workers: int, seeds: int) -> float:
    """Flights per second of the damage study's tasks on ``workers`` local processes."""
    from tools.experiment.damage.flight import run_damage_task
    from tools.experiment.damage.grid import DamageFlight

    tasks = [DamageFlight(plant, "clsac", k, v, 10.0, s) for s in range(1, seeds + 1) for k, v in FAULTS]
    return flights_per_s(tasks, workers, run_damage_task)


def law_seconds(plant: str, controllers, seeds: int) -> dict[str, list[float]]:
    """{controller: seconds per flight}: the study's tasks (``FAULTS`` x ``seeds``) flown one at a time here
    (``tools.experiment.damage.flight.run_damage_task``), each timed alone, the controllers in turn on each task (a
    change of the machine's load falls on every law alike)."""
    from tools.experiment.damage.flight import run_damage_task
    from tools.experiment.damage.grid import DamageFlight

    out: dict[str, list[float]] = {c: [] for c in controllers}
    for s in range(1, seeds + 1):
        for k, v in FAULTS:
            for c in controllers:
                t0 = time.perf_counter()
                run_damage_task(DamageFlight(plant, c, k, v, 10.0, s))
                out[c].append(time.perf_counter() - t0)
    return out


def law_figures(plant: str, tag: str, seeds: int, laws=None) -> dict:
    """Each registered law's flights per second over the PID's on ``plant`` (median seconds per flight)."""
    from autopilot import controllers as registry

    laws = list(laws or registry.NAMES)
    times = law_seconds(plant, list(dict.fromkeys(["baseline", *laws])), seeds)
    med = {c: statistics.median(v) for c, v in times.items()}
    figs = {}
    for c in laws:
        if c == "baseline":
            continue
        figs[f"damage_{tag}_{c}_of_pid"] = figure(
            med["baseline"] / med[c],
            "x",
            TARGET_OF_PID,
            higher=True,
            flights_per_s=round(1.0 / med[c], 3),
            pid_flights_per_s=round(1.0 / med["baseline"], 3),
            median_s=round(med[c], 4),
            pid_median_s=round(med["baseline"], 4),
            n=len(FAULTS) * seeds,
        )
    return figs


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m tools.bench.damage", description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="one seed, one floor repetition")
    p.add_argument("--seeds", type=int, default=None, help="seeds per fault (default 4, quick 1)")
    p.add_argument("--law-seeds", type=int, default=1, help="seeds per fault for each law against the PID (default 1)")
    p.add_argument("--laws-only", action="store_true", help="only each law against the PID (no floor)")
    args = p.parse_args(argv or [])
    seeds = args.seeds or (1 if args.quick else 4)
    reps = 1 if args.quick else 3
    load = machine_load()
    figs = {}
    for plant, tag, target in (("jsbsim:c172x", "jsbsim", TARGET_OF_FLOOR), ("kh2013a", "kh2013a", None)):
        figs.update(law_figures(plant, tag, max(1, args.law_seeds)))
        if args.laws_only:
            continue
        floors = {k: floor_s(plant, k, v, reps) for k, v in FAULTS}
        mean_floor = statistics.fmean(floors.values())
        figs[f"damage_{tag}_floor"] = figure(
            mean_floor,
            "s",
            per_fault={k: round(v, 4) for k, v in floors.items()},
            note="the plant alone, one 30 s flight, mean over the faults",
        )
        for workers in (1, 2):
            rate = study_rate(plant, workers, seeds)
            floor = floor_rate(plant, workers, seeds)
            figs[f"damage_{tag}_{workers}_worker{'s' if workers > 1 else ''}_of_floor"] = figure(
                rate / floor,
                "x",
                target,
                higher=True,
                flights_per_s=round(rate, 3),
                floor_flights_per_s=round(floor, 3),
                floor_assumed_flights_per_s=round(workers / mean_floor, 3),
            )
    report(f"damage study, load {load['load1']} on {load['cpus']} CPU(s)", figs)
    return figs


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
