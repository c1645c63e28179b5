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
"""

from __future__ import annotations

import argparse
import statistics
import time

from tools.bench import figure, load_warning, machine_load, print_table

QUICK_ARGV = ["--quick"]
TARGET_OF_FLOOR = 0.85
FAULTS = (("none", None), ("effectiveness", 0.3), ("stuck", 0.0), ("rate", 20.0), ("delay", 0.05))


def floor_s(plant: str, kind: str, value, reps: int) -> float:
    """Seconds per 30 s flight of the plant alone with the fault (median of ``reps``)."""
    from sitl import damage
    from sitl import plant as plants
    from tools.experiment.damage.flight import disturbances
    from tools.experiment.damage.grid import NONE, fault_of
    from tools.experiment.scenario import Scenario, _atmosphere, _inprocess_disturbances

    faults = () if kind == NONE else (fault_of(kind, value, 10.0),)
    scen = Scenario(plant=plant, disturbances=disturbances("light", 1), faults=faults)
    times = []
    for _ in range(reps):
        dist = _inprocess_disturbances(scen, atmosphere=True)
        inj = _atmosphere(scen, dist)
        ac = plants.build(plant, 1000.0, None, dist, plants.needs_damaged_model(faults))
        adv = ac.advance if inj is None else (lambda u, m, _ac=ac, _inj=inj: _inj.advance(_ac, u, m))
        if faults:
            adv = damage.ScheduledEffects(ac, damage.Schedule(faults, 0.0, 1e-3), adv).advance
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
    from tools.experiment.damage.grid import Flight
    from tools.experiment.study import execute

    tasks = [Flight(plant, "clsac", k, v, 10.0, s) for s in range(1, seeds + 1) for k, v in FAULTS]
    t0 = time.perf_counter()
    execute(tasks, None, None, workers, simulate=_floor_task)
    return len(tasks) / (time.perf_counter() - t0)


def study_rate(plant: str, workers: int, seeds: int) -> float:
    """Flights per second of the damage study's tasks on ``workers`` local processes."""
    from tools.experiment.damage.flight import simulate
    from tools.experiment.damage.grid import Flight
    from tools.experiment.study import execute

    tasks = [Flight(plant, "clsac", k, v, 10.0, s) for s in range(1, seeds + 1) for k, v in FAULTS]
    t0 = time.perf_counter()
    execute(tasks, None, None, workers, simulate=simulate)
    return len(tasks) / (time.perf_counter() - t0)


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m tools.bench.damage", description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="one seed, one floor repetition")
    p.add_argument("--seeds", type=int, default=None, help="seeds per fault (default 4, quick 1)")
    args = p.parse_args(argv or [])
    seeds = args.seeds or (1 if args.quick else 4)
    reps = 1 if args.quick else 3
    load = machine_load()
    figs = {}
    for plant, tag, target in (("jsbsim:c172x", "jsbsim", TARGET_OF_FLOOR), ("kh2013a", "kh2013a", None)):
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
    print_table(f"damage study, load {load['load1']} on {load['cpus']} CPU(s)", figs)
    warning = load_warning()
    if warning:
        print(warning)
    return figs


if __name__ == "__main__":
    main()
