"""``python -m tools.experiment SCENARIO`` (a reference scenario, ``tools.experiment.runs``), ``python -m
tools.experiment robustness`` (the Monte Carlo study), ``python -m tools.experiment replay`` (one of its runs) and
``python -m tools.experiment damage`` (the damage study): flags in, the runs out; the work is in ``runs``, ``study``
and ``damage``."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from autopilot.params import arg_type
from autopilot.shared.cli import OneLineArgumentParser
from tools.experiment.outdir import OutDirError, check_out_dir, default_out_dir, prepare_out_dir
from tools.experiment.runs import (
    SCENARIOS,
    TRANSPORTS,
    ExperimentError,
    format_table,
    get_scenario,
    get_transport,
    require_design,
    run_experiment,
    select_runs,
    with_disturbances,
    with_plant,
)


def build_parser() -> argparse.ArgumentParser:
    from sitl.plant_kinds import help_text as plant_help  # numpy: here, not on every import of the dispatcher

    p = OneLineArgumentParser(
        prog="python -m tools.experiment",
        description='Fly a reference scenario (docs/spec.md, "Reference scenario") for each controller variant; '
        "write OUT/summary.json and OUT/<scenario>.png and print the metrics.",
    )
    p.add_argument(
        "scenario",
        help=f"scenario name ({', '.join(SCENARIOS)}); or 'robustness': the Monte Carlo study, "
        "'python -m tools.experiment robustness --help'; or 'replay': one run of the study alone, "
        "'python -m tools.experiment replay --help'; or 'damage': the damage study, faults in mid-flight, "
        "'python -m tools.experiment damage --help'; or 'delay-margin': each law's largest extra actuator "
        "delay, 'python -m tools.experiment delay-margin --help'",
    )
    p.add_argument("--out", metavar="DIR", help="output folder (default: a new runs/<scenario>-<timestamp>/)")
    p.add_argument(
        "--transport",
        default="inprocess",
        metavar="NAME",
        help=f"how to fly it: {' | '.join(TRANSPORTS)} (default: inprocess)",
    )
    p.add_argument(
        "--runs",
        metavar="A,B,...",
        help="comma-separated subset of runs (default: all; paper: sac,clsac,clsac_lv10,clsac_lv50,clsac_lv100; "
        "also baseline, the fixed-gain PID)",
    )
    p.add_argument("--no-plot", action="store_true", help="do not write the figure")
    p.add_argument(
        "--no-rrd", action="store_true", help="do not write OUT/<scenario>.rrd (every run side by side in Rerun)"
    )
    p.add_argument(
        "--pfc",
        choices=("paper", "robust"),
        default=None,
        help="PFC for every run: paper = 10/(4s+40) (default), robust = 10/(s+10) (see python -m tools.pfc)",
    )
    p.add_argument(
        "--sigma-xu",
        type=arg_type("CLSAC_SIGMA_X"),  # the parameter table's bounds, as python -m autopilot --sigma-xu
        default=None,
        metavar="SIGMA",
        help="sigma-modification of K_Ix, K_Iu for every run (default 0, the paper)",
    )
    p.add_argument(
        "--turbulence",
        choices=("light", "moderate", "severe"),
        default=None,
        help="turbulence (mavlink; in-process too on a JSBSim plant, which flies its own)",
    )
    p.add_argument("--seed", type=int, default=None, metavar="N", help="seed of the disturbances (default 0)")
    p.add_argument(
        "--plant",
        default=None,
        metavar="PLANT",
        help=f"the plant: {plant_help()} (docs/plants.md)",  # from the kinds' records (sitl.plant_kinds)
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["robustness"]:  # the Monte Carlo study (tools.experiment.study), its own flags
        from tools.experiment.study.cli import main as study_main

        return study_main(argv[1:])
    if argv[:1] == ["damage"]:  # the damage study (tools.experiment.damage), its own flags
        from tools.experiment.damage.cli import main as damage_main

        return damage_main(argv[1:])
    if argv[:1] == ["delay-margin"]:  # each law's delay margin (tools.experiment.delay_margin), its own flags
        from tools.experiment.delay_margin import main as margin_main

        return margin_main(argv[1:])
    if argv[:1] == ["replay"]:  # one run of the study, alone
        from tools.experiment.study.cli import replay_main

        return replay_main(argv[1:])
    args = build_parser().parse_args(argv)
    try:
        # cheap checks first (no scenario import), then the ones that need the scenario's runs
        if args.scenario not in SCENARIOS:
            raise ExperimentError(f"unknown scenario {args.scenario!r} (known: {', '.join(SCENARIOS)})")
        if args.transport not in TRANSPORTS:
            raise ExperimentError(f"unknown transport {args.transport!r} (known: {', '.join(TRANSPORTS)})")
        runs = None if args.runs is None else args.runs.split(",")
        if runs is not None and any(not s.strip() for s in runs):
            raise ExperimentError(f"--runs has an empty name in {args.runs!r}")
        if args.sigma_xu is not None and not (0 <= args.sigma_xu < float("inf")):
            raise ExperimentError(f"--sigma-xu must be finite and >= 0, got {args.sigma_xu!r}")
        out = Path(args.out) if args.out else default_out_dir(args.scenario)
        check_out_dir(out)
        scen, available = get_scenario(args.scenario)
        specs = select_runs(runs, available)
        if args.plant is not None:
            scen = with_plant(scen, args.plant)  # a bad plant fails before any folder is made
        require_design(scen, args.pfc)
        dist = {"turbulence": args.turbulence, "seed": args.seed}
        with_disturbances(scen, dist, args.transport)
        get_transport(args.transport)  # fail before creating any folder if it is unavailable
        out = prepare_out_dir(out)
        t0 = time.perf_counter()
        print(f"scenario {args.scenario!r}: {len(specs)} run(s) via {args.transport}, output in {out.resolve()}")
        results = run_experiment(
            out,
            args.transport,
            specs,
            plot=not args.no_plot,
            scenario=args.scenario,
            log=print,
            pfc=args.pfc,
            sigma_xu=args.sigma_xu,
            rrd=not args.no_rrd,
            plant=args.plant,
            disturbances=dist,
        )
    except (ExperimentError, OutDirError) as exc:
        print(f"python -m tools.experiment: error: {exc}", file=sys.stderr)
        return 2
    except (RuntimeError, OSError) as exc:  # a transport's run failed, or the disk did
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        if isinstance(exc, OSError) and exc.filename:
            first = f"could not write {exc.filename}: {exc.strerror}"
        print(f"python -m tools.experiment: error: {first}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("python -m tools.experiment: interrupted", file=sys.stderr)
        return 130
    scen, _ = get_scenario(args.scenario)
    if args.plant is not None:
        scen = with_plant(scen, args.plant)
    print()
    print(format_table(results, scen))
    print()
    print(f"done in {time.perf_counter() - t0:.1f} s; files in {out.resolve()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
