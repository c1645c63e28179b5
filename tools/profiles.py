"""Roll command profiles, as functions of time in seconds returning radians.  No I/O except ``from_csv``."""

from __future__ import annotations

import math


def square(t: float, amplitude: float, period: float) -> float:
    """Square wave starting at +amplitude at t = 0, switching every half period (DESIGN.md section 4)."""
    half = 0.5 * period
    # The 1e-9 guard makes switch instants computed as k / rate land on the new level.
    return amplitude if int(math.floor(t / half + 1e-9)) % 2 == 0 else -amplitude


def step(t: float, amplitude: float, t_step: float = 1.0) -> float:
    """0 before ``t_step``, ``amplitude`` from ``t_step`` on."""
    return amplitude if t >= t_step - 1e-9 else 0.0


def sine(t: float, amplitude: float, period: float) -> float:
    """amplitude * sin(2 pi t / period)."""
    return amplitude * math.sin(2.0 * math.pi * t / period)


def from_csv(path: str) -> tuple[list[float], list[float]]:
    """Read a profile from a CSV file of ``time_s, roll_deg`` rows (header and ``#`` lines skipped).

    Returns (times in s, rolls in rad), times strictly increasing.  Raises ValueError with the line
    number on a malformed, non-finite or out-of-order row.
    """
    times: list[float] = []
    rolls: list[float] = []
    with open(path, newline="") as f:
        for lineno, line in enumerate(f, 1):
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            parts = [p.strip() for p in text.replace(";", ",").split(",")]
            try:
                t, r = float(parts[0]), float(parts[1])
            except (ValueError, IndexError):
                if not times and lineno == 1:
                    continue  # a header line
                raise ValueError(f"{path}:{lineno}: expected 'time_s, roll_deg', got {text!r}") from None
            if not (math.isfinite(t) and math.isfinite(r)):
                raise ValueError(f"{path}:{lineno}: values must be finite, got {text!r}")
            if times and t <= times[-1]:
                raise ValueError(f"{path}:{lineno}: times must increase, got {t} after {times[-1]}")
            times.append(t)
            rolls.append(math.radians(r))
    if not times:
        raise ValueError(f"{path}: no data rows")
    return times, rolls


def hold(t: float, times: list[float], values: list[float]) -> float:
    """Zero-order hold of a (times, values) table: the value of the last row at or before t (first row before)."""
    from bisect import bisect_right

    i = bisect_right(times, t + 1e-9) - 1
    return values[max(i, 0)]
