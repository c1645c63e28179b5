"""``Flight``: one flight of SITL + autopilot + GCS script as real processes over loopback UDP.

The programmatic form of ``python -m tools.launch``; its keywords are the launcher's long flags (``rrd=False`` for
``--no-rrd``, ``series=False`` for ``--no-series``, ``profile="sine"`` for the positional profile), with the same
defaults and units (degrees and Hz as on the flags)::

    from tools.flight import Flight

    result = Flight(lockstep=True, duration=5, controller="sac", out="runs/x").run()
    result.ok, result.metrics["ise_ref"], result.series["phi"]
    result.completed, result.controlled, result.reason    # True, False, "out of envelope: |roll| reached ..."

    with Flight(lockstep=True, duration=600, out="runs/y") as flight:   # starts the three processes
        flight.wait(timeout=2.0)                                          # fly 2 s of wall clock, then leave
    flight.result.reason                                                  # "stopped by the caller after ..."

Every flight, however it ends, leaves in its folder ``flight.tlog`` (every packet the autopilot sent and received),
``summary.json`` (one run with the metrics of what flew, plus counters, timing, events and exit codes),
``<process>.log`` for each child (and ``web.log``, the ``--web`` server's, with ``web``), ``flight.rrd`` (``rrd``)
and ``autopilot_series.npz``/``sitl_series.npz`` (``series``).  A bad keyword value raises ``FlightConfigError`` at
construction, an unknown keyword TypeError.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import threading
import time
from dataclasses import dataclass, field, fields
from functools import cached_property
from pathlib import Path

from autopilot import flags
from autopilot.envelope import MAX_ROLL_DEG, MAX_SATURATED_SHARE, Envelope
from autopilot.flags import CONTROLLERS, default_lv, envelope_roll_deg, envelope_saturated_pct
from autopilot.metrics import METRIC_NAMES
from autopilot.shared import cli
from autopilot.shared.process import (
    EXIT_ADDRESS_IN_USE,
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_OUT_OF_ENVELOPE,
    EXIT_USAGE,
    rt_throttling,
    write_json_atomic,
)
from tools.children import Child, free_udp_ports, new_run_dir, stop_children
from tools.profiles import Profile, ProfileError

PROCESSES = ("sitl", "gcs", "autopilot")
PROFILES = ("square", "step", "sine")
MERGE_MAX_MB = 64.0  # default rrd_merge_max_mb: larger telemetry parts are concatenated (streamed), not merged
PNG_MAX_POINTS = 20_000  # flight.png plots every k-th step of a long flight: bounded memory whatever its length
DEFAULT_DURATION_S = 30.0  # a flight's length unless given (a csv profile: its last breakpoint)
RUDDER_MAX_DEG = 30.0  # the servo calibration's full deflection (SITL and autopilot default)


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
    pfc: str = "paper"  # a key of autopilot.config.PFC_PRESETS
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
    quiet: bool = False  # do not echo the children's output (it is still in DIR/<process>.log)
    viewer: bool = False  # spawn a Rerun viewer (or reuse the one on port 9876) and stream to it live
    connect: str | None = None  # stream live to a running Rerun viewer at this URL
    rrd: bool = True  # Rerun telemetry of the autopilot and the SITL, joined into DIR/flight.rrd
    # parts up to this size are merged (compacted, indexed: memory about twice their size); larger ones are
    # concatenated (streamed into one file without an index: bounded memory whatever the flight's length)
    rrd_merge_max_mb: float = MERGE_MAX_MB
    series: bool = True  # per-step series in DIR/autopilot_series.npz and DIR/sitl_series.npz
    png: bool = True  # DIR/flight.png: roll vs command and reference models, rudder, adaptive gains (from the series)
    web: bool = False  # serve the Rerun web viewer (tools.web: HTTP web_port, gRPC web_grpc_port) and stream to it
    web_host: str = "127.0.0.1"  # the address it binds: loopback unless asked (0.0.0.0 exposes it, unauthenticated)
    web_port: int = 9090  # its HTTP port (the page a browser opens)
    web_grpc_port: int = 9877  # its gRPC proxy (the processes stream to it, the browser reads it)
    gcs_peer: tuple = ()  # more ground stations (HOST:PORT) the autopilot streams to, e.g. MAVProxy on :14550
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
    plant: str = "kh2013a"  # the SITL's plant (sitl.plant): kh2013a, FILE.toml or jsbsim:MODEL[:KEY=VALUE,...]
    params: str | os.PathLike | None = None  # the autopilot's parameter file; default the plant's designed one
    baseline_gains: str | tuple | None = None  # "KP,KI,KD" of the baseline; default the plant's designed ones
    command: Profile = field(init=False, repr=False, compare=False)  # the profile the GCS flies

    def __post_init__(self) -> None:
        from autopilot.config import PFC_PRESETS

        def put(name, value):
            object.__setattr__(self, name, value)

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
            ("envelope_roll", envelope_roll_deg),
            ("envelope_saturated", envelope_saturated_pct),
            ("sysid", cli.sysid_arg),
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
        _require(
            self.controller in CONTROLLERS,
            "controller",
            f"controller must be one of {', '.join(CONTROLLERS)}, got {self.controller!r}",
        )
        _require(self.pfc in PFC_PRESETS, "pfc", f"pfc must be one of {', '.join(PFC_PRESETS)}, got {self.pfc!r}")
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
        _require(
            self.base_port is None or (isinstance(self.base_port, int) and 1 <= self.base_port <= 65532),
            "base_port",
            f"base_port must be in 1..65532 (it and the next three ports are used), got {self.base_port!r}",
        )
        from autopilot.loop import AutopilotOptions  # the autopilot's default attitude timeout

        att_timeout = AutopilotOptions.attitude_timeout_s
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
        from tools import web

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
        self._check_plant()

    def _check_plant(self) -> None:
        from autopilot.params import ParamError, load_file
        from sitl import disturbances
        from sitl import plant as plants

        try:
            plants.check(self.plant)
            plants.check_disturbances(self.plant, {k: getattr(self, k) for k in disturbances.FLAGS})
        except plants.PlantError as exc:
            raise FlightConfigError("plant", f"plant: {exc}") from None
        if self.surface_limit_deg is not None and self.u_limit_deg > self.surface_limit_deg:
            object.__setattr__(self, "u_limit_deg", self.surface_limit_deg)  # the command stops at the surface's stop
        if self.baseline_gains is not None:
            from autopilot.flags import baseline_gains

            gains = self.baseline_gains
            text = gains if isinstance(gains, str) else ",".join(repr(float(g)) for g in gains)
            object.__setattr__(self, "baseline_gains", _checked("baseline_gains", baseline_gains, text))
        if self.params is not None:
            try:
                load_file(self.params)
            except OSError as exc:
                raise FlightConfigError("params", f"params: cannot read {self.params}: {exc.strerror or exc}") from None
            except ParamError as exc:
                raise FlightConfigError("params", f"params: {exc}") from None

    @property
    def params_file(self) -> str | None:
        """The autopilot's --params: the one given, else the PFC designed for the plant (tools.pfc design, shipped
        beside it), for SAC/CL-SAC only (the baseline has no PFC)."""
        if self.params is not None:
            return str(self.params)
        if self.controller == "baseline":
            return None
        from tools.plant import designed_params

        path = designed_params(self.plant)
        return None if path is None else str(path)

    @property
    def surface_limit_deg(self) -> float | None:
        """The plant's surface stop (deg; None: unlimited, the KH2013A)."""
        from sitl import plant as plants

        limit = plants.surface_limit_rad(self.plant)
        return None if limit is None else math.degrees(limit)

    @property
    def baseline_gains_flown(self) -> tuple | None:
        """The baseline's gains: the ones given, else those designed for the plant; None: the built-in defaults."""
        if self.controller != "baseline":
            return None
        if self.baseline_gains is not None:
            return tuple(self.baseline_gains)
        from tools.plant import designed_baseline

        return designed_baseline(self.plant)

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
            and self.plant == "kh2013a"
        )
        return "paper" if paper else "custom"


@dataclass(frozen=True)
class FlightResult:
    """How a flight ended and what it left; ``series`` is read from the run folder on first use.

    Two facts: ``completed`` (flown to the end, every process clean) and ``controlled`` (it stayed inside the
    envelope, ``autopilot.envelope``; None when the autopilot left no verdict).  ``ok`` is both."""

    ok: bool
    exit_code: int  # 0 ok, 1 a process failed, 3 out of the envelope, 130 interrupted or stopped by the caller
    reason: str | None  # None when ok, else one line: what failed, or why the flight was not controlled
    metrics: dict  # the five METRIC_NAMES of what flew (None if nothing flew)
    out: Path
    summary: dict  # what summary.json holds
    completed: bool = False
    controlled: bool | None = None

    @property
    def outcome(self) -> str:
        """ "OK", "OUT OF ENVELOPE" or "FAILED" (``summary["outcome"]``)."""
        return outcome_of(self.exit_code)

    @cached_property
    def series(self) -> dict:
        """The per-step series (``load_series``): arrays keyed like ``tools.scenario.SERIES``; {} if not recorded."""
        return load_series(self.out)


# ---------------------------------------------------------------------------------------- child processes
def child_argvs(
    cfg: FlightConfig,
    out: Path,
    sitl_port: int,
    gcs_port: int,
    telemetry: dict[str, list[str]] | None = None,
    key_file: Path | None = None,
    ap_ports: tuple[int, int] | None = None,
) -> dict[str, list[str]]:
    """The command line of each process of the flight; ``ap_ports``: the autopilot's SITL-link and GCS-link ports,
    given to all three so that every link is pinned to its peer from the start (docs/design.md, "Trust model")."""
    py = [sys.executable, "-u", "-m"]
    pwm = ["--rudder-max-deg", repr(max(RUDDER_MAX_DEG, cfg.u_limit_deg))]
    sitl = (
        py
        + [
            "sitl",
            "--listen",
            f"127.0.0.1:{sitl_port}",
            "--rate",
            repr(cfg.rate),
            "--physics-rate",
            repr(cfg.physics_rate),
            "--start-time",
            repr(cfg.start_time),
            "--stats-json",
            str(out / "sitl.json"),
        ]
        + pwm
        + cfg.disturbance_argv
        + (["--plant", cfg.plant] if cfg.plant != "kh2013a" else [])
    )
    ap = (
        py
        + [
            "autopilot",
            "--sitl",
            f"127.0.0.1:{sitl_port}",
            "--gcs",
            f"127.0.0.1:{gcs_port}",
            "--rate",
            repr(cfg.rate),
            "--controller",
            cfg.controller,
            "--lv",
            repr(cfg.lv_value),
            "--pfc",
            cfg.pfc,
            "--sigma-xu",
            repr(cfg.sigma_xu),
            "--dead-zone-deg",
            repr(cfg.dead_zone_deg),
            *(["--ki-max", repr(cfg.ki_max)] if cfg.ki_max is not None else []),
            *(["--freeze-when-saturated"] if cfg.freeze_when_saturated else []),
            "--name",
            cfg.name or cfg.controller,
            "--u-limit-deg",
            repr(cfg.u_limit_deg),
            "--envelope-roll",
            repr(cfg.envelope_roll),
            "--envelope-saturated",
            repr(cfg.envelope_saturated),
            *([] if cfg.envelope else ["--no-envelope"]),
            "--duration",
            repr(cfg.duration),
            "--telemetry-rate",
            repr(cfg.gcs_telemetry_rate),
            "--tlog",
            str(out / "flight.tlog"),
            "--stats-json",
            str(out / "autopilot.json"),
        ]
        + pwm
    )
    if cfg.params_file is not None:
        ap += ["--params", cfg.params_file]
    if cfg.baseline_gains_flown is not None:
        ap += ["--baseline-gains", ",".join(repr(g) for g in cfg.baseline_gains_flown)]
    # Lockstep: the GCS schedules the profile up to the end; real time: it flies until the autopilot powers off.
    gcs = py + [
        "tools.gcs",
        "--listen",
        f"127.0.0.1:{gcs_port}",
        "--duration",
        repr(cfg.duration if cfg.lockstep else 0),
        "--amplitude",
        repr(cfg.amplitude),
        "--period",
        repr(cfg.period),
        "--stats-json",
        str(out / "gcs.json"),
        "--start-time",
        repr(cfg.start_time),
    ]
    gcs += ["--csv", cfg.csv] if cfg.csv else [cfg.profile]
    if cfg.series:
        ap += ["--series", str(out / "autopilot_series.npz")]
        sitl += ["--series", str(out / "sitl_series.npz")]
    if cfg.lockstep:
        sitl += ["--lockstep", "--duration", repr(cfg.duration)]
        ap += ["--lockstep", "--lockstep-idle-exit", "5"]
        gcs += ["--lockstep"]
    else:
        sitl += ["--sensor-rate", repr(cfg.sensor_rate)]
        if cfg.rt_priority:
            ap += ["--rt-priority", str(cfg.rt_priority)]
            sitl += ["--rt-priority", str(max(1, cfg.rt_priority - 1))]
        if cfg.busy_wait:
            ap += ["--busy-wait"]
    if cfg.pin and (os.cpu_count() or 1) >= 2:
        # The autopilot gets CPU 1 to itself; the SITL and the GCS share CPU 0 (a GCS woken on the autopilot's
        # CPU preempts it mid-frame: attitude-to-servo latency p99 0.13-0.65 ms -> 0.08-0.12 ms here).
        sitl += ["--cpu", "0"]
        gcs += ["--cpu", "0"]
        ap += ["--cpu", "1"]
    if telemetry:
        for name, argv in (("sitl", sitl), ("autopilot", ap)):
            argv += telemetry[name]
    if key_file is not None:
        for argv in (sitl, ap, gcs):
            argv += ["--signing-key", str(key_file)]
    for argv in (sitl, ap, gcs):
        argv += ["--sysid", str(cfg.sysid)]
    if ap_ports is not None:
        a_sitl, a_gcs = (f"127.0.0.1:{p}" for p in ap_ports)
        ap += ["--sitl-bind", a_sitl, "--listen", a_gcs, "--gcs-peer", f"127.0.0.1:{gcs_port}"]
        sitl += ["--autopilot", a_sitl]
        gcs += ["--vehicle", a_gcs]
    for host, port in cfg.gcs_peer:
        ap += ["--gcs-peer", f"{host}:{port}"]
    return {"sitl": sitl, "autopilot": ap, "gcs": gcs}


def _flight_key(cfg: FlightConfig, out: Path) -> Path | None:
    """The signing key file of the flight: ``signing_key``, else a new one in DIR/signing.key (mode 0600);
    None when signing is off."""
    if not cfg.signing:
        return None
    if cfg.signing_key is not None:
        return Path(cfg.signing_key)
    from autopilot.shared.signing import write_key

    path = out / "signing.key"
    path.unlink(missing_ok=True)
    write_key(path)
    return path


def _telemetry_argvs(
    cfg: FlightConfig, out: Path, web_url: str | None = None
) -> tuple[dict[str, list[str]] | None, dict[str, Path], str | None]:
    """One recording id for the flight; each process writes its own part file (joined at the end).  ``web_url``: the
    flight's web viewer (``--web``, already started), which the processes stream to."""
    if not (cfg.rrd or cfg.viewer or cfg.connect or cfg.web):
        return None, {}, None
    from autopilot.shared import telemetry as tm

    rid = tm.new_recording_id()
    parts = tm.part_paths(out) if cfg.rrd else {}
    for p in parts.values():
        p.parent.mkdir(parents=True, exist_ok=True)
        p.unlink(missing_ok=True)
    url = cfg.connect or (tm.spawn_viewer() if cfg.viewer else None)  # one viewer for both processes
    if web_url is not None:
        url = web_url
    if url:  # the processes send data only; the layout that joins them comes from here
        from tools.views import flight_blueprint

        tm.send_blueprint(url, flight_blueprint(), rid)
    argv = {}
    for name in ("autopilot", "sitl"):
        argv[name] = ["--recording-id", rid]
        if name in parts:
            argv[name] += ["--rrd", str(parts[name])]
        if url:
            argv[name] += ["--connect", url]
    return argv, parts, rid


def serve_web(web) -> str:
    """Start the flight's web viewer (a ``tools.web.WebServer``, bound to loopback unless ``web_host`` says otherwise)
    and print where to open it; the URL the processes stream to.  It ends with the flight (``Flight._stop_web``)."""
    url = web.start()
    for line in web.notice():
        print(line, flush=True)
    return url


def _web_server(cfg: FlightConfig, out: Path):
    """The flight's ``tools.web.WebServer`` (not started), its output in DIR/web.log."""
    from tools.web import WebServer

    return WebServer(cfg.web_host, cfg.web_port, cfg.web_grpc_port, log_path=out / "web.log")


def write_flight_png(cfg: FlightConfig, out: Path, name: str, metrics: dict) -> Path | None:
    """DIR/flight.png from the flight's series (``tools.plots.flight_figure``); None without series."""
    from tools.plots import save_flight_figure
    from tools.scenario import RunResult

    series = load_series(out, max_points=PNG_MAX_POINTS)
    if not series or series.get("t") is None or not len(series["t"]):
        return None
    res = RunResult(name, cfg.lv_value if cfg.controller != "sac" else 0.0, metrics, series)
    mode = "lockstep" if cfg.lockstep else "real time"
    title = f"Flight {out.name}: {res.name}, {mode}, {cfg.rate:g} Hz"
    return save_flight_figure(res, out / "flight.png", math.radians(cfg.u_limit_deg), title)


def _join_telemetry(
    parts: dict[str, Path], out: Path, recording_id: str | None, merge_max_mb: float
) -> tuple[Path | None, bool, str | None]:
    """Join the processes' part files into DIR/flight.rrd (whatever ended the flight); (path, indexed, error).

    ``rerun rrd merge`` compacts the chunks and writes the footer (index) the viewer uses for random access, but
    holds the whole recording in memory (about twice the files' size).  So parts larger than ``merge_max_mb`` in
    all (a flight of more than about 15 minutes at 100 Hz by default) are concatenated instead: their messages
    are copied into the same one file without decoding, a buffer at a time (constant memory whatever the
    flight's length; no footer, so ``indexed`` is False).  Either way the flight has one recording, with the
    viewer layout."""
    existing = [p for p in parts.values() if p.exists() and p.stat().st_size > 0]
    if not existing:
        return None, False, ("no telemetry was written" if parts else None)
    from autopilot.shared import telemetry as tm
    from tools.views import flight_blueprint

    target = out / "flight.rrd"
    indexed = sum(p.stat().st_size for p in existing) <= merge_max_mb * 1e6
    try:
        if indexed:
            tm.merge_recordings(existing, target, blueprint=flight_blueprint(), remove_parts=True)
        else:
            tm.concatenate_recordings(
                existing, target, blueprint=flight_blueprint(), recording_id=recording_id, remove_parts=True
            )
    except Exception as exc:  # noqa: BLE001  (a flight's other files stay valid; say what went wrong)
        return None, False, f"joining telemetry into {target} failed: {exc}"
    try:
        (out / ".parts").rmdir()
    except OSError:
        pass
    return target, indexed, None


# ---------------------------------------------------------------------------------------- summary
def _load(path: Path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def build_summary(
    cfg: FlightConfig,
    out: Path,
    stats: dict,
    exit_codes: dict,
    failed: str | None,
    error: str | None,
    exit_code: int,
    wall: float,
    rrd_path: Path | None,
    rrd_indexed: bool = False,
) -> dict:
    """summary.json of a flight from the processes' stats files (``stats``: process name -> dict or None)."""
    ap, sitl, gcs = stats["autopilot"], stats["sitl"], stats["gcs"]
    runs = []
    if ap and ap.get("metric_samples"):
        runs.append(
            {
                "name": ap["name"],
                "Lv": ap["Lv"],
                "metrics": ap["metrics"],
                "steps": ap["steps"],
                "controlled": ap.get("controlled"),
            }
        )
    return {
        "scenario": cfg.scenario,
        "runs": runs,
        "transport": "mavlink",
        "mode": "lockstep" if cfg.lockstep else "realtime",
        "signing": cfg.signing,  # MAVLink 2 signing on every link (docs/design.md, "Trust model")
        "controller": cfg.controller,
        "Lv": cfg.lv_value,
        "pfc": cfg.pfc,
        "sigma_xu": cfg.sigma_xu,
        "dead_zone_deg": cfg.dead_zone_deg,
        "ki_max": cfg.ki_max,
        "freeze_when_saturated": cfg.freeze_when_saturated,
        "duration_s": cfg.duration,
        "rate_hz": cfg.rate,
        "physics_rate_hz": cfg.physics_rate,
        "start_time_s": cfg.start_time,
        "profile": {
            "kind": "csv" if cfg.csv else cfg.profile,
            "amplitude_deg": cfg.amplitude,
            "period_s": cfg.period,
            "csv": cfg.csv,
        },
        "ok": exit_code == 0,
        "outcome": outcome_of(exit_code),
        "exit_code": exit_code,
        # flown to the end with every process clean / inside the envelope (README, "Outcomes"; autopilot.envelope)
        "completed": exit_code in (EXIT_OK, EXIT_OUT_OF_ENVELOPE),
        "controlled": ap.get("controlled") if ap else None,
        "failed": failed,
        "error": error,
        "exit_codes": exit_codes,
        "wall_s": wall,
        "rtf": sitl.get("rtf") if sitl else None,
        "sim_time_s": sitl.get("sim_time_s") if sitl else None,
        "timing": ap.get("timing") if ap else None,
        "events": {"autopilot": ap.get("events") if ap else None, "sitl": sitl.get("events") if sitl else None},
        "disturbances": sitl.get("disturbances") if sitl else None,  # what the SITL injected (sitl.disturbances)
        "counters": {
            "autopilot": ap.get("links") if ap else None,
            "sitl": sitl.get("link") if sitl else None,
            "gcs": gcs.get("link") if gcs else None,
        },
        "files": {
            "tlog": str(out / "flight.tlog"),
            "rrd": str(rrd_path) if rrd_path else None,  # DIR/flight.rrd, one recording with the viewer layout
            # merged with rerun's footer (index); False: concatenated without one (a long flight, bounded memory)
            "rrd_indexed": bool(rrd_path) and rrd_indexed,
            "summary": str(out / "summary.json"),
            "logs": {n: str(out / f"{n}.log") for n in PROCESSES},
            "stats": {n: str(out / f"{n}.json") for n in PROCESSES},
        },
    }


def _npz_columns(path: Path, keys=None, stride: int = 1, start: int = 0) -> dict:
    """Columns of an .npz, every ``stride``-th value from index ``start``, read a chunk at a time (the memory
    held is the decimated columns, whatever the file's length)."""
    import zipfile

    import numpy as np

    out = {}
    with zipfile.ZipFile(path) as zf:
        for member in zf.namelist():
            key = member[:-4] if member.endswith(".npy") else member
            if keys is not None and key not in keys:
                continue
            with zf.open(member) as f:
                version = np.lib.format.read_magic(f)
                read_header = (
                    np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
                )
                shape, _fortran, dtype = read_header(f)
                n = shape[0] if shape else 1
                kept, i0 = [], 0
                while i0 < n:
                    m = min(1 << 16, n - i0)
                    a = np.frombuffer(f.read(m * dtype.itemsize), dtype=dtype, count=m)
                    j = start - i0 if i0 <= start else (start - i0) % stride  # first index to keep here
                    if j < m:
                        kept.append(a[j::stride].copy())
                    i0 += m
                out[key] = np.concatenate(kept) if kept else np.empty(0, dtype)
    return out


def load_series(out_dir, max_points: int | None = None) -> dict:
    """Merge DIR/autopilot_series.npz and DIR/sitl_series.npz into tools.scenario.SERIES-style arrays;
    ``max_points``: every k-th step only, at most that many (a plot of a long flight in bounded memory)."""
    import zipfile

    import numpy as np

    out_dir = Path(out_dir)
    try:
        with zipfile.ZipFile(out_dir / "autopilot_series.npz") as zf, zf.open("t.npy") as f:
            version = np.lib.format.read_magic(f)
            read_header = (
                np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            )
            steps = read_header(f)[0][0]
        series = _npz_columns(out_dir / "autopilot_series.npz", stride=(stride := _stride(steps, max_points)))
    except (OSError, KeyError, zipfile.BadZipFile):
        return {}
    if series.get("t") is not None and len(series["t"]):
        series["t"] = series["t"] - series["t"][0]
    try:
        # SITL rows are the state after frame k, i.e. at t_{k+1}; the state at t_0 is the initial zero.
        s = _npz_columns(out_dir / "sitl_series.npz", ("v", "delta_r"), stride, start=stride - 1)
        n = len(series.get("t", ()))
        for key in ("v", "delta_r"):
            col = np.concatenate([[0.0], s[key]])[:n]
            if len(col) == n:
                series[key] = col
    except (OSError, KeyError, zipfile.BadZipFile):
        pass
    return series


def _stride(steps: int, max_points: int | None) -> int:
    return 1 if not max_points or steps <= max_points else -(-steps // max_points)


# ---------------------------------------------------------------------------------------- the verdict
# A previous flight's files in a reused folder: removed before a new flight starts, so none can pass for its own.
STALE_FILES = (
    "autopilot.json",
    "sitl.json",
    "gcs.json",
    "autopilot_series.npz",
    "sitl_series.npz",
    "flight.rrd",
    "flight.png",
)


def provisional_summary(pid: int) -> dict:
    """DIR/summary.json while a flight runs: not OK until the launcher writes the verdict."""
    return {
        "ok": False,
        "running": True,
        "exit_code": None,
        "failed": None,
        "error": f"the flight has not ended: it is still running, or its launcher (pid {pid}) was killed",
        "launcher_pid": pid,
    }


def write_refusal(out: str | os.PathLike, process: str, reason: str) -> Path | None:
    """DIR/summary.json of a flight refused before anything was started (a value that cannot be flown):
    ``ok: false``, exit status 2, the process the value belongs to, the reason and nothing flown.  So a caller that
    reads summary.json finds the verdict whatever ended the launch.  None if DIR cannot be made or written (the
    one-line error on stderr still says why)."""
    path = Path(out) / "summary.json"
    summary = {
        "ok": False,
        "refused": True,  # nothing was started
        "exit_code": EXIT_USAGE,
        "failed": process,
        "error": f"{process}: {reason} (refused before the flight: nothing was started)",
        "flown": {"steps": 0, "steps_asked": None, "fraction": 0.0, "frames": 0, "sim_time_s": 0.0, "complete": False},
        "files": {"summary": str(path)},
    }
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(path, summary)
    except OSError:
        return None
    return path


def _ended_normally(ap: dict | None) -> bool:
    """The autopilot's own stats say its run reached the end (not stopped, not a peer's silence)."""
    return bool(ap) and str(ap.get("exit_reason", "")).startswith("end of run")


def _sitl_flown_steps(cfg: FlightConfig, sitl: dict) -> int:
    """Control steps the aircraft flew under the autopilot's commands, from the SITL's own counters (the flight of
    an autopilot that left no stats): lockstep, its frames (each one waits for an answer); real time, the control
    periods of sim time from the first servo command it applied to the last, less the time it flew on its servo
    timeout in between (whatever it flew after the last command, nobody was behind it)."""
    if cfg.lockstep:
        return int(sitl.get("frames") or 0)
    first, last = sitl.get("first_servo_sim_s"), sitl.get("last_servo_sim_s")
    if first is None or last is None:
        return 0
    commanded = last - first - (sitl.get("servo_timeout_s") or 0.0)
    return max(0, int(commanded * cfg.rate + 1e-6) + 1)  # the last command's own period included


def flown_report(cfg: FlightConfig, stats: dict) -> dict:
    """What flew against what was asked: control steps, SITL frames and sim time; ``fraction`` = steps flown /
    steps asked.

    Lockstep: the autopilot's steps (each one a SITL frame answered).  Real time: the steps asked less every control
    period lost (docs/design.md, "summary.json"): a step flown as a hold for want of attitude, a step that came more
    than the attitude timeout after its deadline or after the step before, and each control period of sim time the
    SITL flew on its servo timeout (rudder neutral, no command: ``servo_timeout_s``, plus the episode still on at
    the end unless the autopilot ended its run itself).  Without the autopilot's stats (it was killed) the steps
    come from what the SITL flew (``_sitl_flown_steps``)."""
    ap, sitl = stats["autopilot"], stats["sitl"]
    asked = round(cfg.duration * cfg.rate)
    lost = {"hold_steps": 0, "late_steps": 0, "servo_timeout_s": 0.0}
    if ap:
        source = "autopilot"
        steps = ap["steps"]
        if not cfg.lockstep:
            lost["hold_steps"] = ap.get("hold_steps", 0)
            lost["late_steps"] = ap.get("late_steps", 0)
            if sitl:
                lost["servo_timeout_s"] = sitl.get("servo_timeout_s", 0.0) + (
                    0.0 if _ended_normally(ap) else sitl.get("servo_timeout_open_s", 0.0)
                )
            timeout_steps = int(round(lost["servo_timeout_s"] * cfg.rate))
            lost_steps = lost["hold_steps"] + lost["late_steps"] + timeout_steps
            steps = max(0, min(steps, asked) - lost_steps) if ap["metric_samples"] else 0
    elif sitl:
        source = "sitl"
        steps = min(_sitl_flown_steps(cfg, sitl), asked)
    else:
        source, steps = None, 0
    return {
        "steps": steps,
        "steps_asked": asked,
        "fraction": steps / asked if asked else 0.0,
        "frames": sitl.get("frames") if sitl else None,
        "sim_time_s": steps / cfg.rate,
        "duration_s": cfg.duration,
        "lost": lost,  # real time: what was not flown (steps, and sim s on the SITL's servo timeout)
        "source": source,  # whose counters the steps come from: the autopilot's, or the SITL's if it left none
        # lockstep: the SITL flew exactly the frames asked as well
        "complete": steps >= asked and (not cfg.lockstep or (sitl or {}).get("frames") == asked),
    }


GCS_END_SLACK_S = 0.5  # the ground station sees the vehicle's clock a telemetry period late (0.1 s in lockstep)
# A process that sent nothing for this long had stopped: each one sends at least a 1 Hz HEARTBEAT while it runs.
STALL_S = 2.0
# Which process's receive clocks hear which peer: (listener, where its stats keep that link's counters).
HEARD_BY = {
    "autopilot": (("sitl", ("link",)), ("gcs", ("link",))),
    "sitl": (("autopilot", ("links", "sitl")),),
    "gcs": (("autopilot", ("links", "gcs")),),
}


def _reached_end(name: str, st: dict | None, duration: float) -> bool:
    """Whether a child that ended says it ended at the end of the run: its exit reason is "end of run" and, for
    the ground-station script, the vehicle clock it saw reached the duration (a forged POWEROFF heartbeat also
    reads "end of run (vehicle powered off)", but in the middle of the profile)."""
    st = st or {}
    if not str(st.get("exit_reason", "")).startswith("end of run"):
        return False
    if name == "gcs":  # how far along its profile the vehicle's clock was
        if st.get("sim_ms") is None or st.get("origin_ms") is None:
            return False
        return (st["sim_ms"] - st["origin_ms"]) / 1000.0 >= duration - GCS_END_SLACK_S
    return True


def _last_heard(name: str, stats: dict) -> tuple[float | None, list[str]]:
    """When a peer last accepted a packet from process ``name`` (monotonic), and which peers heard it."""
    times = []
    for listener, path in HEARD_BY[name]:
        c = stats.get(listener) or {}
        for key in path:
            c = c.get(key) or {}
        if c.get("last_rx_mono") is not None:
            times.append((c["last_rx_mono"], listener))
    return (max(times)[0], [n for _, n in times]) if times else (None, [])


def silences(children: dict, stats: dict, t_end: float) -> dict[str, tuple[float, float, str]]:
    """Each process's longest time without sending anything, begun before the flight ended: (from, seconds,
    evidence), on the machine's monotonic clock.  From the process's own send clock (its stats' ``sent``: the
    longest gap between two sends, or from its last send to the end of its run loop); for a process that left no
    stats (killed while stopped, SIGKILL), from its peers' receive clocks: from the last packet one of them
    accepted from it to its exit (or the end of the flight)."""
    out = {}
    for name in PROCESSES:
        st = stats.get(name)
        sent = (st or {}).get("sent")
        if sent:
            if sent.get("longest_gap_from_mono") is not None:
                out[name] = (sent["longest_gap_from_mono"], sent["longest_gap_s"], f"{name}'s own send clock")
            continue
        heard, by = _last_heard(name, stats)
        if heard is None:
            continue
        c = children.get(name)
        until = c.exited_at if c is not None and c.exited_at is not None else t_end
        out[name] = (heard, min(until, t_end) - heard, f"the receive clock of {' and '.join(by)}")
    return {n: s for n, s in out.items() if s[0] < t_end}


def first_stall(children: dict, stats: dict, t_end: float) -> tuple[str, float, float, str] | None:
    """The process that stopped sending first (name, from, seconds, evidence): of the silences longer than
    ``STALL_S``, the one that began first; None if no process went silent that long."""
    long = [(s[0], n, s[1], s[2]) for n, s in silences(children, stats, t_end).items() if s[1] >= STALL_S]
    if not long:
        return None
    t_from, name, seconds, evidence = min(long)
    return name, t_from, seconds, evidence


def _steps(n: int) -> str:
    return f"{n} step" if n == 1 else f"{n} steps"


def _stall_reason(children: dict, stall: tuple) -> str:
    name, t_from, seconds, evidence = stall
    t0 = min(c.started for c in children.values())
    return f"{name} stalled: sent nothing for {seconds:.1f} s from {t_from - t0:.1f} s after start ({evidence})"


def shortfall(flown: dict, stats: dict, rate: float) -> tuple[str, str]:
    """(process, reason) of a flight the autopilot flew to its end with steps lost.  The steps flown late and the
    time the SITL flew without a command are the autopilot's loss; the steps flown as a hold for want of attitude,
    the SITL's (its attitude did not arrive within the attitude timeout).  The owner of the larger loss, in control
    periods, is named (the autopilot on a tie); the reason lists every loss."""
    ap = stats.get("autopilot") or {}
    lost = flown["lost"]
    tmo = ap.get("attitude_timeout_s")
    autopilot_loss = lost["late_steps"] + round(lost["servo_timeout_s"] * rate)
    name = "sitl" if lost["hold_steps"] > autopilot_loss else "autopilot"
    parts = []
    if lost["late_steps"]:
        parts.append(
            f"{_steps(lost['late_steps'])} flown later than the attitude timeout ({tmo:g} s) "
            f"(the latest {ap.get('max_lateness_s', 0.0):.3g} s late)"
        )
    if lost["servo_timeout_s"]:
        parts.append(f"the SITL flew {lost['servo_timeout_s']:.3g} s on its servo timeout (rudder neutral, no command)")
    if lost["hold_steps"]:
        parts.append(f"{_steps(lost['hold_steps'])} flown as a hold without attitude (none fresher than {tmo:g} s)")
    if not parts:
        parts.append(f"{flown['steps_asked'] - flown['steps']} of {flown['steps_asked']} steps not flown")
    return name, f"{name}: " + "; ".join(parts)


def verdict(
    children: dict, stats: dict, flown: dict, exit_code: int, failed, error, t_end: float
) -> tuple[int, str | None, str | None]:
    """(exit code, process that failed first, reason) of a flight from what flew and how each process ended.

    OK only if every step asked was flown (lockstep: and the SITL flew as many frames), every process exited with
    status 0 and wrote its stats.  Otherwise the culprit comes from evidence, in this order:

    1. if the autopilot flew its run to the end, no other process ended early or failed, but steps were lost (real
       time: late, holds, servo timeout), the owner of the larger loss (``shortfall``; a stall is noted);
    2. the process that stopped sending first (``first_stall``: a silence of ``STALL_S`` or more on its own send
       clock, or on its peers' receive clocks if it left no stats), whoever noticed it;
    3. the process that exited first (a child that ends early with status 0 included), or, when it ended because
       a peer went silent (its stats' ``peer_lost``), that peer.

    The reason is one line with the numbers, plus the fraction flown.
    """
    complete = flown["complete"]
    ap_exit = children["autopilot"].exited_at
    ap_exit = t_end if ap_exit is None else min(ap_exit, t_end)
    early = [  # a child that ended before the autopilot did, other than by reaching the end of the run itself
        c
        for n, c in children.items()
        if n != "autopilot"
        and c.exited_at is not None
        and c.exited_at < ap_exit
        and not _reached_end(n, stats.get(n), flown["duration_s"])
    ]
    clean = all(c.code == 0 for c in children.values()) and all(stats.values()) and not early
    pct = 100.0 * flown["fraction"]
    tail = (
        f"; flown {pct:.3g} % ({flown['steps']} of {flown['steps_asked']} steps, "
        f"{flown['sim_time_s']:g} of {flown['duration_s']:g} s)"
    )
    if complete and clean:
        return (EXIT_OK, None, None) if exit_code == EXIT_OK else (exit_code, failed, f"{error}{tail}")
    # exits seen while the flight ran (not those of stopping it), in order
    order = sorted(
        (c for c in children.values() if c.exited_at is not None and c.exited_at < t_end), key=lambda c: c.exited_at
    )
    if not order and failed is not None and failed not in children:  # the launcher itself ended it (wall clock)
        return exit_code, failed, f"{error}{tail}"
    stall = first_stall(children, stats, t_end)
    stalled = None if stall is None else _stall_reason(children, stall)
    ended_early = early or any(c.code not in (None, 0) for c in order)
    if not complete and _ended_normally(stats.get("autopilot")) and not ended_early:
        # every process flew to the end: what failed the flight is the steps lost (a stall, if any, is noted)
        name, why = shortfall(flown, stats, flown["steps_asked"] / flown["duration_s"])
        return EXIT_FAILED, name, "; ".join([why, *([stalled] if stalled else [])]) + tail
    if stall is not None:
        name = stall[0]
        reports = [
            f"{n} reports: {st['exit_reason']}"
            for n, st in stats.items()
            if n != name and st and st.get("peer_lost") and st.get("exit_reason")
        ]
        return EXIT_FAILED, name, "; ".join([stalled, *reports]) + tail
    first = order[0] if order else children.get(failed) or children["autopilot"]
    name = first.name
    seen = {name}
    while (peer := (stats.get(name) or {}).get("peer_lost")) and peer in children and peer not in seen:
        blamer, name = name, peer  # it ended because this peer went silent: blame the peer
        seen.add(name)
    culprit = children[name]
    own = (stats.get(name) or {}).get("exit_reason")
    if name != first.name:
        why = f"{name} stalled or died: {blamer} reports: {(stats.get(blamer) or {}).get('exit_reason')}"
    elif culprit.code not in (None, 0):
        why = f"{name} failed (exit code {culprit.code}): {culprit.reason()}"
    elif culprit.code == 0:
        why = f"{name} exited early (exit code 0): {own or culprit.reason()}"
        st = stats.get(name) or {}
        if st.get("sim_ms") is not None and st.get("origin_ms") is not None:
            why += f" after {(st['sim_ms'] - st['origin_ms']) / 1000.0:g} s of its profile"
    elif error:
        why = error
    else:
        missing = [n for n, st in stats.items() if not st]
        why = f"{name}: {own or culprit.reason()}" + (f" (no stats from {', '.join(missing)})" if missing else "")
    return EXIT_FAILED, name, why + tail


def outcome_of(exit_code: int) -> str:
    """The launcher's last line for an exit status: OK (0), OUT OF ENVELOPE (3) or FAILED (anything else)."""
    return {EXIT_OK: "OK", EXIT_OUT_OF_ENVELOPE: "OUT OF ENVELOPE"}.get(exit_code, "FAILED")


def envelope_verdict(
    exit_code: int, failed: str | None, error: str | None, controlled: dict | None
) -> tuple[int, str | None, str | None]:
    """A completed flight (``exit_code`` 0 from ``verdict``) that left the envelope is OUT OF ENVELOPE (exit 3) with
    the autopilot's reason; one without the autopilot's verdict fails.  Any other outcome stays as it is."""
    if exit_code != EXIT_OK:
        return exit_code, failed, error
    if controlled is None:
        return EXIT_FAILED, "autopilot", "autopilot: its stats have no envelope verdict (controlled)"
    if not controlled["ok"]:
        return EXIT_OUT_OF_ENVELOPE, None, f"out of envelope: {controlled['reason']}"
    return exit_code, failed, error


# ---------------------------------------------------------------------------------------- the flight
class Flight:
    """One flight: ``run()`` blocks and returns its ``FlightResult``; as a context manager, entering starts the
    processes and leaving stops whatever still runs, after which ``result`` holds the ``FlightResult``.

    ``start()``, ``wait(timeout)``, ``stop()`` and ``running`` are the pieces; ``interrupt()`` (safe from a signal
    handler or another thread) ends the flight as interrupted at the next poll of ``wait``.
    """

    def __init__(self, **options):
        known = {f.name for f in fields(FlightConfig) if f.init}
        unknown = sorted(set(options) - known)
        if unknown:
            raise TypeError(f"Flight() got unknown keyword argument(s): {', '.join(unknown)}")
        self.config = FlightConfig(**options)
        self.out: Path | None = None  # the run folder, once started
        self.result: FlightResult | None = None
        self._children: dict[str, Child] = {}
        self._parts: dict[str, Path] = {}
        self._recording_id: str | None = None
        self._web = None  # the --web server (tools.web.WebServer), stopped when the flight ends
        self._t0: float | None = None
        self._interrupt = threading.Event()

    @classmethod
    def for_scenario(cls, scenario, run, out, **options) -> Flight:
        """The lockstep flight of one ``tools.scenario`` RunSpec of a Scenario: quiet, with series, no flight.rrd
        (an experiment logs its runs side by side from the series)."""
        profile = scenario.profile
        if profile.kind not in PROFILES or (profile.kind == "step" and profile.step_time != 1.0):
            raise FlightConfigError(
                "profile",
                f"profile: {profile!r} has no launcher flags (square, step at 1 s, "
                "sine): fly it from a CSV file with csv=FILE",
            )
        return cls(
            lockstep=True,
            duration=scenario.duration_s,
            controller=run.controller or ("sac" if run.lv == 0 else "clsac"),
            lv=run.lv,
            pfc=run.pfc or "paper",
            sigma_xu=run.sigma_xu or 0.0,
            name=run.name,
            rate=scenario.control_rate_hz,
            physics_rate=scenario.physics_rate_hz,
            profile=profile.kind,
            amplitude=math.degrees(profile.amplitude),
            period=profile.period,
            u_limit_deg=math.degrees(scenario.u_limit_rad),
            plant=scenario.plant,
            params=scenario.params,
            baseline_gains=scenario.baseline_gains,
            **dict(scenario.disturbances),
            out=out,
            quiet=True,
            series=True,
            rrd=False,
            png=False,
            **options,
        )

    @property
    def running(self) -> bool:
        """Started and not yet ended."""
        return self._t0 is not None and self.result is None

    @property
    def pids(self) -> dict[str, int]:
        """Process id of each child started (the last attempt's, if ports had to be tried again)."""
        return {name: c.proc.pid for name, c in self._children.items()}

    def __enter__(self) -> Flight:
        return self.start()

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            if self.result is None:
                if exc_type is KeyboardInterrupt:
                    self._end(EXIT_INTERRUPTED, None, "interrupted (Ctrl-C)")
                else:
                    self.stop()
        finally:
            self._stop_web()  # whatever happened above
        return False

    def _start_web(self) -> str:
        """Start the --web server before anything else; a port taken (or rerun failing) refuses the flight: one
        line, DIR/summary.json says so, nothing started (``tools.web.WebServerError`` is raised to the caller)."""
        from tools.web import WebServerError

        self._web = _web_server(self.config, self.out)
        try:
            return serve_web(self._web)
        except WebServerError as exc:
            write_refusal(self.out, "web", str(exc))
            raise

    def _stop_web(self) -> None:
        if self._web is not None:
            self._web.stop()

    def run(self) -> FlightResult:
        """Fly to the end (or until interrupted) and return the result."""
        with self:
            return self.wait()

    def interrupt(self) -> None:
        """Ask the flight to end as interrupted (exit code 130) at the next poll of ``wait``."""
        self._interrupt.set()

    def start(self) -> Flight:
        """Start the SITL, the GCS script and the autopilot on free ports (or ``base_port``) and wait until the
        first two listen; a process failing at start-up ends the flight (see ``result``)."""
        if self._t0 is not None:
            raise RuntimeError("this flight was already started; a Flight flies once")
        cfg = self.config
        self._t0 = time.monotonic()
        self.out = (
            Path(cfg.out)
            if cfg.out
            else new_run_dir("runs", f"-{'lockstep' if cfg.lockstep else 'rt'}-{cfg.controller}")
        )
        self.out.mkdir(parents=True, exist_ok=True)
        for f in (*STALE_FILES, "summary.json"):
            (self.out / f).unlink(missing_ok=True)
        # Until the flight ends the verdict is "not OK": a launcher killed outright (SIGKILL) leaves this, never
        # an earlier flight's "ok: true" in a reused folder.
        write_json_atomic(self.out / "summary.json", provisional_summary(os.getpid()))
        web_url = self._start_web() if cfg.web else None
        try:
            telemetry, self._parts, self._recording_id = _telemetry_argvs(cfg, self.out, web_url)
            key_file = _flight_key(cfg, self.out)
            for attempt in range(3):
                ports = range(cfg.base_port, cfg.base_port + 4) if cfg.base_port is not None else free_udp_ports(4)
                sitl_port, gcs_port, *ap_ports = ports
                self._spawn(child_argvs(cfg, self.out, sitl_port, gcs_port, telemetry, key_file, tuple(ap_ports)))
                failed = self._await_listening()
                if failed is None:
                    break
                if failed.code == EXIT_ADDRESS_IN_USE and cfg.base_port is None and attempt < 2:
                    stop_children(self._children.values())  # a free port was taken in between: try others
                    continue
                self._end(
                    EXIT_FAILED,
                    failed.name,
                    f"{failed.name} failed at start-up (exit code {failed.code}): {failed.reason()}",
                )
                break
        except BaseException as exc:
            interrupted = isinstance(exc, KeyboardInterrupt)
            self._end(
                EXIT_INTERRUPTED if interrupted else EXIT_FAILED,
                None if interrupted else "launch",
                "interrupted (Ctrl-C)" if interrupted else f"start-up failed: {type(exc).__name__}: {exc}",
            )
            raise
        return self

    def _spawn(self, argvs: dict[str, list[str]]) -> None:
        # All three start together (the autopilot announces itself until the SITL and the GCS answer).
        echo = not self.config.quiet
        self._children = {
            "sitl": Child("sitl", argvs["sitl"], self.out / "sitl.log", echo, "listening on"),
            "gcs": Child("gcs", argvs["gcs"], self.out / "gcs.log", echo, "listening on"),
            "autopilot": Child("autopilot", argvs["autopilot"], self.out / "autopilot.log", echo),
        }

    def _await_listening(self) -> Child | None:
        """Wait (up to 60 s each, or until interrupted) for the SITL and the GCS to listen; the one that exited
        instead, if any."""
        for c in (self._children["sitl"], self._children["gcs"]):
            while not c.ready.wait(0.05) and not self._interrupt.is_set() and time.monotonic() - c.started <= 60:
                pass
            if c.code is not None:
                return c
        return None

    def wait(self, timeout: float | None = None) -> FlightResult | None:
        """Watch the flight until it ends (its result) or ``timeout`` wall seconds pass (None)."""
        if self._t0 is None:
            raise RuntimeError("the flight was not started: call start() or run()")
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.result is None:
            if self._interrupt.is_set():
                self._end(EXIT_INTERRUPTED, None, "interrupted (Ctrl-C)")
            elif not self._poll() and deadline is not None and time.monotonic() >= deadline:
                return None
        return self.result

    def stop(self) -> FlightResult:
        """End the flight now if it still runs (SIGINT to each process, killed after 5 s) and return its result:
        not ok, exit code 130, reason "stopped by the caller after X s of Y s"."""
        if self._t0 is None:
            raise RuntimeError("the flight was not started: call start() or run()")
        if self.result is None and not self._poll():  # it may have just ended by itself
            self._end(EXIT_INTERRUPTED, None, None, stopped=True)
        return self.result

    def _poll(self) -> bool:
        """One look at the processes (at most 50 ms); True if that ended the flight."""
        ap = self._children["autopilot"]
        code = ap.wait(0.05)
        if code is not None:
            if code != 0:
                self._end(EXIT_FAILED, "autopilot", f"autopilot failed (exit code {code}): {ap.reason()}")
            else:
                self._land()
            return True
        for c in (self._children["sitl"], self._children["gcs"]):
            if c.code not in (None, 0):
                self._end(EXIT_FAILED, c.name, f"{c.name} failed (exit code {c.code}): {c.reason()}")
                return True
        limit = self.config.wall_timeout
        if time.monotonic() - self._t0 > limit:
            why = "--timeout" if self.config.timeout else "the default limit; --timeout S sets it"
            self._end(EXIT_FAILED, "launch", f"flight did not finish within {limit:.0f} s of wall clock ({why})")
            return True
        return False

    def _land(self) -> None:
        """The autopilot ended the flight: the GCS sees it power off; the SITL ends by itself in lockstep, unless
        the autopilot ended before the end of the run (then nobody answers the SITL's frames: it is stopped now)."""
        failed = error = None
        interrupted = set()
        if not self.config.lockstep or not _ended_normally(_load(self.out / "autopilot.json")):
            self._children["sitl"].interrupt()
            interrupted.add("sitl")
        for name in ("gcs", "sitl"):
            c = self._children[name]
            code = c.wait(5.0)
            if code is None and name not in interrupted:  # (one that ignores SIGINT is killed by _end)
                c.interrupt()
                code = c.wait(5.0)
            if code not in (None, 0):
                failed, error = name, f"{name} failed (exit code {code}): {c.reason()}"
        self._end(EXIT_FAILED if failed else EXIT_OK, failed, error)

    def _end(self, exit_code: int, failed: str | None, error: str | None, stopped: bool = False) -> None:
        """Stop what still runs, merge the telemetry, write summary.json and set ``result``."""
        cfg = self.config
        t_end = time.monotonic()  # exits seen after this are those of stopping the flight
        try:
            stop_children(self._children.values())
        finally:
            self._stop_web()  # nothing streams any more: the server ends with the flight
        rrd_path, rrd_indexed, rrd_error = _join_telemetry(
            self._parts, self.out, self._recording_id, cfg.rrd_merge_max_mb
        )
        if rrd_error and exit_code == EXIT_OK:
            exit_code, failed, error = EXIT_FAILED, "telemetry", rrd_error
        stats = {n: _load(self.out / f"{n}.json") for n in PROCESSES}
        flown = flown_report(cfg, stats)
        if stopped:
            error = f"stopped by the caller after {flown['sim_time_s']:g} s of {cfg.duration:g} s (sim time)"
        elif exit_code != EXIT_INTERRUPTED:
            exit_code, failed, error = verdict(self._children, stats, flown, exit_code, failed, error, t_end)
            exit_code, failed, error = envelope_verdict(
                exit_code, failed, error, (stats["autopilot"] or {}).get("controlled")
            )
        summary = build_summary(
            cfg,
            self.out,
            stats,
            {n: c.code for n, c in self._children.items()},
            failed,
            error,
            exit_code,
            time.monotonic() - self._t0,
            rrd_path,
            rrd_indexed,
        )
        summary["flown"] = flown
        runs = summary["runs"]
        metrics = {k: runs[0]["metrics"].get(k) for k in METRIC_NAMES} if runs else dict.fromkeys(METRIC_NAMES)
        png = None
        if cfg.png and cfg.series:
            try:
                png = write_flight_png(cfg, self.out, cfg.name or cfg.controller, metrics)
            except (OSError, ValueError, KeyError) as exc:  # a picture never fails a flight: say why it is missing
                print(f"launch: flight.png not written: {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)
        summary["files"]["png"] = str(png) if png else None
        write_json_atomic(self.out / "summary.json", summary)
        controlled = (summary["controlled"] or {}).get("ok")
        self.result = FlightResult(
            exit_code == EXIT_OK, exit_code, error, metrics, self.out, summary, summary["completed"], controlled
        )


def run_lockstep(scenario, run, workdir):
    """Fly one RunSpec of a Scenario in lockstep over real processes and UDP; metrics from what flew.

    The ``mavlink`` transport of ``tools.experiment``: files go to ``workdir``; returns a
    ``tools.scenario.RunResult`` whose series have the keys of ``tools.scenario.SERIES``, recorded by the
    autopilot (controller side, ``u`` = the command that flew, after PWM) and the SITL (``v``, ``delta_r``)."""
    from tools.scenario import RunResult

    res = Flight.for_scenario(scenario, run, Path(workdir)).run()
    if not res.ok or not res.summary["runs"]:
        raise RuntimeError(f"mavlink run {run.name} failed: {res.reason} (see {res.out})")
    return RunResult(run.name, run.lv, res.metrics, res.series)
