"""Per-step series recorder: a hook that keeps one row per step and saves the columns as ``.npz``."""

from __future__ import annotations

from collections.abc import Callable, Sequence


class SeriesRecorder:
    """``recorder(record)`` appends ``row(record)`` (a tuple ordered like ``keys``); ``save(path)`` writes one
    array per key.  The autopilot and the SITL each give their own keys and row function."""

    def __init__(self, keys: Sequence[str], row: Callable[[object], tuple]):
        self.keys = tuple(keys)
        self._row = row
        self.rows: list = []

    def __call__(self, record) -> None:
        self.rows.append(self._row(record))

    def __len__(self) -> int:
        return len(self.rows)

    def save(self, path) -> None:
        import numpy as np

        arr = np.asarray(self.rows, dtype=float).reshape(-1, len(self.keys))
        np.savez(path, **{k: arr[:, i] for i, k in enumerate(self.keys)})
