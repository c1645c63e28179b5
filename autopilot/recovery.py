"""Recovery after a fault (docs/design.md, section 4, "Three outcomes"): how long the roll took to come back to the
commanded response after a fault's onset, or that it did not.  Pure functions, no I/O.

The deviation d = roll - y_r from the commanded response is measured as its RMS over consecutive 1 s blocks from the
onset, so a step's designed transient (which decays within its block) is not a loss of tracking, while a limit
cycle or a drift is.  The band is the same flight's own tracking before the fault, doubled (``RECOVERY_MARGIN``):
the reference square wave's steps from -A to +A are twice its first step from 0, and RMS is linear in a step's size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

RECOVERY_BLOCK_S = 1.0
RECOVERY_MARGIN = 2.0  # the band: this x the worst block RMS deviation before the onset ...
RECOVERY_MIN_BAND_DEG = 1.0  # ... and at least this


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


def _block_rms(t, d, start: float, stop: float, width: float) -> tuple[list[float], list[float]]:
    """RMS of ``d`` over the consecutive blocks [start + k width, start + (k + 1) width) that end by ``stop``
    (those with samples): (the blocks' starts, their RMS)."""
    import numpy as np

    starts, values = [], []
    k = 0
    while start + (k + 1) * width <= stop + 1e-9:
        a, b = start + k * width, start + (k + 1) * width
        i, j = np.searchsorted(t, [a - 1e-9, b - 1e-9])
        if j > i:
            starts.append(a)
            values.append(float(np.sqrt(np.mean(d[i:j] ** 2))))
        k += 1
    return starts, values


def recovery(t, roll, command, onset_s: float, band_rad: float | None = None, *, until_s: float | None = None):
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
    ``RECOVERY_MIN_BAND_DEG`` (1 deg); with no whole fault-free block before the onset, not measured."""
    import numpy as np

    t = np.asarray(t, dtype=float)
    d = np.asarray(roll, dtype=float) - np.asarray(command, dtype=float)
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
        _, pre = _block_rms(t, d, first, onset_s, w)
        worst_pre = max(pre) if pre else math.nan
        if not math.isfinite(worst_pre):
            return Recovery(
                onset_s, None, None, None, None, stop, "not measured: the roll before the onset is not finite"
            )
        band_rad = max(RECOVERY_MARGIN * worst_pre, math.radians(RECOVERY_MIN_BAND_DEG))
    band_deg = math.degrees(band_rad)
    starts, rms = _block_rms(t, d, onset_s, stop, w)
    if not rms:
        return Recovery(onset_s, band_deg, None, None, None, stop, "not measured: no whole second after the onset")
    worst = max(rms) if all(math.isfinite(v) for v in rms) else math.inf
    outside = [i for i, v in enumerate(rms) if not v <= band_rad]
    if outside and outside[-1] == len(rms) - 1:
        why = f"not recovered: the roll's deviation still {math.degrees(rms[-1]):.1f} deg RMS at {stop:.1f} s"
        return Recovery(onset_s, band_deg, False, None, math.degrees(worst), stop, why + f" (band {band_deg:.1f} deg)")
    k = outside[-1] + 1 if outside else 0
    time_s = starts[k] - onset_s
    why = f"recovered {time_s:.1f} s after the onset (1 s RMS deviation back within {band_deg:.1f} deg and stayed)"
    return Recovery(onset_s, band_deg, True, time_s, math.degrees(worst), stop, why)
