"""The reference scenario ``paper`` (docs/spec.md, "Reference scenario") and its in-process closed loop.  No I/O."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from autopilot import controllers
from autopilot.clsac import GAIN_FIELDS, MODEL_FIELDS, gains_of, model_of
from autopilot.config import ClSacConfig
from autopilot.shared.mavlink import quaternion_to_roll, roll_to_quaternion
from autopilot.shared.pwm import PwmMap
from autopilot.step import ControlStep, ProfileSetpoints
from sitl import plant as plants
from tools.flight.profiles import Profile


class Rates:
    """A flight's count of control periods and of physics steps per period, from its ``duration_s``,
    ``control_rate_hz`` and ``physics_rate_hz`` (the :class:`Scenario`'s and the gym's ``Episode``'s)."""

    duration_s: float
    control_rate_hz: float
    physics_rate_hz: float

    @property
    def steps(self) -> int:
        """Number of control steps in the run."""
        return int(round(self.duration_s * self.control_rate_hz))

    @property
    def physics_per_control(self) -> int:
        return int(round(self.physics_rate_hz / self.control_rate_hz))


@dataclass(frozen=True)
class Scenario(Rates):
    """A roll scenario: the command ``profile`` (any ``tools.flight.profiles.Profile``: square, step, sine or CSV
    breakpoints) flown for ``duration_s``.  Defaults are the paper scenario (docs/spec.md, "Reference
    scenario"): a +-10 deg square wave of period 10 s, +10 deg first, for 30 s."""

    name: str = "paper"
    profile: Profile = Profile.square(amplitude_deg=10.0, period=10.0)
    duration_s: float = 30.0
    control_rate_hz: float = 100.0
    physics_rate_hz: float = 1000.0
    u_limit_rad: float = math.radians(30.0)
    plant: str = plants.KH2013A  # sitl.plant: kh2013a, FILE.toml or jsbsim:MODEL[:KEY=VALUE,...]
    # A parameter file (autopilot.params) on top of every SAC/CL-SAC run's configuration, and the baseline's gains;
    # None: the ones designed for the plant (tools.design.linearise.designed_params, designed_baseline), else the
    # defaults.
    params: str | None = None
    baseline_gains: tuple | None = None
    # The SITL's disturbances ((dest, value) pairs of sitl.disturbances.FLAGS): in-process, a JSBSim plant's own
    # turbulence, and with run_inprocess(atmosphere=True) the KH2013A's atmosphere (the SITL's injector); the rest
    # (sensors, link faults, --scale) over MAVLink only.
    disturbances: tuple = ()
    # Mid-flight faults (sitl.damage.Fault or KIND[=VALUE]@START[:END] specs), flown as the SITL flies --fault.
    faults: tuple = ()
    # A gain schedule of the fixed-gain PID: ((t_s, (KP, KI, KD)), ...), each from the first control step at or
    # after t_s (autopilot.baseline.Baseline.set_gains); () for none.
    gain_schedule: tuple = ()

    def __post_init__(self) -> None:
        if not isinstance(self.profile, Profile):
            raise ValueError(f"profile must be a tools.flight.profiles.Profile, got {self.profile!r}")
        if self.faults:
            from sitl import damage

            faults = tuple(f if isinstance(f, damage.Fault) else damage.parse(str(f)) for f in self.faults)
            object.__setattr__(self, "faults", faults)
        for name in ("duration_s", "control_rate_hz", "physics_rate_hz", "u_limit_rad"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be positive and finite, got {v!r}")
        ratio = self.physics_rate_hz / self.control_rate_hz
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ValueError(
                f"physics_rate_hz ({self.physics_rate_hz}) must be a whole multiple of control_rate_hz "
                f"({self.control_rate_hz})"
            )

    @property
    def amplitude_rad(self) -> float:
        return self.profile.amplitude

    @property
    def period_s(self) -> float:
        return self.profile.period

    def command(self, t: float) -> float:
        """u_m(t), the roll command in rad."""
        return self.profile.value(t)


@dataclass(frozen=True)
class RunSpec:
    """One run: its name, L_v, and optionally a PFC preset and the K_Ix/K_Iu leakage (None: keep the base's)."""

    name: str
    lv: float
    pfc: str | None = None  # a key of autopilot.config.PFC_PRESETS
    sigma_xu: float | None = None  # sigma_x = sigma_u
    controller: str | None = None  # "baseline": the fixed-gain PID (autopilot.baseline); None: SAC/CL-SAC by lv


PAPER = Scenario()
PAPER_RUNS = (
    RunSpec("sac", 0.0),
    RunSpec("clsac", 20.0),
    RunSpec("clsac_lv10", 10.0),
    RunSpec("clsac_lv50", 50.0),
    RunSpec("clsac_lv100", 100.0),
)
# Runs an experiment may name (--runs baseline) that are not flown by default.
BASELINE_RUN = RunSpec("baseline", 0.0, controller="baseline")


def run_of(controller: str) -> RunSpec:
    """The run of a registered controller (``autopilot.controllers``) at its default L_v: SAC and CL-SAC are told
    apart by L_v (``controller`` None), any other law by its name."""
    c = controllers.get(controller)
    return RunSpec(c.name, c.lv, controller=None if c.law == "clsac" else c.name)


OPTIONAL_RUNS = (BASELINE_RUN,)


def params_config(path: str, cfg: ClSacConfig) -> ClSacConfig:
    """``cfg`` with a parameter file's values (``autopilot.params``) on top, as ``python -m autopilot --params`` does:
    the file overrides the flags."""
    from autopilot.params import ParamTable, load_file

    table = ParamTable(cfg, {"attitude_timeout_s": 0.1, "setpoint_timeout_s": 1.0, "max_roll_rad": 0.8})
    table.update(table.split(load_file(path))[0])  # another law's values (a design's PID gains) are not its own
    return table.config


def controller_config(scenario: Scenario, run: RunSpec, base: ClSacConfig | None = None) -> ClSacConfig:
    from tools.design.linearise import designed_law_params, designed_params, flown_baseline_gains

    # every law clips at the surface's stop, as the launcher and the studies fly it (sitl.plant.surface_limit_rad)
    limit = min(scenario.u_limit_rad, plants.surface_limit_rad(scenario.plant) or math.inf)
    law = controllers.get(run.controller).kind if run.controller is not None else None
    if law is not None and law.generic:  # a law on autopilot.law's interface: its design for the plant, if any
        cfg = controllers.get(run.controller).config(control_rate_hz=scenario.control_rate_hz, u_limit_rad=limit)
        path = scenario.params or (designed_law_params(scenario.plant, law.design) if law.design else None)
        return cfg if path is None else params_config(str(path), cfg)
    if run.controller is not None and not controllers.get(run.controller).adaptive:  # the fixed-gain PID
        flown = flown_baseline_gains(run.controller, scenario.plant, scenario.baseline_gains)
        return controllers.get(run.controller).config(
            control_rate_hz=scenario.control_rate_hz, u_limit_rad=limit, gains=flown
        )
    cfg = (base or ClSacConfig()).with_(lv=run.lv, control_rate_hz=scenario.control_rate_hz, u_limit_rad=limit)
    params = scenario.params or designed_params(scenario.plant)  # as tools.flight.FlightConfig.params_file
    if base is None and params is not None:
        cfg = params_config(str(params), cfg)
    if run.pfc is not None:
        cfg = cfg.with_pfc(run.pfc)
    if run.sigma_xu is not None:
        cfg = cfg.with_(sigma_x=run.sigma_xu, sigma_u=run.sigma_xu)
    return cfg


@dataclass
class RunResult:
    name: str
    lv: float
    metrics: dict[str, float]
    series: dict[str, np.ndarray] = field(repr=False)


SERIES = (
    "t",
    "um",
    "phi",
    *MODEL_FIELDS,
    "u",
    *GAIN_FIELDS,
    "v",
    "p",
    "r",
    "delta_r",
)


def _inprocess_disturbances(scenario: Scenario, atmosphere: bool = False):
    """The disturbances a plant flies by itself (a JSBSim plant's turbulence, crosswind, seed), or None; anything the
    SITL's injector would have to apply (sensors, link, the KH2013A atmosphere unless ``atmosphere``) flies over
    MAVLink only."""
    if not scenario.disturbances:
        return None
    from sitl.disturbances import from_values

    dist = from_values(dict(scenario.disturbances))
    rest = plants.injected(scenario.plant, dist)
    if (rest.atmosphere.active and not atmosphere) or rest.sensors.active or rest.faults.active or rest.scales:
        raise ValueError("these disturbances fly over MAVLink only (tools.flight, the mavlink transport)")
    return dist


def _atmosphere(scenario: Scenario, dist):
    """The SITL's injector of the atmosphere a plant does not fly by itself (``sitl.disturbances.Injector``, as a
    lockstep SITL builds it: the same seed streams), or None."""
    rest = None if dist is None else plants.injected(scenario.plant, dist)
    if rest is None or not rest.atmosphere.active:
        return None
    from sitl.disturbances import Injector

    return Injector(rest, 1.0 / scenario.physics_rate_hz, scenario.control_rate_hz, lockstep=True)


def scheduled_faults(plant, faults, physics_rate_hz: float, advance):
    """The plant's ``advance`` flown through the faults as the SITL flies ``--fault`` (``sitl.fault_injection``):
    one schedule on the physics-step grid from t = 0 (``sitl.damage.ScheduledEffects``); None without faults."""
    if not faults:
        return None
    from sitl import damage

    return damage.ScheduledEffects(plant, damage.Schedule(faults, 0.0, 1.0 / physics_rate_hz), advance)


def aircraft(scenario: Scenario, atmosphere: bool = False):
    """(the plant, its ``advance(u, n)``): the scenario's plant with the disturbances it flies in-process
    (:func:`_inprocess_disturbances`, :func:`_atmosphere` with ``atmosphere``) and its faults
    (:func:`scheduled_faults`)."""
    dist = _inprocess_disturbances(scenario, atmosphere)
    ac = plants.build(scenario.plant, scenario.physics_rate_hz, None, dist, plants.needs_damaged_model(scenario.faults))
    air = _atmosphere(scenario, dist) if atmosphere else None
    advance = ac.advance if air is None else (lambda u, m: air.advance(ac, u, m))
    faulted = scheduled_faults(ac, scenario.faults, scenario.physics_rate_hz, advance)
    return ac, advance if faulted is None else faulted.advance


def run_inprocess(
    scenario: Scenario = PAPER,
    run: RunSpec = PAPER_RUNS[1],
    base: ClSacConfig | None = None,
    wire: PwmMap | None = None,
    *,
    atmosphere: bool = False,
) -> RunResult:
    """Fly the scenario with the control step and the aircraft in one process.

    Order per control step k (the same as over MAVLink in lockstep): the aircraft's roll at t_k is
    measured, ``autopilot.step.ControlStep`` computes u[k], the aircraft advances one control period
    with u[k] held (exact ZOH, ``sitl.Aircraft.advance``).

    The scenario's faults fly as the SITL flies ``--fault`` (``sitl.damage.advance_scheduled``, the one schedule
    on the physics-step grid from t = 0) and its gain schedule retunes the fixed-gain PID at its times.

    ``wire``: also model exactly what the MAVLink path adds, so the two compare like for like: roll and
    the setpoint quaternion travel as float32, and the rudder command flies (and is scored) after the
    1 us PWM quantisation of this calibration.

    ``atmosphere``: fly the scenario's turbulence, gusts and crosswind on a plant that does not fly its own (the
    KH2013A, a plant file) too, sampled per physics step by the SITL's own ``sitl.disturbances.Injector`` (the
    robustness study's plant files); without it they fly over MAVLink only.
    """
    command = scenario.command
    if wire is not None:

        def command(t: float, _f=scenario.command) -> float:  # SET_ATTITUDE_TARGET.q travels as float32
            return quaternion_to_roll(np.float32(roll_to_quaternion(_f(t))))

    step = ControlStep(controller_config(scenario, run, base), wire, ProfileSetpoints(command))
    law = step.law
    if scenario.faults:
        plants.check_faults(scenario.plant, scenario.faults)  # PlantError: a kind the plant cannot fly
    ac, advance = aircraft(scenario, atmosphere)
    n = scenario.steps
    nphys = scenario.physics_per_control
    out = np.empty((n, len(SERIES)))
    rate = scenario.control_rate_hz
    retunes = {max(0, math.ceil(round(ts * rate, 6))): g for ts, g in scenario.gain_schedule}
    for k in range(n):
        t = k / rate
        if k in retunes:
            law.set_gains(*retunes[k])
        x = ac.truth
        phi = float(x[3]) if wire is None else float(np.float32(x[3]))  # ATTITUDE.roll travels as float32
        p, yaw = (float(x[1]), float(x[2])) if wire is None else (float(np.float32(x[1])), float(np.float32(x[2])))
        r = step(t, phi, p=p, r=yaw)  # ATTITUDE's rollspeed and yawspeed (a law on autopilot.law's interface)
        out[k] = (
            t,
            r.um,
            phi,
            *model_of(law),
            r.u,
            *gains_of(law),
            x[0],
            x[1],
            x[2],
            x[4],
        )
        advance(r.u, nphys)
    series = {name: out[:, i].copy() for i, name in enumerate(SERIES)}
    return RunResult(run.name, run.lv, step.metrics.result(), series)
