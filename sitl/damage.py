"""Mid-flight faults of the aircraft (``--fault KIND[=VALUE]@START[:END]``): the spec, the schedule, what is active
at each physics step, and the surface's actuator under them.  Pure and I/O-free (the link faults are
``sitl.faults``; how each plant applies a fault: ``sitl.aircraft``, ``sitl.jsbsim_plant``; docs/faults.md).

A fault starts at the first physics step whose time is >= START (sim seconds, the flight's clock) and stays until
the first one >= END (without END: to the end).  The faults active at a step combine into one :class:`Effect`:
effectiveness, damping and inertia factors multiply, CG shifts and delays add, the smallest rate limit holds, a
stuck surface stays stuck (at the newest position given) whatever else is active, ``off`` makes the servo's
command 0, the newest airspeed is the safety pilot's target.  Everything is a function of the spec and the step
index: a lockstep flight with faults repeats bit for bit.

Values are given at the command-line edge in the units below and held in SI (:class:`Fault`.value).
"""

from __future__ import annotations

import argparse
import math
import re
from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from autopilot.shared.servo_failures import FAULT_PREFIX
from sitl.fault_kinds import (
    JSBSIM_KINDS,
    KINDS,
    KT,
    LINEAR_KINDS,
    MAX_AIRSPEED_KT,
    MAX_CG_M,
    MAX_FACTOR,
    SERVO_KINDS,
    SURFACE_KINDS,
    FaultKind,
    help_text,
)

COMMAND_LINE = "command line"
GROUND_STATION = "ground station"
ALL = "all"  # Fault.surface: every surface of the plant (a ground station's instance 0)
# The bounds every fault value is held to, on the command line, for ground stations (the same table,
# ``autopilot.shared.servo_failures.LIMITS``), in Flight and in both studies: each kind's record
# (``sitl.fault_kinds.FaultKind.bound``); a plant's own are narrower (its surface's travel for a stuck angle, its trim
# range for an airspeed: ``sitl.plant.check_faults``).
MAX_DELAY_S = KINDS["delay"].bound  # s
MAX_STUCK_DEG = KINDS["stuck"].bound  # deg: no surface travels further (a plant's own travel is checked with the plant)
MAX_RATE_DEG_S = KINDS["rate"].bound  # deg/s
MAX_TIME_S = 1e6  # START and END, sim seconds (11.6 days: longer than any flight; a flight's own end is narrower)
# A number as the command line takes it: ASCII digits only (float() would also take fullwidth and Arabic-Indic
# digits, "1_0", "inf" and "nan"), an optional sign, fraction and exponent.
NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")


class FaultSpecError(ValueError):
    """A --fault spec is malformed or out of range; the message names the spec and what is wrong."""


Kind = FaultKind  # a fault kind: its record (``sitl.fault_kinds.KINDS``)
SYNTAX = "KIND[=VALUE]@START[:END]"


@dataclass(frozen=True)
class Fault:
    """One fault: its kind, its value in SI (None: none given), START and END (sim s; END None: it stays), and
    where it came from (``COMMAND_LINE`` or ``GROUND_STATION``)."""

    kind: str
    value: float | None
    start: float
    end: float | None = None
    source: str = COMMAND_LINE
    # the surface it hits: None the plant's first (the command's: the only one of a SISO plant, a MIMO plant's
    # aileron), ALL every surface (a ground station's instance 0), or a surface's name (``Schedule.surfaces``)
    surface: str | None = None

    @property
    def label(self) -> str:
        """``KIND[=VALUE]`` in the command line's units (``rate=20``, ``stuck``)."""
        if self.value is None:
            return self.kind
        k = KINDS[self.kind]
        return f"{self.kind}={self.value / k.to_si:.6g}"

    @property
    def spec(self) -> str:
        """The spec back (``rate=20@10:15``)."""
        end = "" if self.end is None else f":{self.end:.9g}"
        return f"{self.label}@{self.start:.9g}{end}"

    def record(self, started: bool, surface: str | None = None) -> dict:
        """Its entry in ``summary.json`` ``faults`` (SI; ``unit`` is the value's; ``surface``: the name of the surface
        it hits, ``Schedule.surface_name``, None for a fault of the whole aircraft)."""
        return {
            "kind": self.kind,
            "surface": surface,
            "value": self.value,
            "unit": (KINDS[self.kind].si_unit or None) if self.value is not None else None,
            "start": self.start,
            "end": self.end,
            "source": self.source,
            "spec": self.spec,
            "started": started,
        }


def number(text: str) -> float | None:
    """``text`` as a finite float if it is a number in ASCII digits (``NUMBER``), else None."""
    t = str(text).strip()
    if not NUMBER.fullmatch(t):
        return None
    v = float(t)
    return v if math.isfinite(v) else None


def _number(spec: str, what: str, text: str) -> float:
    t = str(text).strip()
    if t.lower().lstrip("+-") in ("inf", "infinity", "nan"):
        raise FaultSpecError(f"fault {spec!r}: {what} must be finite, got {text!r}")
    if not NUMBER.fullmatch(t):
        raise FaultSpecError(f"fault {spec!r}: {what} must be a number in ASCII digits (e.g. 10, 1e-3), got {text!r}")
    v = float(t)
    if not math.isfinite(v):
        raise FaultSpecError(f"fault {spec!r}: {what} must be finite, got {text!r}")
    return v


def parse_kind(spec: str, text: str) -> tuple[str, float | None]:
    """``KIND[=VALUE]`` -> (kind, value in SI or None); raises FaultSpecError."""
    name, sep, value = text.partition("=")
    name = name.strip()
    kind = KINDS.get(name)
    if kind is None:
        raise FaultSpecError(f"fault {spec!r}: unknown kind {name!r}; kinds: {', '.join(KINDS)}")
    if not sep:
        if kind.value == "required":
            unit = f" {kind.unit}" if kind.unit else ""
            raise FaultSpecError(f"fault {spec!r}: {name} needs a value ({name}=VALUE{unit})")
        return name, None
    if kind.value == "none":
        raise FaultSpecError(f"fault {spec!r}: {name} takes no value")
    v = _number(spec, f"{name}'s value", value)
    why = kind.check(v)
    if why is not None:
        raise FaultSpecError(f"fault {spec!r}: {name} {why}, got {value.strip()}")
    return name, v * kind.to_si


def parse(text: str, source: str = COMMAND_LINE) -> Fault:
    """A ``KIND[=VALUE]@START[:END]`` spec -> Fault; raises FaultSpecError with a one-line reason."""
    spec = str(text).strip()
    head, sep, when = spec.partition("@")
    if not sep:
        raise FaultSpecError(f"fault {spec!r}: expected {SYNTAX}, missing @START (sim seconds)")
    kind, value = parse_kind(spec, head)
    start_text, colon, end_text = when.partition(":")
    start = _number(spec, "START", start_text)
    if start < 0:
        raise FaultSpecError(f"fault {spec!r}: START must be >= 0 s, got {start_text}")
    if start > MAX_TIME_S:
        raise FaultSpecError(f"fault {spec!r}: START must be at most {MAX_TIME_S:g} s, got {start_text}")
    end = None
    if colon:
        end = _number(spec, "END", end_text)
        if end > MAX_TIME_S:
            raise FaultSpecError(f"fault {spec!r}: END must be at most {MAX_TIME_S:g} s, got {end_text}")
        if end <= start:
            raise FaultSpecError(f"fault {spec!r}: END must be after START, got {start_text}:{end_text}")
    return Fault(kind, value, start, end, source)


def fault_arg(text: str) -> Fault:
    """``--fault`` for argparse: a FaultSpecError becomes the one-line usage error."""
    try:
        return parse(text)
    except FaultSpecError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_argument(parser) -> None:
    """``--fault`` (repeatable), the same on ``python -m sitl`` and ``python -m tools.launch``."""
    parser.add_argument(
        "--fault",
        type=fault_arg,
        action="append",
        default=None,
        metavar=SYNTAX,
        help="a fault in mid-flight, from START to END sim seconds (without END it stays), repeatable: "
        f"{help_text()} (docs/faults.md)",
    )


def to_argv(faults) -> list[str]:
    """The ``--fault`` flags that give ``faults`` (Fault objects or spec strings) to another command line."""
    out: list[str] = []
    for f in faults or ():
        out += ["--fault", f.spec if isinstance(f, Fault) else str(f)]
    return out


def check_kinds(faults, kinds: frozenset, plant: str, why: dict | None = None) -> None:
    """FaultSpecError for the first fault whose kind the plant cannot do (``kinds``: the ones it can; ``why``: a
    reason per kind, if there is one)."""
    for f in faults:
        if f.kind not in kinds:
            reason = (why or {}).get(f.kind) or f"it does {', '.join(k for k in KINDS if k in kinds)}"
            raise FaultSpecError(f"--fault {f.spec} cannot fly on --plant {plant}: {reason}")


# ---------------------------------------------------------------------------------------------- what is active
@dataclass(frozen=True)
class Effect:
    """What the faults active at one step do together (SI).  ``Effect()`` is the aircraft as built."""

    effectiveness: float = 1.0
    damping: float = 1.0
    stuck: bool = False
    stuck_at: float | None = None  # rad; None: where it was when it jammed
    off: bool = False
    rate: float | None = None  # rad/s
    delay: float = 0.0  # s
    inertia: float = 1.0
    cg: float = 0.0  # m, to the right
    airspeed: float | None = None  # m/s
    # a square MIMO plant's second surface (the rudder): the servo faults on it (stuck, off, rate, delay), None when
    # it has none; every other field is the first surface's or the whole aircraft's
    second: Effect | None = None

    @property
    def nominal(self) -> bool:
        return self == NOMINAL

    @property
    def servo(self) -> bool:
        """A fault on the servo's path (stuck, off, rate, delay)."""
        return self.stuck or self.off or self.rate is not None or self.delay > 0

    def servo_differs(self, other: Effect) -> bool:
        """Whether the servo's faults differ from ``other``'s (``SERVO_FIELDS``): a new ``Actuator`` takes over."""
        return any(getattr(self, k) != getattr(other, k) for k in SERVO_FIELDS)

    @property
    def airframe(self) -> bool:
        """A change of the airframe's coefficients (effectiveness, damping)."""
        return self.effectiveness != 1.0 or self.damping != 1.0


NOMINAL = Effect()
# The Effect's fields of the servo kinds (``sitl.fault_kinds.SERVO_KINDS``' fields, and where a stuck one is held)
SERVO_FIELDS = (*(KINDS[k].field for k in KINDS if k in SERVO_KINDS), "stuck_at")


def combine(faults) -> Effect:
    """The Effect of the faults active together, in the order they started (see the module docstring): each kind's
    record folds its value in (``sitl.fault_kinds.FaultKind.fold``)."""
    e = NOMINAL
    for f in faults:
        e = KINDS[f.kind].fold(e, f.value)
    return e


class Schedule:
    """The faults of a flight on the physics-step grid: step 0 is sim time ``t0``, one step is ``dt``.

    ``segments(step, n)`` cuts n steps from ``step`` at every step where a fault starts or ends, with the faults
    that start and end there; ``effect(step)`` is what is active at a step.  A fault from a ground station is
    added while flying (``add(fault, step)``); ``clear(source, step)`` ends every active fault of a source."""

    def __init__(self, faults=(), t0: float = 0.0, dt: float = 1e-3, surfaces: tuple = ()):
        self.t0, self.dt = float(t0), float(dt)
        self.surfaces = tuple(surfaces)  # the plant's surfaces in its order (sitl.plant.surfaces_of); () unnamed
        self.entries: list[list] = []  # [fault, start step, end step or None]
        for f in faults:
            self.add(f)

    def surface_name(self, fault: Fault) -> str | None:
        """The surface ``fault`` hits, by name (``aileron+rudder`` for all of a MIMO plant's), None for a fault of
        the whole aircraft (damping, inertia, cg, airspeed)."""
        if fault.kind not in SURFACE_KINDS:
            return None
        if fault.surface == ALL:
            return "+".join(self.surfaces) or ALL
        if fault.surface is None:
            return self.surfaces[0] if self.surfaces else None
        return fault.surface

    def _on(self, fault: Fault, i: int) -> bool:
        """Whether ``fault`` acts on surface ``i`` (the airframe's faults: on the first, the Effect's own fields)."""
        if fault.kind not in SERVO_KINDS or fault.surface is None:
            return i == 0
        if fault.surface == ALL:
            return True
        names = self.surfaces or (None,)
        return i < len(names) and fault.surface == names[i]

    def step_of(self, t: float) -> int:
        """The first physics step whose time is >= t (0 for any t before the flight's start)."""
        return max(0, math.ceil(round((t - self.t0) / self.dt, 6)))

    def time_of(self, step: int) -> float:
        return self.t0 + step * self.dt

    def add(self, fault: Fault, step: int | None = None) -> Fault:
        """Schedule ``fault`` (from ``step`` if given: a ground station's, now); returns it."""
        start = self.step_of(fault.start) if step is None else int(step)
        end = None if fault.end is None else max(start, self.step_of(fault.end))
        self.entries.append([fault, start, end])
        return fault

    def clear(self, source: str, step: int, surface: int | None = None) -> int:
        """End, at ``step``, every fault of ``source`` active then or still to come (``surface``: only those that
        act on the surface of that index); how many."""
        n = 0
        for e in self.entries:
            f, start, end = e
            if surface is not None and not self._on(f, surface):
                continue
            if f.source == source and (end is None or end > step):
                e[2] = max(start, step)
                e[0] = replace(f, end=max(f.start, self.time_of(step)))
                n += 1
        return n

    def active(self, step: int) -> list[Fault]:
        return [f for f, s, e in self.entries if s <= step and (e is None or step < e)]

    def effect(self, step: int) -> Effect:
        """What is active at ``step``: the first surface's and the whole aircraft's faults; on a plant of two
        surfaces, the second's servo faults as ``Effect.second``."""
        active = self.active(step)
        e = combine(f for f in active if self._on(f, 0))
        if len(self.surfaces) > 1:
            e2 = combine(f for f in active if self._on(f, 1))
            if e2 != NOMINAL:
                e = replace(e, second=e2)
        return e

    def segments(self, step: int, n: int) -> list[tuple[int, list[tuple[Fault, bool]]]]:
        """[(steps, [(fault, started?), ...]), ...] covering steps ``step`` .. ``step + n - 1``: each piece begins
        with the faults that start (True) or end (False) at its first step."""
        marks = sorted({b for _f, s, e in self.entries for b in (s, e) if b is not None and step < b < step + n})
        out = []
        k = step
        for b in [*marks, step + n]:
            if b > k:
                out.append((b - k, self.changes(k)))
                k = b
        return out

    def changes(self, step: int) -> list[tuple[Fault, bool]]:
        """The faults that start (True) or end (False) at ``step``, ends first."""
        ends = [(f, False) for f, s, e in self.entries if e == step and s < step]
        starts = [(f, True) for f, s, e in self.entries if s == step and (e is None or e > step)]
        return ends + starts

    def records(self, step: int) -> list[dict]:
        """The ``summary.json`` entries, ``started`` for those whose start step was reached by ``step``."""
        return [f.record(s < step, self.surface_name(f)) for f, s, _e in self.entries]


def advance_scheduled(schedule: Schedule, plant, advance, u: float, n: int, change) -> object:
    """Fly ``n`` physics steps of ``plant`` with the command ``u`` held, through ``schedule``: the steps are cut where
    a fault starts or ends (``Schedule.segments``), ``change(step, changes)`` is called at each cut (the caller hands
    the plant the new ``Schedule.effect`` there), ``advance(u, m)`` flies each piece.  Returns the truth state
    after the last piece.  The SITL's endpoint (``sitl.fault_injection``) and the in-process runner
    (``tools.experiment.scenario.run_inprocess``) both fly faults through this one function."""
    k = plant.steps
    x = None
    for m, changes in schedule.segments(k, n):
        if changes:
            change(k, changes)
        x = advance(u, m)
        k += m
    return plant.truth if x is None else x


class ScheduledEffects:
    """A plant flown through a :class:`Schedule` with nothing said (the in-process runner's form of the SITL's
    ``sitl.fault_injection.FaultInjection``): ``advance(u, n)`` as the plant's, the plant's ``set_effect`` called
    where the active faults' :class:`Effect` changes."""

    def __init__(self, plant, schedule: Schedule, advance=None):
        self.plant, self.schedule = plant, schedule
        self._advance = advance or plant.advance
        self.effect = NOMINAL
        # the steps where a fault starts or ends: between them the plant's own advance is called directly (the
        # same call advance_scheduled makes for a piece without changes; the schedule is fixed, no ground station)
        self._marks = sorted({b for _f, s, e in schedule.entries for b in (s, e) if b is not None})
        self._next = self._marks[0] if self._marks else None

    def _change(self, step: int, _changes) -> None:
        effect = self.schedule.effect(step)
        if effect != self.effect:
            self.plant.set_effect(effect)
            self.effect = effect

    def advance(self, u: float, n: int):
        nxt = self._next
        if nxt is None or nxt >= self.plant.steps + n:
            return self._advance(u, n)
        x = advance_scheduled(self.schedule, self.plant, self._advance, u, n, self._change)
        later = [b for b in self._marks if b >= self.plant.steps]
        self._next = later[0] if later else None
        return x


def status_text(fault: Fault, started: bool, t: float, surface: str | None = None) -> str:
    """The SITL's STATUSTEXT when a fault starts or ends (``FAULT_PREFIX``: the autopilot's telemetry marks it);
    ``surface``: the surface it hits (``Schedule.surface_name``), named after the fault."""
    on = f" on the {surface}" if surface else ""
    if started:
        return f"{FAULT_PREFIX}start t={t:.3f}: {fault.label}{on} ({fault.source})"
    return f"{FAULT_PREFIX}end t={t:.3f}: {fault.label}{on}"


# ---------------------------------------------------------------------------------------------- the linear plant
def airframe_matrix(a_p: np.ndarray, effect: Effect, roll_rate: int | None) -> np.ndarray:
    """A_p with the servo last (``sitl.model.augmented_matrices``) under ``effect``: the deflection's column of the
    airframe rows (B_lp, the control derivatives) times the effectiveness, the roll-rate state's own term (L_p,
    A_lp[1, 1] on the KH2013A) times the damping."""
    a = np.array(a_p, dtype=float)
    n = a.shape[0]
    if effect.effectiveness != 1.0:
        a[: n - 2, n - 2] *= effect.effectiveness
    if effect.damping != 1.0:
        if roll_rate is None:
            raise FaultSpecError("damping: this plant has no roll-rate state")
        a[roll_rate, roll_rate] *= effect.damping
    return a


def roll_rate_index(truth) -> int | None:
    """The state of a linear plant that is the roll rate p (``truth``: its rows onto [v, p, r, phi], None when the
    states are those; ``sitl.linear_plant``), None when p is not one state but a combination (a transfer function)."""
    if truth is None:
        return 1  # sitl.model.P
    row = np.asarray(truth, dtype=float)[1]
    hot = np.flatnonzero(row)
    return int(hot[0]) if len(hot) == 1 and row[hot[0]] == 1.0 else None


def coasting_matrix(a: np.ndarray) -> np.ndarray:
    """A with the servo's rows replaced by delta' = delta_dot, delta_dot' = 0: the surface moves at a constant rate
    over a step (0: stuck), the airframe sees it exactly (the ZOH of this matrix is exact for a ramp)."""
    c = np.array(a, dtype=float)
    n = c.shape[0]
    c[n - 2 :, :] = 0.0
    c[n - 2, n - 1] = 1.0
    return c


class Actuator:
    """The surface's actuator under the servo faults of an Effect, one physics step at a time.

    ``command(u)`` is what the servo is driven with: u delayed by ``round(delay / dt)`` steps (the delay line starts
    full of ``u_last``, the command held before), 0 when the surface is off.  ``surface(delta, delta_free,
    rate_free)`` says what the surface does with the servo's free step (delta_free, rate_free) from delta:
    ``(True, rate)`` to coast this step at ``rate`` (stuck: 0; a rate limit: +-rate when the free step moves more
    than rate * dt), ``(False, rate)`` to take the free step with its rate clipped to the limit."""

    def __init__(self, effect: Effect, dt: float, u_last: float = 0.0):
        self.effect = effect
        self.stuck = effect.stuck
        self.off = effect.off
        self.rate = effect.rate
        self._max_move = None if effect.rate is None else effect.rate * dt
        n = int(round(effect.delay / dt))
        self.delay_steps = n
        self._line = deque([float(u_last)] * n) if n else None

    def command(self, u: float) -> float:
        line = self._line
        if line is not None:
            line.append(u)
            u = line.popleft()
        return 0.0 if self.off else u

    def surface(self, delta: float, delta_free: float, rate_free: float) -> tuple[bool, float]:
        if self.stuck:
            return True, 0.0
        r = self.rate
        if r is None:
            return False, rate_free
        move = delta_free - delta
        if move > self._max_move:
            return True, r
        if move < -self._max_move:
            return True, -r
        return False, min(r, max(-r, rate_free))


def jammed(old: Effect, new: Effect, delta: float) -> float | None:
    """The position (rad) the surface jumps to when ``new`` takes over from ``old``: where it is (``delta``) or the
    position given when it jams, the new position when a stuck one is given another; None: no jump."""
    if not new.stuck:
        return None
    if not old.stuck:
        return delta if new.stuck_at is None else new.stuck_at
    if new.stuck_at is not None and new.stuck_at != old.stuck_at:
        return new.stuck_at
    return None


# ---------------------------------------------------------------------------------------------- ground stations
class InjectionFilter:
    """Resent commands: the same MAV_CMD_INJECT_FAILURE params (1..7) as the last one, within ``window_s`` wall
    seconds of it, are a resend (its ACK was lost): answered with the same result, not applied again."""

    def __init__(self, window_s: float):
        self.window_s = window_s
        self._last: tuple | None = None  # (params, wall time, result)

    @staticmethod
    def _key(params: tuple) -> tuple:
        return tuple(float(p).hex() for p in params)  # NaN (a "not used" param) equals NaN here

    def resent(self, params: tuple, now: float) -> int | None:
        """The result given to the identical last command, if this is its resend; else None."""
        last = self._last
        if last is not None and last[0] == self._key(params) and now - last[1] <= self.window_s:
            return last[2]
        return None

    def remember(self, params: tuple, now: float, result: int) -> None:
        self._last = (self._key(params), now, result)


__all__ = [
    "ALL",
    "COMMAND_LINE",
    "JSBSIM_KINDS",
    "KT",
    "LINEAR_KINDS",
    "MAX_AIRSPEED_KT",
    "MAX_CG_M",
    "MAX_FACTOR",
    "SERVO_FIELDS",
    "SERVO_KINDS",
    "SURFACE_KINDS",
    "GROUND_STATION",
    "KINDS",
    "Actuator",
    "Effect",
    "Fault",
    "FaultSpecError",
    "InjectionFilter",
    "Kind",
    "Schedule",
    "ScheduledEffects",
    "advance_scheduled",
    "add_argument",
    "airframe_matrix",
    "check_kinds",
    "coasting_matrix",
    "combine",
    "parse",
    "status_text",
    "to_argv",
]
