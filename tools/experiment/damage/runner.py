"""The damage study, start to end: the designs, then the flights, on ``tools.experiment.study.execute`` (here, a
pool of local processes or a Dask cluster), then ``summary.json`` and ``damage.png``."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

from tools.experiment.damage import grid
from tools.experiment.damage.aggregate import summarise
from tools.experiment.damage.flight import simulate


@dataclass(frozen=True)
class Study:
    """What to fly (the command line's flags, checked)."""

    plants: tuple = grid.DEFAULT_PLANTS
    controllers: tuple = grid.CONTROLLERS
    kinds: tuple = grid.DEFAULT_KINDS
    severities: dict = field(default_factory=lambda: dict(grid.SEVERITIES))
    onsets: tuple = grid.DEFAULT_ONSETS
    seed: int = 1
    runs: int = 2
    duration: float = grid.DEFAULT_DURATION_S
    turbulence: str = grid.DEFAULT_TURBULENCE

    def cells(self) -> tuple[dict, dict]:
        """({plant: [(kind, value), ...]}, {plant: {kind: why not}})."""
        from sitl import plant as plants

        cells, skipped = {}, {}
        for p in self.plants:
            cells[p], skipped[p] = grid.fault_cells(self.kinds, self.severities, plants.fault_refusals(p), p)
        return cells, skipped

    def flights(self) -> list[grid.Flight]:
        cells, _ = self.cells()
        return grid.make_flights(
            self.plants, self.controllers, cells, self.onsets, self.seed, self.runs, self.duration, self.turbulence
        )


def run(study: Study, *, workers: int = 1, scheduler: str | None = None, progress: bool = True, log=print) -> dict:
    """Fly the study; its ``summary.json`` document (``write`` puts it on disk)."""
    from tools.experiment.study import Progress, execute

    flights = study.flights()
    prep = grid.designs_needed(flights)
    free = [f for f in flights if f.controller not in (grid.RETUNED, grid.ENERGY)]
    bound = [f for f in flights if f.controller in (grid.RETUNED, grid.ENERGY)]
    where = scheduler or f"{workers} local process(es)"
    log(
        f"{len(flights)} flights and {len(prep)} design(s) (the PID retuned for each linear fault, the PID at "
        f"CL-SAC's energy) on {where}"
    )
    bar = Progress(len(prep) + len(flights), "damage", enabled=progress)
    t0 = time.perf_counter()
    # Phase 1: the designs (the longest tasks, first) with the flights that need none; phase 2: the flights that
    # fly a design.  Each result depends on its task only, whichever phase or worker computed it.
    first = execute([*prep, *free], scheduler, bar, workers, simulate=simulate)
    designed = dict(zip(prep, first[: len(prep)]))
    gains = {t: tuple(r["gains"]) for t, r in designed.items()}
    bound = grid.with_designs(bound, gains)
    second = execute(bound, scheduler, bar, workers, simulate=simulate)
    t1 = time.perf_counter()
    by_task = dict(zip(free, first[len(prep) :])) | dict(zip(bound, second))
    flights = grid.with_designs(flights, gains)
    results = [by_task[f] for f in flights]
    return {
        "study": "damage",
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
        "cells": summarise(flights, results),
        "flights": len(flights),
        "wall_s": t1 - t0,
        "flights_per_s": len(flights) / (t1 - t0) if t1 > t0 else None,
        "executor": scheduler or f"{workers} local process(es)",
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


def write(doc: dict, out: Path, plot: bool = True) -> list[Path]:
    """``out/summary.json`` and (``plot``) ``out/damage.png``; the paths written."""
    from autopilot.shared.process import write_json_atomic

    out = Path(out)
    written = [out / "summary.json"]
    write_json_atomic(written[0], doc)
    if plot:
        from tools.view.damage_png import draw

        written.append(
            draw(doc["cells"], doc["plants"], doc["kinds"], doc["controllers"], doc["labels"], out / "damage.png")
        )
    return written
