"""What the SITL knows of each JSBSim aircraft it flies, from the model itself: the surface the roll loop drives
(:func:`surface_map`, measured on the model's own flight control system), the safety pilot's gains
(:data:`PILOTS`: the aircraft it was checked on, :func:`pilot_gains` refuses the others) and, when a trim fails,
the airspeeds that do trim (:func:`trimming_airspeeds`).

**The surface.**  The autopilot commands a deflection delta (rad) from the trim; JSBSim takes a normalised command
(``fcs/aileron-cmd-norm``, ``fcs/rudder-cmd-norm``, -1..1) that each model's flight control system maps to the
deflection its aerodynamics read (``AERO_PROPERTY``: c172x reads ``fcs/effective-aileron-pos`` = (left - right)/2,
most models ``fcs/left-aileron-pos-rad`` alone).  The mapping is measured on a throwaway copy of the model: the
command stepped to -0.9, -0.45, 0, 0.45, 0.9, each approached from -1 so that an actuator's hysteresis shifts every
reading alike, gives the deflection per unit command on each side (``positive_rad``, ``negative_rad``: pa28's
left aileron is 15 deg up and 30 deg down a unit, JSBSim's aerosurface_scale), checked piecewise linear.  The
same run gives the actuator's rate limit (the fastest the deflection moved, none if it jumps in one step) and its
hysteresis (backlash: the gap between 0 approached from above and from below).  c172x keeps its documented 17.5 deg
(aileron) and 16 deg (rudder) per unit (``KNOWN``): the measurement agrees to 0.02 % (JSBSim's 0.01745 for pi/180),
and every flight of it stays as before.

**JSBSim's step.**  JSBSim sizes its flight control components' time step when the model is loaded (its default,
1/120 s); the SITL loads the model and then sets its physics step (1 ms at 1 kHz), as ``trimmed_fdm`` always has.
An actuator's rate limit then acts per physics step as if each step were 1/120 s: c172x's aileron actuator, 1.57
rad/s in its file (90 deg/s), moves at most 1.57/120 rad a step, 13.1 rad/s at 1 kHz, and its lag filters run as
fast.  The mapping is measured the same way, at the SITL's physics rate, so ``rate_limit_rad_s`` is the rate the
SITL's aircraft flies (docs/jsbsim.md).
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

FT = 0.3048  # m per ft
COMMAND = {"aileron": "fcs/aileron-cmd-norm", "rudder": "fcs/rudder-cmd-norm"}
# The deflection (rad) the aerodynamics read, in order of preference (the first one a model's aerodynamics name).
AERO_PROPERTY = {
    "aileron": (
        "fcs/effective-aileron-pos",
        "fcs/aileron-pos-rad",
        "fcs/left-aileron-pos-rad",
        "fcs/right-aileron-pos-rad",
    ),
    "rudder": ("fcs/rudder-pos-rad",),
}
KNOWN = {("c172x", "aileron"): 17.5, ("c172x", "rudder"): 16.0}  # deg per unit command (docs/jsbsim.md)
PHYSICS_RATE_HZ = 1000.0  # the SITL's default physics rate, at which the mapping is measured
POINTS = (-0.9, -0.45, 0.0, 0.45, 0.9)  # normalised commands measured
LINEAR_RTOL = 1e-3  # the half-way points within this of the straight line: piecewise linear


class JsbsimPlantError(ValueError):
    """A JSBSim plant spec is malformed, its model does not exist, or the trim failed."""


def _root() -> Path:
    import jsbsim

    return Path(jsbsim.get_default_root_dir())


def available_models() -> list[str]:
    """The aircraft the installed JSBSim wheel ships (``aircraft/NAME/NAME.xml``)."""
    root = _root() / "aircraft"
    return sorted(d.name for d in root.iterdir() if (d / f"{d.name}.xml").is_file())


def _new_fdm():
    os.environ.setdefault("JSBSIM_DEBUG", "0")  # no start-up banner on the SITL's stdout
    import jsbsim

    fdm = jsbsim.FGFDMExec(None)  # None: the wheel's own root (its aircraft, engines, systems)
    fdm.set_debug_level(0)
    return fdm


def quiet_outputs(fdm) -> None:
    """The model's own <output> (c172x: JSBout172B.csv in the working folder, opened by run_ic even when disabled):
    pointed at the null device, and off."""
    n = 0
    while fdm.set_output_filename(n, os.devnull):
        n += 1
    fdm.disable_output()


@contextlib.contextmanager
def quiet_stdio():
    """File descriptors 1 and 2 to the null device for the block: JSBSim's C++ writes there directly (a failed trim's
    "Sorry, udot doesn't appear to be trimmable"), so Python's own redirection does not reach it."""
    import sys

    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        try:
            import ctypes

            ctypes.CDLL(None).fflush(None)  # C's and C++'s buffered output, to the null device too
        except (OSError, AttributeError):
            pass
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, null):
            os.close(fd)


def _aero_text(model: str) -> str:
    """The text of a model's <aerodynamics> (inline, or the file it names)."""
    folder = _root() / "aircraft" / model
    text = (folder / f"{model}.xml").read_text(errors="replace")
    m = re.search(r"<aerodynamics([^>]*)>(.*?)</aerodynamics>", text, re.S)
    if m:
        return m.group(2)
    m = re.search(r"<aerodynamics[^>]*file\s*=\s*\"([^\"]+)\"", text)
    if m:
        for name in (m.group(1), m.group(1) + ".xml"):
            if (folder / name).is_file():
                return (folder / name).read_text(errors="replace")
    return ""


def aero_property(model: str, surface: str) -> str:
    """The deflection property (rad) of ``surface`` that ``model``'s aerodynamics read; JsbsimPlantError if none of
    ``AERO_PROPERTY`` (e.g. a model that reads a normalised position only)."""
    text = _aero_text(model)
    for prop in AERO_PROPERTY[surface]:
        if re.search(re.escape(prop) + r"(?![\w\-])", text):
            return prop
    found = sorted(set(re.findall(r"fcs/[\w\-]*" + surface + r"[\w\-]*", text)))
    reads = f"reads {', '.join(found)}" if found else f"reads no {surface} position"
    raise JsbsimPlantError(
        f"jsbsim plant: {model}'s aerodynamics {reads}, not a deflection in rad ({', '.join(AERO_PROPERTY[surface])}): "
        f"give its scale, jsbsim:{model}:surface_max_deg=DEG"
    )


@dataclass(frozen=True)
class SurfaceMap:
    """How a model's normalised command moves the deflection its aerodynamics read, relative to a command of 0."""

    model: str
    surface: str
    prop: str  # the deflection property (rad), AERO_PROPERTY
    positive_rad: float  # deflection per unit positive command
    negative_rad: float  # per unit negative command
    rate_limit_rad_s: float | None = None  # the actuator's, None if the deflection follows the command at once
    hysteresis_rad: float = 0.0  # the actuator's backlash
    measured: bool = True  # False: KNOWN (c172x)

    @property
    def symmetric(self) -> bool:
        return self.positive_rad == self.negative_rad

    @property
    def limit_rad(self) -> float:
        """The stop the roll loop may command to on both sides (the smaller of the two)."""
        return min(self.positive_rad, self.negative_rad)

    def deflection(self, norm: float) -> float:
        """The deflection (rad, relative to a command of 0) of a normalised command."""
        return norm * (self.positive_rad if norm >= 0.0 else self.negative_rad)

    def command(self, deflection: float) -> float:
        """The normalised command (not clipped) that gives ``deflection`` (rad, relative to a command of 0)."""
        return deflection / (self.positive_rad if deflection >= 0.0 else self.negative_rad)

    def slope(self, norm: float) -> float:
        """rad per unit command at ``norm`` (the mean of both sides at 0)."""
        if norm > 0.0:
            return self.positive_rad
        return self.negative_rad if norm < 0.0 else 0.5 * (self.positive_rad + self.negative_rad)

    def describe(self) -> str:
        side = (
            f"{math.degrees(self.positive_rad):.4g} deg per unit command"
            if self.symmetric
            else f"{math.degrees(self.positive_rad):.4g} deg per unit positive, {math.degrees(self.negative_rad):.4g} "
            "per unit negative command"
        )
        how = "measured on the model" if self.measured else "c172x's documented scale"
        rate = "" if self.rate_limit_rad_s is None else f"; actuator rate limit {self.rate_limit_rad_s:.4g} rad/s"
        hyst = f", hysteresis {self.hysteresis_rad:.4g} rad" if self.hysteresis_rad > 1e-9 else ""
        return f"{self.prop}: {side} ({how}){rate}{hyst}"


def _settle(fdm, cmd_node, prop_node, value: float, dt: float, max_steps: int = 5000) -> tuple[float, list[float]]:
    """The command to ``value`` and the model stepped until the deflection stops moving: (deflection, its rate in
    each step it moved, rad/s)."""
    cmd_node.set_double_value(value)
    last, still, rates = prop_node.get_double_value(), 0, []
    for _ in range(max_steps):
        fdm.run()
        now = prop_node.get_double_value()
        if abs(now - last) >= 1e-12:
            rates.append(abs(now - last) / dt)
        still = still + 1 if abs(now - last) < 1e-12 else 0
        last = now
        if still >= 3:
            break
    return last, rates


def _rate_limit(rates: list[float]) -> float | None:
    """The rate a move ran at in most of its steps (a rate limit), None if it jumped or slowed down (a lag)."""
    if len(rates) < 4:
        return None
    mid = sorted(rates)[len(rates) // 2]
    steady = sum(1 for r in rates if abs(r - mid) <= 0.01 * mid)
    return mid if steady >= 0.5 * len(rates) else None


@functools.cache
def _measure(model: str, surface: str, airspeed_kt: float, altitude_m: float, physics_rate_hz: float) -> SurfaceMap:
    with quiet_stdio():  # JSBSim's chatter while loading a model (its refusal is the one line raised)
        return _measure_quietly(model, surface, airspeed_kt, altitude_m, physics_rate_hz)


def _measure_quietly(model: str, surface: str, airspeed_kt: float, altitude_m: float, physics_rate_hz: float):
    """``surface``'s mapping on ``model``, flown at the given condition on a throwaway copy stepped as the SITL steps
    it (its step set after the model is loaded: module docstring, "JSBSim's step"), at ``physics_rate_hz``."""
    prop = aero_property(model, surface)
    fdm = _new_fdm()
    if not fdm.load_model(model):
        raise JsbsimPlantError(f"jsbsim plant: JSBSim could not load model {model!r}")
    quiet_outputs(fdm)
    dt = 1.0 / physics_rate_hz
    fdm.set_dt(dt)
    fdm["ic/vc-kts"] = airspeed_kt
    fdm["ic/h-sl-ft"] = altitude_m / FT
    try:
        fdm.run_ic()
    except Exception as exc:  # noqa: BLE001  (JSBSim's own errors: a model that needs FlightGear's properties)
        raise JsbsimPlantError(f"jsbsim plant: JSBSim cannot fly {model} on its own: {exc}") from None
    pm = fdm.get_property_manager()
    cmd, pos = pm.get_node(COMMAND[surface]), pm.get_node(prop)
    if cmd is None or pos is None:
        raise JsbsimPlantError(f"jsbsim plant: {model} has no {COMMAND[surface]} or {prop}")
    values, move = {}, []
    for x in POINTS:
        _settle(fdm, cmd, pos, -1.0, dt)
        values[x], rates = _settle(fdm, cmd, pos, x, dt)
        move = rates if x == POINTS[-1] else move  # the longest move, -1 to 0.9
    _settle(fdm, cmd, pos, 1.0, dt)
    from_above, _ = _settle(fdm, cmd, pos, 0.0, dt)
    cmd.set_double_value(0.0)
    zero = values[0.0]
    kp, kn = (abs(values[x] - zero) / abs(x) for x in (0.9, -0.9))
    for x, k in ((0.45, kp), (-0.45, kn)):
        if not math.isfinite(k) or k <= 0.0 or abs(abs(values[x] - zero) - k * abs(x)) > LINEAR_RTOL * k:
            raise JsbsimPlantError(
                f"jsbsim plant: {model}'s {surface} does not move in proportion to its command ({prop} at "
                + ", ".join(f"{v:+.4g} rad at {c:+g}" for c, v in values.items())
                + f"): give its scale, jsbsim:{model}:surface_max_deg=DEG"
            )
    return SurfaceMap(model, surface, prop, kp, kn, _rate_limit(move), max(0.0, from_above - zero))


def surface_map(
    model: str,
    surface: str,
    airspeed_kt: float = 90.0,
    altitude_m: float = 1000.0,
    physics_rate_hz: float = PHYSICS_RATE_HZ,
) -> SurfaceMap:
    """How ``model``'s command moves its ``surface`` (module docstring); c172x: ``KNOWN``, with the actuator's rate
    limit and hysteresis measured.  Raises JsbsimPlantError when the model's aerodynamics read no deflection in rad
    or its command does not map linearly on each side."""
    m = _measure(model, surface, float(airspeed_kt), float(altitude_m), float(physics_rate_hz))
    deg = KNOWN.get((model, surface))
    if deg is None:
        return m
    k = math.radians(deg)
    return SurfaceMap(model, surface, m.prop, k, k, m.rate_limit_rad_s, m.hysteresis_rad, measured=False)


# ------------------------------------------------------------------------------------------ the safety pilot
@dataclass(frozen=True)
class PilotGains:
    """The safety pilot's loops (``sitl.jsbsim_plant.SafetyPilot``; SI: rad, m, m/s): tuned on c172x at 100 kt."""

    k_h: float = 0.01  # pitch per m of altitude error
    k_hdot: float = 0.02  # pitch per m/s of climb rate
    theta_max: float = math.radians(5.0)  # the pitch offset's bound
    k_theta: float = 4.0  # elevator per rad of pitch error
    k_i: float = 1.0  # per rad s
    k_q: float = 1.5  # per rad/s of pitch rate
    k_v: float = 0.05  # throttle per m/s of airspeed error
    k_vi: float = 0.01  # per m


PILOT = PilotGains()
# The aircraft the safety pilot holds, each with the airspeed (kt) it was checked at, at 1000 m: a roll PD flying
# +-10 deg roll steps for 30 s, the altitude held within PILOT_HOLDS_M and the airspeed within PILOT_HOLDS_M_S
# (tests/sitl/test_jsbsim_models.py flies them again).  All with the c172x's gains.
PILOTS = {
    "737": 190.0,
    "787-8": 180.0,
    "A320": 180.0,
    "A4": 130.0,
    "B747": 170.0,
    "Boeing314": 90.0,
    "DHC6": 90.0,
    "J3Cub": 60.0,
    "OV10": 120.0,
    "T37": 90.0,
    "c172p": 90.0,
    "c172r": 90.0,
    "c172x": 90.0,
    "c182": 90.0,
    "global5000": 160.0,
    "pa28": 90.0,
    "t6texan2": 90.0,
}
PILOT_HOLDS_M, PILOT_HOLDS_M_S = 5.0, 1.5
# Those that trim but that it does not hold with these gains, and what it did (the same check).
PILOT_FAILS = {
    "B17": "lost 177 m of altitude in 30 s at 100 kt",
    "Camel": "let the airspeed drift 2.7 m/s in 30 s at 90 kt",
    "Concorde": "lost 225 m of altitude in 30 s at 200 kt",
    "F4N": "lost 301 m of altitude in 30 s at 150 kt",
    "MD11": "lost 13 m of altitude and 2.1 m/s in 30 s at 180 kt",
    "XB-70": "lost the aircraft (1 km of altitude) in 30 s at 170 kt",
    "f15": "lost 675 m of altitude in 30 s at 140 kt",
    "pogo-jsbsim": "let the airspeed drift 15 m/s in 30 s at 230 kt",
}


def pilot_gains(model: str) -> PilotGains:
    """The safety pilot's gains for ``model``; JsbsimPlantError for an aircraft it does not hold (``PILOTS``)."""
    if model in PILOTS:
        return PILOT
    held = ", ".join(sorted(PILOTS, key=str.lower))
    why = PILOT_FAILS.get(model, "not checked")
    raise JsbsimPlantError(
        f"jsbsim plant: the SITL's safety pilot (altitude and airspeed hold) does not fly {model}: {why}; it holds "
        f"{held}"
    )
