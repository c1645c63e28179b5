"""The SITL's plants behind one interface (``--plant``), like ArduPilot's SIM_Aircraft.  No I/O but the plant file.

A plant has ``advance(delta_command, n, d=None)`` (n physics steps with the servo command held and the
disturbance d, if any, per step), ``truth`` ([v, p, r, phi, delta, delta_dot], ``sitl.model.STATE_NAMES``),
``attitude()`` (roll, pitch, yaw or None, p, q, r), ``steps``, ``time`` and ``config.dt``.  Three kinds:

- ``kh2013a`` (the default): the paper's model, ``sitl.aircraft.Aircraft``;
- ``FILE.toml``: a linear plant of your own (``sitl.linear_plant``), flown by the same ``Aircraft``;
- ``jsbsim:MODEL[:KEY=VALUE,...]``: a JSBSim aircraft (``sitl.jsbsim_plant``).
"""

from __future__ import annotations

import functools
import math
from dataclasses import replace
from importlib import resources
from pathlib import Path

from sitl.aircraft import Aircraft, AircraftConfig
from sitl.linear_plant import PHYSICS_RATE_HZ, PlantFileError
from sitl.linear_plant import load as load_file

KH2013A = "kh2013a"
JSBSIM = "jsbsim:"
# Disturbance flags (sitl.disturbances.FLAGS) a plant kind cannot apply, and why.
UNSUPPORTED = {
    "file": {"scale": "--scale names KH2013A coefficients"},
    "jsbsim": {
        "scale": "--scale names KH2013A coefficients",
        "gust": "--gust is a KH2013A side-gust model (JSBSim flies its own atmosphere: use --turbulence)",
        "turbulence_sigma": "JSBSim's MIL-F-8785C turbulence takes an intensity only (--turbulence)",
        "turbulence_length": "JSBSim's MIL-F-8785C turbulence takes an intensity only (--turbulence)",
        "altitude": "the JSBSim altitude is the plant's own: jsbsim:MODEL:altitude_m=M",
    },
}


class PlantError(ValueError):
    """A --plant value is unusable (a bad file, a bad JSBSim spec or model, a disturbance it cannot fly)."""


def kind(text: str) -> str:
    """``kh2013a``, ``jsbsim`` or ``file``."""
    if text == KH2013A:
        return "kh2013a"
    return "jsbsim" if text.startswith(JSBSIM) else "file"


def shipped(name: str) -> Path:
    """A plant file shipped with the package (``sitl/plants/NAME``)."""
    return Path(str(resources.files("sitl") / "plants" / name))


def _load(text: str, physics_rate_hz: float | None = None):
    """The plant file ``text`` (``sitl.linear_plant.load``), its physics step checked at ``physics_rate_hz`` (None: not
    checked); PlantError with the one-line reason."""
    try:
        return load_file(text, physics_rate_hz)
    except PlantFileError as exc:
        raise PlantError(str(exc)) from None


def check(text: str, physics_rate_hz: float | None = PHYSICS_RATE_HZ) -> str:
    """Validate a --plant value (file parsed and checked, its physics step at ``physics_rate_hz`` unless None;
    JSBSim spec parsed and its model found); returns it.  Raises PlantError with a one-line reason."""
    k = kind(text)
    try:
        if k == "file":
            _load(text, physics_rate_hz)
        elif k == "jsbsim":
            from sitl.jsbsim_models import pilot_gains
            from sitl.jsbsim_plant import JsbsimPlantError, available_models, parse_spec

            try:
                spec = parse_spec(text)
                if spec.model not in available_models():
                    raise JsbsimPlantError(
                        f"jsbsim plant: no model {spec.model!r}; available: {', '.join(available_models())}"
                    )
                _ = spec.surface_maps  # the model's own command -> deflection, or why it has none in rad
                pilot_gains(spec.model)  # the safety pilot holds it, or says why not
            except JsbsimPlantError as exc:
                raise PlantError(str(exc)) from None
    except PlantFileError as exc:
        raise PlantError(str(exc)) from None
    return text


ATMOSPHERE = ("turbulence", "turbulence_sigma", "turbulence_length", "gust", "crosswind")


def check_disturbances(text: str, given: dict) -> None:
    """Raise PlantError if a disturbance flag given (``{dest: value}``, None = not given) cannot fly on this plant."""
    for dest, why in UNSUPPORTED.get(kind(text), {}).items():
        if given.get(dest) is not None:
            raise PlantError(f"--{dest.replace('_', '-')} cannot fly on --plant {text}: {why}")
    air = [d for d in ATMOSPHERE if given.get(d) is not None]
    if air and kind(text) == "file" and _load(text).truth is not None:
        # the gusts enter through the aerodynamic columns of v, p, r (sitl.atmosphere.disturbance_matrix)
        raise PlantError(
            f"--{air[0].replace('_', '-')} cannot fly on --plant {text}: the atmosphere needs the airframe states "
            "[v, p, r, phi], in that order"
        )
    scaled = [d for d in air if d != "crosswind"]  # a steady crosswind is a side velocity: no scale to it
    if scaled and kind(text) == "file" and load_file(text).airspeed_m_s is None:
        raise PlantError(
            f"--{scaled[0].replace('_', '-')} cannot fly on --plant {text}: the Dryden turbulence and the gusts are "
            "scaled to the aircraft, and the file does not say which: give [atmosphere] airspeed = M/S and span = M "
            "(and altitude = M) in it"
        )
    alt = load_file(text).altitude_m if scaled and kind(text) == "file" else None
    if alt is not None and given.get("turbulence") is not None and not 3.048 <= alt <= 304.8:
        raise PlantError(
            f"--turbulence cannot fly on --plant {text}: its [atmosphere] altitude {alt:g} m is outside the "
            "low-altitude Dryden model (3.05..304.8 m, 10..1000 ft)"
        )


def injected(text: str, dist):
    """What ``sitl.disturbances.Injector`` applies on this plant: everything but the atmosphere for JSBSim (it flies
    its own, at the aircraft's airspeed and altitude); on a plant file the atmosphere scaled to its ``[atmosphere]``
    airspeed, span and altitude (``scaled_atmosphere``); all of it, as given, on the KH2013A."""
    if dist is None or kind(text) == "kh2013a":
        return dist
    if kind(text) == "file":
        return replace(dist, atmosphere=scaled_atmosphere(load_file(text), dist.atmosphere))
    from sitl.atmosphere import AtmosphereConfig

    return replace(dist, atmosphere=AtmosphereConfig())


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


def _turbulence_name(dist) -> str | None:
    """The --turbulence intensity behind ``dist`` (JSBSim plants take only the intensity, see UNSUPPORTED)."""
    from sitl.atmosphere import ALTITUDE, DrydenConfig

    turb = None if dist is None else dist.atmosphere.turbulence
    if turb is None:
        return None
    for name in ("light", "moderate", "severe"):
        if DrydenConfig.intensity(name, ALTITUDE) == turb:
            return name
    raise PlantError("JSBSim's MIL-F-8785C turbulence takes an intensity only (--turbulence)")


def fault_refusals(text: str) -> dict[str, str]:
    """The fault kinds (``sitl.damage.KINDS``) this plant cannot fly, each with the reason."""
    from sitl import damage

    k = kind(text)
    if k == "jsbsim":
        from sitl.jsbsim_damage import refusals
        from sitl.jsbsim_plant import _root, parse_spec

        spec = parse_spec(text)
        return refusals(_root() / "aircraft" / spec.model / f"{spec.model}.xml", spec.surfaces[0])
    why = {kd: "a JSBSim aircraft's mass properties and safety pilot only" for kd in damage.JSBSIM_KINDS}
    for kd in damage.LINEAR_KINDS:
        why.pop(kd)
    if k == "file" and damage.roll_rate_index(load_file(text).truth) is None:
        why["damping"] = "the plant file's roll rate is not one of its states (a transfer function)"
    return why


SERVO_SPAN_RAD = math.radians(30.0)  # the servo's +-30 deg at PWM 1000..2000 us (autopilot.shared.pwm)


def surfaces_of(text: str) -> tuple[str, ...]:
    """The plant's surfaces in its order: ``("rudder",)`` on the KH2013A, a square MIMO plant's
    ``("aileron", "rudder")``."""
    if kind(text) == "jsbsim":
        from sitl.jsbsim_plant import parse_spec

        return parse_spec(text).surfaces
    return (surface_of(text),)


def surface_travel_rad(text: str, span_rad: float = SERVO_SPAN_RAD) -> tuple[float, ...]:
    """How far each surface can move from neutral (rad, in ``surfaces_of``'s order): its stop (a plant file's
    ``limit``, a JSBSim surface's), else what the servo can be commanded to (``span_rad``, the PWM's +-30 deg: the
    KH2013A's rudder)."""
    k = kind(text)
    if k == "jsbsim":
        from sitl.jsbsim_plant import parse_spec

        return tuple(min(lim, span_rad) if span_rad else lim for lim in parse_spec(text).surface_limits_rad)
    lim = _load(text).limit_rad if k == "file" else None
    return (span_rad if lim is None else min(lim, span_rad),)


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
    if kind(text) != "jsbsim" or fault.kind not in ("airspeed", "cg"):
        return None
    from sitl.jsbsim_plant import parse_spec

    spec = parse_spec(text)
    if fault.kind == "airspeed":
        kt = fault.value / (1852.0 / 3600.0)
        if not _trims(spec.model, round(kt, 9), spec.altitude_m):
            return f"{spec.model} does not trim in level flight at {kt:.6g} kt, {spec.altitude_m:g} m (its trim range)"
        return None
    from sitl.jsbsim_damage import anatomy
    from sitl.jsbsim_plant import _root

    span = anatomy(_root() / "aircraft" / spec.model / f"{spec.model}.xml", spec.surfaces[0]).span_ft
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
    return any(f.kind in ("effectiveness", "damping", "inertia", "cg") for f in faults)


def build(text: str, physics_rate_hz: float, params: dict | None = None, dist=None, damaged: bool = False):
    """The plant ``text`` names, at the physics rate; ``params``: KH2013A's perturbed matrices (``--scale``);
    ``dist``: the flight's ``sitl.disturbances.Disturbances`` (JSBSim takes its turbulence, crosswind and seed);
    ``damaged``: a JSBSim plant flies the model's copy with the fault properties (``needs_damaged_model``)."""
    k = kind(text)
    if k == "kh2013a":
        return Aircraft(AircraftConfig(physics_rate_hz=physics_rate_hz), params=params)
    if k == "file":
        lp = _load(text, physics_rate_hz)  # its physics step checked at the rate it flies
        if lp.is_mimo:
            raise PlantError(
                f"{text}: a plant file of {lp.m} inputs is designed (python -m tools.pfc design) but not flown by the "
                "SITL: fly the JSBSim aircraft it was linearised from (jsbsim:MODEL:surface=aileron+rudder)"
            )
        cfg = AircraftConfig(
            physics_rate_hz=physics_rate_hz, rudder_limit_rad=lp.limit_rad, rudder_rate_limit_rad_s=lp.rate_limit_rad_s
        )
        return Aircraft(cfg, params=lp.aircraft_params())
    from sitl.jsbsim_plant import JsbsimPlant, JsbsimPlantError, parse_spec

    try:
        return JsbsimPlant(
            parse_spec(text),
            physics_rate_hz,
            turbulence=_turbulence_name(dist),
            seed=0 if dist is None else dist.seed,
            crosswind=0.0 if dist is None else dist.atmosphere.crosswind,
            damaged=damaged,
        )
    except JsbsimPlantError as exc:
        raise PlantError(str(exc)) from None


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
    k = kind(text)
    if k == "file":
        return load_file(text).surface
    if k == "jsbsim":
        from sitl.jsbsim_plant import parse_spec

        return parse_spec(text).surface
    return "rudder"


def name_of(text: str) -> str:
    """The plant's short name (headers, titles, run folders): ``KH2013A``, the JSBSim model (``c172x``, with
    ``-rudder`` on its rudder), a plant file's ``name`` (else its file name)."""
    k = kind(text)
    if k == "file":
        lp = load_file(text)
        return lp.name or Path(text).stem
    if k == "jsbsim":
        from sitl.jsbsim_plant import parse_spec

        spec = parse_spec(text)
        return spec.model + ("" if spec.surface == "aileron" else f"-{spec.surface}")
    return "KH2013A"


def surface_limit_rad(text: str) -> float | None:
    """The surface's deflection limit (rad) of a plant, None if unlimited (KH2013A, a file without ``limit``)."""
    k = kind(text)
    if k == "file":
        return _load(text).limit_rad
    if k == "jsbsim":
        from sitl.jsbsim_plant import parse_spec

        return parse_spec(text).surface_max_rad
    return None


__all__ = [
    "STATE_LIMIT",
    "PlantError",
    "build",
    "check",
    "check_disturbances",
    "divergence",
    "fault_value_refusal",
    "injected",
    "kind",
    "name_of",
    "shipped",
    "surface_limit_rad",
    "surface_of",
    "surface_travel_rad",
    "surfaces_of",
]
