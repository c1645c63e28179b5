"""``python -m tools.experiment damage``: flags in, the damage study out (``runner``; docs/damage.md)."""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from autopilot.shared import cli
from autopilot.shared.cli import OneLineArgumentParser
from tools.experiment import flags
from tools.experiment.damage import grid

PROG = "python -m tools.experiment damage"
LONG_S = 60.0  # from this duration on, the per-period table is printed too
RESERVE_PER_FLIGHT = 2048  # bytes held for summary.json per flight (a flight's record and its cell's share: ~1.7 kB)
MAX_FLIGHTS = 20_000  # the largest grid flown without --max-flights (the docs' largest study is 720 flights)


def build_parser() -> argparse.ArgumentParser:
    from sitl.plant_kinds import help_text as plant_help

    p = OneLineArgumentParser(
        prog=PROG,
        description="The damage study: faults in mid-flight (fault kind x severity x onset x seed x controller) "
        "on each plant, flown in-process; writes OUT/summary.json and OUT/damage.png (docs/damage.md).",
    )
    p.add_argument(
        "--plant",
        default=",".join(grid.DEFAULT_PLANTS),
        metavar="P1,P2",
        help=f"plants: {plant_help(None)} (default {','.join(grid.DEFAULT_PLANTS)})",  # sitl.plant_kinds' records
    )
    p.add_argument(
        "--runs",
        type=cli.count(1, 10**6, name="runs"),
        default=grid.DEFAULT_RUNS,
        help=f"seeds per cell (default {grid.DEFAULT_RUNS}: the least for a 95 %% paired interval)",
    )
    p.add_argument("--seed", type=cli.seed, default=1, help="flight j of a cell flies with seed SEED + j (default 1)")
    flags.add_out(p, "damage")
    flags.add_workers(p)
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="a Dask scheduler (default: run here)")
    p.add_argument(
        "--duration",
        type=cli.duration_s,
        default=grid.DEFAULT_DURATION_S,
        help=f"seconds per flight (default {grid.DEFAULT_DURATION_S:g}; 120-600 for the long flights)",
    )
    p.add_argument(
        "--kinds",
        default=",".join(grid.DEFAULT_KINDS),
        metavar="K1,K2",
        help=f"fault kinds (default {','.join(grid.DEFAULT_KINDS)}; also {_other_kinds()})",
    )
    p.add_argument(
        "--severity",
        action="append",
        default=[],
        metavar="KIND=V1,V2",
        help="a kind's severities in --fault's units (repeatable; defaults: "
        + "; ".join(
            f"{k} {','.join('here' if v is None else f'{v:g}' for v in vs)}" for k, vs in grid.SEVERITIES.items()
        )
        + ")",
    )
    p.add_argument("--onsets", default="10", metavar="T1,T2", help="fault onsets in s of flight time (default 10)")
    p.add_argument(
        "--controllers",
        default=",".join(grid.CONTROLLERS),
        metavar="C1,C2",
        help=f"subset of {','.join(grid.ALL)}, or all (every one of these), or a law of your own: FILE.py:Class, "
        f"module:Class (docs/adding-a-law.md) (default {','.join(grid.CONTROLLERS)})",
    )
    p.add_argument(
        "--turbulence",
        choices=grid.TURBULENCE,
        default=grid.DEFAULT_TURBULENCE,
        help=f"the turbulence each seed draws (default {grid.DEFAULT_TURBULENCE})",
    )
    p.add_argument(
        "--max-flights",
        type=cli.count(1, 10**9, name="max-flights"),
        default=MAX_FLIGHTS,
        metavar="N",
        help=f"refuse a grid of more flights than N (default {MAX_FLIGHTS:,}; the grid's repeated values are "
        "flown once)",
    )
    p.add_argument("--no-plot", action="store_true", help="do not write damage.png")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    return p


def _other_kinds() -> str:
    """The kinds beyond the defaults, from their records: every plant's, then the JSBSim aircraft's."""
    from sitl.fault_kinds import KINDS

    rest = [k for k in KINDS.values() if k.name not in grid.DEFAULT_KINDS]
    every = ", ".join(k.name for k in rest if k.group != "mass")
    return f"{every} and on JSBSim {', '.join(k.name for k in rest if k.group == 'mass')}"


def study_of(args) -> object:
    """The Study of the parsed flags (DamageError, sitl.plant.PlantError with one line)."""
    from sitl import plant as plants
    from tools.experiment.damage.runner import Study

    plant_list = flags.plant_list(args.plant)
    kinds = grid.parse_list(args.kinds, "fault kinds")
    from sitl import damage

    bad = [k for k in kinds if k not in damage.KINDS]
    if bad:
        raise grid.DamageError(f"--kinds: unknown kind {bad[0]!r} (kinds: {', '.join(damage.KINDS)})")
    severities = dict(grid.SEVERITIES)
    for text in args.severity:
        k, vals = grid.parse_severity(text)
        severities[k] = tuple(dict.fromkeys(vals))  # 5000 equal severities are one (and -0.0 is 0.0)
    ctrls = grid.parse_list(args.controllers, "controllers")
    ctrls = [x for c in ctrls for x in (grid.ALL if c == "all" else (c,))]
    for c in ctrls:
        try:
            grid.known(c)
        except ValueError as exc:  # autopilot.law.LawSpecError: what the user's law lacks
            raise grid.DamageError(f"--controllers: {exc}") from None
    onsets = grid.parse_list(args.onsets, "onsets in s", float)
    grid.check_onsets(onsets, args.duration)
    if args.scheduler is not None and not args.scheduler.startswith(("tcp://", "tls://", "inproc://")):
        raise grid.DamageError(f"--scheduler must look like tcp://HOST:PORT, got {args.scheduler!r}")
    if args.seed + args.runs - 1 > cli.MAX_SEED:
        raise grid.DamageError(f"--seed {args.seed} with --runs {args.runs}: the last seed passes 2^63-1")
    study = Study(
        plants=tuple(plant_list),
        controllers=tuple(dict.fromkeys(ctrls)),
        kinds=tuple(dict.fromkeys(kinds)),
        severities=severities,
        onsets=tuple(dict.fromkeys(onsets)),
        seed=args.seed,
        runs=args.runs,
        duration=args.duration,
        turbulence=args.turbulence,
    )
    cells, _ = study.cells()
    if not any(cells.values()):
        raise grid.DamageError("no plant flies any of the fault kinds asked for")
    if study.count() > args.max_flights:
        raise grid.DamageError(
            f"the grid has {study.count():,} flights, more than the cap of {args.max_flights:,} (--max-flights N "
            "raises it; fewer --runs, severities, onsets or controllers make it smaller)"
        )
    if not study.flights():
        raise grid.DamageError(
            "no plant flies any of the controllers asked for (a square MIMO plant flies "
            + ", ".join(grid.MIMO_CONTROLLERS)
            + ")"
        )
    if grid.RETUNED in study.controllers:
        from tools.design.linearise import linear_model

        for p in plant_list:
            if not plants.spec(p).mimo and linear_model(p) is None:
                raise grid.DamageError(f"{grid.RETUNED} needs a linear model of {p} (tools.design.linearise)")
    return study


def main(argv: Sequence[str] | None = None) -> int:
    from sitl import plant as plants
    from tools.experiment.damage.runner import run, write
    from tools.experiment.outdir import OutDirError, check_out_dir, default_out_dir, hold_space, prepare_out_dir
    from tools.experiment.study import StudyError
    from tools.experiment.study.execution import interruptible

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        study = study_of(args)
        out = Path(args.out) if args.out else default_out_dir("damage")
        check_out_dir(out)
    except (grid.DamageError, plants.PlantError, OutDirError) as exc:
        parser.error(str(exc))
    if not math.isfinite(args.duration):
        parser.error("--duration must be finite")
    workers = args.workers or os.cpu_count() or 1
    t0 = time.perf_counter()
    reserve = None
    try:
        out = prepare_out_dir(out)
        reserve = hold_space(out, RESERVE_PER_FLIGHT * study.count() + 64 * 1024)  # summary.json fits a full disk
        _, skipped = study.cells()
        for p, why in skipped.items():
            for k, reason in why.items():
                print(f"not flown on {p}: {k} ({reason})")
        for p in study.plants:
            for c, reason in grid.controller_refusals(p, study.controllers).items():
                print(f"not flown on {p}: controller {c} ({reason})")
        with interruptible() as stop:
            doc = run(study, workers=workers, scheduler=args.scheduler, progress=not args.quiet, stop=stop)
        written, problems = write(doc, out, plot=not args.no_plot, reserve=reserve)
    except (StudyError, OutDirError) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    finally:
        if reserve is not None:
            reserve.release()
    print_tables(doc, study)
    print()
    designs = f" and {len(doc['designs'])} design(s)" if doc["designs"] else ""
    print(
        f"{doc['flights']} flights{designs} in {doc['wall_s']:.1f} s "
        f"({(doc['flights_per_s'] or 0):.2f} flights/s{' with the designs' if designs else ''}), "
        f"{time.perf_counter() - t0:.1f} s in all on "
        f"{doc['executor']}"
    )
    if written:
        print("wrote " + ", ".join(str(w) for w in written))
    return _ending(doc, problems, out)


def legend(controllers) -> str:
    """What each column's controller is (the tables name them by their short, stable names)."""
    return "columns: " + "; ".join(f"{c} = {grid.label(c)}" for c in controllers)


def print_tables(doc: dict, study) -> None:
    from sitl import plant as plants
    from tools.experiment.damage.aggregate import paired_table, period_table, sideslip_table, table

    for p in study.plants:
        print()
        flown = [c for c in study.controllers if c not in grid.controller_refusals(p, study.controllers)]
        print(table(doc["cells"], p, flown))
        if len(flown) > 1 and study.runs > 1:  # one seed pairs nothing
            print()
            print(paired_table(doc["cells"], p, flown))
        if plants.spec(p).mimo:
            print()
            print(sideslip_table(doc["cells"], p, flown))
        if study.duration >= LONG_S:
            print()
            print(period_table(doc["cells"], p, flown))
    print(legend(study.controllers))


def _ending(doc: dict, problems: list[str], out: Path) -> int:
    """The exit status and its lines: 1 for a file not written (a full disk) or an error that stopped the study
    (its partial summary kept), 130 for Ctrl-C (likewise), else 0."""
    for line in problems:
        print(f"{PROG}: error: {line}", file=sys.stderr)
    kept = "kept" if not any("summary.json" in p for p in problems) else "could not keep"
    if doc.get("partial"):
        done = doc["done"]
        what = f"{kept} {done['flights']} of {done['of']} flights in {out / 'summary.json'} (partial)"
        if doc.get("error"):
            print(f"{PROG}: error: {doc['error']}; {what}", file=sys.stderr)
            return 1
        print(f"{PROG}: interrupted: {what}", file=sys.stderr)
        return 130
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
