"""The command lines of a flight's three child processes (``child_argvs``), with their telemetry and signing-key
arguments, built from its settings (``tools.flight.config.FlightConfig``)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from autopilot import controllers
from tools.flight.config import FlightConfig

RUDDER_MAX_DEG = 30.0  # the servo calibration's full deflection (SITL and autopilot default)
MIMO_CHANNELS = (1, 4)  # SERVO_OUTPUT_RAW channels of a square MIMO plant's surfaces: aileron, rudder (ArduPilot Plane)


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
    given to all three so that every link is pinned to its peer from the start (docs/spec.md, "Trust model")."""
    from sitl import plant_kinds

    py = [sys.executable, "-u", "-m"]
    pwm = ["--rudder-max-deg", repr(max(RUDDER_MAX_DEG, cfg.u_limit_deg))]
    if cfg.mimo:  # each surface on its own SERVO_OUTPUT_RAW channel, as ArduPilot Plane: aileron 1, rudder 4
        pwm += ["--rudder-channel", str(MIMO_CHANNELS[0]), "--channel2", str(MIMO_CHANNELS[1])]
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
        + ([] if plant_kinds.kind_of(cfg.plant).paper else ["--plant", cfg.plant])
        + _fault_argv(cfg.fault)
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
            *_adaptive_argv(cfg),
            "--name",
            cfg.name or cfg.controller,
            "--u-limit-deg",
            repr(cfg.u_limit_deg),
            "--envelope-roll",
            repr(cfg.envelope_roll),
            "--envelope-saturated",
            repr(cfg.envelope_saturated),
            *([] if cfg.envelope else ["--no-envelope"]),
            "--surface",
            cfg.surface,
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
    if cfg.mimo:
        ap += ["--u-limit2-deg", repr(cfg.surface2_limit_deg)]
    if cfg.baseline_gains_flown is not None:
        ap += ["--baseline-gains", ",".join(repr(g) for g in cfg.baseline_gains_flown)]
    if cfg.failure_injection:
        ap += ["--failure-injection"]
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
        "--vehicle-timeout",
        repr(cfg.vehicle_timeout),
    ]
    gcs += ["--csv", cfg.csv] if cfg.csv else [cfg.profile]
    if cfg.series:
        ap += ["--series", str(out / "autopilot_series.npz")]
        sitl += ["--series", str(out / "sitl_series.npz")]
    if cfg.lockstep:
        sitl += ["--lockstep", "--duration", repr(cfg.duration)]
        ap += ["--lockstep", "--lockstep-idle-exit", repr(cfg.lockstep_idle_exit)]
        if cfg.lockstep_spin_us is not None:
            ap += ["--lockstep-spin-us", repr(float(cfg.lockstep_spin_us))]
            sitl += ["--spin-us", repr(float(cfg.lockstep_spin_us))]
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


def _adaptive_argv(cfg: FlightConfig) -> list[str]:
    """The adaptive laws' flags (SAC, CL-SAC; the autopilot refuses them for any other law)."""
    if not controllers.get(cfg.controller).adaptive:
        return []
    return [
        "--lv",
        repr(cfg.lv_value),
        "--pfc",
        cfg.pfc or "paper",
        "--sigma-xu",
        repr(cfg.sigma_xu),
        "--dead-zone-deg",
        repr(cfg.dead_zone_deg),
        *(["--ki-max", repr(cfg.ki_max)] if cfg.ki_max is not None else []),
        *(["--freeze-when-saturated"] if cfg.freeze_when_saturated else []),
    ]


def _fault_argv(faults) -> list[str]:
    from sitl import damage

    return damage.to_argv(faults)


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
