"""The damage study's axes and its tasks: fault kind x severity x onset x seed x controller, per plant.  No I/O.

A flight is :class:`DamageFlight` (one task of ``tools.experiment.study.execute``); what it needs designed first (the
PID retuned for a faulted plant, the PID scaled to CL-SAC's energy) are the tasks :class:`Design` and
:class:`Calibration`, flown before the flights that use them.  Every task is a frozen dataclass of plain values: a
result depends on the task only, never on the worker or the order, so a Dask cluster gives a local run's numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from autopilot import controllers as registry
from sitl import damage, fault_kinds
from sitl import plant as plants

# The controllers of the study: the registry's (autopilot.controllers: every built-in law, and a user's own law
# FILE.py:Class or module:Class, flown through the generic loop, tools.experiment.scenario.run_inprocess), SAC and
# CL-SAC with the robust PFC (the launcher's --pfc robust) and two fixed-gain PIDs made here.  The default set is
# the published tables': the registry's controllers with a ``damage`` place, in its order; ``all`` flies every
# registered law too.
ROBUST = {"sac-robust": "sac", "clsac-robust": "clsac"}  # the law flown with autopilot.config.PFC_PRESETS["robust"]
RETUNED = "pid-retuned"  # tools.design.tuning.design_baseline on the plant as it is, switched at the fault's onset
ENERGY = "pid-energy"  # the plant's PID with its gains scaled to CL-SAC's energy on the fault-free scenario
CONTROLLERS = (
    *sorted(
        (c.name for c in registry.CONTROLLERS.values() if c.damage is not None), key=lambda n: registry.get(n).damage
    ),
    *ROBUST,
    RETUNED,
    ENERGY,
)
ALL = (*registry.BUILT_IN, *ROBUST, RETUNED, ENERGY)  # --controllers all
# The study's words for each (the registry's study_label, else its label), and for its own
LABELS = {
    **{c.name: c.study_label or c.label for c in registry.CONTROLLERS.values()},
    "sac-robust": "SAC, robust PFC",
    "clsac-robust": "CL-SAC, robust PFC",
    RETUNED: "PID retuned for the fault",
    ENERGY: "PID at CL-SAC's energy",
}


def label(controller: str) -> str:
    """The study's words for a controller (a user's law: its LABEL, autopilot.controllers.register)."""
    if controller in LABELS:
        return LABELS[controller]
    return registry.get(controller).label


def known(controller: str) -> bool:
    """A controller the study flies: one of ``ALL``, or a user's law that loads (autopilot.law.LawSpecError, one
    line, if it does not)."""
    if controller in ALL:
        return True
    registry.get(controller)  # ValueError / LawSpecError naming what is missing
    return True


NONE = "none"  # the fault-free flight of a cell's controller and seed: the reference every severity is read against
# Severities in the command line's units (deg, deg/s, s, kt, m, or a factor): each kind's record's
# (sitl.fault_kinds.FaultKind.severities).
SEVERITIES = dict(fault_kinds.SEVERITIES)
DEFAULT_KINDS = ("effectiveness", "stuck", "rate", "delay")
DEFAULT_PLANTS = ("kh2013a", "jsbsim:c172x")
DEFAULT_ONSETS = (10.0,)
DEFAULT_RUNS = 6  # the least seeds whose paired sign-test interval reaches 95 % (tools.experiment.damage.stats)
DEFAULT_DURATION_S = 30.0
DEFAULT_TURBULENCE = "light"
TURBULENCE = ("none", "light", "moderate", "severe")
LINEAR_KINDS = fault_kinds.DESIGN_KINDS  # a retuned PID is designed on the faulted linear plant (FaultKind.design)
# A square MIMO plant (jsbsim:MODEL:surface=aileron+rudder) flies the laws autopilot.mimo builds, nothing else.
MIMO_CONTROLLERS = registry.MIMO
MIMO_REFUSALS = {
    "pid-ff": "autopilot.mimo flies clsac, sac and baseline only (the launcher refuses --controller pid-ff on it)",
    "sac-robust": "the robust PFC is a single-input PFC: the MIMO laws fly their design file's PFC matrix",
    "clsac-robust": "the robust PFC is a single-input PFC: the MIMO laws fly their design file's PFC matrix",
    RETUNED: "its PID is retuned on a single-input linear model (tools.design.tuning.design_baseline): no MIMO retune",
    ENERGY: "its gain factor is calibrated on the single-input PID's energy: no MIMO calibration",
}


def controller_refusals(plant: str, controllers) -> dict[str, str]:
    """{controller: why not} for the study's controllers ``plant`` does not fly (a square MIMO plant:
    ``MIMO_REFUSALS``, or a law's own reason; SAC and CL-SAC with the robust PFC on a plant whose design file sets
    the PFC)."""
    if plants.spec(plant).mimo:
        return {
            c: MIMO_REFUSALS.get(c) or registry.get(c).kind.mimo or f"{c} is not flown on a square MIMO plant"
            for c in controllers
            if c not in MIMO_CONTROLLERS
        }
    out = {}
    for c in controllers:  # a bench law without its design for the plant (tools.design.laws)
        law = None if c in ROBUST or c in (RETUNED, ENERGY) else registry.get(c).kind
        if law is not None and law.generic and law.design and not plants.spec(plant).paper:
            from tools.design.linearise import designed_law_params

            if designed_law_params(plant, law.design) is None:
                out[c] = f"{plant} has no design of {c} (python -m tools.design.laws {plant})"
    if any(c in ROBUST for c in controllers):
        from tools.design.linearise import designed_params

        if designed_params(plant) is not None:
            why = (
                "the plant's design file sets SAC's and CL-SAC's PFC and overrides --pfc (the launcher flies the "
                "file's); the robust preset is the KH2013A's"
            )
            out.update({c: why for c in controllers if c in ROBUST})
    return out


class DamageError(ValueError):
    """A flag of the damage study that cannot run; the one-line message names it."""


@dataclass(frozen=True)
class DamageFlight:
    """One flight: ``plant``, ``controller`` (``CONTROLLERS``), the fault ``kind`` (``NONE``: none) of ``value``
    (command-line units; None: a kind without one, ``stuck`` where it is) from ``onset`` s, the disturbance
    ``seed`` and ``turbulence``, ``duration`` s; ``gains`` and ``schedule`` are what the study designed for the
    fixed-gain PIDs (the scenario's ``baseline_gains`` and ``gain_schedule``)."""

    plant: str
    controller: str
    kind: str
    value: float | None
    onset: float
    seed: int
    duration: float = DEFAULT_DURATION_S
    turbulence: str = DEFAULT_TURBULENCE
    gains: tuple | None = None
    schedule: tuple = ()

    @property
    def runs(self) -> tuple[int]:
        """What ``tools.experiment.study.Progress`` counts: one flight."""
        return (self.seed,)

    @property
    def spec(self) -> str | None:
        """The fault as ``--fault`` takes it (``effectiveness=0.3@10``), None for the fault-free flight."""
        if self.kind == NONE:
            return None
        return f"{self.kind}{'' if self.value is None else f'={self.value:g}'}@{self.onset:g}"

    @property
    def cell(self) -> tuple:
        """The cell the flight counts in (all but the seed)."""
        return (self.plant, self.controller, self.kind, self.value, self.onset)


@dataclass(frozen=True)
class Design:
    """The PID ``tools.design.tuning.design_baseline`` gives the plant's linear model under a fault (``NONE``:
    as built)."""

    plant: str
    kind: str
    value: float | None

    @property
    def runs(self) -> tuple[int]:
        return (0,)


@dataclass(frozen=True)
class Calibration:
    """The factor on the plant's PID gains that makes its energy on the fault-free reference scenario CL-SAC's."""

    plant: str

    @property
    def runs(self) -> tuple[int]:
        return (0,)


def fault_of(kind: str, value: float | None, onset: float) -> damage.Fault:
    """The sitl.damage.Fault of a cell (FaultSpecError for a bad value)."""
    return damage.parse(f"{kind}{'' if value is None else f'={value!r}'}@{onset!r}")


def effect_of(kind: str, value: float | None) -> damage.Effect:
    """What the fault does once active (``NONE``: the aircraft as built)."""
    return damage.NOMINAL if kind == NONE else damage.combine([fault_of(kind, value, 0.0)])


def seeds(seed: int, runs: int) -> list[int]:
    """The seeds of a cell's flights: SEED, SEED + 1, ..., the same in every cell (common random numbers)."""
    return [seed + j for j in range(runs)]


def fault_cells(kinds, severities: dict, refusals: dict, plant: str | None = None) -> tuple[list[tuple], dict]:
    """[(kind, value), ...] a plant flies, and {kind: why} for the kinds it cannot (``refusals``:
    ``sitl.plant.fault_refusals``).  ``plant``: each value is held to its bounds too (a stuck angle within its
    surface's travel, an airspeed it trims at: ``sitl.plant.fault_value_refusal``, the SITL's own check); DamageError
    for the first it cannot fly."""
    from sitl import plant as plants

    cells, skipped = [], {}
    for k in kinds:
        if k in refusals:
            skipped[k] = refusals[k]
            continue
        for v in severities[k]:
            if plant is not None:
                why = plants.fault_value_refusal(plant, fault_of(k, v, 0.0))
                if why is not None:
                    raise DamageError(f"--severity {k}={'here' if v is None else f'{v:g}'} on --plant {plant}: {why}")
            cells.append((k, v))
    return cells, skipped


def make_flights(
    plants,
    controllers,
    cells_by_plant: dict,
    onsets,
    seed: int,
    runs: int,
    duration: float,
    turbulence: str,
) -> list[DamageFlight]:
    """Every flight of the study, without the designed gains (``with_designs`` adds them): per plant, controller
    and seed the fault-free flight, and per fault cell and onset one faulted flight (a controller the plant does
    not fly, ``controller_refusals``, flies none)."""
    out = []
    for p in plants:
        refused = controller_refusals(p, controllers)
        for c in controllers:
            if c in refused:
                continue
            for s in seeds(seed, runs):
                out.append(DamageFlight(p, c, NONE, None, float(onsets[0]), s, duration, turbulence))
                for kind, value in cells_by_plant[p]:
                    for t in onsets:
                        out.append(DamageFlight(p, c, kind, value, float(t), s, duration, turbulence))
    return out


def designs_needed(flights) -> list:
    """The Design and Calibration tasks the flights need, each once, in a fixed order."""
    need: dict = {}
    for f in flights:
        if f.controller == RETUNED:
            need.setdefault(Design(f.plant, NONE, None), None)
            if f.kind in LINEAR_KINDS:
                need.setdefault(Design(f.plant, f.kind, f.value), None)
        elif f.controller == ENERGY:
            need.setdefault(Calibration(f.plant), None)
    return list(need)


def with_designs(flights, designed: dict) -> list[DamageFlight]:
    """The flights with their designed gains: ``designed`` maps each Design to (KP, KI, KD) and each Calibration to
    the gains it scaled.  The retuned PID flies the design of the plant as built until the onset, then the design
    of the faulted plant (a perfect gain schedule: it knows the fault the moment it happens); for a fault that is
    not a linear plant (stuck, rate, off ...) there is nothing to retune on and it flies the design as built."""
    from dataclasses import replace

    out = []
    for f in flights:
        if f.controller == RETUNED:
            base = designed[Design(f.plant, NONE, None)]
            sched = ()
            if f.kind in LINEAR_KINDS:
                sched = ((f.onset, designed[Design(f.plant, f.kind, f.value)]),)
            f = replace(f, gains=base, schedule=sched)
        elif f.controller == ENERGY:
            f = replace(f, gains=designed[Calibration(f.plant)])
        out.append(f)
    return out


def parse_list(text: str, what: str, convert=str) -> list:
    """A comma-separated list (DamageError for an empty or malformed one)."""
    try:
        items = [convert(x.strip()) for x in str(text).split(",") if x.strip()]
    except ValueError:
        raise DamageError(f"expected a comma-separated list of {what}, got {text!r}") from None
    if not items:
        raise DamageError(f"expected a comma-separated list of {what}, got {text!r}")
    return items


def parse_severity(text: str) -> tuple[str, tuple]:
    """``KIND=V1,V2,...`` (command-line units; ``stuck=here`` is "where it is") -> (kind, values); each value is
    checked as a fault (``sitl.damage.parse``)."""
    kind, sep, values = str(text).partition("=")
    kind = kind.strip()
    if not sep or kind not in damage.KINDS:
        raise DamageError(f"--severity expects KIND=V1,V2,... with a kind of {', '.join(damage.KINDS)}, got {text!r}")
    if damage.KINDS[kind].value == "none":
        raise DamageError(f"--severity {kind}: {kind} has no severity")

    def one(v: str):
        if kind == "stuck" and v == "here":
            return None
        x = damage.number(v)  # ASCII digits only (float() takes fullwidth digits and "1_0")
        if x is None:
            raise ValueError(f"{v!r} is not a finite number in ASCII digits")
        damage.parse(f"{kind}={x!r}@0")
        return x

    try:
        vals = tuple(one(v.strip()) for v in values.split(",") if v.strip())
    except ValueError as exc:
        why = str(exc)
        raise DamageError(f"--severity {text}: {why}") from None
    if not vals:
        raise DamageError(f"--severity {text}: no values")
    return kind, vals


def check_onsets(onsets, duration: float) -> None:
    for t in onsets:
        if not (math.isfinite(t) and 0.0 < t < duration):
            raise DamageError(f"--onsets: each onset must be inside the flight (0 < t < {duration:g} s), got {t:g}")
