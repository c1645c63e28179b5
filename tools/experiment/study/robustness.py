"""``python -m tools.experiment robustness --plant A[,B...]``: one study per plant, one summary.json.

The KH2013A (``kh2013a``) flies the batched study (``runner``: many aircraft at once, the steps in C where the
kernel builds, numpy otherwise); a JSBSim aircraft or a plant file flies its in-process flights (``flights``).
With one plant, summary.json is that plant's section (the KH2013A's is the study's summary as it always was); with
several, ``{"study": "robustness", "plants": {PLANT: section, ...}, "partial": ..., "timing": ...}``.  Stopped
(``stop``), what is done is kept: the plant being flown is ``partial``, the plants after it are ``not_flown``.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

from tools.experiment.outdir import write_problem
from tools.experiment.study import flights
from tools.experiment.study.aggregation import LONG_DURATION_S
from tools.experiment.study.report import format_table
from tools.experiment.study.runner import (
    finish,
    fly_study,
    run_study,
    study_tables,
    timing,
    write_study_files,
    write_summary,
)
from tools.experiment.study.sampling import StudyOptions


def is_kh2013a(opts) -> bool:
    return isinstance(opts, StudyOptions)


def run_plants(
    plan: list[tuple[str, object]],
    out: Path,
    *,
    log=print,
    progress: bool = True,
    stop: threading.Event | None = None,
    scheduler: str | None = None,
    reserve=None,
) -> dict:
    """Fly each (plant, options) of ``plan`` in turn (``StudyOptions`` for the KH2013A, ``flights.FlightOptions``
    otherwise); write ``out``/summary.json and table.md (and the KH2013A's robustness.png and worst.rrd); return
    the summary."""
    if len(plan) == 1 and is_kh2013a(plan[0][1]):
        return run_study(plan[0][1], out, log=log, progress=progress, stop=stop, reserve=reserve)
    t_start = time.perf_counter()
    client = None
    if scheduler is not None:
        from tools.experiment.study.scheduler import connect

        client = connect(scheduler)
    sections: dict[str, dict] = {}
    kh = None
    try:
        for text, opts in plan:
            if stop is not None and stop.is_set():
                break
            if is_kh2013a(opts):
                t0 = time.perf_counter()
                section, tally, phases = fly_study(opts, log=log, progress=progress, stop=stop, client=client)
                section["timing"] = timing(phases, t0)
                kh = (section, tally, opts)
            else:
                section = flights.fly(opts, log=log, progress=progress, stop=stop, client=client)
            sections[text] = section
            if section.get("error"):  # an error stopped it: the plants after it are not flown
                break
    finally:
        if client is not None:
            client.close(timeout=10)
    out.mkdir(parents=True, exist_ok=True)
    not_flown = [text for text, _ in plan if text not in sections]
    partial = bool(not_flown) or any(s["partial"] for s in sections.values())
    if len(plan) == 1:
        summary = sections[plan[0][0]]
    else:
        summary = {"study": "robustness", "plants": sections, "partial": partial}
        if not_flown:
            summary["not_flown"] = not_flown
        summary["timing"] = {"wall_s": time.perf_counter() - t_start}
    problems: list[str] = []
    write_summary(out, summary, problems, reserve)  # first: no other file can lose it
    try:
        (out / "table.md").write_text(report(sections, headings=len(plan) > 1) + "\n", encoding="utf-8")
    except OSError as exc:
        (out / "table.md").unlink(missing_ok=True)
        problems.append(write_problem(out / "table.md", exc))
    if kh is not None:
        problems += write_study_files(*kh, out, log=log, table=False)
    if "plants" in summary:
        summary["timing"] = {"wall_s": time.perf_counter() - t_start}
    finish(out, summary, problems, log)
    return summary


def sections_of(summary: dict) -> dict[str, dict]:
    """{plant: section} of a summary.json, whatever the number of plants."""
    return summary["plants"] if "plants" in summary else {summary.get("plant", "kh2013a"): summary}


def _flown_one_by_one(section: dict) -> bool:
    """A section of a plant flown flight by flight (``flights``), not in the batched study: its ``kind`` is a plant
    kind's (``sitl.plant_kinds.KINDS``) that the batched study does not fly."""
    from sitl.plant_kinds import KINDS

    if section.get("one_by_one"):  # the flights' own mark (the KH2013A's laws without a batch form too)
        return True
    kind = KINDS.get(section.get("kind"))
    return kind is not None and not kind.batched


def report(sections: dict[str, dict], headings: bool = False, full: bool = True) -> str:
    """The tables of every section (Markdown; table.md), under a heading per plant when ``headings``; not ``full``:
    the KH2013A's main table only (the command prints the others with ``notes``)."""
    parts = []
    for text, s in sections.items():
        if headings:
            parts.append(f"## {text}" + (" (partial)" if s.get("partial") else ""))
        if _flown_one_by_one(s):
            parts += [flights.format_table(s["results"]), flights.format_bounded(s["results"])]
        else:
            parts += study_tables(s) if full else [format_table(s)]
    return "\n\n".join(parts)


def final_line(summary: dict, out: Path) -> str:
    """The last line: what was flown and the whole wait, files included."""
    secs = sections_of(summary)
    if "plants" not in summary:
        s = next(iter(secs.values()))
        t = s["timing"]
        if _flown_one_by_one(s):
            return (
                f"{t['runs']} flights in {t['wall_s']:.1f} s ({(t['runs_per_s'] or 0):.2f} flights/s) on "
                f"{s['where']}; files in {out.resolve()}"
            )
        kinds = ", ".join(f"{p['runs']} of {p['duration_s']:g} s" for p in t["phases"].values())
        return (
            f"{t['runs']} runs ({kinds}) in {t['wall_s']:.1f} s ({(t['runs_per_s'] or 0):,.0f} runs/s), files "
            f"included; files in {out.resolve()}"
        )
    parts = []
    for text, s in secs.items():
        t = s["timing"]
        parts.append(f"{text}: {t['runs']} {'flights' if s.get('kind') else 'runs'} in {t['wall_s']:.1f} s")
    return f"{'; '.join(parts)}; {summary['timing']['wall_s']:.1f} s in all, files included; files in {out.resolve()}"


def notes(summary: dict) -> list[str]:
    """The lines printed under the KH2013A's tables: where each breaks, the worst runs, the long flight."""
    from tools.experiment.study.report import format_breaks, format_long

    lines = []
    s = sections_of(summary).get("kh2013a")
    if s is None or _flown_one_by_one(s):  # the laws without a batch form: one flight at a time
        return lines
    if s["sweep_runs"]:
        lines += ["where each controller stops being bounded (< 90 % of runs), one factor at a time from nominal:"]
        lines += [format_breaks(s)]
    conds = _main_conditions(s)
    for ctrl, by_cond in s["results"].items():
        w = (by_cond.get(conds[-1]) or {}).get("worst") if conds else None
        if w:
            lines.append(f"worst {ctrl} run under {conds[-1]}: {w['replay_inprocess']}")
    if "long_flight" in s:
        lines += [f"\nlong flight ({LONG_DURATION_S:g} s), median peak |roll| per 30 s window:", format_long(s)]
    return lines


def _main_conditions(s: dict) -> list[str]:
    """The study's conditions (not the sweeps'), in order."""
    return [c for c in s["conditions"] if "=" not in c]
