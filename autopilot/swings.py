"""The swing counter of the envelope's oscillation rule (``autopilot.envelope``, module docstring, "Tracking").

A swing is the deviation d = phi - y_r from the commanded response moving at least ``OSC_SWING_DEG`` back from the
extreme it reached since the last swing (a hysteresis: noise and ripple below it count nothing, and d's mean does
not matter).  It is regular when its size (|extreme - last extreme|) and its duration (steps from extreme to
extreme) are each within ``OSC_REGULAR_TOL`` of the previous swing's: a limit cycle repeats itself swing after
swing, the response to turbulence or to a command's step does not.  One definition, elementwise on numpy arrays
(the robustness study's batch; ``tools/experiment/study/kernel.c`` does the same operations in the same order) and
on floats (the autopilot's monitor).  No I/O.
"""

from __future__ import annotations

import math

OSC_SWING_DEG = 4.0  # a swing: d moving this far (peak to peak) back from its last extreme
OSC_REGULAR_TOL = 0.15  # a swing is regular when its size and duration are within 15 % of the previous swing's
OSC_SWINGS_MIN = 16  # regular swings in a window that make a sustained oscillation
OSC_SWING_RAD = math.radians(OSC_SWING_DEG)

# The state of the swing counter (swing_step), in this order: going up (1.0) or down (0.0), the current extreme
# and its step, the last swing's extreme and its step, the last swing's size and duration (steps).
_UP, _EXT, _KEXT, _LAST, _KLAST, _SIZE, _DUR = range(7)


def swing_start(d0) -> list:
    """The swing counter's state at the first sample ``d0`` (a float or an array): going up from d0, no swing yet."""
    if isinstance(d0, (int, float)):
        return [1.0, float(d0), 0.0, float(d0), 0.0, 0.0, 0.0]
    import numpy as np

    d0 = np.array(d0, dtype=float)
    z = np.zeros_like(d0)
    return [z + 1.0, d0.copy(), z.copy(), d0.copy(), z.copy(), z.copy(), z.copy()]


def swing_step(st: list, d, k):
    """One sample ``d`` = phi - y_r (rad) at step ``k`` through the swing counter ``st`` (:func:`swing_start`;
    updated in place): returns whether a regular swing ended here (module docstring, "Tracking").  A swing ends
    when d comes back ``OSC_SWING_DEG`` from the extreme reached since the last one; its size is |extreme - last
    extreme|, its duration the steps between them; regular: the last swing's size and duration both within
    ``OSC_REGULAR_TOL`` of their max with this one's.  A NaN d changes nothing.  Elementwise on numpy arrays (the
    study; kernel.c does the same operations in the same order) and on floats (the monitor)."""
    up = st[_UP] != 0.0
    if isinstance(up, bool):
        return _swing_step_float(st, d, k, up)
    ext = st[_EXT]
    grow = (d > ext) & up | (d < ext) & ~up
    back = (d <= ext - OSC_SWING_RAD) & up | (d >= ext + OSC_SWING_RAD) & ~up
    ext = _where(grow, d, ext)
    kext = _where(grow, k, st[_KEXT])
    size = abs(ext - st[_LAST])
    dur = kext - st[_KLAST]
    prev, pdur = st[_SIZE], st[_DUR]
    regular = back & (prev > 0.0)
    regular = regular & (abs(size - prev) <= OSC_REGULAR_TOL * _max(size, prev))
    regular = regular & (abs(dur - pdur) <= OSC_REGULAR_TOL * _max(dur, pdur))
    st[_SIZE] = _where(back, size, prev)
    st[_DUR] = _where(back, dur, pdur)
    st[_LAST] = _where(back, ext, st[_LAST])
    st[_KLAST] = _where(back, kext, st[_KLAST])
    st[_UP] = _where(back, 1.0 - st[_UP], st[_UP])
    st[_EXT] = _where(back, d, ext)
    st[_KEXT] = _where(back, k, kext)
    return regular


def _swing_step_float(st: list, d: float, k: float, up: bool) -> bool:
    """:func:`swing_step` on floats (the autopilot's monitor, once per control step): the same operations in the same
    order, without the elementwise helpers' type tests (``tests/autopilot/test_swings.py`` holds the two forms to the
    same states, bit for bit)."""
    ext = st[_EXT]
    grow = d > ext if up else d < ext
    back = (d <= ext - OSC_SWING_RAD) if up else (d >= ext + OSC_SWING_RAD)
    if grow:
        ext = d
        kext = k
    else:
        kext = st[_KEXT]
    size = abs(ext - st[_LAST])
    dur = kext - st[_KLAST]
    prev, pdur = st[_SIZE], st[_DUR]
    regular = (
        back
        and prev > 0.0
        and abs(size - prev) <= OSC_REGULAR_TOL * (size if size >= prev else prev)
        and abs(dur - pdur) <= OSC_REGULAR_TOL * (dur if dur >= pdur else pdur)
    )
    if back:
        st[_SIZE] = size
        st[_DUR] = dur
        st[_LAST] = ext
        st[_KLAST] = kext
        st[_UP] = 1.0 - st[_UP]
        st[_EXT] = d
        st[_KEXT] = k
    else:
        st[_EXT] = ext
        st[_KEXT] = kext
    return regular


def _where(c, a, b):
    if isinstance(c, bool):
        return a if c else b
    import numpy as np

    return np.where(c, a, b)


def _max(a, b):
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return a if a >= b else b
    import numpy as np

    return np.maximum(a, b)
