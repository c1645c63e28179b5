"""A Monte Carlo of scalar JSBSim flights over airspeed, turbulence and seed, on the study's executor.

    python -m tools.experiment.jsbsim_study --model c172x --airspeeds 63,90,117 --turbulence none,light,moderate
    --seeds 3
                                 [--controllers sac,clsac,baseline] [--workers N | --scheduler tcp://HOST:PORT]
                                 [--out DIR]

Each flight is the reference scenario flown in-process (``tools.experiment.scenario.run_inprocess``) on
``jsbsim:MODEL:airspeed_kt=V`` with JSBSim's own turbulence seeded with the flight's seed, and the parameter file
designed for the model (``tools.design.linearise.designed_params``: designed at one airspeed, flown at all).  A flight
is a
task of ``tools.experiment.study.execute``: one after the other, ``--workers`` local processes or a Dask cluster
(``--scheduler``), and its result depends on (controller, airspeed, turbulence, seed) only, so the summary is the
same whatever the number of workers.  Bounded: max |roll| < 60 deg and the command saturated in < 20 % of the
steps (as ``tools.experiment.study``).  Writes DIR/summary.json and prints, per controller and condition, the median
ise_ref and energy and the share of bounded flights.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from autopilot import controllers
from autopilot.shared.cli import OneLineArgumentParser
from autopilot.shared.process import write_json_atomic
from tools.experiment.study import BOUND_ROLL_RAD, BOUND_SAT_FRACTION, StudyError, execute

TURBULENCE = ("none", "light", "moderate", "severe")
CONTROLLERS = controllers.NAMES  # autopilot.controllers


@dataclass(frozen=True)
class Flight:
    """One JSBSim flight of the Monte Carlo; ``runs`` (one) is what ``tools.experiment.study.Progress`` counts."""

    controller: str
    model: str
    airspeed_kt: float
    turbulence: str
    seed: int

    @property
    def runs(self) -> tuple[int]:
        return (self.seed,)

    @property
    def condition(self) -> str:
        return f"{self.airspeed_kt:g}kt_{self.turbulence}"


def simulate(task: Flight) -> dict:
    """The flight's metrics, max |roll| and saturated fraction (picklable: runs in a worker)."""
    from sitl import plant as plants
    from tools.experiment.scenario import PAPER, run_inprocess, run_of

    plant = f"jsbsim:{task.model}:airspeed_kt={task.airspeed_kt!r}"
    dist = (("seed", task.seed),) + ((("turbulence", task.turbulence),) if task.turbulence != "none" else ())
    limit = min(PAPER.u_limit_rad, plants.surface_limit_rad(plant))
    scenario = replace(PAPER, plant=plant, u_limit_rad=limit, disturbances=dist)
    run = run_of(task.controller)
    res = run_inprocess(scenario, run)
    u, phi = res.series["u"], res.series["phi"]
    out = dict(res.metrics)
    out["max_abs_roll"] = float(np.max(np.abs(phi)))
    out["sat_fraction"] = float(np.mean(np.abs(u) >= limit * (1 - 1e-9)))
    out["bounded"] = bounded(out["max_abs_roll"], out["sat_fraction"])
    return out


def bounded(max_abs_roll_rad: float, sat_fraction: float) -> bool:
    """Whether one flight stayed bounded: max |roll| < 60 deg and the command saturated in < 20 % of the steps,
    both strict, both required (the study's envelope, ``tools.experiment.study.sampling``)."""
    return bool(max_abs_roll_rad < BOUND_ROLL_RAD and sat_fraction < BOUND_SAT_FRACTION)


def make_flights(model: str, controllers, airspeeds, turbulence, seeds: int) -> list[Flight]:
    return [
        Flight(c, model, float(v), t, s)
        for c in controllers
        for v in airspeeds
        for t in turbulence
        for s in range(seeds)
    ]


def summarise(flights: Sequence[Flight], results: Sequence[dict]) -> dict:
    """Per controller and condition: median ise_ref and energy, share bounded, and every flight's record."""
    table: dict[str, dict[str, dict]] = {}
    for f, r in zip(flights, results):
        cell = table.setdefault(f.controller, {}).setdefault(f.condition, {"flights": []})
        cell["flights"].append({"seed": f.seed, **r})
    for per in table.values():
        for cell in per.values():
            fl = cell["flights"]
            cell["ise_ref_p50"] = statistics.median(x["ise_ref"] for x in fl)
            cell["energy_p50"] = statistics.median(x["energy"] for x in fl)
            cell["bounded_share"] = sum(x["bounded"] for x in fl) / len(fl)
    return table


def format_table(table: dict) -> str:
    conditions = sorted({c for per in table.values() for c in per}, key=lambda c: (float(c.split("kt")[0]), c))
    lines = [f"{'condition':<20}" + "".join(f"{c + ' ise_ref/energy/bounded':>36}" for c in table)]
    for cond in conditions:
        row = f"{cond:<20}"
        for per in table.values():
            cell = per.get(cond)
            row += (
                f"{cell['ise_ref_p50']:>14.4g}{cell['energy_p50']:>12.4g}{100 * cell['bounded_share']:>9.0f} %"
                if cell
                else f"{'-':>36}"
            )
        lines.append(row)
    return "\n".join(lines)


def _list(text: str, what: str, convert=str) -> list:
    try:
        items = [convert(x.strip()) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list of {what}, got {text!r}") from None
    if not items:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list of {what}, got {text!r}")
    return items


def build_parser() -> OneLineArgumentParser:
    p = OneLineArgumentParser(prog="python -m tools.experiment.jsbsim_study", description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default="c172x", help="the JSBSim model (default c172x)")
    p.add_argument("--airspeeds", type=lambda t: _list(t, "airspeeds in kt", float), default=[63.0, 90.0, 117.0])
    p.add_argument("--turbulence", type=lambda t: _list(t, "intensities"), default=["none", "moderate"])
    p.add_argument("--seeds", type=int, default=3, help="flights per controller and condition (default 3)")
    p.add_argument("--controllers", type=lambda t: _list(t, "controllers"), default=list(CONTROLLERS))
    p.add_argument("--workers", type=int, default=1, help="local processes (default 1; results do not change)")
    p.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT", help="a Dask scheduler")
    p.add_argument("--out", default=None, metavar="DIR", help="write DIR/summary.json")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from sitl import plant as plants

    bad = [t for t in args.turbulence if t not in TURBULENCE] + [c for c in args.controllers if c not in CONTROLLERS]
    if bad:
        parser.error(
            f"unknown turbulence or controller {bad[0]!r} (turbulence: {', '.join(TURBULENCE)}; "
            f"controllers: {', '.join(CONTROLLERS)})"
        )
    if args.seeds < 1 or args.workers < 1 or not all(math.isfinite(v) and v > 0 for v in args.airspeeds):
        parser.error("--seeds and --workers must be >= 1 and every airspeed positive")
    try:
        plants.check(f"jsbsim:{args.model}")
    except plants.PlantError as exc:
        parser.error(str(exc))
    if args.scheduler is not None and not args.scheduler.startswith(("tcp://", "tls://", "inproc://")):
        parser.error(f"--scheduler must look like tcp://HOST:PORT, got {args.scheduler!r}")
    flights = make_flights(args.model, args.controllers, args.airspeeds, args.turbulence, args.seeds)
    t0 = time.perf_counter()
    try:
        results = execute(flights, args.scheduler, None, args.workers, simulate=simulate)
    except StudyError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    wall = time.perf_counter() - t0
    table = summarise(flights, results)
    print(format_table(table))
    print(
        f"{len(flights)} flights in {wall:.1f} s ({len(flights) / wall:.2f} flights/s) on "
        f"{args.scheduler or f'{args.workers} local process(es)'}"
    )
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        write_json_atomic(out / "summary.json", {"model": args.model, "wall_s": wall, "table": table})
        print(f"wrote {out / 'summary.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
