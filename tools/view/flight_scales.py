"""The numbers behind what ``flight.png`` (``tools.view.flight_png``) shows where a plain autoscale would mislead:

* ``wrap_runs``: a wrapped angle (the measured roll, ATTITUDE's phi in (-180, 180] deg) is not joined across a wrap,
  where a joined line would be a vertical stroke across the whole panel;
* ``robust_range``: a panel whose values have a few spikes far from the rest (an adaptive gain K_e ~ 330 for a few
  steps among values near 0.1) is scaled to the bulk of its values (percentiles), the spikes clipped at the edge
  and marked, instead of flattening everything else to one line;
* ``label_groups``: the labels of marks that fall within a label's height of each other on the time axis (eight
  faults starting together) are written once, merged, instead of on top of each other.

and the axes' ticks (``nice_ticks``, ``tick_labels``) and plain ranges (``data_range``), as matplotlib chooses them.
Plain numpy, no drawing: ``tools.view.plot_engine`` draws what these say."""

from __future__ import annotations

import math

import numpy as np

# A panel is scaled to the values between these percentiles (of all its finite values) when the whole range is more
# than SPIKE_RATIO times as wide: what lies beyond is less than 2 % of the samples, drawn at the edge and marked.
PERCENTILES = (1.0, 99.0)
SPIKE_RATIO = 3.0
ROBUST_PAD = 0.15  # the bulk's range, widened by this fraction of it on each side (room for the marks)


def wrap_runs(x: np.ndarray, y: np.ndarray, jump: float | None) -> list[tuple[np.ndarray, np.ndarray]]:
    """(x, y) cut where two consecutive values differ by more than ``jump`` (a wrapped angle's half period: 180 deg;
    a real roll does not move half a turn in one sample); the whole line for ``jump`` None."""
    if jump is None or len(y) < 2:
        return [(x, y)]
    cuts = np.flatnonzero(np.abs(np.diff(y)) > jump) + 1
    if not len(cuts):
        return [(x, y)]
    edges = np.concatenate(([0], cuts, [len(y)]))
    return [(x[a:b], y[a:b]) for a, b in zip(edges[:-1], edges[1:])]


def robust_range(values: list[np.ndarray]) -> tuple[float, float] | None:
    """The y range of a panel whose few far values would flatten the rest, or None when the plain range is fine.

    The bulk is the values between the PERCENTILES (all series together); when the full range of the finite values
    is more than SPIKE_RATIO times the bulk's, the range is the bulk's widened by ROBUST_PAD of it on each side (a
    bulk of one value: +-5 % of it, +-0.05 at zero, as ``data_range``)."""
    finite = [v[np.isfinite(v)] for v in values if v is not None]
    finite = np.concatenate([v for v in finite if v.size]) if any(v.size for v in finite) else np.empty(0)
    if finite.size < 2:
        return None
    finite = np.clip(finite, -1e300, 1e300)
    lo, hi = (float(v) for v in np.percentile(finite, PERCENTILES))
    full = float(finite.max()) - float(finite.min())
    bulk = hi - lo
    if bulk <= 1e-12 * max(abs(lo), abs(hi), 1e-300):
        half = 0.05 * abs(lo) if abs(lo) > 1e-290 else 0.05
        lo, hi, bulk = lo - half, hi + half, 2 * half
    if not full > SPIKE_RATIO * bulk:
        return None
    return lo - ROBUST_PAD * bulk, hi + ROBUST_PAD * bulk


def clipped_marks(t: np.ndarray, y: np.ndarray, lim: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The times of the samples of ``y`` above the range ``lim`` and of those below it (finite or infinite)."""
    above = ~np.isnan(y) & (y > lim[1])
    below = ~np.isnan(y) & (y < lim[0])
    return t[above], t[below]


def label_groups(columns: list[float], min_gap: float) -> list[list[int]]:
    """The indexes of marks (at picture ``columns``, in order) whose labels would overlap, in groups: a mark joins the
    group before it when its column is less than ``min_gap`` (a label's height, px) right of the group's last."""
    groups: list[list[int]] = []
    last = None
    for i, col in enumerate(columns):
        if groups and last is not None and col - last < min_gap:
            groups[-1].append(i)
        else:
            groups.append([i])
        last = col
    return groups


def merged_label(texts: list[str], width, room: float) -> str:
    """One label for a group of marks: their distinct texts in order, joined by ", "; when that is wider than
    ``room`` (``width``: a text's drawn width, px), the first text and "(+N more)"."""
    distinct = list(dict.fromkeys(texts))
    joined = ", ".join(distinct)
    if len(distinct) == 1 or width(joined) <= room:
        return joined
    return f"{distinct[0]} (+{len(distinct) - 1} more)"


def nice_ticks(lo: float, hi: float, max_bins: int) -> np.ndarray:
    """Tick values in [lo, hi]: multiples of a step of 1, 2, 2.5 or 5 x 10^k, the smallest giving at most
    ``max_bins`` intervals, and at least two ticks (how matplotlib's default locator chooses them)."""
    raw = (hi - lo) / max_bins
    if not (math.isfinite(raw) and raw > 0.0):  # a range too narrow (or wide) for a float to divide: its ends
        return np.array([lo] if lo == hi else [lo, hi])
    scale = 10.0 ** math.floor(math.log10(raw))
    steps = [m * scale for m in (0.5, 1, 2, 2.5, 5, 10)]
    i = next(i for i, s in enumerate(steps) if s >= raw * (1 - 1e-9))
    for step in steps[i::-1]:  # the first that fits, or smaller ones until two ticks fall in the range
        ticks = np.arange(math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9) + 1) * step
        if len(ticks) >= 2:
            break
    return ticks


def tick_labels(ticks: np.ndarray) -> tuple[list[str], str]:
    """The ticks' labels, all with the decimals the step needs, and the multiplier written above the axis ("1e−5";
    "" if none).  As matplotlib does for values below 1e-4 or from 1e6 on, but from 1e-3 and 1e5 on: labels longer
    than six characters would push the axis label out of the picture."""
    if not len(ticks):
        return [], ""
    big = float(np.max(np.abs(ticks)))
    exp = math.floor(math.log10(big)) if big > 0 else 0
    exp = exp if exp <= -4 or exp >= 5 else 0
    values = ticks / 10.0**exp
    step = abs(values[1] - values[0]) if len(values) > 1 else 1.0
    k = math.floor(math.log10(step) + 1e-9)
    decimals = max(0, -k + (1 if round(step / 10.0**k, 6) == 2.5 else 0))
    labels = []
    for v in values:
        s = f"{v:.{decimals}f}"
        s = s.lstrip("-") if float(s) == 0 else s  # no "-0.0"
        labels.append(s.replace("-", "\u2212"))  # a real minus sign, as matplotlib writes
    return labels, (f"1e{exp}".replace("-", "\u2212") if exp else "")


def data_range(values: list[np.ndarray]) -> tuple[float, float] | None:
    """The range of the finite values, widened by 5 % on each side (matplotlib's margins); a single value gets
    +-5 % of itself (+-0.05 if zero) first.  None without a finite value."""
    finite = [v[np.isfinite(v)] for v in values]
    finite = [np.clip(v, -1e300, 1e300) for v in finite if v.size]  # huge values: a range that does not overflow
    if not finite:
        return None
    lo, hi = float(min(v.min() for v in finite)), float(max(v.max() for v in finite))
    if hi - lo <= 1e-12 * max(abs(lo), abs(hi), 1e-300):
        tiny = max(abs(lo), abs(hi)) < 1e-290  # zero, or so near it that 5 % of it is no wider (denormals)
        lo, hi = (-0.05, 0.05) if tiny else (lo - 0.05 * abs(lo), hi + 0.05 * abs(hi))
    pad = 0.05 * (hi - lo)
    return lo - pad, hi + pad
