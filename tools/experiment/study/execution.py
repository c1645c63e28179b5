"""Many batches: here, on a pool of local processes or on a Dask cluster, streamed in task order (``stream``) with
at most a few in flight, and stopped within a poll (0.1 s) when asked (``stop``, set by ``interruptible`` on
SIGINT); ``execute`` collects them; a progress bar; and the chunks' results as per-run records (``merge``)."""

from __future__ import annotations

import contextlib
import queue
import signal
import sys
import threading
import time
from collections.abc import Iterable, Iterator, Sequence

import numpy as np

from tools.experiment.study.sampling import METRICS, Task
from tools.experiment.study.simulation import simulate

POLL_S = 0.1  # how often a wait looks at ``stop``


class Progress:
    """A one-line progress bar on stderr: runs done, runs/s, estimated time left."""

    def __init__(self, total: int, label: str, stream=None, enabled: bool = True, unit: str = "runs"):
        self.total, self.label, self.done, self.unit = total, label, 0, unit
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.t0 = time.perf_counter()
        self._shown = 0.0

    def add(self, runs: int) -> None:
        self.done += runs
        if not self.enabled:
            return
        now = time.perf_counter()
        if self.done < self.total and now - self._shown < 0.2:  # at most 5 redraws a second
            return
        self._shown = now
        el = now - self.t0
        rate = self.done / el if el > 0 else 0.0
        left = (self.total - self.done) / rate if rate > 0 else float("nan")
        width = 30
        fill = int(width * self.done / max(self.total, 1))
        self.stream.write(
            f"\r{self.label} [{'#' * fill}{'.' * (width - fill)}] {self.done}/{self.total} {self.unit} "
            f"{rate:,.{0 if rate >= 10 else 2}f} {self.unit}/s, {_duration(left)} left "
        )
        if self.done >= self.total:
            self.stream.write("\n")
        self.stream.flush()

    def close(self) -> None:
        """End the bar's line if it stopped short."""
        if self.enabled and self.done < self.total:
            self.stream.write("\n")
            self.stream.flush()


def _duration(s: float) -> str:
    if not s == s or s == float("inf"):
        return "   ? s"
    if s < 600:
        return f"{s:4.0f} s"
    return f"{s / 60:4.0f} min" if s < 36000 else f"{s / 3600:4.0f} h"


@contextlib.contextmanager
def interruptible(stream=None):
    """A ``threading.Event`` set by the first SIGINT (a second one raises KeyboardInterrupt as usual), for
    ``stream(stop=...)``; outside the main thread, an event nothing sets."""
    stop = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    out = stream or sys.stderr

    def handler(_sig, _frame):
        if stop.is_set():
            raise KeyboardInterrupt
        stop.set()
        out.write("\ninterrupted: stopping, keeping the runs done (again to quit at once)\n")
        out.flush()

    old = signal.signal(signal.SIGINT, handler)
    try:
        yield stop
    finally:
        signal.signal(signal.SIGINT, old)


def _ignore_sigint() -> None:  # a pool worker: the parent decides what an interrupt stops
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def stream(
    tasks: Iterable,
    scheduler: str | None = None,
    workers: int = 1,
    simulate=simulate,
    *,
    stop: threading.Event | None = None,
    ahead: int | None = None,
    client=None,
) -> Iterator[tuple[object, dict]]:
    """(task, result) for every task, in task order: in a worker thread of this process (``workers`` 1), a pool of
    ``workers`` local processes, or on the Dask cluster at ``scheduler`` (or ``client``, already connected); at most
    ``ahead`` tasks in flight (default: twice the workers).  Ends early, within ``POLL_S``, once ``stop`` is set;
    closing it stops the work: the pool's processes are terminated, the cluster's futures cancelled.  ``tasks``
    may be a generator (a study of 10^7 runs is never listed whole)."""
    it = iter(tasks)
    if scheduler is None and client is None:
        if workers <= 1:
            yield from _in_thread(it, simulate, stop)
        else:
            yield from _in_pool(it, simulate, workers, ahead or 2 * workers, stop)
        return
    from tools.experiment.study import scheduler as dask

    own = client is None
    client = client or dask.connect(scheduler)
    try:
        yield from _on_cluster(it, simulate, client, ahead or 2 * dask.threads(client), stop)
    finally:
        if own:
            client.close(timeout=dask.TIMEOUT_S)


def _wait(q: queue.Queue, stop: threading.Event | None):
    """The next item of ``q``, or None once ``stop`` is set."""
    while True:
        if stop is not None and stop.is_set():
            return None
        try:
            return q.get(timeout=POLL_S)
        except queue.Empty:
            continue


def _in_thread(it: Iterator, simulate, stop) -> Iterator:
    """One task at a time in a daemon thread, so that this (main) thread stays free to answer SIGINT while a
    batch runs in C; the thread is left to finish its batch when the study stops."""
    todo: queue.Queue = queue.Queue(maxsize=1)
    done: queue.Queue = queue.Queue()
    quit_ = threading.Event()

    def work():
        while not quit_.is_set():
            t = todo.get()
            if t is None:
                return
            try:
                done.put((t, simulate(t), None))
            except BaseException as exc:  # noqa: BLE001 - handed to the main thread
                done.put((t, None, exc))

    worker = threading.Thread(target=work, name="study-batch", daemon=True)
    worker.start()
    busy = False
    try:
        for t in it:
            if stop is not None and stop.is_set():
                return
            todo.put(t)
            busy = True
            item = _wait(done, stop)
            if item is None:
                return
            busy = False
            task, result, exc = item
            if exc is not None:
                raise exc
            yield task, result
    finally:
        quit_.set()
        with contextlib.suppress(queue.Full):
            todo.put_nowait(None)
        if not busy:
            worker.join()  # idle: it ends at once (a process forked next holds no other thread)


def _in_order(submit, it: Iterator, ahead: int, done: queue.Queue, stop) -> Iterator:
    """Keep ``ahead`` tasks submitted (``submit(i, task)``), yield their results in task order as ``done`` delivers
    (index, result, exception)."""
    tasks: dict[int, object] = {}
    ready: dict[int, dict] = {}
    nxt = sub = 0
    exhausted = False
    while True:
        while not exhausted and sub - nxt < ahead and not (stop is not None and stop.is_set()):
            t = next(it, None)
            if t is None:
                exhausted = True
                break
            tasks[sub] = t
            submit(sub, t)
            sub += 1
        if nxt == sub:
            return
        item = _wait(done, stop)
        if item is None:
            return
        i, result, exc = item
        if exc is not None:
            raise exc
        ready[i] = result
        while nxt in ready:
            yield tasks.pop(nxt), ready.pop(nxt)
            nxt += 1


def _in_pool(it: Iterator, simulate, workers: int, ahead: int, stop) -> Iterator:
    import multiprocessing

    done: queue.Queue = queue.Queue()
    pool = multiprocessing.get_context().Pool(workers, initializer=_ignore_sigint)
    try:

        def submit(i, t):
            pool.apply_async(
                simulate,
                (t,),
                callback=lambda r, i=i: done.put((i, r, None)),
                error_callback=lambda e, i=i: done.put((i, None, e)),
            )

        yield from _in_order(submit, it, ahead, done, stop)
    finally:
        pool.terminate()  # the workers stop at once, whatever they were flying
        pool.join()


def _on_cluster(it: Iterator, simulate, client, ahead: int, stop) -> Iterator:
    done: queue.Queue = queue.Queue()
    futures: dict[int, object] = {}

    def submit(i, t):
        fut = futures[i] = client.submit(simulate, t, pure=False)
        fut.add_done_callback(lambda f, i=i: done.put((i, f, None)))  # in Dask's callback thread: no waiting there

    try:
        for k, (task, fut) in enumerate(_in_order(submit, it, ahead, done, stop)):  # k: the task's index
            yield task, fut.result(timeout=60)  # done: its result is fetched, not computed
            futures.pop(k, None)
    finally:
        pending = [f for f in futures.values() if not f.done()]
        if pending:
            client.cancel(pending)


def execute(
    tasks: Sequence[Task],
    scheduler: str | None = None,
    progress: Progress | None = None,
    workers: int = 1,
    simulate=simulate,
    *,
    stop: threading.Event | None = None,
) -> list[dict]:
    """Run every task: locally, one after the other (``workers`` 1) or in a pool of ``workers`` processes, or on
    the Dask cluster at ``scheduler`` (``tcp://HOST:PORT``, reached with every wait bounded:
    ``tools.experiment.study.scheduler``); results in task order whichever.  ``simulate``: the task function (a
    picklable module-level function of a task with ``runs``; the study's flights and damage pass their own).
    ``stop`` (``interruptible``): when set, the results so far (a shorter list)."""
    results = []
    for t, r in stream(tasks, scheduler, workers, simulate, stop=stop):
        results.append(r)
        if progress:
            progress.add(len(t.runs))
    return results


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
