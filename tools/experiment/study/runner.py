"""The KH2013A's whole study (``StudyOptions``, ``run_study``): plan the runs (never listed whole), fly a pilot batch
and print the estimate of time and memory, stream the batches into a ``Tally``, aggregate, report, write the files.
Stopped (``stop``, on SIGINT), it keeps what is done: a summary marked ``partial``."""

from __future__ import annotations

import dataclasses
import datetime as _dt
import math
import os
import threading
import time
from collections.abc import Iterator
from pathlib import Path

from autopilot import controllers as registry
from autopilot.envelope import tracking_limits
from tools.experiment.outdir import one_line, write_figure, write_problem, write_summary
from tools.experiment.study import native
from tools.experiment.study.accumulate import BIN_WIDTH, EXACT_BYTES, Tally, value_bytes
from tools.experiment.study.aggregation import (
    LONG_CONDITIONS,
    LONG_CONTROLLERS,
    LONG_DURATION_S,
    breaks,
    cell_summary,
    long_cell_summary,
)
from tools.experiment.study.execution import Progress, stream
from tools.experiment.study.report import format_breaks, format_long, format_table, save_figure, save_worst_rrd
from tools.experiment.study.sampling import (
    BOUND_ROLL_RAD,
    BOUND_SAT_FRACTION,
    DEG,
    WINDOW_S,
    StudyOptions,
    Task,
    get_condition,
    sweep_conditions,
)
from tools.experiment.study.simulation import simulate

PILOT_RUNS = 200  # runs flown and timed for the estimate, before the study


class Plan:
    """The (condition, run index) pairs of one phase in order, condition after condition, without listing them."""

    def __init__(self, segments):
        self.segments = [(c, n) for c, n in segments if n]
        self.total = sum(n for _, n in self.segments)

    def pairs(self, start: int, stop: int) -> tuple[tuple[str, int], ...]:
        out, base = [], 0
        for cond, n in self.segments:
            lo, hi = max(start - base, 0), min(stop - base, n)
            out += [(cond, i) for i in range(lo, hi)]
            base += n
        return tuple(out)


def _tasks(controllers, plan: Plan, seed: int, chunk: int, duration_s: float, faults=()) -> Iterator[Task]:
    """Every controller's runs in chunks of ``chunk`` (``make_tasks``'s tasks, one at a time)."""
    for c in controllers:
        for i in range(0, plan.total, chunk):
            yield Task(c, plan.pairs(i, min(i + chunk, plan.total)), seed, duration_s, faults=tuple(faults))


def _pilot(controller: str, plan: Plan, seed: int, stop, faults=()) -> float | None:
    """30 s runs per second in this process: a warm-up run (the imports, the C kernel's loading), then up to
    ``PILOT_RUNS`` runs spread over the plan's conditions, timed and thrown away (a few tenths of a second in C)."""
    if not plan.total:
        return None
    per = max(1, PILOT_RUNS // len(plan.segments))
    pairs = tuple((c, i) for c, n in plan.segments for i in range(min(per, n)))
    for _ in stream([Task(controller, pairs[:1], seed, 1.0)], stop=stop):
        pass
    t0 = time.perf_counter()
    flown = list(stream([Task(controller, pairs, seed, faults=tuple(faults))], stop=stop))  # with the study's faults
    return len(pairs) / max(time.perf_counter() - t0, 1e-9) if flown else None


def _rss_bytes() -> int:
    """This process's resident memory now."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _mb(b: float) -> str:
    if b < 1e6:
        return f"{b / 1e3:,.0f} kB"
    return f"{b / 1e6:,.0f} MB" if b < 1e9 else f"{b / 1e9:,.1f} GB"


def _hms(s: float) -> str:
    if s < 120:
        return f"{s:.0f} s"
    return f"{s / 60:.0f} min" if s < 7200 else f"{s / 3600:.1f} h"


def estimate(n30: int, nlong: int, runs_per_s: float, parallel: int, exact: bool, cells: int) -> dict:
    """Time and memory of a study from a pilot's rate (30 s runs per second in one process): a 600 s run costs 20
    of them (the same cost per simulated second, docs/spec.md); ``parallel`` processes or cluster threads."""
    wall = (n30 + nlong * LONG_DURATION_S / 30.0) / max(runs_per_s * parallel, 1e-9)
    windows = int(LONG_DURATION_S / WINDOW_S)
    kept = value_bytes(n30, nlong, windows)
    held = kept if exact else cells * 7 * 8 * int(4 * math.log(10) / math.log1p(BIN_WIDTH))  # bins of 4 decades
    return {
        "runs": n30 + nlong,
        "wall_s": wall,
        "runs_per_s_per_process": runs_per_s,
        "parallel": parallel,
        "memory_bytes": _rss_bytes() + held,
        "values_bytes": kept,
        "percentiles": "exact" if exact else f"binned (relative bin width {BIN_WIDTH:g})",
    }


def estimate_line(e: dict, where: str) -> str:
    kept = (
        f"percentiles exact: {_mb(e['values_bytes'])} of values kept"
        if e["percentiles"] == "exact"
        else f"percentiles binned to {100 * BIN_WIDTH:g} %: the values would take {_mb(e['values_bytes'])}"
    )
    return (
        f"estimate: {e['runs']:,} runs, about {_hms(e['wall_s'])} on {where} "
        f"({e['runs_per_s_per_process']:,.0f} runs of 30 s per second and process, timed on a pilot batch); "
        f"memory about {_mb(e['memory_bytes'])} here ({kept}); Ctrl-C stops and keeps what is done"
    )


def run_study(
    opts: StudyOptions,
    out_dir: str | os.PathLike | None = None,
    *,
    log=print,
    progress: bool = True,
    stop: threading.Event | None = None,
    reserve=None,
):
    """The whole study; returns the summary dict (also written to ``out_dir/summary.json`` with the table,
    the figure and the worst runs' ``.rrd`` when ``out_dir`` is given).  ``stop`` set (``execution.interruptible``):
    the runs done so far, ``summary["partial"]`` True, no figure and no recording.  summary.json is written first
    (the space ``reserve`` holds released if the disk is full), so no other file can lose it, then again last with
    the timing of them all; a file that could not be written is a line of ``summary["output_errors"]``."""
    t_start = time.perf_counter()
    summary, tally, phases = fly_study(opts, log=log, progress=progress, stop=stop)
    if out_dir is None:
        summary["timing"] = timing(phases, t_start)
        return summary
    out, problems = Path(out_dir), []
    summary["timing"] = timing(phases, t_start)  # the flights' (rewritten below with the files')
    write_summary(out, summary, problems, reserve)
    problems += write_study_files(summary, tally, opts, out, log=log)
    summary["timing"] = timing(phases, t_start)  # from the call to the last file
    finish(out, summary, problems, log)
    return summary


def finish(out: Path, summary: dict, problems: list[str], log=print) -> None:
    """summary.json once more, last, with the timing of every file and ``output_errors`` (a line per file that could
    not be written, also kept in the returned summary)."""
    if problems:
        summary["output_errors"] = list(dict.fromkeys(problems))
    if write_summary(out, summary, problems) and not problems:
        log(f"wrote {(out / 'summary.json').resolve()} and table.md")
    if problems:
        summary["output_errors"] = list(dict.fromkeys(problems))


def fly_study(
    opts: StudyOptions,
    *,
    log=print,
    progress: bool = True,
    stop: threading.Event | None = None,
    client=None,
    simulate=simulate,
):
    """Fly the study: (summary without ``timing``, the ``Tally`` of every run, each phase's ``_phase``).  An error
    after the first runs keeps them: ``partial``, ``done`` and ``error`` (its line).  ``simulate``: the batch
    function (``tools.experiment.study.simulation.simulate``)."""
    sweeps = list(sweep_conditions()) if opts.sweep_runs else []
    plan = Plan([(c, opts.runs) for c in opts.conditions] + [(c, opts.sweep_runs) for c in sweeps])
    long_ctrls = [c for c in LONG_CONTROLLERS if c in opts.controllers] if opts.long_runs else []
    long_plan = Plan([(c, opts.long_runs) for c in LONG_CONDITIONS])
    total, n_long = len(opts.controllers) * plan.total, len(long_ctrls) * long_plan.total
    windows = int(LONG_DURATION_S / WINDOW_S)
    exact = value_bytes(total, n_long, windows) <= EXACT_BYTES
    tally = Tally(exact, windows)
    where = opts.scheduler or ("this process" if opts.workers == 1 else f"{opts.workers} local processes")
    steps = "" if opts.scheduler else f" (steps: {native.engine()})"  # a cluster's workers load their own
    log(f"study: {len(opts.controllers)} controllers x {plan.total} runs = {total} runs of 30 s on {where}{steps}")
    own = client is None and opts.scheduler is not None
    if own:
        from tools.experiment.study.scheduler import connect

        client = connect(opts.scheduler)  # bounded: one line if it is not a Dask scheduler
    phases: dict = {}
    error = None
    try:
        rate = _pilot(opts.controllers[0], plan, opts.seed, stop, opts.faults)
        if rate is not None:
            from tools.experiment.study.scheduler import threads

            parallel = threads(client) if client is not None else min(opts.workers, os.cpu_count() or 1)
            cells = len(opts.controllers) * len(plan.segments) + 2 * len(long_ctrls) * len(long_plan.segments)
            est = estimate(total, n_long, rate, parallel, exact, cells)
            log(estimate_line(est, where if client is None else f"{where} ({parallel} worker threads)"))
        t0 = time.perf_counter()
        bar = Progress(total, "30 s runs", enabled=progress)
        rest = _tasks(opts.controllers, plan, opts.seed, opts.chunk, 30.0, opts.faults)
        for t, r in stream(rest, opts.scheduler, opts.workers, simulate, stop=stop, client=client):
            tally.add(t, r)
            bar.add(len(t.runs))
        bar.close()
        phases["runs_30s"] = _phase(tally.runs, 30.0, time.perf_counter() - t0)
        if long_ctrls and not (stop is not None and stop.is_set()):
            log(f"long flight: {len(long_ctrls)} controllers x {long_plan.total} runs of {LONG_DURATION_S:g} s")
            t0, before = time.perf_counter(), tally.runs
            bar = Progress(n_long, "600 s runs", enabled=progress)
            long_tasks = _tasks(long_ctrls, long_plan, opts.seed, opts.chunk, LONG_DURATION_S, opts.faults)
            for t, r in stream(long_tasks, opts.scheduler, opts.workers, simulate, stop=stop, client=client):
                tally.add(t, r)
                bar.add(len(t.runs))
            bar.close()
            phases["runs_600s"] = _phase(tally.runs - before, LONG_DURATION_S, time.perf_counter() - t0)
    except Exception as exc:  # after the first runs, what was flown is kept (partial, with the error's line)
        if not tally.runs:
            raise
        error = one_line(exc)
        phases.setdefault("runs_30s", _phase(tally.runs, 30.0, time.perf_counter() - t0))
    finally:
        if own:
            client.close(timeout=10)
    partial = tally.runs < total + n_long
    summary = study_summary(opts, tally, sweeps, long_ctrls, "runs_600s" in phases)
    summary["partial"] = partial
    if partial:
        summary["done"] = {"runs": tally.runs, "of": total + n_long}
    if error:
        summary["error"] = error
    return summary, tally, phases


def study_summary(opts: StudyOptions, tally: Tally, sweeps, long_ctrls, long_flown: bool) -> dict:
    conds = (*opts.conditions, *sweeps)
    summary: dict = {
        "study": "robustness",
        "plant": "kh2013a",
        "seed": opts.seed,
        # started: within the 30 s runs (their last control step is t = 29.99 s); the surface: the KH2013A's rudder
        **({"faults": [f.record(f.start <= 30.0 - 0.01, _surface(f)) for f in opts.faults]} if opts.faults else {}),
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
        "percentiles": "exact" if tally.exact else f"binned (relative bin width {BIN_WIDTH:g})",
        "conditions": {c: dataclasses.asdict(get_condition(c)) for c in conds},
        "controllers": {
            c: {"label": registry.studied(c).robustness_words, "changes": dict(registry.studied(c).changes)}
            for c in opts.controllers
        },
        "results": {
            c: {cond: cell_summary(tally.cells.get(c, {}).get(cond), cond, c, opts.seed) for cond in conds}
            for c in opts.controllers
        },
    }
    if opts.faults:  # the worst runs' replays fly the same faults
        flags = " " + " ".join(f"--fault {f.spec}" for f in opts.faults)
        for cells in summary["results"].values():
            for cell in cells.values():
                w = cell.get("worst") if isinstance(cell, dict) else None
                if w:
                    w["replay_inprocess"] += flags
                    w["replay_mavlink"] += flags
    summary["breaks"] = breaks(summary)
    if long_ctrls and long_flown:
        summary["long_flight"] = {
            "duration_s": LONG_DURATION_S,
            "window_s": WINDOW_S,
            "runs_per_condition": opts.long_runs,
            "controllers": {
                c: {cond: long_cell_summary(tally.long.get(c, {}).get(cond)) for cond in LONG_CONDITIONS}
                for c in long_ctrls
            },
        }
    summary["created"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    return summary


def timing(phases: dict, t_start: float) -> dict:
    """What the user waits for: from the call to the last file (all the runs, 30 s and 600 s, the aggregation,
    the tables, the figure and the worst runs' recording), and each phase's simulation."""
    wall = time.perf_counter() - t_start
    runs = sum(p["runs"] for p in phases.values())
    return {"wall_s": wall, "runs": runs, "runs_per_s": runs / wall if wall > 0 else None, "phases": phases}


def study_tables(summary: dict) -> list[str]:
    tables = [format_table(summary)]
    if summary["sweep_runs"]:
        tables.append(format_breaks(summary))
    if "long_flight" in summary:
        tables.append(format_long(summary))
    return tables


def write_study_files(
    summary: dict, tally: Tally, opts: StudyOptions, out: Path, *, log=print, table=True
) -> list[str]:
    """table.md (``table``), and unless the study was stopped, robustness.png and worst.rrd; a line per file that
    could not be written (a full disk: no half file is left).  A figure that cannot be drawn is skipped with a line:
    it never fails the study."""
    out.mkdir(parents=True, exist_ok=True)
    problems: list[str] = []
    if table:
        path = out / "table.md"
        try:
            path.write_text("\n\n".join(study_tables(summary)) + "\n", encoding="utf-8")
        except OSError as exc:
            path.unlink(missing_ok=True)
            problems.append(write_problem(path, exc))
    if summary.get("partial"):
        return problems
    png = out / "robustness.png"

    def draw():
        try:
            save_figure(tally, opts, png)
        except ImportError as exc:
            log(f"no figure: {exc}")
            return None
        return png

    if write_figure(png, draw, problems, log, "no figure") is not None:
        log(f"wrote {png.resolve()}")
    path = out / "worst.rrd"
    try:
        rrd = save_worst_rrd(summary, opts, path)
    except (OSError, RuntimeError) as exc:  # a full disk (rerun's writer says RuntimeError): no half file left
        for p in (path, path.with_name(path.name + ".sha256")):
            p.unlink(missing_ok=True)
        problems.append(write_problem(path, exc))
    else:
        if rrd is not None:
            log(f"wrote {rrd.resolve()} (open it with: rerun {rrd.resolve()})")
    return problems


def _phase(runs: int, duration_s: float, wall_s: float) -> dict:
    """One phase's simulation time and its cost per simulated second per aircraft (us)."""
    aircraft_s = runs * duration_s
    return {
        "runs": runs,
        "duration_s": duration_s,
        "wall_s": wall_s,
        "us_per_aircraft_s": 1e6 * wall_s / aircraft_s if aircraft_s else None,
    }


def _surface(fault) -> str | None:
    """The surface a fault of the KH2013A study hits (``sitl.damage.Schedule.surface_name``)."""
    from sitl import damage

    return damage.Schedule((), 0.0, 0.01, ("rudder",)).surface_name(fault)
