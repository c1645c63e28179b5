"""A flight's per-step series read back: ``DIR/autopilot_series.npz`` and ``DIR/sitl_series.npz`` merged into
``tools.experiment.scenario.SERIES``-style arrays (``load_series``), optionally every k-th step only (a long flight's
picture in
bounded memory).  numpy only: the picture's helper process (``tools.view.flight_picture``) reads them without importing
the launcher's modules."""

from __future__ import annotations

from pathlib import Path


def _npz_columns(path: Path, keys=None, stride: int = 1, start: int = 0) -> dict:
    """Columns of an .npz, every ``stride``-th value from index ``start``, read a chunk at a time (the memory
    held is the decimated columns, whatever the file's length)."""
    import zipfile

    import numpy as np

    out = {}
    with zipfile.ZipFile(path) as zf:
        for member in zf.namelist():
            key = member[:-4] if member.endswith(".npy") else member
            if keys is not None and key not in keys:
                continue
            with zf.open(member) as f:
                version = np.lib.format.read_magic(f)
                read_header = (
                    np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
                )
                shape, _fortran, dtype = read_header(f)
                n = shape[0] if shape else 1
                kept, i0 = [], 0
                while i0 < n:
                    m = min(1 << 16, n - i0)
                    a = np.frombuffer(f.read(m * dtype.itemsize), dtype=dtype, count=m)
                    j = start - i0 if i0 <= start else (start - i0) % stride  # first index to keep here
                    if j < m:
                        kept.append(a[j::stride].copy())
                    i0 += m
                out[key] = np.concatenate(kept) if kept else np.empty(0, dtype)
    return out


def load_series(out_dir, max_points: int | None = None) -> dict:
    """Merge DIR/autopilot_series.npz and DIR/sitl_series.npz into tools.experiment.scenario.SERIES-style arrays;
    ``max_points``: every k-th step only, at most that many (a plot of a long flight in bounded memory)."""
    import zipfile

    import numpy as np

    out_dir = Path(out_dir)
    try:
        with zipfile.ZipFile(out_dir / "autopilot_series.npz") as zf, zf.open("t.npy") as f:
            version = np.lib.format.read_magic(f)
            read_header = (
                np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            )
            steps = read_header(f)[0][0]
        series = _npz_columns(out_dir / "autopilot_series.npz", stride=(stride := _stride(steps, max_points)))
    except (OSError, KeyError, zipfile.BadZipFile):
        return {}
    if series.get("t") is not None and len(series["t"]):
        series["t"] = series["t"] - series["t"][0]
    try:
        # SITL rows are the state after frame k, i.e. at t_{k+1}; the state at t_0 is the initial zero.
        s = _npz_columns(out_dir / "sitl_series.npz", ("v", "delta_r"), stride, start=stride - 1)
        n = len(series.get("t", ()))
        for key in ("v", "delta_r"):
            col = np.concatenate([[0.0], s[key]])[:n]
            if len(col) == n:
                series[key] = col
    except (OSError, KeyError, zipfile.BadZipFile):
        pass
    return series


def _stride(steps: int, max_points: int | None) -> int:
    return 1 if not max_points or steps <= max_points else -(-steps // max_points)
