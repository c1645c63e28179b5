"""One aircraft as the environments fly it (``tools.experiment.gym.roll``, ``tools.experiment.gym.vector``): the
options checked as the launcher checks them, the SITL's plant, faults, atmosphere and sensors, the wire, the
reference model and the product's metrics and verdict.  No I/O.

A :class:`Lane` is the lockstep flight of ``python -m tools.launch --lockstep`` with the autopilot's law replaced by
the caller's action, frame by frame, in the order the SITL flies it (``sitl.endpoint.Sitl.run_lockstep``):

1. the SITL measures the plant (``sitl.disturbances.Injector.measure``: the sensor errors; roll wrapped to
   (-pi, pi]) and sends ATTITUDE, whose roll, roll rate and yaw rate travel as float32;
2. the autopilot reads the command u_m(t_k) (the GCS's SET_ATTITUDE_TARGET quaternion, float32) and answers with a
   servo pulse: here the action, clipped to the surface's limit and rounded to 1 us (``autopilot.shared.pwm``);
3. the SITL flies the pulse's angle for one control period of physics steps: the faults through the one schedule
   (``sitl.damage.ScheduledEffects``), the atmosphere through the injector (``sitl.disturbances.Injector``).

So a PID policy flies the launcher's roll series (tests/tools/experiment/test_gym.py).
"""

from __future__ import annotations

import functools
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from autopilot.envelope import TRACK_BLOCK_S, TRACK_BLOCKS, Envelope, EnvelopeMonitor
from autopilot.metrics import MetricsAccumulator
from autopilot.shared.mavlink import quaternion_to_roll, roll_to_quaternion
from autopilot.shared.numerics import wrap_pi, zoh
from autopilot.shared.pwm import PwmMap
from sitl import damage
from sitl import plant as plants
from sitl.disturbances import FLAGS
from tools.experiment.scenario import Rates, scheduled_faults

DEG = math.pi / 180.0
RUDDER_MAX_DEG = 30.0  # the servo calibration's full deflection (tools.flight.command_lines.RUDDER_MAX_DEG)
U_LIMIT_RAD = RUDDER_MAX_DEG * DEG  # the reference scenario's command limit (tools.experiment.scenario.PAPER)
# The reference model y_m,ol the reward and ise_ref track (paper sec. 5.1: A_m = -5, B_m = 5, C_m = 1; the same in
# autopilot.config.ClSacConfig and autopilot.baseline.BaselineConfig): the command filtered by 1/(0.2 s + 1).
REF_AM, REF_BM, REF_CM = -5.0, 5.0, 1.0
# Link faults and --scale's sampled ranges aside, the SITL's disturbance flags (sitl.disturbances.FLAGS).
LINK = ("loss", "delay", "duplicate", "reorder")
DISTURBANCES = tuple(d for d in FLAGS if d not in LINK and d != "seed")
PROFILE = ("profile", "amplitude", "period", "csv")
OPTIONS = ("plant", "fault", "duration", "control_rate", "physics_rate", *PROFILE, *DISTURBANCES, "effort_weight")


@dataclass(frozen=True)
class Episode(Rates):
    """What one episode flies: the plant spec, the faults (``sitl.damage.Fault``), the disturbance flags' values
    (``{dest: value}``, as ``sitl.disturbances.from_values`` takes them, seed aside), the command (``tools.flight.
    profiles.Profile``), the duration and the rates, and the reward's effort weight."""

    plant: str
    faults: tuple
    disturbances: dict = field(hash=False)
    profile: object
    duration_s: float
    control_rate_hz: float
    physics_rate_hz: float
    effort_weight: float

    @property
    def mimo(self) -> bool:
        """A square MIMO plant (``jsbsim:MODEL:surface=aileron+rudder``): roll on the aileron, sideslip on the
        rudder."""
        return plants.spec(self.plant).mimo

    @property
    def limits_rad(self) -> tuple[float, ...]:
        """Each surface's limit: the roll's (``u_limit_rad``), and on a MIMO plant the rudder's stop."""
        if not self.mimo:
            return (self.u_limit_rad,)
        from sitl.jsbsim_plant import parse_spec

        lims = parse_spec(self.plant).surface_limits_rad
        return (min(U_LIMIT_RAD, lims[0]), min(U_LIMIT_RAD, lims[1]))

    @property
    def u_limit_rad(self) -> float:
        """The surface's limit: the scenario's 30 deg or the surface's own stop (a JSBSim aircraft's, a file's)."""
        return min(U_LIMIT_RAD, plants.surface_limit_rad(self.plant) or math.inf)


def _argv(opts: dict) -> list[str]:
    """The launcher's command line for the options (``python -m tools.launch --lockstep ...``)."""
    from sitl.disturbances import to_argv

    argv = ["--lockstep", "--plant", str(opts.get("plant", plants.KH2013A))]
    faults = opts.get("fault")
    for f in [] if faults is None else [faults] if isinstance(faults, (str, damage.Fault)) else list(faults):
        argv += ["--fault", f.spec if isinstance(f, damage.Fault) else str(f)]
    for key, flag in (("duration", "--duration"), ("control_rate", "--rate"), ("physics_rate", "--physics-rate")):
        if opts.get(key) is not None:
            argv += [flag, repr(float(opts[key]))]
    for key in ("amplitude", "period", "csv"):
        if opts.get(key) is not None:
            argv += [f"--{key}", str(opts[key])]
    values = {d: opts.get(d) for d in DISTURBANCES}
    for d, v in values.items():  # a repeatable flag (--gust, --scale) given one value as text
        if isinstance(v, str) and FLAGS[d][1].get("action") == "append":
            values[d] = [v]
    argv += to_argv(values)
    if opts.get("profile") is not None:
        argv.append(str(opts["profile"]))
    return argv


def episode(opts: dict) -> Episode:
    """The episode the options ask for, checked by the launcher's own parser and ``Flight``: a bad value raises
    ValueError with the one line ``python -m tools.launch`` prints after ``error:``."""
    from tools.flight import Flight, FlightConfigError
    from tools.flight.profiles import Profile
    from tools.launch import _flag, build_parser

    unknown = sorted(set(opts) - set(OPTIONS))
    if unknown:
        raise ValueError(f"unknown option {unknown[0]!r}; options: {', '.join(OPTIONS)}")
    parser = build_parser()

    def error(message: str):
        raise ValueError(message)

    parser.error = error  # the launcher's one-line message, raised instead of printed
    args = parser.parse_args(_argv(opts))
    try:
        Flight(**vars(args))  # what the launcher checks before it starts anything (plant, faults, disturbances)
    except FlightConfigError as exc:
        dest, message = exc.field, str(exc)
        raise ValueError(_flag(dest) + message[len(dest) :] if message.startswith(dest) else message) from None
    rate = float(args.rate)
    physics = args.physics_rate or rate * math.ceil(round(1000.0 / rate, 9))  # the launcher's default
    profile = Profile.of(args.profile, amplitude_deg=args.amplitude, period=args.period, csv=args.csv)
    duration = args.duration if args.duration is not None else (profile.end if args.csv else 30.0)
    weight = float(opts.get("effort_weight", 1.0))
    if not (math.isfinite(weight) and weight >= 0):
        raise ValueError(f"effort_weight must be >= 0 and finite, got {opts.get('effort_weight')!r}")
    dist = {d: getattr(args, d) for d in DISTURBANCES}
    return Episode(args.plant, tuple(args.fault or ()), dist, profile, float(duration), rate, float(physics), weight)


@functools.lru_cache(maxsize=16)
def commands(profile, dt: float, steps: int) -> np.ndarray:
    """u_m(k dt), k = 0..steps, as the autopilot has it: the GCS's SET_ATTITUDE_TARGET quaternion in float32
    (``tools.experiment.scenario.run_inprocess``'s wire model); computed once per profile and length, read-only."""
    um = np.array([quaternion_to_roll(np.float32(roll_to_quaternion(profile.value(k * dt)))) for k in range(steps + 1)])
    um.flags.writeable = False
    return um


class Lane:
    """One aircraft flown by actions: ``observe()`` after construction, then ``act(u)`` once per control period
    (the pulse), ``advance()`` (the physics), ``score(...)`` (the metrics and the verdict), ``observe()`` again."""

    def __init__(self, ep: Episode, seed: int):
        from sitl.disturbances import Injector, from_values

        self.ep = ep
        self.seed = int(seed)
        dist = from_values({**ep.disturbances, "seed": self.seed})
        rest = plants.injected(ep.plant, dist)  # as the SITL: JSBSim flies its own atmosphere
        self.inj = Injector(rest, 1.0 / ep.physics_rate_hz, ep.control_rate_hz, True)
        params = self.inj.params()
        self.plant = plants.build(ep.plant, ep.physics_rate_hz, params, dist, plants.needs_damaged_model(ep.faults))
        self.euler = plants.spec(ep.plant).euler
        self.sensors = self.inj.sensors is not None
        advance = self.plant.advance if self.inj.atmosphere is None else self._advance_air
        self.scheduled = scheduled_faults(self.plant, ep.faults, ep.physics_rate_hz, advance)
        self.schedule = None if self.scheduled is None else self.scheduled.schedule
        self._advance = advance if self.scheduled is None else self.scheduled.advance
        self.mimo = ep.mimo
        self.limits = ep.limits_rad
        self.limit = self.limits[0]
        self.pwm = PwmMap(rudder_max_rad=max(U_LIMIT_RAD, self.limit))  # the launcher's calibration
        self.u2 = self.beta = self.beta_cmd = 0.0
        if self.mimo:  # the rudder's pulse on its own channel, the same span (tools.experiment.mimo_inprocess)
            self.pwm2 = PwmMap(rudder_max_rad=max(U_LIMIT_RAD, self.limit))
            delay = self.inj.sensors.cfg.delay if self.sensors else 0
            self._side = deque(maxlen=delay + 1)  # AOA_SSA's sensor delay (sitl.endpoint.Sitl._measure_sideslip)
        self.dt = 1.0 / ep.control_rate_hz
        phi, gam = zoh(np.array([[REF_AM]]), np.array([[REF_BM]]), self.dt)
        self.ref = (float(phi[0, 0]), float(gam[0, 0]))  # y_m,ol's exact ZOH (autopilot.baseline.Baseline)
        self.xm = 0.0
        self.k = 0
        self.u = 0.0
        self.metrics = MetricsAccumulator(self.dt)
        self.monitor = EnvelopeMonitor(Envelope(surface=plants.spec(ep.plant).surfaces[0]))
        self.exit: str | None = None
        self._block = -1
        self.measure()

    def _advance_air(self, u: float, n: int):
        return self.inj.advance(self.plant, u, n)

    def command(self, k: int) -> float:
        """u_m(t_k) as the autopilot has it (:func:`commands`)."""
        return float(commands(self.ep.profile, self.dt, self.ep.steps)[min(k, self.ep.steps)])

    def measure(self) -> None:
        """The ATTITUDE of this frame (``sitl.endpoint.Sitl._send_attitude``): roll, roll rate, yaw rate."""
        if self.sensors:
            phi, p, r = self.inj.measure(self.plant.truth)
            phi = wrap_pi(phi)
        elif self.euler:
            phi, _theta, _psi, p, _q, r = self.plant.attitude()
        else:
            x = self.plant.truth.tolist()
            phi, p, r = wrap_pi(x[3]), x[1], x[2]
        self.phi, self.p, self.r = (float(np.float32(v)) for v in (phi, p, r))
        self.um = self.command(self.k)
        if self.mimo:  # AOA_SSA: the sideslip in deg as float32; its command as the GCS's profile gives it
            self._side.append(self.plant.sideslip())
            self.beta = math.radians(float(np.float32(math.degrees(self._side[0][1]))))
            self.beta_cmd = self.ep.profile.sideslip(min(self.k, self.ep.steps) * self.dt)
        self.ym = REF_CM * self.xm

    def observation(self) -> np.ndarray:
        if self.mimo:
            obs = (self.phi, self.p, self.r, self.beta, self.um, self.beta_cmd, self.u, self.u2)
            return np.array(obs, dtype=np.float64)
        return np.array([self.phi, self.p, self.r, self.um, self.u], dtype=np.float64)

    def act(self, a: float) -> float:
        """The angle the servo flies for the action ``a`` (rad): clipped to the limit, through the 1 us pulse."""
        lim = self.limit
        u = lim if a > lim else (-lim if a < -lim else a)
        self.u = self.pwm.to_rad(self.pwm.to_pwm(u))
        return self.u

    def act2(self, a: float) -> float:
        """A MIMO plant's rudder: clipped to its stop, through its 1 us pulse, held by the plant (``u2``)."""
        lim = self.limits[1]
        u = lim if a > lim else (-lim if a < -lim else a)
        self.u2 = self.plant.u2 = self.pwm2.to_rad(self.pwm2.to_pwm(u))
        return self.u2

    def advance(self) -> None:
        self._advance(self.u, self.ep.physics_per_control)

    def score(self) -> tuple[float, bool]:
        """This step's reward and whether the verdict is decided out of the envelope (before the plant moved):
        the sample (phi_k, y_m,ol k, u_k) goes into the metrics and the monitor as the autopilot's would."""
        phi, ym, u = self.phi, self.ym, self.u
        self.metrics.add(phi, ym, ym - phi, u)
        d = phi - ym
        if self.mimo:  # the sideslip's error and the rudder's effort too
            d2, u2 = self.beta - self.beta_cmd, self.u2
            reward = -(d * d + d2 * d2 + self.ep.effort_weight * (u * u + u2 * u2)) * self.dt
        else:
            reward = -(d * d + self.ep.effort_weight * (u * u)) * self.dt
        ft = self.k * self.dt
        text = self.monitor.add(ft, phi, u, self.limit, ym)
        if self.exit is None and self.monitor.roll_exit_s is not None:
            self.exit = text or f"ENVELOPE: |roll| reached {self.monitor.envelope.max_roll_deg:g} deg"
        block = math.floor(ft / TRACK_BLOCK_S + 1e-6)  # the monitor's 1 s blocks: a window closes as one begins
        if self.exit is None and block != self._block and block >= TRACK_BLOCKS:
            w = self.monitor.tracking().first_oscillation  # a closed window that oscillated (a limit cycle): out
            if w is not None and w.end_s <= ft + 1e-6:  # (the window still open ends later)
                self.exit = (
                    f"ENVELOPE: oscillation +-{w.amplitude_deg:.0f} deg in the window {w.start_s:g}-{w.end_s:g} s"
                )
        self._block = block
        if self.exit is None and self.monitor.n_saturated >= self.share_steps():
            self.exit = f"ENVELOPE: {self.monitor.envelope.surface} saturated in {self.monitor.n_saturated} steps"
        self.xm = self.ref[0] * self.xm + self.ref[1] * self.um
        self.k += 1
        return reward, self.exit is not None

    def share_steps(self) -> float:
        """Saturated steps from which the whole flight's share cannot come back under the limit."""
        return self.monitor.envelope.max_saturated_share * self.ep.steps

    def diverged(self) -> str | None:
        return plants.divergence(np.asarray(self.plant.truth, dtype=float))

    def fault_state(self) -> dict:
        """The faults active at the plant's current physics step and their combined effect (``sitl.damage``)."""
        if self.schedule is None:
            return {"active": [], "effect": dict(vars(damage.NOMINAL))}
        step = self.plant.steps
        active = [f.spec for f in self.schedule.active(step)]
        return {"active": active, "effect": dict(vars(self.schedule.effect(step)))}

    def info(self) -> dict:
        m = self.metrics.result()
        return {
            "t": self.k * self.dt,
            "ise_ref": m["ise_ref"],
            "energy": m["energy"],
            "saturation": self.monitor.saturated_share if self.monitor.n else 0.0,
            "max_abs_u": m["max_abs_u"],
            "ym": self.ym,
            "fault": self.fault_state(),
            "envelope": self.exit,
        }

    def penalty(self) -> float:
        """The reward of an early end: the rest of the flight at the envelope's roll limit, |phi - y_m| = 60 deg
        per step (so ending early never pays)."""
        rest = self.ep.steps - self.k
        return -rest * self.monitor.envelope.max_roll_rad**2 * self.dt
