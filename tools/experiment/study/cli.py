"""The study's command lines: ``python -m tools.experiment robustness`` (the study) and ``python -m tools.experiment
replay`` (one run alone), dispatched by ``tools.experiment.cli``."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from autopilot.shared import cli
from autopilot.shared.cli import OneLineArgumentParser
from tools.experiment.outdir import check_out_dir, default_out_dir, prepare_out_dir
from tools.experiment.study.aggregation import LONG_DURATION_S
from tools.experiment.study.report import format_breaks, format_long, format_table
from tools.experiment.study.runner import run_study
from tools.experiment.study.sampling import CONTROLLERS, METRICS, StudyError, StudyOptions, get_condition
from tools.experiment.study.simulation import replay

# ---------------------------------------------------------------------------------------- command line
ROBUSTNESS_PROG = "python -m tools.experiment robustness"
REPLAY_PROG = "python -m tools.experiment replay"


def build_parser(prog: str = ROBUSTNESS_PROG) -> argparse.ArgumentParser:
    """The study's flags."""
    p = OneLineArgumentParser(prog=prog, description="Monte Carlo robustness study; see tools.experiment.study's doc.")
    add_run_arguments(p)
    return p


def build_replay_parser(prog: str = REPLAY_PROG) -> argparse.ArgumentParser:
    """One run of the study, alone, with its metrics (the command summary.json's ``replay_inprocess`` gives)."""
    q = OneLineArgumentParser(prog=prog, description="One run of the robustness study, alone, with its metrics.")
    q.add_argument("--controller", required=True, choices=tuple(CONTROLLERS))
    q.add_argument("--condition", required=True)
    q.add_argument("--seed", type=cli.seed, required=True)
    q.add_argument("--run", type=cli.count(0, 10**9, name="run"), required=True)
    q.add_argument("--duration", type=cli.duration_s, default=30.0)
    return q


def add_run_arguments(r: argparse.ArgumentParser) -> None:
    r.add_argument(
        "--runs",
        type=cli.count(1, 10**7, name="runs"),
        default=1000,
        help="runs per controller and condition (default 1000)",
    )
    r.add_argument("--seed", type=cli.seed, default=0, help="run i draws from numpy default_rng([seed, i]) (default 0)")
    r.add_argument("--out", metavar="DIR", help="output folder (default: a new runs/robustness-<timestamp>/)")
    r.add_argument("--controllers", metavar="A,B", help=f"subset of: {','.join(CONTROLLERS)} (default all)")
    r.add_argument("--conditions", metavar="A,B", help="subset of: nominal,moderate,severe (default all)")
    r.add_argument(
        "--sweep-runs",
        type=cli.count(0, 10**6, name="sweep_runs"),
        default=100,
        help="runs per sweep point (loss, delay, turbulence; 0: none)",
    )
    r.add_argument(
        "--long-runs",
        type=cli.count(0, 10**6, name="long_runs"),
        default=10,
        help="runs of the 600 s long flight (0: none; default 10)",
    )
    r.add_argument(
        "--chunk",
        type=cli.count(1, 10**6, name="chunk"),
        default=2500,
        help="runs per batch (results do not depend on it)",
    )
    r.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="a Dask scheduler (default: run here)")
    r.add_argument(
        "--workers",
        type=cli.count(1, 1024, name="workers"),
        default=1,
        help="local processes when no --scheduler (default 1; results do not change)",
    )
    r.add_argument("--no-progress", action="store_true", help="no progress bar")


def options_from_args(args) -> StudyOptions:
    def names(text):
        if text is None:
            return None
        items = tuple(s.strip() for s in text.split(","))
        if not all(items):
            raise StudyError(f"empty name in {text!r}")
        return items

    kw = dict(
        runs=args.runs,
        seed=args.seed,
        sweep_runs=args.sweep_runs,
        long_runs=args.long_runs,
        chunk=args.chunk,
        scheduler=args.scheduler,
        workers=args.workers,
    )
    if args.controllers:
        kw["controllers"] = names(args.controllers)
    if args.conditions:
        kw["conditions"] = names(args.conditions)
    return StudyOptions(**kw)


def main_run(args, prog: str) -> int:
    try:
        opts = options_from_args(args)
        out = Path(args.out) if args.out else default_out_dir("robustness")
        check_out_dir(out)
        out = prepare_out_dir(out)
        summary = run_study(opts, out, progress=not args.no_progress)
    except (StudyError, ValueError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    print()
    print(format_table(summary))
    print()
    if summary["sweep_runs"]:
        print("where each controller stops being bounded (< 90 % of runs), one factor at a time from nominal:")
        print(format_breaks(summary))
    for ctrl, by_cond in summary["results"].items():
        w = by_cond.get(opts.conditions[-1], {}).get("worst")
        if w:
            print(f"worst {ctrl} run under {opts.conditions[-1]}: {w['replay_inprocess']}")
    if "long_flight" in summary:
        print(f"\nlong flight ({LONG_DURATION_S:g} s), median peak |roll| per 30 s window:")
        print(format_long(summary))
    t = summary["timing"]
    kinds = ", ".join(f"{p['runs']} of {p['duration_s']:g} s" for p in t["phases"].values())
    print(
        f"\n{t['runs']} runs ({kinds}) in {t['wall_s']:.1f} s ({t['runs_per_s']:,.0f} runs/s), files included; "
        f"files in {out.resolve()}"
    )
    return 0


def main_replay(args, prog: str) -> int:
    try:
        get_condition(args.condition)
        r = replay(args.controller, args.condition, args.seed, args.run, args.duration, record=False)
    except StudyError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    print(
        f"{args.controller} under {args.condition}, seed {args.seed}, run {args.run} (PFC "
        f"{'paper' if r['pfc_paper'][0] else 'robust'}): bounded {bool(r['bounded'][0])}"
        f" (oscillating {bool(r['oscillating'][0])}, not following {bool(r['not_following'][0])})"
    )
    for m in METRICS:
        print(f"  {m:<13} {float(r[m][0]):.10g}")
    return 0


def main(argv: Sequence[str] | None = None, prog: str = ROBUSTNESS_PROG) -> int:
    """``python -m tools.experiment robustness FLAGS``."""
    return main_run(build_parser(prog).parse_args(argv), prog)


def replay_main(argv: Sequence[str] | None = None, prog: str = REPLAY_PROG) -> int:
    """``python -m tools.experiment replay FLAGS``."""
    return main_replay(build_replay_parser(prog).parse_args(argv), prog)
