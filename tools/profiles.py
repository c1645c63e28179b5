"""Roll command profiles, as functions of time in seconds returning radians.  No I/O except ``from_csv``."""

from __future__ import annotations

import math


def square(t: float, amplitude: float, period: float) -> float:
    """Square wave starting at +amplitude at t = 0, switching every half period (DESIGN.md section 4)."""
    half = 0.5 * period
    # The 1e-9 guard makes switch instants computed as k / rate land on the new level.
    return amplitude if int(math.floor(t / half + 1e-9)) % 2 == 0 else -amplitude
