"""Arrow columns for ``RecordingStream.send_columns``: scalar series, time columns, series styles."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pyarrow as pa
import rerun as rr

from autopilot.shared.telemetry.layout import SIM_TIME, WALL_TIME, Rgb


class _ArrowBatch:
    """Minimal ComponentBatchLike around a ready pyarrow array (avoids rerun's per-call converters)."""

    __slots__ = ("_array",)

    def __init__(self, array: pa.Array):
        self._array = array

    def as_arrow_array(self) -> pa.Array:
        return self._array


_SCALARS = rr.Scalars.descriptor_scalars()


def scalar_column(values: np.ndarray) -> rr.ComponentColumn:
    """A ``Scalars`` column from an (n,) or (n, k) float array: k series per row (one per instance)."""
    v = np.ascontiguousarray(values, dtype=np.float64)
    n = v.shape[0]
    k = 1 if v.ndim == 1 else v.shape[1]
    offsets = np.arange(0, n * k + 1, k, dtype=np.int32)
    return rr.ComponentColumn(_SCALARS, _ArrowBatch(pa.array(v.reshape(-1), pa.float64())), offsets=offsets)


def sim_time_column(seconds: np.ndarray, timeline: str = SIM_TIME) -> rr.TimeColumn:
    """Duration column rounded to the nanosecond.

    rerun's own float path truncates (``(t * 1e9).astype(int)``), which maps 0.0075 s to 7499999 ns:
    two processes computing the same instant differently would then land on different indices.
    """
    ns = np.rint(np.asarray(seconds, dtype=np.float64) * 1e9).astype(np.int64)
    return rr.TimeColumn(timeline, duration=ns.astype("timedelta64[ns]"))


def wall_time_column(epoch_seconds: np.ndarray, timeline: str = WALL_TIME) -> rr.TimeColumn:
    """Timestamp column from ``time.time()`` seconds, rounded to the nanosecond."""
    ns = np.rint(np.asarray(epoch_seconds, dtype=np.float64) * 1e9).astype(np.int64)
    return rr.TimeColumn(timeline, timestamp=ns.astype("datetime64[ns]"))


def series_style(labels: Sequence[str], colors: Sequence[Rgb], step: bool = False) -> rr.SeriesLines:
    """Legend names and colours of the series of one entity; ``step`` draws staircases."""
    return rr.SeriesLines(
        names=list(labels), colors=[list(c) for c in colors], interpolation_mode="StepAfter" if step else None
    )
