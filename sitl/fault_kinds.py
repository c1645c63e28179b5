"""The fault kinds of ``--fault``, one record each (``KINDS``): how a value is given and bounded, which plants fly
it, which direction is worse, the damage study's default severities, and how it acts in the SITL
(``sitl.damage.combine`` folds it into an ``Effect``), in the KH2013A study's numpy and C paths
(``tools.experiment.study.faults``) and in the PID retuned for it (``tools.design.tuning.faulted_plant``).
Pure, no I/O.  Adding a kind: docs/adding-a-fault-kind.md.

The bounds of the servo kinds are the ground stations' (``autopilot.shared.servo_failures.LIMITS``: the autopilot
may not import ``sitl``); every other bound is written here once.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

from autopilot.shared.servo_failures import LIMITS

KT = 1852.0 / 3600.0  # m/s per kt
DEG = math.pi / 180.0

# What a fault's group needs of the plant (``sitl.plant_kinds.PlantKind.faults`` lists the groups a kind flies):
# ``servo``: the servo's path (every plant), ``airframe``: the linear airframe's coefficients (every plant; a
# plant file's damping needs its roll rate as a state), ``mass``: a JSBSim aircraft's mass properties and safety pilot.
GROUPS = ("servo", "airframe", "mass")
GROUP_REASONS = {"mass": "a JSBSim aircraft's mass properties and safety pilot only"}
# How the KH2013A study (numpy and C, ``tools.experiment.study.faults``) flies a kind; None: it does not.
STUDY_MATRICES = "matrices"  # a matrix set of its own (the exact ZOH of the faulted A_p)
STUDY_JUMP = "jump"  # the coasting matrix set, the surface jumping where it jams
STUDY_OFF = "off"  # the servo driven with 0
STUDY_DELAY = "delay line"  # a line of whole control periods
STUDY_SUBSTEPS = "substeps"  # SUBSTEPS physics steps a control step (a rate limit's coast-or-not)
# How the PID retuned for the fault (``tools.design.tuning``) takes a kind; None: no linear plant to design on.
DESIGN_AIRFRAME = "airframe"  # faulted_plant: A_p under ``sitl.damage.airframe_matrix``
DESIGN_DELAY = "delay"  # design_baseline's delay_steps


@dataclass(frozen=True)
class FaultKind:
    """One fault kind.

    ``value``: ``none`` (no value), ``optional`` or ``required``; ``unit``: the command line's (``metavar`` its
    name in ``--help``), ``si_unit`` and ``to_si`` the held value's; ``bound``: the largest magnitude, in the command
    line's unit, and ``check(v)`` the reason a value is refused (None: taken); ``group``: what it needs of the plant
    (``GROUPS``; the plant kinds that fly it: ``sitl.plant.plants_flying``); ``surface``: it hits one surface (a
    fault record names which); ``field``: the ``sitl.damage.Effect`` field it sets and ``fold(effect, value)`` how it
    joins the faults already active;
    ``jsbsim_property``: a JSBSim aircraft flies it through the model copy's fault properties
    (``sitl.jsbsim_damage``); ``severities``: the damage study's defaults (command-line units; None: no value);
    ``worse``: ``lower`` when a lower value is the worse fault, else ``higher``; ``study``, ``design``: how the
    KH2013A study and the retuned PID take it (``STUDY_*``, ``DESIGN_*``; None: they do not)."""

    name: str
    value: str
    unit: str
    si_unit: str
    to_si: float
    bound: float | None
    check: Callable[[float], str | None]
    help: str
    metavar: str
    group: str
    surface: bool
    field: str
    fold: Callable
    severities: tuple
    worse: str = "higher"
    jsbsim_property: bool = False
    study: str | None = None
    design: str | None = None

    @property
    def servo(self) -> bool:
        """On the servo's path (every plant has it)."""
        return self.group == "servo"

    @property
    def syntax(self) -> str:
        """``KIND``, ``KIND=METAVAR`` or ``KIND[=METAVAR]``, as ``--help`` shows it."""
        if self.value == "none":
            return self.name
        v = f"={self.metavar}"
        return f"{self.name}{v}" if self.value == "required" else f"{self.name}[{v}]"

    def active(self, effect) -> bool:
        """Whether ``effect`` (a ``sitl.damage.Effect``) has this kind active (its field off the nominal value)."""
        return getattr(effect, self.field) != getattr(type(effect)(), self.field)


# ---------------------------------------------------------------------------------------------- value checks
def positive(bound: float, unit: str = "") -> Callable[[float], str | None]:
    """(0, bound]."""
    say = f"must be > 0 and at most {bound:g}{f' {unit}' if unit else ''}"
    return lambda v: None if 0.0 < v <= bound else say


def within(bound: float, unit: str) -> Callable[[float], str | None]:
    """[-bound, bound]."""
    say = f"must be within +-{bound:g} {unit}"
    return lambda v: None if abs(v) <= bound else say


def from_zero(bound: float, unit: str) -> Callable[[float], str | None]:
    """[0, bound]."""
    say = f"must be in [0, {bound:g}] {unit}"
    return lambda v: None if 0.0 <= v <= bound else say


def at_least_one(bound: float) -> Callable[[float], str | None]:
    """[1, bound]: ballast can only add."""

    def check(v: float) -> str | None:
        if v < 1.0:
            return "must be >= 1 (ballast can only add inertia)"
        return None if v <= bound else f"must be at most {bound:g}"

    return check


def _any(_v: float) -> str | None:
    return None


MAX_FACTOR = 10.0  # effectiveness, damping, inertia
MAX_AIRSPEED_KT = 5000.0  # the JSBSim spec's airspeed_kt range (a plant's own: its trim range)
MAX_CG_M = 5.0


# ---------------------------------------------------------------------------------------------- the table
def _times(field: str) -> Callable:
    return lambda e, v: replace(e, **{field: getattr(e, field) * v})


def _plus(field: str) -> Callable:
    return lambda e, v: replace(e, **{field: getattr(e, field) + v})


KINDS: dict[str, FaultKind] = {
    k.name: k
    for k in (
        FaultKind(
            "effectiveness", "required", "", "", 1.0, MAX_FACTOR, positive(MAX_FACTOR),
            "the surface moves the aircraft F times as much", "F", "airframe", True, "effectiveness",
            _times("effectiveness"), (0.1, 0.3, 0.6), worse="lower", jsbsim_property=True,
            study=STUDY_MATRICES, design=DESIGN_AIRFRAME,
        ),
        FaultKind(
            "stuck", "optional", "deg", "rad", DEG, LIMITS["stuck"], within(LIMITS["stuck"], "deg"),
            "the surface jams where it is, or at DEG", "DEG", "servo", True, "stuck",
            lambda e, v: replace(e, stuck=True, stuck_at=v if v is not None else e.stuck_at), (-5.0, 0.0, 5.0),
            study=STUDY_JUMP,
        ),
        FaultKind(
            "off", "none", "", "", 1.0, None, _any, "the surface floats to neutral: no authority", "", "servo", True,
            "off", lambda e, _v: replace(e, off=True), (None,), study=STUDY_OFF,
        ),
        FaultKind(
            "rate", "required", "deg/s", "rad/s", DEG, LIMITS["rate"], positive(LIMITS["rate"], "deg/s"),
            "slews no faster than DEG_PER_S", "DEG_PER_S", "servo", True, "rate",
            lambda e, v: replace(e, rate=v if e.rate is None else min(e.rate, v)), (5.0, 20.0, 60.0), worse="lower",
            study=STUDY_SUBSTEPS,
        ),
        FaultKind(
            "delay", "required", "s", "s", 1.0, LIMITS["delay"], from_zero(LIMITS["delay"], "s"),
            "S of extra actuator delay (whole physics steps)", "S", "servo", True, "delay", _plus("delay"),
            (0.02, 0.05, 0.1), study=STUDY_DELAY, design=DESIGN_DELAY,
        ),
        FaultKind(
            "damping", "required", "", "", 1.0, MAX_FACTOR, positive(MAX_FACTOR), "the roll damping (L_p, Clp) times F",
            "F", "airframe", False, "damping", _times("damping"), (0.3, 0.6), worse="lower", jsbsim_property=True,
            study=STUDY_MATRICES, design=DESIGN_AIRFRAME,
        ),
        FaultKind(
            "inertia", "required", "", "", 1.0, MAX_FACTOR, at_least_one(MAX_FACTOR),
            "JSBSim: the roll inertia Ixx times F (tip ballast)", "F", "mass", False, "inertia", _times("inertia"),
            (1.3, 1.6), jsbsim_property=True,
        ),
        FaultKind(
            "cg", "required", "m", "m", 1.0, MAX_CG_M, within(MAX_CG_M, "m"),
            "JSBSim: the CG M metres to the right (wing-tip ballast)", "M", "mass", False, "cg", _plus("cg"),
            (0.05, 0.1), jsbsim_property=True,
        ),
        FaultKind(
            "airspeed", "required", "kt", "m/s", KT, MAX_AIRSPEED_KT, positive(MAX_AIRSPEED_KT, "kt"),
            "JSBSim: the safety pilot holds KT knots", "KT", "mass", False, "airspeed",
            lambda e, v: replace(e, airspeed=v), (63.0, 117.0), worse="lower",
        ),
    )
}  # fmt: skip

SERVO_KINDS = frozenset(k.name for k in KINDS.values() if k.servo)  # on the servo's path: every plant has them
SURFACE_KINDS = frozenset(k.name for k in KINDS.values() if k.surface)  # a fault record names the surface it hits
LINEAR_KINDS = frozenset(k.name for k in KINDS.values() if k.group != "mass")  # a linear plant flies them
JSBSIM_KINDS = frozenset(KINDS)
STUDY_KINDS = tuple(k.name for k in KINDS.values() if k.study is not None)  # the KH2013A study's
DESIGN_KINDS = tuple(k.name for k in KINDS.values() if k.design is not None)  # a retuned PID is designed for them
WORSE_LOWER = tuple(k.name for k in KINDS.values() if k.worse == "lower")  # the worst severity is the lowest value
SEVERITIES = {k.name: k.severities for k in KINDS.values()}  # the damage study's, in the command line's units


def help_text() -> str:
    """The kinds as ``--fault``'s help lists them: every plant's, then the JSBSim-only ones."""
    every = ", ".join(k.syntax for k in KINDS.values() if k.group != "mass")
    jsbsim = ", ".join(k.syntax for k in KINDS.values() if k.group == "mass")
    return f"{every}; on JSBSim also {jsbsim}"


__all__ = [
    "DESIGN_KINDS",
    "GROUPS",
    "JSBSIM_KINDS",
    "KINDS",
    "LINEAR_KINDS",
    "SERVO_KINDS",
    "SEVERITIES",
    "STUDY_KINDS",
    "SURFACE_KINDS",
    "WORSE_LOWER",
    "FaultKind",
    "help_text",
]
