"""Recovery after a fault (docs/design.md, section 4, "Three outcomes"): how long the roll took to come back to the
commanded response after a fault's onset, or that it did not.  Pure functions, no I/O.

The deviation d = roll - y_r from the commanded response is measured as its RMS over consecutive 1 s blocks from the
onset, so a limit cycle or a drift is a loss of tracking.  Given the raw command u_m as well (the launcher gives it),
only settled blocks are judged: those that start at least ``RECOVERY_SETTLE_S`` after the command last stepped,
so a step's designed transient (the roll lags y_m,ol by design on CL-SAC, 5-8 deg RMS in a step's first second on
the paper's square wave) is neither a loss nor what sets the band.  The band is the same flight's own settled
tracking before the fault, doubled (``RECOVERY_MARGIN``), and at least ``RECOVERY_MIN_BAND_DEG``.  A command that
never holds still (a sine) has every block judged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

RECOVERY_BLOCK_S = 1.0
RECOVERY_MARGIN = 2.0  # the band: this x the worst block RMS deviation before the onset ...
RECOVERY_MIN_BAND_DEG = 1.0  # ... and at least this
# A block is settled when the command has not stepped for this long before it: the paper's commanded response
# (y_m,ol, a 2nd-order model with a 0.5 s rise) and CL-SAC's designed lag on it have settled to 1 % within 2 s.
RECOVERY_SETTLE_S = 2.0


@dataclass(frozen=True)
class Recovery:
    """How the roll came back after a fault's onset (:func:`recovery`)."""

    onset_s: float
    band_deg: float | None  # the band on the 1 s blocks' RMS deviation; None: none could be set
    recovered: bool | None  # None: not measured (``reason`` says why)
    time_s: float | None  # from the onset to the start of the block from which every block stayed in the band
    worst_deg: float | None  # the worst block RMS deviation after the onset
    until_s: float  # the end of what was judged (the series' end or the next fault's onset)
    reason: str

    def to_dict(self) -> dict:
        """``summary.json``'s ``recovery`` entry (a non-finite number as null)."""
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in self.__dict__.items()}


def _block_rms(t, d, start: float, stop: float, width: float, steps=None) -> tuple[list[float], list[float]]:
    """RMS of ``d`` over the consecutive blocks [start + k width, start + (k + 1) width) that end by ``stop``
    (those with samples, and, given the command's step times ``steps``, settled: no step in
    [a - RECOVERY_SETTLE_S, b)): (the blocks' starts, their RMS)."""
    import numpy as np

    starts, values = [], []
    k = 0
    while start + (k + 1) * width <= stop + 1e-9:
        a, b = start + k * width, start + (k + 1) * width
        i, j = np.searchsorted(t, [a - 1e-9, b - 1e-9])
        unsettled = steps is not None and bool(np.any((steps > a - RECOVERY_SETTLE_S + 1e-9) & (steps < b - 1e-9)))
        if j > i and not unsettled:
            starts.append(a)
            values.append(float(np.sqrt(np.mean(d[i:j] ** 2))))
        k += 1
    return starts, values


def _steps(t, raw):
    """The times at which the raw command steps (the flight's start counts as one: the roll starts level whatever
    the first command), or None when it never holds still (a moving command: more changes than half its samples),
    or when no raw command is given."""
    import numpy as np

    if raw is None:
        return None
    raw = np.asarray(raw, dtype=float)
    moved = np.flatnonzero(np.abs(np.diff(raw)) > 1e-9) + 1
    if len(moved) > len(raw) // 2:
        return None
    return np.asarray(t, dtype=float)[np.concatenate(([0], moved))]


def recovery(
    t,
    roll,
    command,
    onset_s: float,
    band_rad: float | None = None,
    *,
    until_s: float | None = None,
    raw_command=None,
):
    """The recovery after a fault that began at ``onset_s``, from a flight's sim times (s), roll and the commanded
    response it should follow (rad; the launcher gives the law's y_m,ol: the raw command's steps would read as
    losses at every step).

    The deviation d = roll - command is measured as its RMS over consecutive ``RECOVERY_BLOCK_S`` (1 s) blocks
    from the onset to ``until_s`` (default: the end of the series; the launcher gives the next fault's onset), so a
    step's transient, which decays within its block, is not a loss while a limit cycle or a drift is.  Recovered at
    ``time_s`` after the onset: the start of the first block from which every later block has RMS <= the band (0.0:
    never out of it); "not recovered" when the last block is outside.  The band: ``band_rad``, else
    ``RECOVERY_MARGIN`` (2) times the worst block RMS of the fault-free flight before the onset (the same
    flight's own tracking: its square wave's later steps are up to twice its first), at least
    ``RECOVERY_MIN_BAND_DEG`` (1 deg); with no whole fault-free block before the onset, not measured.
    ``raw_command``: the raw command u_m (rad) on the same samples: only settled blocks are judged (module doc)."""
    import numpy as np

    t = np.asarray(t, dtype=float)
    d = np.asarray(roll, dtype=float) - np.asarray(command, dtype=float)
    steps = _steps(t, raw_command)
    end = float(t[-1]) + (float(t[-1] - t[-2]) if len(t) > 1 else 0.0) if len(t) else onset_s
    stop = end if until_s is None else min(until_s, end)
    w = RECOVERY_BLOCK_S
    if band_rad is None:
        before = np.flatnonzero(t < onset_s - 1e-9)
        if not len(before) or onset_s - float(t[0]) < w - 1e-9:
            return Recovery(
                onset_s, None, None, None, None, stop, "not measured: no fault-free second before the onset"
            )
        first = onset_s - math.floor((onset_s - float(t[0])) / w + 1e-9) * w
        _, pre = _block_rms(t, d, first, onset_s, w, steps)
        if not pre:
            return Recovery(onset_s, None, None, None, None, stop, "not measured: no settled second before the onset")
        worst_pre = max(pre) if pre else math.nan
        if not math.isfinite(worst_pre):
            return Recovery(
                onset_s, None, None, None, None, stop, "not measured: the roll before the onset is not finite"
            )
        band_rad = max(RECOVERY_MARGIN * worst_pre, math.radians(RECOVERY_MIN_BAND_DEG))
    band_deg = math.degrees(band_rad)
    starts, rms = _block_rms(t, d, onset_s, stop, w, steps)
    if not rms:
        why = "not measured: no whole " + ("settled " if steps is not None else "") + "second after the onset"
        return Recovery(onset_s, band_deg, None, None, None, stop, why)
    worst = max(rms) if all(math.isfinite(v) for v in rms) else math.inf
    outside = [i for i, v in enumerate(rms) if not v <= band_rad]
    if outside and outside[-1] == len(rms) - 1:
        why = f"not recovered: the roll's deviation still {math.degrees(rms[-1]):.1f} deg RMS at {stop:.1f} s"
        return Recovery(onset_s, band_deg, False, None, math.degrees(worst), stop, why + f" (band {band_deg:.1f} deg)")
    k = outside[-1] + 1 if outside else 0
    time_s = starts[k] - onset_s
    what = "settled 1 s" if steps is not None else "1 s"
    why = f"recovered {time_s:.1f} s after the onset ({what} RMS deviation back within {band_deg:.1f} deg and stayed)"
    return Recovery(onset_s, band_deg, True, time_s, math.degrees(worst), stop, why)
