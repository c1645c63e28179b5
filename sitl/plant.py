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

import functools
import math
from dataclasses import replace

from sitl.linear_plant import PHYSICS_RATE_HZ
from sitl.plant_kinds import JSBSIM, KH2013A, KINDS, Plant, PlantError, PlantSpec, kind_of, shipped, spec

# Disturbance flags (sitl.disturbances.FLAGS) a plant kind cannot apply, and why (``PlantKind.unsupported``).
UNSUPPORTED = {name: k.unsupported for name, k in KINDS.items() if k.unsupported}


def kind(text: str) -> str:
    """The name of the plant's kind (``sitl.plant_kinds.KINDS``: ``kh2013a``, ``jsbsim`` or ``file``)."""
    return kind_of(text).name


def _load(text: str, physics_rate_hz: float | None = None):
    """The plant file ``text`` (``sitl.linear_plant.load``), its physics step checked at ``physics_rate_hz`` (None: not
    checked); PlantError with the one-line reason."""
    return spec(text).model if physics_rate_hz is None else KINDS["file"].parse(text, physics_rate_hz)


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
    air = [d for d in ATMOSPHERE if given.get(d) is not None]
    lp = spec(text).linear if air else None
    if lp is not None and lp.truth is not None:
        # the gusts enter through the aerodynamic columns of v, p, r (sitl.atmosphere.disturbance_matrix)
        raise PlantError(
            f"--{air[0].replace('_', '-')} cannot fly on --plant {text}: the atmosphere needs the airframe states "
            "[v, p, r, phi], in that order"
        )
    scaled = [d for d in air if d != "crosswind"]  # a steady crosswind is a side velocity: no scale to it
    if scaled and lp is not None and lp.airspeed_m_s is None:
        raise PlantError(
            f"--{scaled[0].replace('_', '-')} cannot fly on --plant {text}: the Dryden turbulence and the gusts are "
            "scaled to the aircraft, and the file does not say which: give [atmosphere] airspeed = M/S and span = M "
            "(and altitude = M) in it"
        )
    alt = lp.altitude_m if scaled and lp is not None else None
    if alt is not None and given.get("turbulence") is not None and not 3.048 <= alt <= 304.8:
        raise PlantError(
            f"--turbulence cannot fly on --plant {text}: its [atmosphere] altitude {alt:g} m is outside the "
            "low-altitude Dryden model (3.05..304.8 m, 10..1000 ft)"
        )


def injected(text: str, dist):
    """What ``sitl.disturbances.Injector`` applies on this plant: everything but the atmosphere for JSBSim (it flies
    its own, at the aircraft's airspeed and altitude); on a plant file the atmosphere scaled to its ``[atmosphere]``
    airspeed, span and altitude (``scaled_atmosphere``); all of it, as given, on the KH2013A."""
    if dist is None:
        return dist
    ps = spec(text)
    if ps.own_atmosphere:
        from sitl.atmosphere import AtmosphereConfig

        return replace(dist, atmosphere=AtmosphereConfig())
    if ps.linear is not None:
        return replace(dist, atmosphere=scaled_atmosphere(ps.linear, dist.atmosphere))
    return dist


def scaled_atmosphere(lp, atm):
    """``atm`` (``sitl.atmosphere.AtmosphereConfig``) for the aircraft of plant file ``lp``: the Dryden filters and
    the gusts at its airspeed and span; a --turbulence intensity at its altitude too, unless --altitude, the sigmas
    or the scale lengths were given.  Unchanged without ``[atmosphere]`` (only a crosswind is then allowed)."""
    if lp.airspeed_m_s is None:
        return atm
    from sitl.atmosphere import ALTITUDE, DrydenConfig

    turb = atm.turbulence
    if turb is not None:
        name = next((n for n in ("light", "moderate", "severe") if DrydenConfig.intensity(n, ALTITUDE) == turb), None)
        if name is not None and lp.altitude_m is not None:
            turb = DrydenConfig.intensity(name, lp.altitude_m)
        turb = replace(turb, airspeed=lp.airspeed_m_s, span=lp.span_m)
    gusts = tuple(replace(g, airspeed=lp.airspeed_m_s) for g in atm.gusts)
    return replace(atm, turbulence=turb, gusts=gusts)


def fault_refusals(text: str) -> dict[str, str]:
    """The fault kinds (``sitl.fault_kinds.KINDS``) this plant cannot fly, each with the reason: a kind of a group
    its kind does not fly (``PlantKind.faults``), a JSBSim model's own (``sitl.jsbsim_damage.refusals``), damping on
    a plant file whose roll rate is no state."""
    from sitl import damage
    from sitl.fault_kinds import GROUP_REASONS

    ps = spec(text)
    if ps.jsbsim is not None:
        from sitl.jsbsim_damage import refusals
        from sitl.jsbsim_plant import _root

        m = ps.jsbsim
        return refusals(_root() / "aircraft" / m.model / f"{m.model}.xml", m.surfaces[0])
    why = {kd.name: GROUP_REASONS[kd.group] for kd in damage.KINDS.values() if kd.group not in ps.kind.faults}
    if ps.linear is not None and damage.roll_rate_index(ps.linear.truth) is None:
        why["damping"] = "the plant file's roll rate is not one of its states (a transfer function)"
    return why


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
    js = spec(text).jsbsim
    if js is None or fault.kind not in ("airspeed", "cg"):
        return None
    if fault.kind == "airspeed":
        kt = fault.value / (1852.0 / 3600.0)
        if not _trims(js.model, round(kt, 9), js.altitude_m):
            return f"{js.model} does not trim in level flight at {kt:.6g} kt, {js.altitude_m:g} m (its trim range)"
        return None
    from sitl.jsbsim_damage import anatomy
    from sitl.jsbsim_plant import _root

    span = anatomy(_root() / "aircraft" / js.model / f"{js.model}.xml", js.surfaces[0]).span_ft
    most = 0.25 * span * 0.3048 if span else None  # half the half span: a tip ballast as heavy as the aircraft
    if most and abs(fault.value) > most:
        return f"beyond {most:.2f} m (half the half span) the wing-tip ballast would weigh more than the aircraft"
    return None


@functools.lru_cache(maxsize=64)
def _trims(model: str, kt: float, altitude_m: float) -> bool:
    """Whether JSBSim's ``model`` trims in level flight at ``kt`` knots and ``altitude_m`` (one trim)."""
    from sitl.jsbsim_models import quiet_stdio
    from sitl.jsbsim_plant import JsbsimPlantError, JsbsimSpec, trimmed_fdm

    with quiet_stdio():  # JSBSim's chatter ("Sorry, udot doesn't appear to be trimmable")
        try:
            trimmed_fdm(JsbsimSpec(model, airspeed_kt=kt, altitude_m=altitude_m), 0.01, suggest=False)
        except JsbsimPlantError:
            return False
    return True


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
