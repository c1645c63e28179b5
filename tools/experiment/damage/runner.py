"""The damage study, start to end: the designs, then the flights, on ``tools.experiment.study.execute`` (here, a
pool of local processes or a Dask cluster), then ``summary.json`` and ``damage.png``."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

from tools.experiment.damage import grid
from tools.experiment.damage.aggregate import paired_list, summarise
from tools.experiment.damage.flight import run_damage_task


@dataclass(frozen=True)
class Study:
    """What to fly (the command line's flags, checked)."""

    plants: tuple = grid.DEFAULT_PLANTS
    controllers: tuple = grid.CONTROLLERS
    kinds: tuple = grid.DEFAULT_KINDS
    severities: dict = field(default_factory=lambda: dict(grid.SEVERITIES))
    onsets: tuple = grid.DEFAULT_ONSETS
    seed: int = 1
    runs: int = grid.DEFAULT_RUNS
    duration: float = grid.DEFAULT_DURATION_S
    turbulence: str = grid.DEFAULT_TURBULENCE

    def cells(self) -> tuple[dict, dict]:
        """({plant: [(kind, value), ...]}, {plant: {kind: why not}})."""
        from sitl import plant as plants

        cells, skipped = {}, {}
        for p in self.plants:
            cells[p], skipped[p] = grid.fault_cells(self.kinds, self.severities, plants.fault_refusals(p), p)
        return cells, skipped

    def count(self) -> int:
        """How many flights ``flights`` lists, without listing them (``make_flights``' loops counted)."""
        cells, _ = self.cells()
        n = 0
        for p in self.plants:
            flown = [c for c in self.controllers if c not in grid.controller_refusals(p, self.controllers)]
            n += len(flown) * self.runs * (1 + len(cells[p]) * len(self.onsets))
        return n

    def flights(self) -> list[grid.DamageFlight]:
        cells, _ = self.cells()
        return grid.make_flights(
            self.plants, self.controllers, cells, self.onsets, self.seed, self.runs, self.duration, self.turbulence
        )


def plan_line(flights, prep, where: str) -> str:
    """The first line: the flights and, if any, the designs they need (only those asked for)."""
    parts = []
    retuned = sum(isinstance(t, grid.Design) for t in prep)
    calibrated = sum(isinstance(t, grid.Calibration) for t in prep)
    if retuned:
        parts.append(f"{retuned} for {grid.RETUNED}: the plant's PID as built and retuned for each linear fault")
    if calibrated:
        parts.append(f"{calibrated} for {grid.ENERGY}: the PID scaled to CL-SAC's energy")
    designs = f" and {len(prep)} design(s) ({'; '.join(parts)})" if prep else ""
    return f"{len(flights)} flights{designs} on {where}"


def run(
    study: Study,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    progress: bool = True,
    log=print,
    stop=None,
    simulate=run_damage_task,
) -> dict:
    """Fly the study; its ``summary.json`` document (``write`` puts it on disk).  ``stop`` set (SIGINT,
    ``tools.experiment.study.execution.interruptible``) or an error after the first flight: the flights done so far,
    ``partial`` True, ``done`` {flights, of} and ``error`` (the error's line, if one stopped it).  ``simulate``: the
    task function (``tools.experiment.damage.flight.run_damage_task``)."""
    from tools.experiment.study import Progress
    from tools.experiment.study.execution import stream

    flights = study.flights()
    prep = grid.designs_needed(flights)
    free = [f for f in flights if f.controller not in (grid.RETUNED, grid.ENERGY)]
    bound = [f for f in flights if f.controller in (grid.RETUNED, grid.ENERGY)]
    where = scheduler or f"{workers} local process(es)"
    log(plan_line(flights, prep, where))
    bar = Progress(len(prep) + len(flights), "damage", enabled=progress)
    t0 = time.perf_counter()
    done: dict = {}  # task -> its result, as they come
    error = None
    try:
        # Phase 1: the designs (the longest tasks, first) with the flights that need none; phase 2: the flights
        # that fly a design.  Each result depends on its task only, whichever phase or worker computed it.
        for t, r in stream([*prep, *free], scheduler, workers, simulate, stop=stop):
            done[t] = r
            bar.add(1)
        if all(t in done for t in prep):
            gains = {t: tuple(done[t]["gains"]) for t in prep}
            for t, r in stream(grid.with_designs(bound, gains), scheduler, workers, simulate, stop=stop):
                done[t] = r
                bar.add(1)
    except Exception as exc:  # after the first flight, what was flown is kept (a partial summary)
        if not any(isinstance(t, grid.DamageFlight) for t in done):
            raise
        error = f"{type(exc).__name__}: {exc}".strip().splitlines()[0]
    finally:
        bar.close()
    t1 = time.perf_counter()
    designed = {t: done[t] for t in prep if t in done}
    gains = {t: tuple(r["gains"]) for t, r in designed.items()}
    flown = []
    for f in flights:
        try:
            task = grid.with_designs([f], gains)[0]
        except KeyError:  # its design was not made: not flown
            continue
        if task in done:
            flown.append(task)
    doc = {
        "study": "damage",
        "partial": len(flown) < len(flights),
        "plants": list(study.plants),
        "controllers": list(study.controllers),
        "labels": {c: grid.label(c) for c in study.controllers},
        "kinds": list(study.kinds),
        "severities": {k: list(study.severities[k]) for k in study.kinds},
        "onsets_s": list(study.onsets),
        "seed": study.seed,
        "runs": study.runs,
        "seeds": grid.seeds(study.seed, study.runs),
        "duration_s": study.duration,
        "turbulence": study.turbulence,
        "not_flown": not_flown(study),
        "designs": [
            {"task": type(t).__name__.lower(), "plant": t.plant, **_task_fields(t), **_plain(r)}
            for t, r in designed.items()
        ],
        "statistics": STATISTICS,
        "cells": (cells := summarise(flown, [done[f] for f in flown])),
        "paired": paired_list(cells),
        "flights": len(flown),
        "wall_s": t1 - t0,
        "flights_per_s": len(flown) / (t1 - t0) if t1 > t0 else None,
        "executor": where,
    }
    if doc["partial"]:
        doc["done"] = {"flights": len(flown), "of": len(flights)}
        if error:
            doc["error"] = error
    return doc


STATISTICS = {
    "reference": "each law is paired with CL-SAC (the first controller when CL-SAC is not flown) on the seeds both "
    "flew (common random numbers)",
    "paired_difference": "median of the per-seed differences law - reference of ise_ref after the onset, with the "
    "sign test's interval; under 6 seeds the seeds' range with its own confidence 1 - 2^(1-n), and no difference shown",
    "controlled": "the seeds only one law keeps, and the exact two-sided sign test (McNemar) on them",
    "energy_ratio": "median of the per-seed ratios of the energy after the onset, law / reference, sign-test interval",
    "digits": "a median is printed to the place of the leading digit of its interval's half width (1-3 digits)",
    "long_flights": "the mean ise_ref per 10 s period over the last 100 s, 95 % percentile bootstrap over the (seed, "
    "period) units, 2000 resamples, a fixed generator",
    "share": "95 % Wilson score interval",
}


def not_flown(study: Study) -> dict:
    """{plant: {kind: why, ..., "controllers": {controller: why}}} for what a plant does not fly (plants that fly
    everything asked for are not listed)."""
    _, skipped = study.cells()
    out = {}
    for p in study.plants:
        why = dict(skipped.get(p) or {})
        refused = grid.controller_refusals(p, study.controllers)
        if refused:
            why["controllers"] = refused
        if why:
            out[p] = why
    return out


def _task_fields(t) -> dict:
    return {"kind": t.kind, "severity": t.value} if isinstance(t, grid.Design) else {}


def _plain(r: dict) -> dict:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in r.items()}


def write(doc: dict, out: Path, plot: bool = True, reserve=None, log=print) -> tuple[list[Path], list[str]]:
    """``out/summary.json`` first (the space ``reserve`` holds released if the disk is full), then (``plot``)
    ``out/damage.png``: (the paths written, a line per file that could not be written).  A picture that cannot be
    drawn never loses the summary: it is skipped with a line (``log``); one that cannot be written is a problem."""
    from tools.experiment.outdir import write_figure, write_summary

    out, problems = Path(out), []
    summary = write_summary(out, doc, problems, reserve, indent=1)
    if summary is None:
        return [], problems
    written = [summary]
    if plot and doc["cells"]:
        from tools.view.damage_png import draw

        png = out / "damage.png"
        cells = (doc["cells"], doc["plants"], doc["kinds"], doc["controllers"], doc["labels"])
        drawn = write_figure(png, lambda: draw(*cells, png), problems, log)
        if drawn is not None:
            written.append(drawn)
    return written, problems
