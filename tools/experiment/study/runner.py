"""The whole study (``StudyOptions``, ``run_study``): sample, simulate, aggregate, report, write the files."""

from __future__ import annotations

import dataclasses
import datetime as _dt
import os
import time
from pathlib import Path

from autopilot.envelope import tracking_limits
from autopilot.shared.process import write_json_atomic
from tools.experiment.study import native
from tools.experiment.study.aggregation import (
    LONG_CONDITIONS,
    LONG_CONTROLLERS,
    LONG_DURATION_S,
    aggregate,
    breaks,
    long_flight_summary,
)
from tools.experiment.study.execution import Progress, execute, merge
from tools.experiment.study.report import format_breaks, format_long, format_table, save_figure, save_worst_rrd
from tools.experiment.study.sampling import (
    BOUND_ROLL_RAD,
    BOUND_SAT_FRACTION,
    CONTROLLERS,
    DEG,
    WINDOW_S,
    StudyOptions,
    get_condition,
    make_tasks,
    sweep_conditions,
)


def run_study(opts: StudyOptions, out_dir: str | os.PathLike | None = None, *, log=print, progress: bool = True):
    """The whole study; returns the summary dict (also written to ``out_dir/summary.json`` with the table,
    the figure and the worst runs' ``.rrd`` when ``out_dir`` is given)."""
    t_start = time.perf_counter()
    pairs = [(c, i) for c in opts.conditions for i in range(opts.runs)]
    sweeps = list(sweep_conditions()) if opts.sweep_runs else []
    pairs += [(c, i) for c in sweeps for i in range(opts.sweep_runs)]
    tasks = make_tasks(opts.controllers, pairs, opts.seed, opts.chunk)
    long_ctrls = [c for c in LONG_CONTROLLERS if c in opts.controllers] if opts.long_runs else []
    long_pairs = [(c, i) for c in LONG_CONDITIONS for i in range(opts.long_runs)]
    long_tasks = make_tasks(long_ctrls, long_pairs, opts.seed, opts.chunk, LONG_DURATION_S)
    total = sum(len(t.runs) for t in tasks)
    bar = Progress(total, "30 s runs", enabled=progress)
    where = opts.scheduler or ("this process" if opts.workers == 1 else f"{opts.workers} local processes")
    steps = "" if opts.scheduler else f" (steps: {native.engine()})"  # a cluster's workers load their own
    log(f"study: {len(opts.controllers)} controllers x {len(pairs)} runs = {total} runs of 30 s on {where}{steps}")
    t0 = time.perf_counter()
    results = execute(tasks, opts.scheduler, bar, opts.workers)
    phases = {"runs_30s": _phase(total, 30.0, time.perf_counter() - t0)}
    merged = merge(tasks, results)
    summary: dict = {
        "study": "robustness",
        "seed": opts.seed,
        "runs_per_condition": opts.runs,
        "sweep_runs": opts.sweep_runs,
        "scheduler": opts.scheduler or "local",
        "bounds": {
            "max_abs_roll_deg": BOUND_ROLL_RAD / DEG,
            "sat_fraction": BOUND_SAT_FRACTION,
            "tracking": tracking_limits(),  # and no window that oscillates or does not follow (autopilot.envelope)
        },
        "units": {
            "ise_ref": "rad^2 s",
            "ise_crm": "rad^2 s",
            "energy": "rad^2 s",
            "tv": "rad",
            "max_abs_u": "rad",
            "max_abs_roll": "rad",
            "sat_fraction": "1",
        },
        "conditions": {c: dataclasses.asdict(get_condition(c)) for c in (*opts.conditions, *sweeps)},
        "controllers": {
            c: {"label": CONTROLLERS[c].label, "changes": dict(CONTROLLERS[c].changes)} for c in opts.controllers
        },
        "results": {
            c: {cond: aggregate(merged[c], cond, c, opts.seed) for cond in (*opts.conditions, *sweeps)}
            for c in opts.controllers
        },
    }
    summary["breaks"] = breaks(summary)
    n_long = sum(len(t.runs) for t in long_tasks)
    if long_tasks:
        log(f"long flight: {len(long_ctrls)} controllers x {len(long_pairs)} runs of {LONG_DURATION_S:g} s")
        t0 = time.perf_counter()
        lres = execute(long_tasks, opts.scheduler, Progress(n_long, "600 s runs", enabled=progress), opts.workers)
        phases["runs_600s"] = _phase(n_long, LONG_DURATION_S, time.perf_counter() - t0)
        lmerged = merge(long_tasks, lres)
        summary["long_flight"] = {
            "duration_s": LONG_DURATION_S,
            "window_s": WINDOW_S,
            "runs_per_condition": opts.long_runs,
            "controllers": {
                c: {cond: long_flight_summary(lmerged[c], cond) for cond in LONG_CONDITIONS} for c in long_ctrls
            },
        }
    summary["created"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")

    def timing() -> dict:
        """What the user waits for: from the call to the last file (all the runs, 30 s and 600 s, the
        aggregation, the tables, the figure and the worst runs' recording), and each phase's simulation."""
        wall = time.perf_counter() - t_start
        runs = total + n_long
        return {"wall_s": wall, "runs": runs, "runs_per_s": runs / wall if wall > 0 else None, "phases": phases}

    if out_dir is None:
        summary["timing"] = timing()
        return summary

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tables = [format_table(summary)]
    if summary["sweep_runs"]:
        tables.append(format_breaks(summary))
    if "long_flight" in summary:
        tables.append(format_long(summary))
    (out / "table.md").write_text("\n\n".join(tables) + "\n", encoding="utf-8")
    try:
        png = save_figure(merged, opts, out / "robustness.png")
        log(f"wrote {png.resolve()}")
    except ImportError as exc:
        log(f"no figure: {exc}")
    rrd = save_worst_rrd(summary, opts, out / "worst.rrd")
    if rrd is not None:
        log(f"wrote {rrd.resolve()} (open it with: rerun {rrd.resolve()})")
    summary["timing"] = timing()  # summary.json last: its timing covers every other file
    write_json_atomic(out / "summary.json", summary, indent=2, allow_nan=False)
    log(f"wrote {(out / 'summary.json').resolve()} and table.md")
    return summary


def _phase(runs: int, duration_s: float, wall_s: float) -> dict:
    """One phase's simulation time and its cost per simulated second per aircraft (us)."""
    aircraft_s = runs * duration_s
    return {
        "runs": runs,
        "duration_s": duration_s,
        "wall_s": wall_s,
        "us_per_aircraft_s": 1e6 * wall_s / aircraft_s if aircraft_s else None,
    }
