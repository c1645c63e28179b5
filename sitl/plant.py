"""The SITL's plants behind one interface (``--plant``), like ArduPilot's SIM_Aircraft.  No I/O but the plant file.

A plant has ``advance(delta_command, n, d=None)`` (n physics steps with the servo command held and the
disturbance d, if any, per step), ``truth`` ([v, p, r, phi, delta, delta_dot], ``sitl.model.STATE_NAMES``),
``attitude()`` (roll, pitch, yaw or None, p, q, r), ``steps``, ``time`` and ``config.dt``
(``sitl.plant_kinds.Plant``).  The kinds are one table, ``sitl.plant_kinds.KINDS``, one record each:

- ``kh2013a`` (the default): the paper's model, ``sitl.aircraft.Aircraft``;
- ``FILE.toml``: a linear plant of your own (``sitl.linear_plant``), flown by the same ``Aircraft``;
- ``jsbsim:MODEL[:KEY=VALUE,...]``: a JSBSim aircraft (``sitl.jsbsim_plant``).

A --plant value is parsed once into a ``PlantSpec`` (``spec(text)``); the functions here read it.
"""

from __future__ import annotations

import math

from sitl.linear_plant import PHYSICS_RATE_HZ
from sitl.plant_kinds import (
    JSBSIM,
    KH2013A,
    KINDS,
    Plant,
    PlantError,
    PlantSpec,
    kind_of,
    shipped,
    spec,
)

# Disturbance flags (sitl.disturbances.FLAGS) a plant kind cannot apply, and why (``PlantKind.unsupported``).
UNSUPPORTED = {name: k.unsupported for name, k in KINDS.items() if k.unsupported}


def kind(text: str) -> str:
    """The name of the plant's kind (``sitl.plant_kinds.KINDS``: ``kh2013a``, ``jsbsim`` or ``file``)."""
    return kind_of(text).name


def check(text: str, physics_rate_hz: float | None = PHYSICS_RATE_HZ) -> str:
    """Validate a --plant value (file parsed and checked, its physics step at ``physics_rate_hz`` unless None;
    JSBSim spec parsed and its model found); returns it.  Raises PlantError with a one-line reason."""
    kind_of(text).check(text, physics_rate_hz)
    return text


ATMOSPHERE = ("turbulence", "turbulence_sigma", "turbulence_length", "gust", "crosswind")


def check_disturbances(text: str, given: dict) -> None:
    """Raise PlantError if a disturbance flag given (``{dest: value}``, None = not given) cannot fly on this plant."""
    for dest, why in kind_of(text).unsupported.items():
        if given.get(dest) is not None:
            raise PlantError(f"--{dest.replace('_', '-')} cannot fly on --plant {text}: {why}")
    ps = spec(text)
    ps.kind.disturbances(text, ps.model, [d for d in ATMOSPHERE if given.get(d) is not None], given)


def injected(text: str, dist):
    """What ``sitl.disturbances.Injector`` applies on this plant (its kind's ``atmosphere``): everything but the
    atmosphere for JSBSim (it flies its own, at the aircraft's airspeed and altitude); on a plant file the atmosphere
    scaled to its ``[atmosphere]`` airspeed, span and altitude (``scaled_atmosphere``); all of it, as given, on the
    KH2013A."""
    if dist is None:
        return dist
    ps = spec(text)
    return ps.kind.atmosphere(ps.model, dist)


def fault_refusals(text: str) -> dict[str, str]:
    """The fault kinds (``sitl.fault_kinds.KINDS``) this plant cannot fly, each with the reason: a kind of a group
    its kind does not fly (``PlantKind.faults``), and the plant's own (``PlantKind.refusals``: a JSBSim model's,
    ``sitl.jsbsim_damage.refusals``; damping on a plant file whose roll rate is no state)."""
    from sitl.fault_kinds import GROUP_REASONS
    from sitl.fault_kinds import KINDS as FAULT_KINDS

    ps = spec(text)
    why = {kd.name: GROUP_REASONS[kd.group] for kd in FAULT_KINDS.values() if kd.group not in ps.kind.faults}
    return why | ps.kind.refusals(ps.model)


def plants_flying(fault_kind: str) -> tuple[str, ...]:
    """The plant kinds (``sitl.plant_kinds.KINDS``) that fly a fault kind: those whose ``faults`` list its record's
    group (a plant may still refuse it: ``fault_refusals``)."""
    from sitl.fault_kinds import KINDS as FAULT_KINDS

    return tuple(p for p, pk in KINDS.items() if FAULT_KINDS[fault_kind].group in pk.faults)


SERVO_SPAN_RAD = math.radians(30.0)  # the servo's +-30 deg at PWM 1000..2000 us (autopilot.shared.pwm)


def surfaces_of(text: str) -> tuple[str, ...]:
    """The plant's surfaces in its order: ``("rudder",)`` on the KH2013A, a square MIMO plant's
    ``("aileron", "rudder")``."""
    return spec(text).surfaces


def surface_travel_rad(text: str, span_rad: float = SERVO_SPAN_RAD) -> tuple[float, ...]:
    """How far each surface can move from neutral (rad, in ``surfaces_of``'s order): its stop (a plant file's
    ``limit``, a JSBSim surface's), else what the servo can be commanded to (``span_rad``, the PWM's +-30 deg: the
    KH2013A's rudder)."""
    return tuple(span_rad if lim is None else (min(lim, span_rad) if span_rad else lim) for lim in spec(text).travel)


def fault_value_refusal(text: str, fault, span_rad: float = SERVO_SPAN_RAD, surface: int | None = None) -> str | None:
    """Why this plant cannot fly ``fault``'s value (None: it can): a stuck position beyond the travel of the surface
    it hits (``surface``: its index, None for all of them), a JSBSim airspeed outside the aircraft's trim range (it
    does not trim there at its altitude), a cg shift beyond half the half span."""
    if fault.value is None:
        return None
    if fault.kind == "stuck":
        travel = surface_travel_rad(text, span_rad)
        names = surfaces_of(text)
        idx = range(len(travel)) if surface is None else (surface,)
        for i in idx:
            if abs(fault.value) > travel[i] * (1.0 + 1e-12):
                return (
                    f"{math.degrees(fault.value):.6g} deg is beyond the {names[i]}'s travel, "
                    f"+-{math.degrees(travel[i]):.6g} deg"
                )
        return None
    ps = spec(text)
    return ps.kind.value_refusal(ps.model, fault)


def check_faults(text: str, faults, span_rad: float = SERVO_SPAN_RAD) -> None:
    """PlantError if a fault (``sitl.damage.Fault``) cannot fly on this plant: its kind, or its value
    (``fault_value_refusal``: a stuck angle beyond the surface's travel, an airspeed it does not trim at, a cg
    shift too large)."""
    from sitl import damage

    why = fault_refusals(text)
    try:
        damage.check_kinds(faults, frozenset(damage.KINDS) - set(why), text, why)
    except damage.FaultSpecError as exc:
        raise PlantError(str(exc)) from None
    for f in faults:
        reason = fault_value_refusal(text, f, span_rad)
        if reason is not None:
            raise PlantError(f"--fault {f.spec} cannot fly on --plant {text}: {reason}")


def needs_damaged_model(faults) -> bool:
    """Whether a JSBSim plant must fly the model's copy with the fault properties (``sitl.jsbsim_damage``)."""
    from sitl.fault_kinds import KINDS as FAULT_KINDS

    return any(FAULT_KINDS[f.kind].jsbsim_property for f in faults)


def build(text: str, physics_rate_hz: float, params: dict | None = None, dist=None, damaged: bool = False) -> Plant:
    """The plant ``text`` names (its kind's ``construct``), at the physics rate; ``params``: KH2013A's perturbed
    matrices (``--scale``); ``dist``: the flight's ``sitl.disturbances.Disturbances`` (JSBSim takes its turbulence,
    crosswind and seed); ``damaged``: a JSBSim plant flies the model's copy with the fault properties
    (``needs_damaged_model``)."""
    ps = spec(text)
    return ps.kind.construct(ps, physics_rate_hz, params, dist, damaged)


# The SITL stops the flight once its plant has diverged: a truth state [v, p, r, phi, delta, delta_dot] (m/s, rad/s,
# rad/s, rad, rad, rad/s) not finite or beyond STATE_LIMIT.  An unstable plant is flown (it is a legitimate thing to
# fly) until then; far inside what ATTITUDE's float32 carries, far outside any aircraft.
STATE_LIMIT = 1e6
STATE_NAMES = ("v", "p", "r", "phi", "delta", "delta_dot")
STATE_UNITS = ("m/s", "rad/s", "rad/s", "rad", "rad", "rad/s")


def divergence(truth) -> str | None:
    """None while every entry of the truth state is finite and within ``STATE_LIMIT``, else which one is not."""
    total = float(truth.dot(truth))  # NaN or inf if an entry is
    if total < STATE_LIMIT * STATE_LIMIT:
        return None
    for name, unit, x in zip(STATE_NAMES, STATE_UNITS, truth.tolist()):
        if not math.isfinite(x):
            return f"{name} became {x} (not a finite number)"
        if abs(x) > STATE_LIMIT:
            return f"|{name}| reached {abs(x):.3g} {unit}, beyond the {STATE_LIMIT:g} the SITL flies"
    return None


def surface_of(text: str) -> str:
    """The surface the plant's command drives: ``rudder`` (the KH2013A), a plant file's ``[input] surface``, a JSBSim
    spec's ``surface`` (aileron by default)."""
    return spec(text).surface


def name_of(text: str) -> str:
    """The plant's short name (headers, titles, run folders): ``KH2013A``, the JSBSim model (``c172x``, with
    ``-rudder`` on its rudder), a plant file's ``name`` (else its file name)."""
    return spec(text).name


def surface_limit_rad(text: str) -> float | None:
    """The surface's deflection limit (rad) of a plant, None if unlimited (KH2013A, a file without ``limit``)."""
    return spec(text).travel[0]


__all__ = [
    "JSBSIM",
    "KH2013A",
    "STATE_LIMIT",
    "Plant",
    "PlantError",
    "PlantSpec",
    "build",
    "check",
    "check_disturbances",
    "divergence",
    "fault_value_refusal",
    "injected",
    "kind",
    "name_of",
    "plants_flying",
    "shipped",
    "spec",
    "surface_limit_rad",
    "surface_of",
    "surface_travel_rad",
    "surfaces_of",
]
