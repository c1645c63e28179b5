"""Many batches: here, on a pool of local processes or on a Dask cluster (``execute``), with a progress bar,
and their results merged per controller and run (``merge``)."""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence

import numpy as np

from tools.experiment.study.sampling import METRICS, StudyError, Task
from tools.experiment.study.simulation import simulate


class Progress:
    """A one-line progress bar on stderr: runs done, runs/s, estimated time left."""

    def __init__(self, total: int, label: str, stream=None, enabled: bool = True):
        self.total, self.label, self.done = total, label, 0
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.t0 = time.perf_counter()

    def add(self, runs: int) -> None:
        self.done += runs
        if not self.enabled:
            return
        el = time.perf_counter() - self.t0
        rate = self.done / el if el > 0 else 0.0
        left = (self.total - self.done) / rate if rate > 0 else float("nan")
        width = 30
        fill = int(width * self.done / max(self.total, 1))
        self.stream.write(
            f"\r{self.label} [{'#' * fill}{'.' * (width - fill)}] {self.done}/{self.total} runs "
            f"{rate:,.0f} runs/s, {left:4.0f} s left "
        )
        if self.done >= self.total:
            self.stream.write("\n")
        self.stream.flush()


def execute(
    tasks: Sequence[Task],
    scheduler: str | None = None,
    progress: Progress | None = None,
    workers: int = 1,
    simulate=simulate,
) -> list[dict]:
    """Run every task: locally, one after the other (``workers`` 1) or in a pool of ``workers`` processes, or on
    the Dask cluster at ``scheduler`` (``tcp://HOST:PORT``); results in task order whichever.  ``simulate``: the
    task function (a picklable module-level function of a task with ``runs``; ``tools.experiment.jsbsim_study`` passes
    its
    own)."""
    results: list[dict | None] = [None] * len(tasks)
    if scheduler is None and workers <= 1:
        for i, t in enumerate(tasks):
            results[i] = simulate(t)
            if progress:
                progress.add(len(t.runs))
        return results  # type: ignore[return-value]
    if scheduler is None:
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(max_workers=workers) as pool:
            index = {pool.submit(simulate, t): i for i, t in enumerate(tasks)}
            for fut in as_completed(index):
                i = index[fut]
                results[i] = fut.result()
                if progress:
                    progress.add(len(tasks[i].runs))
        return results  # type: ignore[return-value]
    try:
        from distributed import Client, as_completed  # lazy: dask is an optional (dev) dependency
    except ImportError as exc:
        raise StudyError(f"--scheduler needs dask.distributed (pip install 'dask[distributed]'): {exc}") from None
    try:
        client = Client(scheduler, timeout="10s")
    except (OSError, TimeoutError) as exc:
        raise StudyError(f"cannot connect to the Dask scheduler at {scheduler}: {exc}") from None
    with client:
        futures = client.map(simulate, list(tasks), pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        for fut in as_completed(futures):
            i = index[fut.key]
            results[i] = fut.result()
            if progress:
                progress.add(len(tasks[i].runs))
    return results  # type: ignore[return-value]


def merge(tasks: Sequence[Task], results: Sequence[dict]) -> dict[str, dict[tuple[str, int], dict]]:
    """{controller: {(condition, run): per-run record}} from the chunks."""
    out: dict[str, dict[tuple[str, int], dict]] = {}
    for t, r in zip(tasks, results):
        d = out.setdefault(t.controller, {})
        for j, pair in enumerate(t.runs):
            rec = {m: float(r[m][j]) for m in METRICS}
            rec["bounded"] = bool(r["bounded"][j])
            rec["oscillating"] = bool(r["oscillating"][j])  # a sustained oscillation (autopilot.envelope)
            rec["not_following"] = bool(r["not_following"][j])
            rec["pfc"] = "paper" if r["pfc_paper"][j] else "robust"
            rec["window_peak_roll"] = r["window_peak_roll"][j]
            rec["draws"] = {k: (v[j].tolist() if np.ndim(v[j]) else float(v[j])) for k, v in r["draws"].items()}
            d[pair] = rec
    return out
