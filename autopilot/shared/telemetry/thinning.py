"""What a live viewer gets: a thinned copy of the rows (``ThinnedSink``), next to the full ones (``TeeSink``).

A viewer drawing with software rendering (the web viewer in a browser without a GPU: SwiftShader) could not keep up
with every row of a flight: measured (``python -m tools.bench viewer``), it fell a minute behind a 90 s real-time
flight and kept falling.  What it cannot keep up with is mostly the number of chunks (one per plot per flush of each
process: about 90 a second), less their rows: the web viewer loaded a 60 s flight's 2710 chunks of 0.5 s in 215 s
and the same rows in 320 chunks of 5 s in 6 s; the same 2710 chunks at 20 rows/s took 170 s.  So a writer with a live
viewer sends it at most ``rate_hz`` rows per second of sim time of each table of lines, gathered into one chunk per
plot every ``BATCH_S`` seconds (``ThinnedSink``), while its recording (a spool or a part file) keeps every row as it
comes (``TeeSink`` hands each flush to both).  No rerun here: the sinks are duck-typed (``rerun_sink.RerunSink``,
``spool.SpoolSink``).

Which rows a thinned table keeps: sim time is cut into buckets of ``1 / rate_hz`` seconds (bucket
``floor(t_ns / (1e9 / rate_hz))`` of the nanosecond the row is recorded at) and the first row of each bucket goes
to the viewer (a row whose bucket is the one of the row before it, in this flush or the last, does not).  A 100 Hz
table at 25 Hz keeps every fourth row; a table slower than ``rate_hz`` (the 10 Hz link counters) keeps all.
Tables of markers (``Plot.points``: the PARAM_SET and fault marks), state changes and event lines are never
thinned, and go on at once: each one is an event the viewer must show.
"""

from __future__ import annotations

import math
import time

import numpy as np

BATCH_S = 4.0  # wall seconds a thinned table's rows are gathered for before they go to the viewer, as one chunk


def thinned(sim: np.ndarray, rate_hz: float, last_bucket: float) -> tuple[np.ndarray, float]:
    """(the mask of the rows of ``sim`` to keep, the bucket of the last row): the first row of each
    ``1 / rate_hz`` s bucket of sim time; ``last_bucket`` is the bucket of the row before ``sim[0]`` (-inf: none)."""
    ns = np.rint(np.asarray(sim, dtype=np.float64) * 1e9)  # the instant as recorded (columns.sim_time_column)
    bucket = np.floor(ns / (1e9 / rate_hz))
    if bucket.size == 0:
        return np.zeros(0, dtype=bool), last_bucket
    before = np.empty_like(bucket)
    before[0] = last_bucket
    before[1:] = bucket[:-1]
    return bucket != before, float(bucket[-1])


class ThinnedSink:
    """A sink that hands ``inner`` at most ``rate_hz`` rows per second of sim time of each table of lines, each
    table's rows gathered for ``batch_s`` wall seconds into one call (the writer's ``flush`` after which they are due
    sends them; ``close`` sends what is left)."""

    def __init__(self, inner, rate_hz: float, batch_s: float = BATCH_S, clock=time.monotonic):
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be positive, got {rate_hz!r}")
        if not (math.isfinite(batch_s) and batch_s >= 0):
            raise ValueError(f"batch_s must be >= 0 s, got {batch_s!r}")
        self.inner = inner
        self.rate_hz = float(rate_hz)
        self.batch_s = float(batch_s)
        self._clock = clock
        self._due = clock() + self.batch_s
        self._tables: list[list] = []  # [inner handle, thinned?, last bucket, rows waiting]
        self.rows_in = 0  # rows offered
        self.rows_out = 0  # rows handed on

    @property
    def chunks_sent(self) -> int:
        return self.inner.chunks_sent

    def table(self, layout):
        thin = not any(p.points for p in layout.plots)  # markers are events: every one goes, at once
        handle = [self.inner.table(layout), thin, -math.inf, []]
        self._tables.append(handle)
        return handle

    def channel(self, path: str, label: str, colors: dict, warn: frozenset):
        return self.inner.channel(path, label, colors, warn)

    def rows(self, handle, sim: np.ndarray, wall: np.ndarray, vals: np.ndarray) -> None:
        inner, thin, last, waiting = handle
        self.rows_in += len(sim)
        if not thin:
            self._send(inner, sim, wall, vals)
            return
        keep, handle[2] = thinned(sim, self.rate_hz, last)
        if keep.any():
            waiting.append((sim[keep], wall[keep], vals[keep]))

    def _send(self, inner, sim, wall, vals) -> None:
        if len(sim):
            self.rows_out += len(sim)
            self.inner.rows(inner, sim, wall, vals)

    def _send_waiting(self) -> None:
        for handle in self._tables:
            waiting = handle[3]
            if waiting:
                handle[3] = []
                self._send(handle[0], *(np.concatenate(parts) for parts in zip(*waiting)))

    def states(self, handle, sim, wall, states) -> None:
        self.inner.states(handle, sim, wall, states)

    def events(self, sim, wall, texts, levels) -> None:
        self.inner.events(sim, wall, texts, levels)

    def flush(self) -> None:
        now = self._clock()
        if now >= self._due:
            self._due = now + self.batch_s
            self._send_waiting()
        self.inner.flush()

    def close(self) -> None:
        self._send_waiting()
        self.inner.flush()
        close = getattr(self.inner, "close", None)
        if close is not None:
            close()


class TeeSink:
    """Several sinks as one: every registration and every flush goes to each, in order (the recording first)."""

    def __init__(self, *sinks):
        if not sinks:
            raise ValueError("a TeeSink needs at least one sink")
        self.sinks = sinks

    @property
    def chunks_sent(self) -> int:
        """The first sink's (the recording's) chunks."""
        return self.sinks[0].chunks_sent

    def table(self, layout):
        return tuple(s.table(layout) for s in self.sinks)

    def channel(self, path: str, label: str, colors: dict, warn: frozenset):
        return tuple(s.channel(path, label, colors, warn) for s in self.sinks)

    def rows(self, handle, sim, wall, vals) -> None:
        for s, h in zip(self.sinks, handle):
            s.rows(h, sim, wall, vals)

    def states(self, handle, sim, wall, states) -> None:
        for s, h in zip(self.sinks, handle):
            s.states(h, sim, wall, states)

    def events(self, sim, wall, texts, levels) -> None:
        for s in self.sinks:
            s.events(sim, wall, texts, levels)

    def flush(self) -> None:
        for s in self.sinks:
            s.flush()

    def close(self) -> None:
        for s in self.sinks:
            close = getattr(s, "close", None)
            if close is not None:
                close()
