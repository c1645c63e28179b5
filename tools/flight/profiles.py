"""Roll command profiles, as functions of time in seconds returning radians.  No I/O except ``from_csv``.

``Profile`` is one profile as a value (kind and parameters, SI inside) with ``value(t)`` and its discontinuities;
the plain functions below are what it evaluates.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass

from autopilot.shared.cli import MAX_SIM_S, SIDESLIP_ENVELOPE_DEG

KINDS = ("square", "step", "sine", "csv")
SIDE_RANGE = f"must be in [-{SIDESLIP_ENVELOPE_DEG:g}, {SIDESLIP_ENVELOPE_DEG:g}] deg (the sideslip envelope)"


def square(t: float, amplitude: float, period: float) -> float:
    """Square wave starting at +amplitude at t = 0, switching every half period."""
    half = 0.5 * period
    # The 1e-9 guard makes switch instants computed as k / rate land on the new level.
    return amplitude if int(math.floor(t / half + 1e-9)) % 2 == 0 else -amplitude


def step(t: float, amplitude: float, t_step: float = 1.0) -> float:
    """0 before ``t_step``, ``amplitude`` from ``t_step`` on."""
    return amplitude if t >= t_step - 1e-9 else 0.0


def sine(t: float, amplitude: float, period: float) -> float:
    """amplitude * sin(2 pi t / period)."""
    return amplitude * math.sin(2.0 * math.pi * t / period)


def read_csv(path: str) -> tuple[list[float], list[float], list[float] | None]:
    """Read a profile from a CSV file of ``time_s, roll_deg[, sideslip_deg]`` rows (header and ``#`` lines skipped;
    the third column, a square MIMO plant's sideslip command, is optional: 0 where a row has none).

    Returns (times in s, rolls in rad, sideslips in rad or None without a third column), times strictly
    increasing.  Raises ValueError with the line
    number on a malformed, non-finite, out-of-range or out-of-order row: times are bounded like durations, in
    [0, MAX_SIM_S] s (a day of sim time), rolls like ``--amplitude``, in [-180, 180] deg.
    """
    times: list[float] = []
    rolls: list[float] = []
    sides: list[float] = []
    third = False
    try:
        with open(path, "rb") as f:
            data = f.read().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not a text file (byte {exc.start} is not UTF-8): rows 'time_s, roll_deg'") from None
    if "\0" in data:
        raise ValueError(f"{path}: not a text file (a NUL byte): rows 'time_s, roll_deg'")
    for lineno, line in enumerate(data.splitlines(), 1):
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
        if not 0.0 <= t <= MAX_SIM_S:
            raise ValueError(f"{path}:{lineno}: time must be in [0, {MAX_SIM_S:g}] s, got {parts[0]!r}")
        if not -180.0 <= r <= 180.0:
            raise ValueError(f"{path}:{lineno}: roll must be in [-180, 180] deg, got {parts[1]!r}")
        if times and t <= times[-1]:
            raise ValueError(f"{path}:{lineno}: times must increase, got {t} after {times[-1]}")
        b = 0.0
        if len(parts) > 2 and parts[2]:
            try:
                b = float(parts[2])
            except ValueError:
                raise ValueError(f"{path}:{lineno}: sideslip_deg must be a number, got {parts[2]!r}") from None
            if not (math.isfinite(b) and abs(b) <= SIDESLIP_ENVELOPE_DEG):
                raise ValueError(f"{path}:{lineno}: sideslip {SIDE_RANGE}, got {parts[2]!r}")
            third = True
        times.append(t)
        rolls.append(math.radians(r))
        sides.append(math.radians(b))
    if not times:
        raise ValueError(f"{path}: no data rows")
    return times, rolls, (sides if third else None)


def from_csv(path: str) -> tuple[list[float], list[float]]:
    """``read_csv``'s (times in s, rolls in rad): a ``time_s, roll_deg`` profile."""
    times, rolls, _sides = read_csv(path)
    return times, rolls


def hold(t: float, times: list[float], values: list[float]) -> float:
    """Zero-order hold of a (times, values) table: the value of the last row at or before t (first row before)."""
    i = bisect_right(times, t + 1e-9) - 1
    return values[max(i, 0)]


class ProfileError(ValueError):
    """A bad profile parameter; the message names the field and the value."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field


@dataclass(frozen=True)
class Profile:
    """A roll command profile: ``value(t)`` in rad at time ``t`` in s from the profile's start.

    ``amplitude`` in rad (square, step, sine), ``period`` in s (square, sine), ``step_time`` in s (step),
    ``times`` in s and ``values`` in rad (csv: each value held until the next time, never interpolated; the
    last time is the profile's end, :attr:`end`).
    """

    kind: str = "square"
    amplitude: float = math.radians(10.0)
    period: float = 10.0
    step_time: float = 1.0
    times: tuple[float, ...] = ()
    values: tuple[float, ...] = ()
    # A square MIMO plant's second setpoint, the sideslip (rad): a CSV's third column (held like the roll, on its
    # ``times``), else one constant; no sideslip setpoint is sent unless one is given (``has_sideslip``)
    sideslips: tuple[float, ...] = ()
    sideslip_const: float | None = None

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ProfileError("kind", f"kind must be one of {', '.join(KINDS)}, got {self.kind!r}")
        if not math.isfinite(self.amplitude):
            raise ProfileError("amplitude", f"amplitude must be finite, got {self.amplitude!r}")
        if not (math.isfinite(self.period) and self.period > 0):
            raise ProfileError("period", f"period must be positive and finite, got {self.period!r}")
        if not (math.isfinite(self.step_time) and self.step_time >= 0):
            raise ProfileError("step_time", f"step_time must be finite and >= 0, got {self.step_time!r}")
        object.__setattr__(self, "times", tuple(self.times))
        object.__setattr__(self, "values", tuple(self.values))
        object.__setattr__(self, "sideslips", tuple(self.sideslips))
        if self.sideslips and len(self.sideslips) != len(self.times):
            raise ProfileError("sideslips", "sideslips must be one per time")
        c = self.sideslip_const
        if c is not None and not (math.isfinite(c) and abs(math.degrees(c)) <= SIDESLIP_ENVELOPE_DEG + 1e-9):
            raise ProfileError("sideslip", f"the sideslip command {SIDE_RANGE}, got {math.degrees(c):g}")
        if self.kind == "csv":
            self._check_table()

    def _check_table(self) -> None:
        if not self.times or len(self.times) != len(self.values):
            raise ProfileError(
                "times",
                f"times and values must be non-empty and of one length, got {len(self.times)} and {len(self.values)}",
            )
        for name in ("times", "values"):
            bad = [v for v in getattr(self, name) if not math.isfinite(v)]
            if bad:
                raise ProfileError(name, f"{name} must be finite, got {bad[0]!r}")
        for a, b in zip(self.times, self.times[1:]):
            if b <= a:
                raise ProfileError("times", f"times must increase, got {b!r} after {a!r}")
        if not (0.0 <= self.times[0] and self.times[-1] <= MAX_SIM_S):
            raise ProfileError(
                "times", f"times must be in [0, {MAX_SIM_S:g}] s, got {self.times[0]!r}..{self.times[-1]!r}"
            )
        if any(abs(v) > math.pi for v in self.values):
            raise ProfileError("values", f"values must be in [-pi, pi] rad, got {max(self.values, key=abs)!r}")

    @property
    def end(self) -> float | None:
        """A CSV profile's last breakpoint (s): where the flight ends unless a duration is given; None otherwise."""
        return self.times[-1] if self.kind == "csv" else None

    @classmethod
    def square(cls, amplitude_deg: float = 10.0, period: float = 10.0) -> Profile:
        """+amplitude from t = 0, switching every half period."""
        return cls("square", math.radians(amplitude_deg), period)

    @classmethod
    def step(cls, amplitude_deg: float = 10.0, step_time: float = 1.0) -> Profile:
        """0 before ``step_time``, amplitude from it on."""
        return cls("step", math.radians(amplitude_deg), step_time=step_time)

    @classmethod
    def sine(cls, amplitude_deg: float = 10.0, period: float = 10.0) -> Profile:
        return cls("sine", math.radians(amplitude_deg), period)

    @classmethod
    def from_csv(cls, path: str) -> Profile:
        """The breakpoints of a ``time_s, roll_deg`` CSV file, held; OSError if it cannot be read."""
        try:
            times, values, sides = read_csv(path)
        except ValueError as exc:
            raise ProfileError("csv", str(exc)) from None
        return cls("csv", times=tuple(times), values=tuple(values), sideslips=tuple(sides or ()))

    @classmethod
    def of(
        cls,
        kind: str = "square",
        *,
        amplitude_deg: float = 10.0,
        period: float = 10.0,
        step_time: float = 1.0,
        csv: str | None = None,
    ) -> Profile:
        """The profile a command line names: ``kind`` with its parameters, or the CSV file ``csv``."""
        if csv:
            return cls.from_csv(csv)
        return cls(kind, math.radians(amplitude_deg), period, step_time)

    @property
    def has_sideslip(self) -> bool:
        """A sideslip setpoint is given (a CSV's third column or ``sideslip_const``): the GCS sends it."""
        return bool(self.sideslips) or self.sideslip_const is not None

    def sideslip(self, t: float) -> float:
        """The sideslip command in rad at ``t`` s (0 without one)."""
        if self.sideslips:
            return hold(t, self.times, self.sideslips)
        return self.sideslip_const or 0.0

    def value(self, t: float) -> float:
        """The roll command in rad at ``t`` s."""
        k = self.kind
        if k == "square":
            return square(t, self.amplitude, self.period)
        if k == "step":
            return step(t, self.amplitude, self.step_time)
        if k == "sine":
            return sine(t, self.amplitude, self.period)
        return hold(t, self.times, self.values)

    def breakpoints_ms(self, a_ms: int, b_ms: int) -> list[int]:
        """Discontinuity instants (whole ms from the start) in [a_ms, b_ms]."""
        k = self.kind
        if k == "square":
            half = self.period * 500.0
            j = math.ceil(a_ms / half - 1e-9)
            out = []
            while j * half <= b_ms + 1e-9:
                out.append(int(round(j * half)))
                j += 1
            return out
        if k == "step":
            s = int(round(self.step_time * 1000))
            return [s] if a_ms <= s <= b_ms else []
        if k == "csv":
            return [int(round(t * 1000)) for t in self.times if a_ms <= round(t * 1000) <= b_ms]
        return []
