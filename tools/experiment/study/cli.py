"""The study's command lines: ``python -m tools.experiment robustness`` (the study) and ``python -m tools.experiment
replay`` (one run alone), dispatched by ``tools.experiment.cli``."""

from __future__ import annotations

import argparse
import math
import re
import sys
from collections.abc import Sequence
from pathlib import Path

from autopilot import controllers
from autopilot import controllers as registry
from autopilot.shared import cli
from autopilot.shared.cli import OneLineArgumentParser
from sitl import plant as plants
from sitl.plant_kinds import help_text as plant_help
from tools.experiment import flags
from tools.experiment.outdir import check_out_dir, default_out_dir, hold_space, prepare_out_dir
from tools.experiment.study import faults as study_faults
from tools.experiment.study import flights
from tools.experiment.study.execution import interruptible
from tools.experiment.study.robustness import final_line, notes, report, run_plants, sections_of
from tools.experiment.study.sampling import METRICS, StudyError, StudyOptions, get_condition
from tools.experiment.study.simulation import replay

# ---------------------------------------------------------------------------------------- command line
ROBUSTNESS_PROG = "python -m tools.experiment robustness"
REPLAY_PROG = "python -m tools.experiment replay"


def build_parser(prog: str = ROBUSTNESS_PROG) -> argparse.ArgumentParser:
    """The study's flags."""
    p = OneLineArgumentParser(
        prog=prog,
        description="The Monte Carlo robustness study of one plant or several: the KH2013A's batched study "
        "(docs/experiments.md), a JSBSim aircraft's or a plant file's in-process flights (docs/jsbsim.md).",
    )
    add_run_arguments(p)
    return p


def build_replay_parser(prog: str = REPLAY_PROG) -> argparse.ArgumentParser:
    """One run of the study, alone, with its metrics (the command summary.json's ``replay_inprocess`` gives)."""
    q = OneLineArgumentParser(prog=prog, description="One run of the robustness study, alone, with its metrics.")
    q.add_argument("--controller", required=True, choices=registry.ROBUSTNESS)
    q.add_argument("--condition", required=True)
    q.add_argument("--seed", type=cli.seed, required=True)
    q.add_argument("--run", type=cli.count(0, 10**9, name="run"), required=True)
    q.add_argument("--duration", type=cli.duration_s, default=30.0)
    _add_fault(q)
    return q


def add_run_arguments(r: argparse.ArgumentParser) -> None:
    r.add_argument(
        "--plant",
        metavar="PLANT[,PLANT...]",
        help=f"the plants studied: {plant_help(note=lambda k: 'the batched study below' if k.batched else '')} "
        "(docs/plants.md), or a comma-separated list of them: one summary.json with a section per plant",
    )
    r.add_argument(
        "--controllers",
        metavar="A,B",
        help=f"kh2013a: a subset of {','.join(registry.ROBUSTNESS)}; a JSBSim aircraft or plant file: of "
        f"{','.join(flights.CONTROLLERS)} (default: all of each); either: also any registered law "
        f"({','.join(n for n in controllers.NAMES if n not in flights.CONTROLLERS)}) or one of your own, FILE.py:Class "
        "(docs/adding-a-law.md), flown one in-process flight at a time",
    )
    r.add_argument(
        "--seed",
        type=cli.seed,
        help="kh2013a: run i draws from numpy default_rng([seed, i]); a JSBSim aircraft or plant file: flight i flies "
        f"with the seed seed*{flights.SEED_STRIDE} + i (default 0)",
    )
    flags.add_out(r, "robustness")
    r.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="a Dask scheduler (default: run here)")
    flags.add_workers(r, 1)
    r.add_argument("--no-progress", action="store_true", help="no progress bar")
    k = r.add_argument_group("kh2013a (many aircraft at once, as numpy arrays or in C)")
    k.add_argument(
        "--runs",
        type=cli.count(1, 10**7, name="runs"),
        help="runs per controller and condition (default 1000; up to 10^7: the estimate is printed first and a "
        "study beyond 256 MB of values bins its percentiles)",
    )
    k.add_argument("--conditions", metavar="A,B", help="a subset of nominal,moderate,severe (default all)")
    k.add_argument(
        "--sweep-runs",
        type=cli.count(0, 10**6, name="sweep_runs"),
        help="runs per sweep point (loss, delay, turbulence; 0: none; default 100)",
    )
    k.add_argument(
        "--long-runs",
        type=cli.count(0, 10**6, name="long_runs"),
        help="runs of the 600 s long flight (0: none; default 10)",
    )
    k.add_argument(
        "--chunk",
        type=cli.count(1, 10**6, name="chunk"),
        help="runs per batch (default 2500; results do not depend on it)",
    )
    _add_fault(k)
    f = r.add_argument_group("a JSBSim aircraft or plant file (one in-process flight at a time)")
    f.add_argument(
        "--airspeeds",
        metavar="KT,...",
        help="a JSBSim aircraft's airspeeds (kt), each a condition (default: the spec's airspeed_kt, 90)",
    )
    f.add_argument(
        "--turbulence",
        metavar="A,B",
        help=f"the turbulence levels flown, of {','.join(flights.TURBULENCE)} (default none,moderate; none on a "
        "plant file whose states cannot carry the atmosphere)",
    )
    f.add_argument(
        "--seeds",
        type=cli.count(1, flights.MAX_SEEDS, name="seeds"),
        help="flights per controller and condition (default 3)",
    )


def _add_fault(group) -> None:
    """``--fault`` (repeatable): ``sitl.damage``'s spec, the kinds the study flies exactly (study.faults)."""
    from sitl import damage

    group.add_argument(
        "--fault",
        type=damage.fault_arg,
        action="append",
        default=None,
        metavar=damage.SYNTAX,
        help="a fault in every run, from START to END sim seconds (without END it stays), repeatable: "
        "effectiveness=F, damping=F, stuck[=DEG], off, delay=S (whole 10 ms periods), rate=DEG_PER_S (docs/faults.md)",
    )


KH2013A_FLAGS = ("runs", "conditions", "sweep_runs", "long_runs", "chunk", "fault")
FLIGHT_FLAGS = ("airspeeds", "turbulence", "seeds")


def _names(text: str | None, flag: str) -> tuple[str, ...] | None:
    """A comma-separated list given to ``flag`` (None: not given); refuses an empty one or an empty name."""
    if text is None:
        return None
    items = tuple(s.strip() for s in text.split(","))
    if not text.strip():
        raise StudyError(f"--{flag} is empty")
    if not all(items):
        raise StudyError(f"--{flag} has an empty name in {text!r}")
    return items


def split_plants(text: str | None) -> list[str]:
    """The --plant list: comma-separated, a JSBSim spec keeping its own KEY=VALUE pairs (``jsbsim:c172x:
    airspeed_kt=60,surface=rudder,kh2013a`` is two plants)."""
    if text is None:
        return [plants.KH2013A]
    out: list[str] = []
    for piece in _names(text, "plant"):
        if out and plants.kind_of(out[-1]).keyed and re.fullmatch(r"[a-z_]+=[^:]*", piece):
            out[-1] += "," + piece
        else:
            out.append(piece)
    dup = next((p for i, p in enumerate(out) if p in out[:i]), None)
    if dup is not None:
        raise StudyError(f"--plant names {dup} twice")
    return out


def _airspeeds(text: str | None) -> tuple[float, ...] | None:
    names = _names(text, "airspeeds")
    if names is None:
        return None
    try:
        values = tuple(float(v) for v in names)
    except ValueError:
        raise StudyError(f"--airspeeds expects airspeeds in kt, got {text!r}") from None
    if not all(math.isfinite(v) and v > 0 for v in values):
        raise StudyError(f"--airspeeds must be positive and finite, got {text!r}")
    return values


def plan_from_args(args) -> list[tuple[str, object]]:
    """(plant, its study's options) for each --plant, every flag checked against the plants it applies to."""
    texts = split_plants(args.plant)
    for text in texts:
        if not _batched_plant(text):
            try:
                plants.check(text)
            except plants.PlantError as exc:
                raise StudyError(str(exc)) from None
    controllers = _names(args.controllers, "controllers")
    controllers_of = registry.CONTROLLERS
    seed = 0 if args.seed is None else args.seed
    plan: list[tuple[str, object]] = []
    # laws without a batch form (autopilot.controllers.Law.batch, or one that does not fly the controller's
    # configuration: pid-ff): a registered one, or a user's (FILE.py:Class, module:Class); an unknown name is the
    # batched study's to refuse
    unbatched = tuple(c for c in controllers or () if not _batched(c) and (c in controllers_of or ":" in c))
    batched_plant = next((t for t in texts if _batched_plant(t)), None)  # the KH2013A: the batched study's plant
    if unbatched and batched_plant is not None:
        # The KH2013A's batched study flies the laws of its kernel; any other law (mrac, l1, indi, a user's own)
        # flies the generic loop, one in-process flight at a time, bit for bit its lockstep flight
        # (tools.experiment.scenario.run_inprocess), as a JSBSim aircraft's or a plant file's study does.
        i = texts.index(batched_plant)
        texts = [*texts[:i], *([batched_plant] if len(unbatched) < len(controllers) else []), GENERIC, *texts[i + 1 :]]
    batched = None if controllers is None else tuple(c for c in controllers if c not in unbatched)
    scalar = [t for t in texts if not _batched_plant(t)]
    batched_given = any(_batched_plant(t) for t in texts)
    given = {k for k in (*KH2013A_FLAGS, *FLIGHT_FLAGS) if getattr(args, k) is not None}
    for k in KH2013A_FLAGS:
        if k in given and not batched_given and GENERIC in texts:
            raise StudyError(
                f"--{k.replace('_', '-')} applies to the KH2013A's batched study: {', '.join(unbatched)} "
                "(no batch form) fly --seeds flights per --turbulence level, one in-process flight at a time"
            )
        if k in given and not batched_given:
            raise StudyError(
                f"--{k.replace('_', '-')} applies to --plant kh2013a only (a JSBSim aircraft or plant file flies "
                "--seeds flights per --turbulence level and airspeed)"
            )
    for k in FLIGHT_FLAGS:
        if k in given and not scalar:
            raise StudyError(
                f"--{k} applies to a JSBSim aircraft or plant file only (--plant kh2013a flies --runs runs per "
                "--conditions condition)"
            )
    if "fault" in given and scalar:
        raise StudyError(
            "--fault in the robustness study flies on --plant kh2013a alone (on a JSBSim aircraft or plant file: "
            "python -m tools.experiment damage)"
        )
    if "airspeeds" in given and not any(plants.kind_of(t).own_atmosphere for t in texts):
        raise StudyError("--airspeeds applies to a JSBSim aircraft (--plant jsbsim:MODEL) only")
    for text in texts:
        if _batched_plant(text):
            kw = {k: getattr(args, k) for k in ("runs", "sweep_runs", "long_runs", "chunk") if k in given}
            if args.fault:
                study_faults.check(args.fault)
                kw["faults"] = tuple(args.fault)
            if batched is not None:
                kw["controllers"] = batched
            if "conditions" in given:
                kw["conditions"] = _names(args.conditions, "conditions")
            plan.append((text, StudyOptions(seed=seed, scheduler=args.scheduler, workers=args.workers, **kw)))
            continue
        if text == GENERIC:
            _generic_plan(args, unbatched, seed, plan)
            continue
        airspeeds = _airspeeds(args.airspeeds) if plants.kind_of(text).own_atmosphere else None
        turbulence = _names(args.turbulence, "turbulence")
        if turbulence is None:
            turbulence = ("none", "moderate")
            try:
                plants.check_disturbances(text, {"turbulence": "moderate"})
            except plants.PlantError:
                turbulence = ("none",)  # a plant file whose states cannot carry the atmosphere
        seeds = 3 if args.seeds is None else args.seeds
        if seed > (cli.MAX_SEED - seeds) // flights.SEED_STRIDE:
            raise StudyError(
                f"--seed {seed}: its flights' seeds (seed*{flights.SEED_STRIDE} + i) pass 2^63-1 on --plant {text}"
            )
        opts = flights.FlightOptions(
            text,
            controllers or flights.CONTROLLERS,
            turbulence,
            seeds,
            seed,
            airspeeds,
            args.workers,
            args.scheduler,
        )
        flights.check(opts)
        plan.append((text, opts))
    return plan


GENERIC = "kh2013a (one flight at a time)"  # the KH2013A's section of the laws without a batch form


def _batched(name: str) -> bool:
    """A controller of the batched study (``autopilot.controllers.ROBUSTNESS``) whose law has a batch form that flies
    it (its record's ``batch``: ``Controller.batch_form``)."""
    return name in registry.ROBUSTNESS and registry.studied(name).batch_form() is not None


def _batched_plant(text: str) -> bool:
    """The plant the batched study (numpy and ``kernel.c``) flies, by its kind's record (the KH2013A); not GENERIC."""
    return text != GENERIC and plants.kind_of(text).batched


def _generic_plan(args, names: tuple[str, ...], seed: int, plan: list) -> None:
    """The KH2013A flown by the laws without a batch form: ``flights.FlightOptions`` on kh2013a (the turbulence
    levels of --turbulence, default none and moderate; --seeds flights each, default 3)."""
    turbulence = _names(args.turbulence, "turbulence") or ("none", "moderate")
    opts = flights.FlightOptions(
        plants.KH2013A,
        names,
        turbulence,
        3 if args.seeds is None else args.seeds,
        seed,
        None,
        args.workers,
        args.scheduler,
    )
    flights.check(opts)
    plan.append((GENERIC, opts))


def options_from_args(args) -> StudyOptions:
    """The KH2013A study's options (``--plant kh2013a``)."""
    for text, opts in plan_from_args(args):
        if _batched_plant(text):
            return opts
    raise StudyError("--plant does not name kh2013a")


def main_run(args, prog: str) -> int:
    try:
        plan = plan_from_args(args)
        out = Path(args.out) if args.out else default_out_dir("robustness")
        check_out_dir(out)
        if args.scheduler is not None:
            from tools.experiment.study.scheduler import probe

            probe(args.scheduler)  # bounded: one line if it is not a Dask scheduler, before any folder
        out = prepare_out_dir(out)
        reserve = hold_space(out)  # summary.json fits a disk that fills while the study flies
        try:
            with interruptible() as stop:
                summary = run_plants(
                    plan, out, progress=not args.no_progress, stop=stop, scheduler=args.scheduler, reserve=reserve
                )
        finally:
            reserve.release()
    except (StudyError, ValueError) as exc:
        print(
            f"{prog}: error: {str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__}",
            file=sys.stderr,
        )
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    print()
    print(report(sections_of(summary), headings="plants" in summary, full=False))
    lines = notes(summary)
    if lines:
        print()
        print("\n".join(lines))
    print(f"\n{final_line(summary, out)}")
    for line in summary.get("output_errors") or ():  # a full disk: every file that could not be written
        print(f"{prog}: error: {line}", file=sys.stderr)
    if summary.get("output_errors"):
        return 1
    errors = [s["error"] for s in sections_of(summary).values() if s.get("error")]
    if errors:  # an error after the first runs: what was flown is kept
        print(f"{prog}: error: {errors[0]}; kept what was done in {(out / 'summary.json').resolve()} (partial)",
              file=sys.stderr)  # fmt: skip
        return 1
    if summary.get("partial"):
        print(
            f"{prog}: interrupted: kept what was done in {(out / 'summary.json').resolve()} (partial)", file=sys.stderr
        )
        return 130
    return 0


def main_replay(args, prog: str) -> int:
    try:
        get_condition(args.condition)
        study_faults.check(args.fault or ())
        r = replay(
            args.controller, args.condition, args.seed, args.run, args.duration, record=False, faults=args.fault or ()
        )
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
