"""``FlightConfig``: a flight's settings, checked at construction (``FlightConfigError``).  The command lines of its
three child processes are ``tools.flight.command_lines``."""

from __future__ import annotations

import argparse
import functools
import math
import os
from dataclasses import dataclass, field, fields

from autopilot import controllers, flags
from autopilot.envelope import MAX_ROLL_DEG, MAX_SATURATED_SHARE, Envelope
from autopilot.flags import default_lv, envelope_roll_deg, envelope_saturated_pct
from autopilot.shared import cli
from autopilot.shared.process import rt_throttling
from tools.flight import designs
from tools.flight.profiles import Profile, ProfileError

PROCESSES = ("sitl", "gcs", "autopilot")
PROFILES = ("square", "step", "sine")
MERGE_MAX_MB = 64.0  # default rrd_merge_max_mb: larger telemetry parts are concatenated (streamed), not merged
LIVE_RATE_HZ = 20.0  # default live_rate: rows per sim second of each table a live viewer gets (docs/telemetry.md)
LIVE_WINDOW_S = 20.0  # default live_window: the sim seconds a live viewer's plots show


DEFAULT_DURATION_S = 30.0  # a flight's length unless given (a csv profile: its last breakpoint)


# How long a peer's silence is waited out before a process gives up (each one's own flag, the launcher passes it):
LOCKSTEP_IDLE_EXIT_S = 5.0  # the lockstep autopilot, SITL silent after a frame (autopilot --lockstep-idle-exit)
VEHICLE_TIMEOUT_S = 5.0  # the GCS script, vehicle silent (tools.gcs --vehicle-timeout; its default too)


class FlightConfigError(ValueError):
    """A bad Flight keyword value; the one-line message starts with the keyword's name and gives the value."""

    def __init__(self, field_name: str, message: str):
        super().__init__(message)
        self.field = field_name


def _checked(name: str, check, value):
    """``value`` through one of the command line's argument types, a FlightConfigError naming ``name`` if bad."""
    try:
        return check(value)
    except TypeError:
        raise FlightConfigError(name, f"{name}: expected a number, got {value!r}") from None
    except (ValueError, argparse.ArgumentTypeError) as exc:
        raise FlightConfigError(name, f"{name}: {exc}") from None


def _require(ok: bool, name: str, message: str) -> None:
    if not ok:
        raise FlightConfigError(name, message)


@dataclass(frozen=True, kw_only=True)
class FlightConfig:
    """The keywords of ``Flight``, validated: the long flags of ``python -m tools.launch``."""

    lockstep: bool = False  # SITL as time master, as fast as the machine allows (default: real time)
    duration: float | None = None  # sim s; default 30, or a csv profile's last breakpoint (its end)
    controller: str = "clsac"  # one of CONTROLLERS
    lv: float | None = None  # default 0 for sac, 20 for clsac
    pfc: str | None = None  # a key of autopilot.config.PFC_PRESETS; None: the plant's design, the paper's on KH2013A
    sigma_xu: float = 0.0  # sigma-modification of K_Ix, K_Iu (0 = the paper)
    dead_zone_deg: float = 0.0  # robustness options of the law (ClSacConfig), off by default = the paper
    ki_max: float | None = None
    freeze_when_saturated: bool = False
    rate: float = 100.0  # control rate, Hz
    physics_rate: float | None = None  # Hz, a whole multiple of rate; default the smallest one >= 1 kHz
    sensor_rate: float = 200.0  # real time ATTITUDE rate, Hz
    telemetry_rate: float | None = None  # GCS stream, Hz; default 50 in real time, 10 of sim time in lockstep
    out: str | os.PathLike | None = None  # run folder; default a new runs/<timestamp>-... folder
    base_port: int | None = None  # SITL on it, GCS on the next; default free ports
    start_time: float = 0.0  # initial sim clock, s
    profile: str = "square"  # one of PROFILES
    csv: str | None = None  # a profile from a CSV file of "time_s, roll_deg" rows instead
    amplitude: float = 10.0  # deg
    period: float = 10.0  # s
    u_limit_deg: float = 30.0  # rudder command limit (clipped to the plant's surface limit, e.g. 17.5 deg on c172x)
    # The envelope of a controlled flight (autopilot.envelope): |roll| < envelope_roll deg and the rudder saturated
    # in < envelope_saturated % of the steps; envelope=False (--no-envelope): not judged, only measured
    envelope_roll: float = MAX_ROLL_DEG
    envelope_saturated: float = 100.0 * MAX_SATURATED_SHARE
    envelope: bool = True
    timeout: float | None = None  # wall-clock limit of the whole flight, s; default from the duration
    rt_priority: int = 0  # real time: SCHED_FIFO priority of the autopilot (SITL one below), 0 = normal
    pin: bool = False  # the autopilot alone on CPU 1; the SITL and the GCS script on CPU 0
    busy_wait: bool = False  # real time: the autopilot never sleeps between steps (one CPU at 100 %)
    # lockstep: how long the autopilot and the SITL busy-poll for the other's frame before sleeping in select, us;
    # None = the processes' own default (500 us, autopilot --lockstep-spin-us, sitl --spin-us)
    lockstep_spin_us: float | None = None
    # lockstep: the autopilot gives up (powers off, the SITL is blamed) after this many wall s of SITL silence after a
    # frame (autopilot --lockstep-idle-exit)
    lockstep_idle_exit: float = LOCKSTEP_IDLE_EXIT_S
    # the GCS script ends with "vehicle lost" after this many wall s without a word from the vehicle (tools.gcs
    # --vehicle-timeout)
    vehicle_timeout: float = VEHICLE_TIMEOUT_S
    quiet: bool = False  # do not echo the children's output (it is still in DIR/<process>.log)
    viewer: bool = False  # spawn a Rerun viewer (or reuse the one on port 9876) and stream to it live
    connect: str | None = None  # stream live to a running Rerun viewer at this URL
    rrd: bool = True  # Rerun telemetry of the autopilot and the SITL, joined into DIR/flight.rrd
    # the processes write their parts with rerun as they fly (else they spool their rows and the launcher records
    # them after the flight in sim-time order: the same rows, no rerun for the file in either process)
    rrd_live: bool = False
    # parts up to this size are merged (compacted, indexed: memory about twice their size); larger ones are
    # concatenated (streamed into one file without an index: bounded memory whatever the flight's length)
    rrd_merge_max_mb: float = MERGE_MAX_MB
    # a live viewer (viewer, connect, web) gets at most this many rows per second of sim time of each table of lines
    # (autopilot.shared.telemetry.thinning; 0: every row); DIR/flight.rrd keeps every row
    live_rate: float = LIVE_RATE_HZ
    live_window: float = LIVE_WINDOW_S  # a live viewer's plots show the last this many sim s (0: the whole flight)
    series: bool = True  # per-step series in DIR/autopilot_series.npz and DIR/sitl_series.npz
    png: bool = True  # DIR/flight.png: roll vs command and reference models, rudder, adaptive gains (from the series)
    web: bool = (
        False  # serve the Rerun web viewer (tools.flight.web: HTTP web_port, gRPC web_grpc_port) and stream to it
    )
    web_host: str = "127.0.0.1"  # the address it binds: loopback unless asked (0.0.0.0 exposes it, unauthenticated)
    web_port: int = 9090  # its HTTP port (the page a browser opens)
    web_grpc_port: int = 9877  # its gRPC proxy (the processes stream to it, the browser reads it)
    gcs_peer: tuple = ()  # more ground stations (HOST:PORT) the autopilot streams to, e.g. MAVProxy on :14550
    # the autopilot takes MAV_CMD_INJECT_FAILURE from a ground station and relays it to the SITL (SYS_FAILURE_EN 1)
    failure_injection: bool = False
    name: str | None = None  # run name in summary.json; default the controller
    signing: bool = True  # MAVLink 2 signing on every link; a new key per flight in DIR/signing.key unless signing_key
    signing_key: str | os.PathLike | None = None  # sign with this key file (autopilot.shared.signing) instead
    sysid: int = 1  # the vehicle's MAVLink system id (all three processes' --sysid): launches with others are others
    # Disturbances, passed to the SITL only (sitl.disturbances.FLAGS: text as on the command line, or parsed)
    turbulence: str | None = None  # light | moderate | severe Dryden turbulence
    turbulence_sigma: str | tuple | None = None  # "SV,SW" m/s
    turbulence_length: str | tuple | None = None  # "LV,LW" m
    altitude: float | None = None  # m, for the turbulence scales (default 10)
    gust: str | tuple | None = None  # "AMP,LEN,START" (m/s, m, s) 1-cosine side gust, or a list of them
    crosswind: float | None = None  # m/s
    roll_noise: float | None = None  # deg
    roll_bias: float | None = None  # deg
    rate_noise: float | None = None  # deg/s
    rate_bias: float | None = None  # deg/s
    sensor_delay: int | None = None  # samples
    loss: float | None = None  # link loss probability, each direction
    delay: float | None = None  # link one-way delay, s (sim s in lockstep)
    duplicate: float | None = None  # link duplication probability
    reorder: float | None = None  # link reordering probability
    scale: str | tuple | None = None  # "NAME=F" or "NAME=LO:HI" plant scale factor, or a list of them
    seed: int | None = None  # seed of every disturbance (default 0)
    # mid-flight faults, passed to the SITL (sitl.damage): "KIND[=VALUE]@START[:END]" specs (or Fault), a list of them
    fault: str | tuple | list | None = None
    plant: str = "kh2013a"  # the SITL's plant (sitl.plant): kh2013a, FILE.toml or jsbsim:MODEL[:KEY=VALUE,...]
    params: str | os.PathLike | None = None  # the autopilot's parameter file; default the plant's designed one
    baseline_gains: str | tuple | None = None  # "KP,KI,KD" of the baseline; default the plant's designed ones
    command: Profile = field(init=False, repr=False, compare=False)  # the profile the GCS flies

    def __post_init__(self) -> None:
        from autopilot.config import PFC_PRESETS

        def put(name, value):
            object.__setattr__(self, name, value)

        for f in fields(self):  # a switch is True or False: "no", 0 or None would be taken as on or off by truth
            if f.type == "bool" and not isinstance(value := getattr(self, f.name), bool):
                raise FlightConfigError(f.name, f"{f.name} must be True or False, got {value!r}")

        for name, check in (  # the launcher's own argument types: values that cannot be flown are rejected here
            ("rate", flags.rate_arg),  # the parameter table's bounds (autopilot.params.PARAMS), as the flags
            ("sensor_rate", cli.sensor_rate_hz),
            ("sigma_xu", flags.sigma_xu_arg),
            ("dead_zone_deg", cli.nonneg_float),
            ("start_time", cli.clock_s),
            ("amplitude", cli.angle_deg),
            ("period", cli.timeout_s),
            ("u_limit_deg", flags.u_limit_deg_arg),
            ("rt_priority", cli.rt_priority_arg),
            ("rrd_merge_max_mb", cli.bounded(0.0, 1e6, "MB")),
            ("live_rate", cli.bounded(0.0, 1e4, "Hz")),
            ("live_window", cli.bounded(0.0, cli.MAX_SIM_S, "s")),
            ("envelope_roll", envelope_roll_deg),
            ("envelope_saturated", envelope_saturated_pct),
            ("sysid", cli.sysid_arg),
            ("lockstep_idle_exit", cli.timeout_s),
            ("vehicle_timeout", cli.timeout_s),
        ):
            put(name, _checked(name, check, getattr(self, name)))
        for name, check in (
            ("duration", cli.duration_s),
            ("lv", flags.lv_arg),
            ("ki_max", cli.positive_float),
            ("physics_rate", cli.physics_rate_hz),
            ("telemetry_rate", cli.stream_rate_or_0),
            ("timeout", cli.timeout_s),
            ("connect", cli.viewer_url),
        ):
            if getattr(self, name) is not None:
                put(name, _checked(name, check, getattr(self, name)))
        try:  # a registered name, or a user's law (FILE.py:Class, module:Class: loaded and checked, autopilot.law)
            controllers.get(self.controller)
        except ValueError as exc:
            raise FlightConfigError("controller", f"controller: {exc}") from None
        refused = designs.law_refusal(self.controller)  # a user's law is built once here: its constructor's error
        if refused is not None:
            raise FlightConfigError("controller", refused)
        _require(
            self.pfc is None or self.pfc in PFC_PRESETS,
            "pfc",
            f"pfc must be one of {', '.join(PFC_PRESETS)}, got {self.pfc!r}",
        )
        mimo_refusal = controllers.get(self.controller).kind.mimo  # a law without a square-MIMO form: why
        if mimo_refusal and designs.is_mimo(self):
            raise FlightConfigError(
                "controller", f"controller {self.controller}: {self.plant} is a square MIMO plant: {mimo_refusal}"
            )
        given = {k: getattr(self, k) for k in (*flags.ADAPTIVE_ONLY, "baseline_gains")}
        refused = flags.inapplicable(self.controller, given)
        if refused is not None:  # a value the law would not fly: refused, not ignored
            key, why = refused
            raise FlightConfigError(key, f"{key}{flags.value_text(getattr(self, key))}: {why}")
        _require(
            self.profile in PROFILES, "profile", f"profile must be one of {', '.join(PROFILES)}, got {self.profile!r}"
        )
        if self.physics_rate is None:
            put("physics_rate", cli.default_physics_rate(self.rate))
        ratio = self.physics_rate / self.rate
        _require(
            abs(ratio - round(ratio)) <= 1e-9,
            "physics_rate",
            f"physics_rate ({self.physics_rate:g}) must be a whole multiple of the control rate ({self.rate:g})",
        )
        k0 = self.start_time * self.rate  # lockstep frame K0 = start_time x rate (the SITL's own rule, sitl.__main__)
        _require(
            not self.lockstep or abs(k0 - round(k0)) <= 1e-6,
            "start_time",
            f"start_time ({self.start_time:g}) must be a whole number of frames at the control rate ({self.rate:g} Hz) "
            f"in lockstep: a multiple of {1.0 / self.rate:g} s",
        )
        _require(
            self.base_port is None or (isinstance(self.base_port, int) and 1 <= self.base_port <= 65532),
            "base_port",
            f"base_port must be in 1..65532 (it and the next three ports are used), got {self.base_port!r}",
        )
        from autopilot.params import ATTITUDE_TIMEOUT_S as att_timeout  # the autopilot's default

        _require(
            self.lockstep or self.sensor_rate * att_timeout >= 2.0,
            "sensor_rate",
            f"sensor_rate must be at least {2.0 / att_timeout:g} Hz in real time (the autopilot holds wings level "
            f"after {att_timeout:g} s without attitude: two ATTITUDE per timeout at least), got {self.sensor_rate:g}",
        )
        _require(
            not (self.busy_wait and self.lockstep),
            "busy_wait",
            "busy_wait is for real time (lockstep already polls before sleeping)",
        )
        _require(
            self.lockstep_spin_us is None or 0.0 <= self.lockstep_spin_us <= 1e6,
            "lockstep_spin_us",
            f"lockstep_spin_us must be in 0..1000000 us, got {self.lockstep_spin_us!r}",
        )
        _require(
            not (self.busy_wait and self.rt_priority and rt_throttling()),
            "busy_wait",
            f"busy_wait with a real-time priority: a SCHED_FIFO thread that never sleeps is stopped by the "
            f"kernel's real-time throttling ({rt_throttling()}); use one or the other",
        )
        try:
            command = Profile.of(self.profile, amplitude_deg=self.amplitude, period=self.period)
        except ProfileError as exc:
            raise FlightConfigError(exc.field, str(exc)) from None
        if self.csv is not None:
            _require(
                self.profile == "square",
                "csv",
                f"csv: give either a profile or csv, not both (profile {self.profile!r}, csv {self.csv!r})",
            )
            _require(os.path.isfile(self.csv), "csv", f"csv: no such file {self.csv!r}")
            try:
                command = Profile.from_csv(self.csv)
            except (OSError, ProfileError) as exc:
                raise FlightConfigError("csv", f"csv: {exc}") from None
        put("command", command)
        if self.duration is None:  # a csv profile flies to its last breakpoint, any other 30 s
            _require(
                command.end is None or command.end > 0,
                "csv",
                f"csv: the last breakpoint of {self.csv!r} is at 0 s: give a duration",
            )
            put("duration", DEFAULT_DURATION_S if command.end is None else command.end)
        put("gcs_peer", tuple(_checked("gcs_peer", cli.peer_endpoint, p) for p in self.gcs_peer or ()))
        from tools.flight import web

        put("web_host", _checked("web_host", web.bind_host, self.web_host))
        for name in ("web_port", "web_grpc_port"):
            put(name, _checked(name, web.tcp_port, getattr(self, name)))
        _require(
            self.web_port != self.web_grpc_port,
            "web_port",
            f"web_port must differ from the gRPC port (web_grpc_port), both are {self.web_port}",
        )
        if self.out is not None:
            problem = cli.output_dir_problem(self.out)
            _require(problem is None, "out", f"out: {problem}")
        if self.signing_key is not None:
            from autopilot.shared.signing import KeyFileError, load_key

            _require(self.signing, "signing_key", "signing_key: give a key or signing=False (--no-signing), not both")
            try:
                load_key(self.signing_key)
            except KeyFileError as exc:
                raise FlightConfigError("signing_key", f"signing_key: {exc}") from None
        from sitl import disturbances

        try:
            values = disturbances.parse_values({k: getattr(self, k) for k in disturbances.FLAGS})
            for k, v in values.items():
                put(k, v)
            disturbances.from_values(values)
        except disturbances.DisturbanceValueError as exc:
            raise FlightConfigError(exc.field, str(exc)) from None
        except disturbances.ERRORS as exc:
            raise FlightConfigError("disturbances", str(exc)) from None
        put("fault", _faults(self.fault))
        self._check_plant()

    def _check_plant(self) -> None:
        from autopilot.params import ParamError, load_file
        from sitl import disturbances
        from sitl import plant as plants

        try:
            plants.check(self.plant, self.physics_rate)
            plants.check_disturbances(self.plant, {k: getattr(self, k) for k in disturbances.FLAGS})
            plants.check_faults(self.plant, self.fault)
            if plants.spec(self.plant).jsbsim is not None:
                _trims(self.plant)  # a JSBSim aircraft that does not trim there is refused before anything starts
        except plants.PlantError as exc:
            raise FlightConfigError("plant", f"plant: {exc}") from None
        if self.surface_limit_deg is not None and self.u_limit_deg > self.surface_limit_deg:
            object.__setattr__(self, "u_limit_deg", self.surface_limit_deg)  # the command stops at the surface's stop
        if self.baseline_gains is not None:
            from autopilot.flags import baseline_gains

            gains = self.baseline_gains
            text = gains if isinstance(gains, str) else ",".join(repr(float(g)) for g in gains)
            object.__setattr__(self, "baseline_gains", _checked("baseline_gains", baseline_gains, text))
            if len(self.baseline_gains) > 3 and not dict(controllers.get(self.controller).options).get("feedforward"):
                raise FlightConfigError(
                    "baseline_gains",
                    f"baseline_gains: a fourth gain (KFF) is pid-ff's feed-forward, not {self.controller}'s: "
                    "give KP,KI,KD",
                )
        if self.params is not None:
            try:
                designs.check_params(load_file(self.params), self.controller)
            except OSError as exc:
                raise FlightConfigError("params", f"params: cannot read {self.params}: {exc.strerror or exc}") from None
            except ParamError as exc:
                raise FlightConfigError("params", f"params: {exc}") from None
        self._check_design()

    def _check_design(self) -> None:
        """The plant's design or a clear refusal (``tools.flight.designs.refusal``)."""
        from tools.flight.designs import refusal

        refused = refusal(self)
        if refused is not None:
            raise FlightConfigError(*refused)

    @property
    def params_file(self) -> str | None:
        """The autopilot's --params: the one given, else the design made for the plant (``tools.pfc design``, found
        where ``tools.design.linearise.design_path`` says), which holds every controller's values; not for the
        baseline when its gains are given (they fly instead of the design's)."""
        if self.params is not None:
            return str(self.params)
        law = controllers.get(self.controller).kind
        if law.generic:  # a law on autopilot.law's interface: its design beside the plant's (PLANT-laws.params)
            from tools.design.linearise import designed_law_params

            path = designed_law_params(self.plant, law.design) if law.design else None
            return None if path is None else str(path)
        if not controllers.get(self.controller).adaptive and self.baseline_gains is not None:
            return None
        from tools.design.linearise import designed_params

        path = designed_params(self.plant)
        return None if path is None else str(path)

    @property
    def surface(self) -> str:
        """The surface the command drives: rudder (the KH2013A, a plant file's ``[input] surface``), aileron, ...;
        a square MIMO plant's first (the aileron: the roll channel the loop's verdict and messages name)."""
        from sitl import plant as plants

        return plants.spec(self.plant).surfaces[0]

    @property
    def mimo(self) -> bool:
        """A square MIMO plant (``jsbsim:MODEL:surface=aileron+rudder``): two surfaces, roll and sideslip."""
        from sitl import plant as plants

        return plants.spec(self.plant).mimo

    @property
    def surface2_limit_deg(self) -> float | None:
        """A square MIMO plant's second surface's stop (deg), None for one surface."""
        if not self.mimo:
            return None
        from sitl.jsbsim_plant import parse_spec

        return math.degrees(parse_spec(self.plant).surface_limits_rad[1])

    @property
    def plant_name(self) -> str:
        """The plant as headers, titles and run folders name it: KH2013A, c172x, a plant file's name."""
        from sitl import plant as plants

        return plants.name_of(self.plant)

    @property
    def surface_limit_deg(self) -> float | None:
        """The plant's surface stop (deg; None: unlimited, the KH2013A)."""
        from sitl import plant as plants

        limit = plants.surface_limit_rad(self.plant)
        return None if limit is None else math.degrees(limit)

    @property
    def baseline_gains_flown(self) -> tuple | None:
        """The baseline's gains given, else None (the design's parameter file, or the built-in defaults); pid-ff:
        with its feed-forward K_ff (``tools.design.linearise.flown_baseline_gains``)."""
        c = controllers.get(self.controller)
        if c.law != "baseline":
            return None
        if not dict(c.options).get("feedforward"):
            return None if self.baseline_gains is None else tuple(self.baseline_gains)
        from tools.design.linearise import flown_baseline_gains

        return flown_baseline_gains(self.controller, self.plant, self.baseline_gains)

    @property
    def disturbed(self) -> bool:
        """Any disturbance given (sitl.disturbances.FLAGS other than the seed): not the still-air, ideal flight."""
        from sitl import disturbances

        return any(getattr(self, k) is not None for k in disturbances.FLAGS if k != "seed")

    @property
    def disturbance_argv(self) -> list[str]:
        """The SITL flags of the disturbances (empty for an ideal flight)."""
        from sitl import disturbances

        return disturbances.to_argv({k: getattr(self, k) for k in disturbances.FLAGS})

    @property
    def flight_envelope(self) -> Envelope:
        """The envelope the flight is judged against (``autopilot.envelope.Envelope``)."""
        return Envelope(self.envelope_roll, self.envelope_saturated / 100.0, check=self.envelope)

    @property
    def lv_value(self) -> float:
        """Lv flown: the given one, else 0 for sac and 20 for clsac."""
        return self.lv if self.lv is not None else default_lv(self.controller)

    @property
    def gcs_telemetry_rate(self) -> float:
        """In lockstep the GCS stream only serves the ground station (the tlog has every frame's ATTITUDE and
        SERVO_OUTPUT_RAW anyway) and 10 Hz of sim time is still hundreds of messages per wall second."""
        if self.telemetry_rate is not None:
            return self.telemetry_rate
        return 10.0 if self.lockstep else 50.0

    @property
    def wall_timeout(self) -> float:
        return self.timeout or ((60.0 + self.duration * 0.5) if self.lockstep else (self.duration + 30.0))

    @property
    def scenario(self) -> str:
        """ "paper" for the reference scenario's set-up, else "custom"."""
        from sitl import plant_kinds

        paper = (
            self.profile == "square"
            and not self.csv
            and self.amplitude == 10.0
            and self.period == 10.0
            and self.duration == 30.0
            and self.rate == 100.0
            and self.physics_rate == 1000.0
            and self.u_limit_deg == 30.0
            and not self.disturbed
            and not self.fault
            and plant_kinds.kind_of(self.plant).paper
        )
        return "paper" if paper else "custom"


def _faults(value) -> tuple:
    """``fault``: None, one spec (text or ``sitl.damage.Fault``) or a list of them -> a tuple of Fault."""
    from sitl import damage

    items = [] if value is None else [value] if isinstance(value, (str, damage.Fault)) else list(value)
    try:
        return tuple(v if isinstance(v, damage.Fault) else damage.parse(v) for v in items)
    except damage.FaultSpecError as exc:
        raise FlightConfigError("fault", f"fault: {exc}") from None


@functools.cache
def _trims(plant: str) -> None:
    """Build (and so trim) a JSBSim plant once per process: ``sitl.plant.PlantError`` if it cannot trim (an airspeed
    outside the aircraft's envelope, a model that is not an aircraft), found here instead of in the SITL mid-launch."""
    from sitl import plant as plants
    from sitl.jsbsim_models import quiet_stdio

    with quiet_stdio():  # JSBSim's own chatter (its C++ writes to fds 1 and 2): the refusal is one line
        plants.build(plant, 1000.0)
