"""Per-step series recorder: a hook that keeps one row per step and saves the columns as ``.npz``.

Memory stays bounded whatever the flight's length: rows are kept as float64 in a buffer of ``CHUNK_ROWS`` rows,
which is spilled to an anonymous temporary file when full, and ``save`` writes the ``.npz`` column by column
from the spill, a chunk at a time (docs/decisions.md, "Bounded memory").
"""

from __future__ import annotations

import math
import os
import tempfile
from array import array
from collections.abc import Callable, Sequence

CHUNK_ROWS = 8192  # rows held in memory before they are spilled to disk


class SeriesRecorder:
    """``recorder(record)`` appends ``row(record)`` (a tuple ordered like ``keys``; None is stored as NaN);
    ``save(path)`` writes one float64 array per key.  The autopilot and the SITL each give their own keys and row
    function."""

    def __init__(self, keys: Sequence[str], row: Callable[[object], tuple]):
        self.keys = tuple(keys)
        self._row = row
        self._buf = array("d")
        self._limit = CHUNK_ROWS * len(self.keys)
        self._spill = None  # temporary file of the rows spilled so far (row-major float64)
        self._spilled = 0  # rows in it

    def __call__(self, record) -> None:
        row = self._row(record)
        buf = self._buf
        n0 = len(buf)
        try:
            buf.extend(row)
        except TypeError:  # a None: extend() may have taken part of the row already
            del buf[n0:]
            buf.extend([math.nan if v is None else v for v in row])
        if len(buf) >= self._limit:
            self._flush()

    def __len__(self) -> int:
        return self._spilled + len(self._buf) // len(self.keys)

    def _flush(self) -> None:
        if self._spill is None:
            self._spill = tempfile.TemporaryFile(prefix="series-")
        self._buf.tofile(self._spill)
        self._spilled += len(self._buf) // len(self.keys)
        del self._buf[:]

    def _chunks(self):
        """The rows in order, as (n, len(keys)) float64 arrays of at most CHUNK_ROWS rows."""
        import numpy as np

        ncol = len(self.keys)
        if self._spill is not None:
            self._spill.seek(0)
            left = self._spilled
            while left:
                n = min(left, CHUNK_ROWS)
                yield np.fromfile(self._spill, dtype=np.float64, count=n * ncol).reshape(n, ncol)
                left -= n
        if self._buf:
            yield np.frombuffer(self._buf, dtype=np.float64).reshape(-1, ncol)

    def save(self, path) -> None:
        """Write ``path`` (``.npz`` added if missing, as ``numpy.savez`` does), one column at a time."""
        import zipfile

        import numpy as np

        path = str(path)
        if not path.endswith(".npz"):
            path += ".npz"
        n = len(self)
        tmp = path + ".tmp"  # renamed when whole: a full disk leaves no half archive (and no temporary file)
        try:
            with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
                for i, key in enumerate(self.keys):
                    with zf.open(f"{key}.npy", "w", force_zip64=True) as f:
                        header = {"descr": np.dtype(np.float64).str, "fortran_order": False, "shape": (n,)}
                        np.lib.format.write_array_header_1_0(f, header)
                        for chunk in self._chunks():
                            f.write(np.ascontiguousarray(chunk[:, i]).tobytes())
            os.replace(tmp, path)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise
