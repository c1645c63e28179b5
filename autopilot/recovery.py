"""Recovery after a fault (docs/spec.md, section 5, "Three outcomes"): how long the roll took to come back to the
commanded response after a fault's onset and follow it, or that it did not.  Pure functions, no I/O.

**The deviation** d = roll - y_r from the commanded response (the law's reference model y_m,ol driven by the
command) is measured as its RMS over the trailing ``RECOVERY_WINDOW_S`` (1 s) at every control step, so a limit
cycle or a drift is a loss of tracking while noise within a second is averaged.  Given the raw command u_m (the
launcher and the damage study give it), only **settled** steps are judged: those whose whole window starts at
least ``RECOVERY_SETTLE_S`` after the command last stepped, so a step's designed transient (CL-SAC lags y_m,ol by
design, 5-8 deg RMS in a step's first second on the paper's square wave) is not a loss.  A command that never holds
still (a sine) has every step judged.

**One band for every law**, from the command alone, never from the flight: ``RECOVERY_BAND_FRAC`` (25 %) of the
command's amplitude (half its range over the flight), at least ``RECOVERY_MIN_BAND_DEG`` (3 deg): 3 deg on the
paper's +-10 deg square wave, for CL-SAC, SAC and the PID alike (``band_deg`` in ``summary.json``).  3 deg is about
ten times the settled deviation of the fault-free flights in still air (0.3 deg RMS on the KH2013A, CL-SAC) and
above light turbulence's on the c172x (2.2 deg); heavier turbulence moves the roll more than the band, and then no
flight, fault or not, is called recovered: the band does not widen for it (the numbers are beside it).

**Recovered** at ``time_s`` after the onset: the time the RMS re-entered the band for the last time, interpolated
linearly between the last judged step outside and the first inside when they are consecutive steps (else the first
judged step inside), with every judged step after it inside; *and* the roll shown to follow the command after it:
over the judged steps inside the band from then on, y_r spans at least ``RECOVERY_FOLLOW_BANDS`` (2) bands (a
jammed surface that leaves the roll where a command happens to be is not a recovery).  "Never out" reads 0.0 s.
A NaN or infinite deviation anywhere in a window puts that window outside the band.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

RECOVERY_WINDOW_S = 1.0  # the trailing window of the RMS deviation
RECOVERY_BAND_FRAC = 0.25  # the band: this x the command's amplitude ...
RECOVERY_MIN_BAND_DEG = 3.0  # ... and at least this
RECOVERY_FOLLOW_BANDS = 2.0  # after the re-entry y_r spans this many bands over the judged steps: it followed
# A step is settled when the command has not stepped for this long before its window: the paper's commanded
# response (y_m,ol, a 2nd-order model with a 0.5 s rise) and CL-SAC's designed lag on it have settled to 1 % within 2 s.
RECOVERY_SETTLE_S = 2.0


@dataclass(frozen=True)
class Recovery:
    """How the roll came back after a fault's onset (:func:`recovery`)."""

    onset_s: float
    band_deg: float | None  # the band on the 1 s RMS deviation; None: none could be set
    recovered: bool | None  # None: not measured (``reason`` says why)
    time_s: float | None  # from the onset to the last re-entry into the band (interpolated)
    worst_deg: float | None  # the worst judged 1 s RMS deviation after the onset
    until_s: float  # the end of what was judged (the series' end or the next fault's onset)
    reason: str

    def to_dict(self) -> dict:
        """``summary.json``'s ``recovery`` entry (a non-finite number as null)."""
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in self.__dict__.items()}


def command_band_rad(command) -> float:
    """The band (rad) for a command series (rad): ``RECOVERY_BAND_FRAC`` of half its range, at least
    ``RECOVERY_MIN_BAND_DEG``; non-finite values are ignored."""
    import numpy as np

    c = np.asarray(command, dtype=float)
    c = c[np.isfinite(c)]
    amp = 0.5 * float(np.max(c) - np.min(c)) if c.size else 0.0
    return max(RECOVERY_BAND_FRAC * amp, math.radians(RECOVERY_MIN_BAND_DEG))


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


def moving_rms(t, d, window_s: float = RECOVERY_WINDOW_S):
    """(rms, starts): per sample k, the RMS of ``d`` over the samples in (t_k - window_s, t_k], and that window's
    first time t_k - window_s; NaN for the samples before one whole window, and where any value in the window is
    not finite."""
    import numpy as np

    t = np.asarray(t, dtype=float)
    d = np.asarray(d, dtype=float)
    bad = ~np.isfinite(d)
    sq = np.where(bad, 0.0, d * d)
    c = np.concatenate(([0.0], np.cumsum(sq)))
    cb = np.concatenate(([0], np.cumsum(bad)))
    first = np.searchsorted(t, t - window_s + 1e-9)  # the window's first sample
    n = np.arange(1, len(t) + 1) - first
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(np.maximum(c[1:] - c[first], 0.0) / n)
    whole = t - window_s >= t[0] - 1e-9 if len(t) else np.zeros(0, bool)
    rms = np.where(whole & (cb[1:] - cb[first] == 0), rms, np.nan)
    return rms, t - window_s


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
    response it should follow (rad; the launcher gives the law's y_m,ol), judged up to ``until_s`` (default: the
    end of the series; the launcher gives the next fault's onset).  ``band_rad``: the band, else the command's
    (:func:`command_band_rad` of ``raw_command``, or of ``command`` without it).  ``raw_command``: the raw command
    u_m (rad) on the same samples: only settled steps are judged (module docstring)."""
    import numpy as np

    t = np.asarray(t, dtype=float)
    ref = np.asarray(command, dtype=float)
    d = np.asarray(roll, dtype=float) - ref
    end = float(t[-1]) + (float(t[-1] - t[-2]) if len(t) > 1 else 0.0) if len(t) else onset_s
    stop = end if until_s is None else min(until_s, end)
    if band_rad is None:
        band_rad = command_band_rad(ref if raw_command is None else raw_command)
    band_deg = math.degrees(band_rad)
    if not len(t):
        return Recovery(onset_s, band_deg, None, None, None, stop, "not measured: no series")
    steps = _steps(t, raw_command)
    rms, starts = moving_rms(t, d)
    judged = (starts >= onset_s - 1e-9) & (t < stop - 1e-9)
    if steps is not None:
        last = steps[np.maximum(np.searchsorted(steps, starts + 1e-9, side="right") - 1, 0)]  # the last step <= start
        later = np.searchsorted(steps, t + 1e-9, side="right") > np.searchsorted(steps, starts + 1e-9, side="right")
        judged &= (starts - last >= RECOVERY_SETTLE_S - 1e-9) & ~later  # settled, and no step inside the window
    idx = np.flatnonzero(judged)
    if not len(idx):
        why = "not measured: no whole " + ("settled " if steps is not None else "") + "second after the onset"
        return Recovery(onset_s, band_deg, None, None, None, stop, why)
    r = rms[idx]
    inside = r <= band_rad  # NaN: outside
    worst = float(np.max(r)) if np.all(np.isfinite(r)) else math.inf
    if not inside[-1]:
        now = "not finite" if not math.isfinite(r[-1]) else f"{math.degrees(r[-1]):.1f} deg RMS"
        why = f"still outside the band at {float(t[idx[-1]]):.2f} s: the roll's deviation {now}"
        why += f" (band {band_deg:.1f} deg)"
        return Recovery(onset_s, band_deg, False, None, math.degrees(worst), stop, why)
    out = np.flatnonzero(~inside)
    if not len(out):
        k, t_in = 0, onset_s
    else:
        k = int(out[-1]) + 1
        a, b = idx[k - 1], idx[k]
        t_in = float(t[b])
        if b == a + 1 and math.isfinite(r[k - 1]):  # consecutive steps: where the RMS crossed the band
            t_in = float(t[a] + (t[b] - t[a]) * (r[k - 1] - band_rad) / (r[k - 1] - r[k]))
    span = float(np.ptp(ref[idx[k:]])) if len(idx[k:]) else 0.0
    if span < RECOVERY_FOLLOW_BANDS * band_rad:
        why = (
            f"back within the band from {t_in:.2f} s, but the commanded response then moved {math.degrees(span):.1f} "
            f"deg over the judged steps (less than {RECOVERY_FOLLOW_BANDS:g} bands): the roll is not shown following "
            f"the command (band {band_deg:.1f} deg)"
        )
        return Recovery(onset_s, band_deg, False, None, math.degrees(worst), stop, why)
    time_s = t_in - onset_s
    what = "settled 1 s" if steps is not None else "1 s"
    why = (
        f"recovered {time_s:.2f} s after the onset ({what} RMS deviation back within {band_deg:.1f} deg, stayed, and "
        f"followed the command)"
    )
    return Recovery(onset_s, band_deg, True, time_s, math.degrees(worst), stop, why)
