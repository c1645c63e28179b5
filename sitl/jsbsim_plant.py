"""A JSBSim aircraft behind the SITL's plant interface (``--plant jsbsim:MODEL[:KEY=VALUE,...]``).

JSBSim's nonlinear 6-DOF model (the wheel's own aircraft, nothing downloaded), trimmed in level flight at the
requested airspeed and altitude (``simulation/do_simple_trim``), stepped at the physics rate.  The autopilot's
command goes through the servo (paper eq. (65) form, exact ZOH per physics step) to the chosen surface, added to
the trim deflection: ``fcs/aileron-cmd-norm`` (or ``fcs/rudder-cmd-norm``) = the command whose deflection is the
trim's plus sign delta, through the model's own mapping of command to deflection (``sitl.jsbsim_models.surface_map``:
measured on the model; c172x: trim + sign delta / 17.5 deg), the sign (``SURFACE_SIGN``) making a positive command
roll the aircraft right.

The axes the roll autopilot does not fly are held by the SITL's safety pilot (:class:`SafetyPilot`), every
``PILOT_EVERY`` physics steps counted from the start, so its rate does not depend on how the steps are chunked:
  - altitude: theta_ref = theta_trim + sat(k_h (h_trim - h) - k_hdot h', +-theta_max), and the elevator
    delta_e = -(k_theta e + k_i int e - k_q q), e = theta_ref - theta, added to the trim;
  - airspeed: throttle = trim + k_v (V_trim - V) + k_vi int (V_trim - V), clipped to [0, 1]
(``sitl.jsbsim_models.PilotGains``; the aircraft it holds, ``PILOTS``, the others refused in one line).
(c172x's own ``c172ap.xml`` altitude hold was tried: it oscillates +-3 deg in pitch and rolls the aircraft by
1.2 deg within 60 s, so the product flies these documented loops instead.)

The truth state is [v, p, r, phi, delta, delta_dot] (``sitl.model.STATE_NAMES``: body side velocity m/s, body
rates rad/s, roll rad, the servo's deflection rad and rate rad/s); :meth:`attitude` gives JSBSim's roll, pitch,
yaw (heading, wrapped to (-pi, pi]) and body rates.  Turbulence is JSBSim's own MIL-F-8785C model, seeded with
``simulation/randomseed``.  Units: SI inside, knots only in the spec's ``airspeed_kt``.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, replace

import numpy as np

from autopilot.shared.numerics import wrap_pi, zoh
from sitl import damage, model
from sitl.jsbsim_models import (
    PILOT,
    JsbsimPlantError,
    PilotGains,
    SurfaceMap,
    _new_fdm,
    _root,
    available_models,
    pilot_gains,
    surface_map,
)

FT = 0.3048  # m per ft
KT = 1852.0 / 3600.0  # m/s per kt
PILOT_EVERY = 10  # safety pilot period in physics steps (100 Hz at 1 kHz physics)
# Safety pilot gains (SI: rad, m, m/s): sitl.jsbsim_models.PilotGains, tuned on c172x at 100 kt: +-10 deg roll steps
# hold 1000 m to 1 m (default flight condition 90 kt, 1000 m: 0.7x and 1.3x of it, 63 and 117 kt, still trim; 130 kt
# does not); the aircraft they hold: sitl.jsbsim_models.PILOTS (the others are refused).
# MIL-F-8785C turbulence as JSBSim offers it (atmosphere/turb-type 3): wind at 20 ft (kt) and the
# probability-of-exceedance index (3: 1e-2 light, 4: 1e-3 moderate, 6: 1e-5 severe).
TURBULENCE = {"light": (15.0, 3), "moderate": (30.0, 4), "severe": (45.0, 6)}
SURFACES = {"aileron": "fcs/aileron-cmd-norm", "rudder": "fcs/rudder-cmd-norm"}
# JSBSim's signs: a positive aileron command rolls right, a positive rudder command yaws and then rolls left.  The
# command is mapped with this sign so that a positive command rolls right, as the law assumes (hf gain > 0).
SURFACE_SIGN = {"aileron": 1.0, "rudder": -1.0}
# Square MIMO plants (docs/plants.md, "m inputs, m outputs"): a ``surface`` naming several surfaces flies one output
# on each, in order: the roll angle on the aileron, the sideslip angle on the rudder (sideslip command 0 by default:
# coordinated flight).  Each surface's sign there makes its own output's high-frequency gain positive: the aileron's
# as above (rolls right), the rudder's JSBSim's own (a positive rudder command yaws the nose left, which raises the
# sideslip beta, the wind from the right).
MIMO = {"aileron+rudder": (("aileron", "phi"), ("rudder", "beta"))}
MIMO_SIGN = {"aileron": 1.0, "rudder": 1.0}
SLUG_LB = 32.174049  # lb per slug (JSBSim's slugtolb)


@dataclass(frozen=True)
class JsbsimSpec:
    """``jsbsim:MODEL[:airspeed_kt=KT,altitude_m=M,surface=aileron|rudder,surface_max_deg=DEG]``."""

    model: str = "c172x"
    airspeed_kt: float = 90.0
    altitude_m: float = 1000.0
    surface: str = "aileron"
    surface_max_deg: float | None = None  # deg of surface per unit normalised command; default the model's (measured)

    def __post_init__(self) -> None:
        if self.surface not in SURFACES and self.surface not in MIMO:
            raise JsbsimPlantError(
                f"jsbsim plant: surface must be aileron, rudder or {', '.join(MIMO)}, got {self.surface!r}"
            )
        for name in ("airspeed_kt", "altitude_m", "surface_max_deg"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise JsbsimPlantError(f"jsbsim plant: {name} must be positive and finite, got {v!r}")
            lo, hi = SPEC_RANGES[name]
            if v is not None and not lo <= v <= hi:
                raise JsbsimPlantError(f"jsbsim plant: {name} must be in [{lo:g}, {hi:g}], got {v!r}")

    @property
    def surfaces(self) -> tuple[str, ...]:
        """The surfaces flown, one per input: (surface,), or a MIMO plant's in order (``MIMO``)."""
        return tuple(s for s, _ in MIMO[self.surface]) if self.surface in MIMO else (self.surface,)

    @property
    def outputs(self) -> tuple[str, ...]:
        """The outputs flown, one per surface: ("phi",), or a MIMO plant's (``MIMO``: phi on the aileron, beta on the
        rudder)."""
        return tuple(y for _, y in MIMO[self.surface]) if self.surface in MIMO else ("phi",)

    @property
    def is_mimo(self) -> bool:
        return self.surface in MIMO

    @property
    def signs(self) -> tuple[float, ...]:
        """Each surface's sign from the law's command to JSBSim's (``SURFACE_SIGN``; MIMO: ``MIMO_SIGN``)."""
        return tuple((MIMO_SIGN if self.is_mimo else SURFACE_SIGN)[s] for s in self.surfaces)

    @property
    def surface_maps(self) -> tuple[SurfaceMap, ...]:
        """Each surface's ``surface_map``, in the order of ``surfaces``."""
        if not self.is_mimo:
            return (self.surface_map,)
        return tuple(replace(self, surface=s).surface_map for s in self.surfaces)

    @property
    def surface_limits_rad(self) -> tuple[float, ...]:
        """Each surface's stop (``surface_max_rad``), in the order of ``surfaces``."""
        return tuple(m.limit_rad for m in self.surface_maps)

    @property
    def surface_map(self) -> SurfaceMap:
        """How the command moves the surface (a MIMO plant: its first surface's, the aileron's): ``surface_max_deg``
        on both sides if given, else the model's own
        (``sitl.jsbsim_models.surface_map``, measured at this airspeed and altitude)."""
        if self.surface_max_deg is None:
            return surface_map(self.model, self.surfaces[0], self.airspeed_kt, self.altitude_m)
        k = math.radians(self.surface_max_deg)
        try:
            m = surface_map(self.model, self.surfaces[0], self.airspeed_kt, self.altitude_m)
        except JsbsimPlantError:  # a scale the model's aerodynamics do not give in rad: the one given
            return SurfaceMap(self.model, self.surfaces[0], SURFACES[self.surfaces[0]], k, k, measured=False)
        return replace(m, positive_rad=k, negative_rad=k, measured=False)

    @property
    def surface_max_rad(self) -> float:
        """The surface's stop relative to neutral, the same on both sides (the smaller side of an asymmetric one)."""
        return self.surface_map.limit_rad

    def text(self, short: bool = False) -> str:
        """The spec string back (``jsbsim:c172x:airspeed_kt=100.0,...``); ``short``: only the keys that differ from
        the defaults, numbers as typed (``jsbsim:J3Cub:airspeed_kt=60``)."""
        keys = ("airspeed_kt", "altitude_m", "surface") + (("surface_max_deg",) if self.surface_max_deg else ())
        if not short:
            return f"jsbsim:{self.model}:" + ",".join(f"{k}={getattr(self, k)}" for k in keys)
        default = JsbsimSpec(model=self.model)
        parts = [k for k in keys if getattr(self, k) != getattr(default, k)]
        value = {
            k: (f"{getattr(self, k):g}" if isinstance(getattr(self, k), float) else getattr(self, k)) for k in parts
        }
        return f"jsbsim:{self.model}" + (":" + ",".join(f"{k}={value[k]}" for k in parts) if parts else "")


# What a spec's numbers may be: a trim the aircraft can fly, and a surface stop an aircraft has (deg per unit
# normalised command; c172x's aileron 17.5).  Outside, refused by name before JSBSim is asked.
SPEC_RANGES = {"airspeed_kt": (1.0, 5000.0), "altitude_m": (1.0, 100_000.0), "surface_max_deg": (1.0, 90.0)}
SPEC_KEYS = ("airspeed_kt", "altitude_m", "surface", "surface_max_deg")
_NUMBER = re.compile(r"[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?")  # a decimal number; no '1_0_0', 'inf' or spaces


def parse_spec(text: str) -> JsbsimSpec:
    """``jsbsim:MODEL[:KEY=VALUE,...]`` -> JsbsimSpec; raises JsbsimPlantError naming the bad part.  Strict: each key
    once, plain decimal numbers within ``SPEC_RANGES``, nothing empty (no trailing ':' or ',')."""
    parts = text.split(":", 2)
    if len(parts) < 2 or parts[0] != "jsbsim" or not parts[1]:
        raise JsbsimPlantError(f"expected jsbsim:MODEL[:KEY=VALUE,...], got {text!r}")
    spec = JsbsimSpec(model=parts[1])
    if len(parts) == 3:
        if not parts[2]:
            raise JsbsimPlantError(f"jsbsim plant: nothing after the last ':' in {text!r} (give KEY=VALUE or no ':')")
        changes = {}
        for item in parts[2].split(","):
            key, sep, value = item.partition("=")
            if not sep or key not in SPEC_KEYS:
                raise JsbsimPlantError(
                    f"jsbsim plant: expected KEY=VALUE with KEY one of {', '.join(SPEC_KEYS)}, got {item!r}"
                )
            if key in changes:
                raise JsbsimPlantError(f"jsbsim plant: {key} given twice in {text!r}")
            if key == "surface":
                changes[key] = value
                continue
            if not _NUMBER.fullmatch(value):
                raise JsbsimPlantError(f"jsbsim plant: {key} must be a decimal number, got {value!r}")
            changes[key] = float(value)
        spec = replace(spec, **changes)
    return spec


def _load_damaged(fdm, spec: JsbsimSpec):
    """Load the model's copy with the fault properties (``sitl.jsbsim_damage``) from a temporary folder, deleted
    once loaded; False if JSBSim could not load it."""
    import tempfile

    from sitl import jsbsim_damage

    root = _root()
    with tempfile.TemporaryDirectory(prefix="clsac-jsbsim-") as tmp:
        jsbsim_damage.write_model(root / "aircraft" / spec.model, tmp, spec.model, spec.surfaces[0])
        return fdm.load_model_with_paths(spec.model, tmp, str(root / "engine"), str(root / "systems"))


def trimmed_fdm(spec: JsbsimSpec, dt: float, seed: int = 0, damaged: bool = False, suggest: bool = True):
    """A JSBSim executive with ``spec.model`` loaded and trimmed in wings-level flight; raises JsbsimPlantError
    (a failed trim names the airspeeds that do trim there, unless ``suggest`` is False).  ``damaged``: the model's
    copy with the fault properties and ballast (``sitl.jsbsim_damage``)."""
    import jsbsim

    if spec.model not in available_models():
        raise JsbsimPlantError(f"jsbsim plant: no model {spec.model!r}; available: {', '.join(available_models())}")
    fdm = _new_fdm()
    try:
        return _trim(fdm, spec, dt, seed, damaged, suggest)
    except jsbsim.BaseError as exc:  # e.g. a property the model reads and nothing defines (L17, f104, fokker50, ...)
        why = " ".join(str(exc).split()) or type(exc).__name__
        raise JsbsimPlantError(f"jsbsim plant: JSBSim cannot initialise model {spec.model!r}: {why}") from None


def _trim(fdm, spec: JsbsimSpec, dt: float, seed: int, damaged: bool, suggest: bool):
    import jsbsim

    if not (_load_damaged(fdm, spec) if damaged else fdm.load_model(spec.model)):
        raise JsbsimPlantError(f"jsbsim plant: JSBSim could not load model {spec.model!r}")
    # The model's own <output> (c172x: JSBout172B.csv in the working folder, opened by run_ic even when disabled):
    # pointed at the null device, and off.
    n = 0
    while fdm.set_output_filename(n, os.devnull):
        n += 1
    fdm.disable_output()
    fdm.set_dt(dt)
    fdm["simulation/randomseed"] = float(seed)
    fdm["ic/vc-kts"] = spec.airspeed_kt
    fdm["ic/h-sl-ft"] = spec.altitude_m / FT
    fdm["ic/psi-true-deg"] = 0.0
    try:
        fdm.run_ic()
    except Exception as exc:  # noqa: BLE001  (JSBSim's own errors: a model that needs FlightGear's properties)
        raise JsbsimPlantError(f"jsbsim plant: JSBSim cannot fly {spec.model} on its own: {exc}") from None
    fdm["propulsion/set-running"] = -1
    try:
        fdm["simulation/do_simple_trim"] = 1
    except jsbsim.TrimFailureError as exc:
        raise JsbsimPlantError(
            f"jsbsim plant: {spec.model} does not trim in level flight at {spec.airspeed_kt:g} kt, "
            f"{spec.altitude_m:g} m ({exc}){_trims_instead(spec) if suggest else ''}"
        ) from None
    return fdm


SUGGEST_KT = tuple(range(30, 310, 10))  # the airspeeds tried when a trim fails (kt)


def trimming_airspeeds(spec: JsbsimSpec, speeds=SUGGEST_KT) -> list[float]:
    """The airspeeds of ``speeds`` (kt) at which ``spec.model`` trims at ``spec.altitude_m`` (JSBSim's chatter
    silenced)."""
    from sitl.jsbsim_models import quiet_stdio

    found = []
    with quiet_stdio():
        for kt in speeds:
            try:
                trimmed_fdm(replace(spec, airspeed_kt=float(kt)), 0.01, suggest=False)
            except JsbsimPlantError:
                continue
            found.append(float(kt))
    return found


def _trims_instead(spec: JsbsimSpec) -> str:
    """What a failed trim adds: the airspeeds that trim there, and the spec to try (the middle of the nearest
    range)."""
    found = trimming_airspeeds(spec)
    if not found:
        return f"; it trims at none of {SUGGEST_KT[0]}-{SUGGEST_KT[-1]} kt there"
    ranges, start = [], found[0]
    for a, b in zip(found, found[1:] + [None]):
        if b is None or b - a > 10.0:
            ranges.append((start, a))
            start = b
    lo, hi = min(
        ranges, key=lambda r: 0.0 if r[0] <= spec.airspeed_kt <= r[1] else min(abs(spec.airspeed_kt - x) for x in r)
    )
    mid = 10.0 * round((lo + hi) / 20.0)
    where = ", ".join(f"{a:g}-{b:g}" if a != b else f"{a:g}" for a, b in ranges)
    return f"; it trims at {where} kt there: try {replace(spec, airspeed_kt=mid).text(short=True)}"


class SafetyPilot:
    """Holds the trim altitude (elevator, through pitch) and airspeed (throttle); see the module docstring."""

    def __init__(self, fdm, dt: float, gains: PilotGains = PILOT):
        self.fdm = fdm
        self.gains = gains
        self.dt = dt * PILOT_EVERY
        self.h0 = fdm["position/h-sl-ft"] * FT
        self.theta0 = fdm["attitude/theta-rad"]
        self.v0 = fdm["velocities/vc-kts"] * KT
        self.elevator0 = fdm["fcs/elevator-cmd-norm"]
        self.throttle0 = fdm["fcs/throttle-cmd-norm"]
        self.int_theta = 0.0
        self.int_v = 0.0
        pm = fdm.get_property_manager()
        self._elevator = pm.get_node("fcs/elevator-cmd-norm")
        self._throttle = pm.get_node("fcs/throttle-cmd-norm")

    def __call__(self) -> None:
        f, g = self.fdm, self.gains
        h, hdot = f["position/h-sl-ft"] * FT, f["velocities/h-dot-fps"] * FT
        theta_ref = self.theta0 + min(g.theta_max, max(-g.theta_max, g.k_h * (self.h0 - h) - g.k_hdot * hdot))
        e = theta_ref - f["attitude/theta-rad"]
        self.int_theta += e * self.dt
        de = -(g.k_theta * e + g.k_i * self.int_theta - g.k_q * f["velocities/q-rad_sec"])
        self._elevator.set_double_value(min(1.0, max(-1.0, self.elevator0 + de)))
        ev = self.v0 - f["velocities/vc-kts"] * KT
        self.int_v += ev * self.dt
        thr = self.throttle0 + g.k_v * ev + g.k_vi * self.int_v
        self._throttle.set_double_value(min(1.0, max(0.0, thr)))


@dataclass(frozen=True)
class JsbsimConfig:
    physics_rate_hz: float = 1000.0

    @property
    def dt(self) -> float:
        return 1.0 / self.physics_rate_hz


class JsbsimPlant:
    """The plant interface on JSBSim: ``advance(u, n)``, ``truth``, ``attitude()``, ``steps``, ``time``."""

    def __init__(
        self,
        spec: JsbsimSpec,
        physics_rate_hz: float = 1000.0,
        turbulence: str | None = None,
        seed: int = 0,
        crosswind: float = 0.0,
        servo: tuple[float, float] = (model.SERVO_WN2, model.SERVO_2ZETA_WN),
        damaged: bool = False,
    ):
        """``damaged``: fly the model's copy with the fault properties and ballast (``sitl.jsbsim_damage``), which
        the faults effectiveness, damping, inertia and cg need (the servo faults and airspeed do not)."""
        self.spec = spec
        self.config = JsbsimConfig(physics_rate_hz)
        dt = self.config.dt
        self.fdm = fdm = trimmed_fdm(spec, dt, seed, damaged)
        first = spec.surfaces[0]  # the surface of the command (a MIMO plant's first: the aileron, on the roll)
        self.surface_trim = fdm[SURFACES[first]]
        self._cmd = fdm.get_property_manager().get_node(SURFACES[first])
        self.surface_map = spec.surface_map  # the model's command -> deflection (sitl.jsbsim_models)
        self._to_norm = self._normalised(self.surface_map, spec.signs[0], self.surface_trim)
        # A square MIMO plant (spec.is_mimo): the second surface (the rudder, on the sideslip) flies ``u2`` (rad),
        # set by the endpoint from its own SERVO_OUTPUT_RAW channel, through a servo of its own (the same eq. (65))
        self.mimo = spec.is_mimo
        self.u2 = self.delta2 = self.delta2_dot = 0.0
        if self.mimo:
            second = spec.surfaces[1]
            m2 = spec.surface_maps[1]
            self._cmd2 = fdm.get_property_manager().get_node(SURFACES[second])
            self._to_norm2 = self._normalised(m2, spec.signs[1], fdm[SURFACES[second]])
            self.surface2_limit_rad = m2.limit_rad
        self.pilot = SafetyPilot(fdm, dt, pilot_gains(spec.model))
        if turbulence is not None:
            w20, severity = TURBULENCE[turbulence]
            fdm["atmosphere/turb-type"] = 3
            fdm["atmosphere/turbulence/milspec/windspeed_at_20ft_AGL-fps"] = w20 * KT / FT
            fdm["atmosphere/turbulence/milspec/severity"] = severity
        if crosswind:
            fdm["atmosphere/wind-east-fps"] = crosswind / FT  # side wind on the trim heading (north)
        wn2, two_zeta_wn = servo
        ad, bd = zoh(np.array([[0.0, 1.0], [-wn2, -two_zeta_wn]]), np.array([[0.0], [wn2]]), dt)
        self._servo = (*(float(v) for v in ad.ravel()), *(float(v) for v in bd.ravel()))
        self.delta = self.delta_dot = 0.0
        self.steps = 0
        self.n = 6
        self._effect = damage.NOMINAL  # the faults' effect flown (set_effect)
        self._act: damage.Actuator | None = None  # the servo's path under a servo fault
        self._act2: damage.Actuator | None = None  # the MIMO plant's second servo's
        self._u_last = 0.0
        self._damaged = damaged
        self._v0 = self.pilot.v0
        if damaged:  # the trimmed aircraft's mass properties: the ballast is sized from them
            from sitl.jsbsim_damage import anatomy

            a = anatomy(_root() / "aircraft" / spec.model / f"{spec.model}.xml", spec.surfaces[0])
            self._ballast0 = a.pointmasses  # index of the first ballast point mass
            self._semispan_in = 6.0 * a.span_ft if a.span_ft else None
            self._mass0 = {k: fdm[f"inertia/{k}"] for k in ("weight-lbs", "cg-x-in", "cg-y-in", "cg-z-in")}
            self._mass0["ixx"] = fdm["inertia/ixx-slugs_ft2"]
        self._read()

    @staticmethod
    def _normalised(m: SurfaceMap, sign: float, trim: float):
        """delta (rad from the trim deflection) -> the normalised command, clipped to [-1, 1]: trim + sign delta / k
        on a symmetric surface (c172x: k = 17.5 deg), else the command whose deflection (``SurfaceMap.command``) is
        the trim's plus sign delta."""
        if m.symmetric:
            k = sign / m.positive_rad

            def norm(d: float) -> float:
                return min(1.0, max(-1.0, trim + d * k))

            return norm
        kp, kn, t0 = m.positive_rad, m.negative_rad, m.deflection(trim)

        def norm_piecewise(d: float) -> float:
            target = t0 + sign * d
            return min(1.0, max(-1.0, target / (kp if target >= 0.0 else kn)))

        return norm_piecewise

    @property
    def time(self) -> float:
        return self.steps * self.config.dt

    def _read(self) -> None:
        f = self.fdm
        self.x = np.array(
            (
                f["velocities/v-fps"] * FT,
                f["velocities/p-rad_sec"],
                f["velocities/r-rad_sec"],
                f["attitude/phi-rad"],
                self.delta,
                self.delta_dot,
            )
        )

    @property
    def truth(self) -> np.ndarray:
        """[v, p, r, phi, delta, delta_dot] after the last advance (a view, do not modify)."""
        return self.x

    @property
    def state(self) -> np.ndarray:
        return self.x.copy()

    def attitude(self) -> tuple[float, float, float, float, float, float]:
        """JSBSim's (roll, pitch, yaw, p, q, r): Euler angles rad (yaw wrapped to (-pi, pi]), body rates rad/s."""
        f = self.fdm
        return (
            f["attitude/phi-rad"],
            f["attitude/theta-rad"],
            wrap_pi(f["attitude/psi-rad"]),
            f["velocities/p-rad_sec"],
            f["velocities/q-rad_sec"],
            f["velocities/r-rad_sec"],
        )

    def held(self) -> dict[str, float]:
        """What the safety pilot holds: altitude m, airspeed m/s, pitch rad, elevator and throttle commands."""
        f = self.fdm
        return {
            "altitude_m": f["position/h-sl-ft"] * FT,
            "airspeed_m_s": f["velocities/vc-kts"] * KT,
            "theta": f["attitude/theta-rad"],
            "elevator": f["fcs/elevator-cmd-norm"],
            "throttle": f["fcs/throttle-cmd-norm"],
        }

    def advance(self, delta_command: float, n: int, d=None) -> np.ndarray:
        """``n`` physics steps with the servo command held; ``d`` must be None (JSBSim has its own atmosphere)."""
        if d is not None:
            raise ValueError("a JSBSim plant takes no disturbance input: its turbulence is JSBSim's own")
        u = float(delta_command)
        if not math.isfinite(u):
            from sitl.aircraft import NonFiniteCommandError

            raise NonFiniteCommandError(f"servo command must be finite, got {delta_command!r}")
        self._u_last = u
        if self._act is not None or self._act2 is not None:
            return self._advance_servo_fault(u, n)
        if self.mimo:
            return self._advance_mimo(u, n)
        a00, a01, a10, a11, b0, b1 = self._servo
        d_, dd = self.delta, self.delta_dot
        run, cmd, norm = self.fdm.run, self._cmd.set_double_value, self._to_norm
        steps = self.steps
        for _ in range(n):
            d_, dd = a00 * d_ + a01 * dd + b0 * u, a10 * d_ + a11 * dd + b1 * u  # exact ZOH of eq. (65)
            cmd(norm(d_))
            if steps % PILOT_EVERY == 0:
                self.pilot()
            run()
            steps += 1
        self.delta, self.delta_dot, self.steps = d_, dd, steps
        self._read()
        return self.x

    def _advance_mimo(self, u: float, n: int) -> np.ndarray:
        """``advance`` of a MIMO plant: both servos (the same exact ZOH of eq. (65)), each on its own surface."""
        a00, a01, a10, a11, b0, b1 = self._servo
        d_, dd, e_, ed = self.delta, self.delta_dot, self.delta2, self.delta2_dot
        u2 = float(self.u2)
        run, cmd, norm = self.fdm.run, self._cmd.set_double_value, self._to_norm
        cmd2, norm2 = self._cmd2.set_double_value, self._to_norm2
        steps = self.steps
        for _ in range(n):
            d_, dd = a00 * d_ + a01 * dd + b0 * u, a10 * d_ + a11 * dd + b1 * u
            e_, ed = a00 * e_ + a01 * ed + b0 * u2, a10 * e_ + a11 * ed + b1 * u2
            cmd(norm(d_))
            cmd2(norm2(e_))
            if steps % PILOT_EVERY == 0:
                self.pilot()
            run()
            steps += 1
        self.delta, self.delta_dot, self.delta2, self.delta2_dot, self.steps = d_, dd, e_, ed, steps
        self._read()
        return self.x

    def sideslip(self) -> tuple[float, float]:
        """JSBSim's (angle of attack, sideslip) in rad: what AOA_SSA carries (sitl.endpoint)."""
        return self.fdm["aero/alpha-rad"], self.fdm["aero/beta-rad"]

    # ------------------------------------------------------------------ faults (sitl.damage)
    def set_effect(self, effect: damage.Effect) -> None:
        """Fly under ``effect`` (``sitl.damage.Effect``) from the next step; ``damage.NOMINAL``: the aircraft as built.

        Effectiveness and damping set the multipliers in the model's coefficient functions, inertia and cg the
        ballast's weights (``sitl.jsbsim_damage``; both need ``damaged=True``), airspeed the safety pilot's target;
        the servo faults put ``damage.Actuator`` on the servo's path."""
        old, self._effect = self._effect, effect
        f = self.fdm
        if self._damaged:
            from sitl.jsbsim_damage import DAMPING, EFFECTIVENESS

            f[EFFECTIVENESS] = effect.effectiveness
            f[DAMPING] = effect.damping
            self._set_ballast(effect)
        elif effect.airframe or effect.inertia != 1.0 or effect.cg != 0.0:
            raise JsbsimPlantError("jsbsim plant: a fault on the airframe needs the plant built with damaged=True")
        self.pilot.v0 = self._v0 if effect.airspeed is None else effect.airspeed
        self._act, self.delta, self.delta_dot = self._servo_effect(self._act, old, effect, self.delta, self.delta_dot)
        if self.mimo:  # the second surface's servo faults (sitl.damage.Effect.second: a ground station's instance)
            old2, new2 = old.second or damage.NOMINAL, effect.second or damage.NOMINAL
            self._act2, self.delta2, self.delta2_dot = self._servo_effect(
                self._act2, old2, new2, self.delta2, self.delta2_dot, self.u2
            )
        self._read()

    def _servo_effect(self, act, old, effect, d_, dd, u_last=None):
        """One surface's servo under ``effect`` (after ``old``): its ``damage.Actuator`` (None: no servo fault, a new
        one when the servo faults change), and its (delta, delta_dot) after the jam's jump and the rate's clip."""
        if not effect.servo:
            return None, d_, dd
        if act is None or effect.servo_differs(act.effect):
            act = damage.Actuator(effect, self.config.dt, self._u_last if u_last is None else u_last)
        act.effect = effect
        jump = damage.jammed(old, effect, d_)
        if jump is not None:
            d_, dd = jump, 0.0
        if effect.rate is not None:
            dd = min(effect.rate, max(-effect.rate, dd))
        return act, d_, dd

    def _set_ballast(self, effect: damage.Effect) -> None:
        """The wing-tip ballast of the inertia and cg faults, sized from the trimmed aircraft's mass properties.

        inertia=F: two equal masses at the CG +-b/2 (the CG stays, Ixx grows by 2 m (b/2)^2 = (F - 1) Ixx, Izz by
        the same, the weight by 2 m); cg=M: one mass at the tip on M's side, w = W M / (b/2 - |M|), which moves the
        CG by M (parallel to the lateral axis; the weight grows by w)."""
        m0, i0, y = self._mass0, self._ballast0, self._semispan_in
        pair = (effect.inertia - 1.0) * m0["ixx"] * SLUG_LB / (2.0 * (y / 12.0) ** 2)
        shift = effect.cg / 0.0254  # in
        tip = math.copysign(y, shift)
        cg_w = (m0["weight-lbs"] + 2.0 * pair) * abs(shift) / (y - abs(shift)) if shift else 0.0
        f = self.fdm
        for i, (w, dy) in enumerate(((pair, -y), (pair, y), (cg_w, tip))):
            f[f"inertia/pointmass-location-X-inches[{i0 + i}]"] = m0["cg-x-in"]
            f[f"inertia/pointmass-location-Y-inches[{i0 + i}]"] = m0["cg-y-in"] + dy
            f[f"inertia/pointmass-location-Z-inches[{i0 + i}]"] = m0["cg-z-in"]
            f[f"inertia/pointmass-weight-lbs[{i0 + i}]"] = w

    def _advance_servo_fault(self, u: float, n: int) -> np.ndarray:
        """``n`` steps with a servo fault on a surface: its servo driven with ``Actuator.command(u)``, the surface
        coasting when stuck or at its rate limit (``Actuator.surface``), else the free step with its rate clipped;
        a surface without one (a MIMO plant's other) flies its servo as ``advance`` does."""
        servo, dt = self._servo, self.config.dt
        run = self.fdm.run
        one = (self._act, self.delta, self.delta_dot, self._cmd.set_double_value, self._to_norm, u)
        surfaces = [list(one)]
        if self.mimo:
            surfaces.append([self._act2, self.delta2, self.delta2_dot, self._cmd2.set_double_value, self._to_norm2])
            surfaces[1].append(float(self.u2))
        steps = self.steps
        for _ in range(n):
            for s in surfaces:
                s[1], s[2] = _servo_step(servo, dt, *s[:3], s[5])
                s[3](s[4](s[1]))
            if steps % PILOT_EVERY == 0:
                self.pilot()
            run()
            steps += 1
        self.delta, self.delta_dot = surfaces[0][1], surfaces[0][2]
        if self.mimo:
            self.delta2, self.delta2_dot = surfaces[1][1], surfaces[1][2]
        self.steps = steps
        self._read()
        return self.x


def _servo_step(servo: tuple, dt: float, act, d_: float, dd: float, u: float) -> tuple[float, float]:
    """One physics step of a servo (eq. (65), its exact ZOH ``servo``) from (d_, dd) with the command ``u``, through
    ``act`` (``damage.Actuator``; None: no fault)."""
    a00, a01, a10, a11, b0, b1 = servo
    if act is None:
        return a00 * d_ + a01 * dd + b0 * u, a10 * d_ + a11 * dd + b1 * u
    ue = act.command(u)
    df, ddf = a00 * d_ + a01 * dd + b0 * ue, a10 * d_ + a11 * dd + b1 * ue  # exact ZOH of eq. (65)
    coast, rate = act.surface(d_, df, ddf)
    return (d_ + rate * dt, rate) if coast else (df, rate)
