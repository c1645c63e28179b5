"""The per-step series recorder: the .npz it writes, and memory bounded whatever the number of rows."""

from __future__ import annotations

import tracemalloc

import numpy as np

from autopilot.shared.series import CHUNK_ROWS, SeriesRecorder


def test_columns_round_trip_through_the_spill(tmp_path):
    rec = SeriesRecorder(("a", "b", "c"), lambda k: (k, 2 * k, None if k % 7 == 0 else True))
    n = 3 * CHUNK_ROWS + 123  # three spills and a partly filled buffer
    for k in range(n):
        rec(k)
    assert len(rec) == n
    rec.save(tmp_path / "s")  # .npz added, as numpy.savez does
    with np.load(tmp_path / "s.npz") as d:
        assert d.files == ["a", "b", "c"]
        assert np.array_equal(d["a"], np.arange(n, dtype=float)) and np.array_equal(d["b"], 2 * d["a"])
        assert np.isnan(d["c"][::7]).all() and d["c"][1] == 1.0


def test_memory_stays_bounded(tmp_path):
    rec = SeriesRecorder(tuple("abcdefghij"), lambda k: (float(k),) * 10)
    tracemalloc.start()
    for k in range(200_000):  # 16 MB of rows
        rec(k)
    rec.save(tmp_path / "big.npz")
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < 4e6  # a few chunks, never the 16 MB
    with np.load(tmp_path / "big.npz") as d:
        assert len(d["j"]) == 200_000 and d["j"][-1] == 199_999.0
