"""``python -m autopilot``: the CL-SAC roll autopilot process (docs/spec.md, "MAVLink" and "Timing modes").

Links: to the SITL (sends SERVO_OUTPUT_RAW to --sitl, receives ATTITUDE) and a GCS stream (sends
HEARTBEAT, ATTITUDE, ATTITUDE_TARGET, SERVO_OUTPUT_RAW, STATUSTEXT to --gcs and answers whoever
talks to it; receives SET_ATTITUDE_TARGET).  Prints its counters at exit; --stats-json writes them
with the run metrics (computed from what flew: the attitude received and the command sent).
"""

from __future__ import annotations

import math
import sys

from autopilot.flags import (
    DEG,
    add_controller_arguments,
    add_envelope_arguments,
    add_surface_argument,
    envelope_from_args,
    flag_text,
    inapplicable,
    rate_arg,
)
from autopilot.params import arg_type
from autopilot.shared import crash
from autopilot.shared.cli import (
    OneLineArgumentParser,
    add_cpu_argument,
    add_pwm_arguments,
    add_rt_priority_argument,
    add_signing_argument,
    add_sysid_argument,
    check_output_files,
    clock_s,
    duration_or_0,
    endpoint,
    fmt_endpoint,
    peer_endpoint,
    pwm2_from_args,
    pwm_from_args,
    signing_key_from_args,
    spin_us,
    stream_rate_or_0,
)
from autopilot.shared.link import ANY_COMPONENT
from autopilot.shared.mavlink import GCS_SYSTEMS
from autopilot.shared.process import (
    apply_cpu,
    apply_rt_priority,
    exit_code_for,
    install_stop_handlers,
    move_other_threads,
    report_write_failures,
    reserve_for,
    rt_throttling,
    write_failure,
    write_stats_json,
)
from autopilot.shared.telemetry.flags import add_arguments as add_telemetry_arguments
from autopilot.shared.telemetry.flags import check_arguments as check_telemetry_arguments
from autopilot.telemetry import attach as attach_telemetry


def build_parser() -> OneLineArgumentParser:
    p = OneLineArgumentParser(prog="python -m autopilot", description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--sitl",
        type=peer_endpoint,
        default=("127.0.0.1", 14560),
        metavar="HOST:PORT",
        help="where the SITL listens (default 127.0.0.1:14560)",
    )
    p.add_argument(
        "--sitl-bind",
        type=endpoint,
        default=("127.0.0.1", 0),
        metavar="HOST:PORT",
        help="local address of the SITL link (default 127.0.0.1:0, an ephemeral port)",
    )
    p.add_argument(
        "--gcs",
        type=peer_endpoint,
        default=("127.0.0.1", 14550),
        metavar="HOST:PORT",
        help="where the GCS stream goes until a GCS talks to us (default 127.0.0.1:14550)",
    )
    p.add_argument(
        "--listen",
        "--gcs-bind",
        dest="gcs_bind",
        type=endpoint,
        default=("127.0.0.1", 0),
        metavar="HOST:PORT",
        help="local address of the GCS link (default 127.0.0.1:0, ephemeral)",
    )
    p.add_argument(
        "--gcs-id",
        action="append",
        default=None,
        metavar="SYS:COMP",
        help=f"accepted GCS system:component (repeatable; default systems {' and '.join(map(str, GCS_SYSTEMS))} "
        "with any component, and any system that sends a MAV_TYPE_GCS HEARTBEAT)",
    )
    add_sysid_argument(p, "the vehicle's MAVLink system id: N:1 to the ground stations, N:140 to the SITL")
    p.add_argument(
        "--gcs-peer",
        action="append",
        type=peer_endpoint,
        default=[],
        metavar="HOST:PORT",
        help="a ground station admitted from the start (repeatable); then, without signing, nobody else is "
        "(default: the first GCS that talks; with --signing-key also any that signs with the key)",
    )
    p.add_argument("--lockstep", action="store_true", help="one control step per SITL frame (default: real time)")
    p.add_argument(
        "--no-pace",
        dest="pace",
        action="store_false",
        help="lockstep: do not wait for GCS setpoints scheduled up to each frame's time",
    )
    p.add_argument("--rate", type=rate_arg, default=100.0, metavar="HZ", help="control rate (default 100)")
    p.add_argument("--name", default=None, help="run name in the stats (default: the controller)")
    p.add_argument(
        "--duration",
        type=duration_or_0,
        default=0.0,
        metavar="S",
        help="stop after S s (lockstep: sim time from the first frame; real time: of control); 0 = run until stopped",
    )
    p.add_argument(
        "--telemetry-rate",
        type=stream_rate_or_0,
        default=50.0,
        metavar="HZ",
        help="ATTITUDE/ATTITUDE_TARGET/SERVO_OUTPUT_RAW to the GCS, per control steps (default 50, 0 = off)",
    )
    p.add_argument(
        "--attitude-timeout",
        type=arg_type("CLSAC_FS_ATT_TMO"),
        default=0.1,
        metavar="S",
        help="real time: failsafe after S s without attitude (default 0.1)",
    )
    p.add_argument(
        "--setpoint-timeout",
        type=arg_type("CLSAC_FS_SP_TMO"),
        default=1.0,
        metavar="S",
        help="real time: wings level after S s without setpoint (default 1.0)",
    )
    p.add_argument(
        "--max-roll-deg", type=arg_type("CLSAC_MAX_ROLL", DEG, "deg"), default=45.0, help="setpoint clamp (default 45)"
    )
    p.add_argument(
        "--setpoint-time",
        choices=("sim", "now"),
        default="sim",
        help="SET_ATTITUDE_TARGET time_boot_ms: 'sim' schedules the setpoint on sim time (0 or past = now; "
        "default), 'now' ignores it and flies every setpoint on arrival, for a ground station that stamps its own "
        "clock (MAVSDK stamps its host's uptime)",
    )
    p.add_argument(
        "--spin-us",
        type=spin_us,
        default=300.0,
        help="real time: busy-wait this long before each deadline for precise timing (default 300)",
    )
    # On a VM a sleeping (halted) vCPU can take milliseconds to be run again; a loop that never sleeps
    # keeps its timing (docs/benchmarks.md: p99 lateness of a bare deadline loop 1.8-3.7 ms -> 0.01 ms).
    p.add_argument(
        "--busy-wait",
        action="store_true",
        help="real time: never sleep between steps, poll the links until each deadline "
        "(one CPU at 100 %%; use with --cpu; not with --rt-priority, see docs/flying.md)",
    )
    # Waking a sleeping process costs ~70 us a frame on a VM; the SITL answers within ~100 us, so polling
    # briefly first raised the lockstep real-time factor from ~45x to ~70x (100 Hz) and ~13x to ~16x (400 Hz).
    p.add_argument(
        "--lockstep-spin-us",
        type=spin_us,
        default=500.0,
        metavar="US",
        help="lockstep: busy-poll this long for the next frame before sleeping (default 500)",
    )
    p.add_argument(
        "--lockstep-idle-exit",
        type=clock_s,
        default=0.0,
        metavar="S",
        help="lockstep: exit if the SITL is silent for S s after the last frame (default 0 = never)",
    )
    p.add_argument("--tlog", default=None, metavar="PATH", help="write every packet sent and received to this .tlog")
    p.add_argument(
        "--stats-json",
        "--metrics-json",
        dest="stats_json",
        default=None,
        metavar="PATH",
        help="write metrics, counters and timing to this JSON file at exit",
    )
    p.add_argument(
        "--series",
        default=None,
        metavar="PATH.npz",
        help="record every control step (setpoint, roll, command, controller internals) to this .npz at exit",
    )
    p.add_argument("--quiet", action="store_true", help="only the start line and the counters")
    p.add_argument(
        "--params",
        default=None,
        metavar="FILE",
        help="load a parameter file at start (MAVProxy 'param save' or QGroundControl format; overrides the flags)",
    )
    p.add_argument(
        "--failure-injection",
        action="store_true",
        help="take MAV_CMD_INJECT_FAILURE from the ground stations and relay it to the SITL (parameter "
        "SYS_FAILURE_EN = 1; default: refused with MAV_RESULT_DENIED, as PX4 does)",
    )
    p.add_argument(
        "--disarmed",
        action="store_true",
        help="start disarmed (rudder neutral until a ground station arms: COMPONENT_ARM_DISARM)",
    )
    p.add_argument(
        "--u-limit2-deg",
        type=float,
        default=None,
        metavar="DEG",
        help="a square MIMO plant (--channel2): the second surface's command limit, deg (default --u-limit-deg)",
    )
    add_controller_arguments(p)
    add_envelope_arguments(p)
    add_surface_argument(p)
    add_telemetry_arguments(p)
    add_pwm_arguments(p)
    add_signing_argument(p)
    add_cpu_argument(p)
    add_rt_priority_argument(p)
    return p


def _gcs_ids(parser, values):
    if not values:
        return tuple((s, ANY_COMPONENT) for s in GCS_SYSTEMS)
    out = []
    for v in values:
        try:
            a, b = v.split(":")
            ids = (int(a), int(b))
        except ValueError:
            parser.error(f"--gcs-id expects SYS:COMP, got {v!r}")
        if not (0 <= ids[0] <= 255 and 0 <= ids[1] <= 255):
            parser.error(f"--gcs-id values must be 0..255, got {v!r}")
        out.append(ids)
    return tuple(out)


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    check_output_files(parser, args, "tlog", "stats_json", "series", "rrd", "telemetry_spool")
    check_telemetry_arguments(parser, args)
    pwm = pwm_from_args(parser, args)
    pwm2 = pwm2_from_args(parser, args)
    if args.busy_wait:
        if args.lockstep:
            parser.error("--busy-wait is for real time (lockstep polls for --lockstep-spin-us before sleeping)")
        if args.rt_priority and rt_throttling():
            parser.error(
                f"--busy-wait with --rt-priority {args.rt_priority}: a SCHED_FIFO thread that never sleeps "
                f"is stopped by the kernel's real-time throttling ({rt_throttling()}) for tens of ms "
                f"each second; use one or the other"
            )
    apply_cpu(parser, args.cpu)
    # The controller's law and its configuration (autopilot.controllers).  The parameter table (autopilot.params)
    # holds the configured L_v (CLSAC_LV: --lv, else the law's default), which mode SAC flies as 0.
    from autopilot import controllers
    from autopilot.config import ConfigError
    from autopilot.loop import Autopilot, AutopilotOptions, series_recorder
    from autopilot.params import ParamError, ParamTable, load_file
    from autopilot.shared.tlog import TlogWriter
    from autopilot.vehicle import Mode

    controller = controllers.get(args.controller)
    refused = inapplicable(args.controller, vars(args))  # a flag the law would not fly: refused, not ignored
    if refused is not None:
        parser.error(f"{flag_text(refused[0], getattr(args, refused[0]))}: {refused[1]}")
    try:
        cfg = controller.config(
            control_rate_hz=args.rate,
            u_limit_rad=math.radians(args.u_limit_deg),
            lv=args.lv,
            pfc=args.pfc or "paper",
            sigma_xu=args.sigma_xu,
            dead_zone_rad=math.radians(args.dead_zone_deg),
            ki_max=args.ki_max,
            freeze_when_saturated=args.freeze_when_saturated,
            gains=args.baseline_gains,
        )
    except ConfigError as exc:
        parser.error(str(exc))
    options = {
        "attitude_timeout_s": args.attitude_timeout,
        "setpoint_timeout_s": args.setpoint_timeout,
        "max_roll_rad": math.radians(args.max_roll_deg),
        "failure_injection": float(args.failure_injection),  # SYS_FAILURE_EN (a --params file may set it too)
    }
    mimo_law = None
    if pwm2 is not None:  # a square MIMO plant: the law of both channels from the design's file (autopilot.mimo)
        mimo_law = _mimo_law(parser, args, controller)
        cfg = mimo_law.config
    if mimo_law is not None:
        from autopilot.mimo import param_table

        params = param_table(mimo_law, options)
    else:
        params = ParamTable(cfg, options)
    not_flown: list[str] = []  # another law's values in the file (a design holds every controller's)
    if args.params and mimo_law is not None:
        not_flown = []  # the file's values are the MIMO law's (autopilot.mimo.from_values), not the table's
    elif args.params:
        try:
            values, not_flown = params.split(load_file(args.params))
            params.update(values)
        except OSError as exc:
            parser.error(f"--params {args.params}: {exc.strerror or exc}")
        except ParamError as exc:  # a line's error names the file already: "FILE:LINE: ..."
            where = "" if str(exc).startswith(str(args.params)) else f"{args.params}: "
            parser.error(f"--params {where}{exc}")
        cfg = params.config
        options = {k: params.option(k) for k in options}
    rate = cfg.control_rate_hz  # CLSAC_RATE from a parameter file wins over --rate
    opts = AutopilotOptions(
        rate_hz=rate,
        lockstep=args.lockstep,
        duration_s=args.duration,
        telemetry_rate_hz=args.telemetry_rate,
        **options,
        pace=args.pace,
        setpoint_time=args.setpoint_time,
        spin_s=math.inf if args.busy_wait else args.spin_us * 1e-6,
        sitl=args.sitl,
        sitl_bind=args.sitl_bind,
        gcs=args.gcs,
        gcs_bind=args.gcs_bind,
        sysid=args.sysid,
        gcs_ids=_gcs_ids(parser, args.gcs_id),
        learn_gcs=not args.gcs_id,  # --gcs-id narrows the ground stations to those listed
        gcs_peers=tuple(args.gcs_peer),
        signing_key=signing_key_from_args(parser, args),
        lockstep_idle_exit_s=args.lockstep_idle_exit,
        lockstep_spin_s=args.lockstep_spin_us * 1e-6,
        name=args.name or args.controller,
        verbose=not args.quiet,
        envelope=envelope_from_args(args),
    )
    tlog = None
    try:
        if args.tlog:
            tlog = TlogWriter(args.tlog)
        ap = Autopilot(
            opts,
            cfg,
            pwm,
            tlog=tlog,
            params=params,
            mode=Mode[controller.mode],
            armed=not args.disarmed,
            law=mimo_law,
            pwm2=pwm2,
        )
    except OSError as exc:
        print(f"autopilot: error: {exc}", file=sys.stderr)
        return exit_code_for(exc)

    recorder = None
    if args.series:
        recorder = series_recorder(mimo=mimo_law is not None, law_fields=getattr(ap.ctrl, "fields", ()))
        ap.hooks.append(recorder)
    channels = None
    if mimo_law is not None:  # per channel: metrics, saturation per surface, max |sideslip| (summary.json)
        from autopilot.mimo import ChannelMetrics

        lim = (
            mimo_law.config.u_limits_rad if mimo_law.kind == "clsac" else [c.config.u_limit_rad for c in mimo_law.laws]
        )
        channels = ChannelMetrics(1.0 / rate, lim)
        ap.hooks.append(channels)
    tel = attach_telemetry(args, ap, control_rate_hz=rate)
    rt_note = apply_rt_priority(args.rt_priority, "autopilot")  # after the helper threads exist: they stay normal
    if args.busy_wait:
        rt_note += "; busy-wait (never sleeps)"
        if args.cpu is not None:
            # The loop never yields its CPU: helper threads left there would preempt it mid-step.
            rt_note += f", {move_other_threads(args.cpu)} helper thread(s) moved off CPU {args.cpu}"

    def stop():
        ap.stop_requested = True

    install_stop_handlers(stop)
    mode = "lockstep" if args.lockstep else "real time"
    shown_lv = 0.0
    if controller.adaptive:  # a MIMO table has no CLSAC_LV: its law's own (autopilot.mimo)
        import numpy as np

        configured = params.get("CLSAC_LV") if "CLSAC_LV" in params else float(np.atleast_2d(cfg.lv)[0, 0])
        shown_lv = controllers.flown_lv(args.controller, configured)
    law = f" (Lv={shown_lv:g})" if controller.adaptive else f" ({controller.label})"  # a PID has no Lv
    print(
        f"autopilot: {opts.name}{law} {mode} at {rate:g} Hz; SITL link {fmt_endpoint(ap.sitl.local)} -> "
        f"{fmt_endpoint(args.sitl)}; GCS link {fmt_endpoint(ap.gcs.local)} -> {fmt_endpoint(args.gcs)}; system id "
        f"{args.sysid}{rt_note}"
        + ("; failure injection on (SYS_FAILURE_EN 1)" if opts.failure_injection else "")
        + (f"; {args.params}: {len(not_flown)} value(s) of another law not flown" if not_flown else ""),
        flush=True,
    )
    reserve = reserve_for(args.stats_json) if args.stats_json else None  # the stats fit on a full disk
    code = 0
    try:
        code = ap.run()
    except Exception as exc:  # noqa: BLE001  (report, still write the files)
        crash.report("autopilot", exc)  # one line; the traceback in autopilot.log (autopilot.shared.crash)
        code = 1
    finally:
        stats = ap.stats()
        if channels is not None:
            stats["sideslip"] = channels.result()
            from autopilot.mimo import with_sideslip

            stats["controlled"] = with_sideslip(stats.get("controlled"), stats["sideslip"])
        if tlog is not None:
            tlog.close()
        ap.close()
        if tel is not None:
            tel.close()
    # a full disk mid-flight: the flight went on; each output that failed is named, what it holds is kept
    failed = [e for e in (tlog.error if tlog else None, tel.write_error if tel else None) if e]
    if recorder is not None:
        failed += filter(None, [write_failure(args.series, lambda: recorder.save(args.series))])
    stats["output_errors"] = list(failed)
    _print_summary(stats)
    if args.stats_json:
        write = lambda: write_stats_json(args.stats_json, stats, reserve)  # noqa: E731
        failed += filter(None, [write_failure(args.stats_json, write)])
    if reserve is not None:
        reserve.release()
    return report_write_failures("autopilot", failed, code)


def _mimo_law(parser, args, controller):
    """The square MIMO law (``autopilot.mimo.from_values``) of ``--params`` (a MIMO design), one line on error."""
    from autopilot import mimo
    from autopilot.config import ConfigError
    from autopilot.params import ParamError, load_file

    if controller.kind.mimo:  # a law without a square-MIMO form, with its reason (autopilot.controllers.Law.mimo)
        parser.error(f"--controller {controller.name} is not flown on a square MIMO plant: {controller.kind.mimo}")
    if not args.params:
        parser.error("--channel2 (a square MIMO plant) flies a MIMO design: give its --params FILE")
    kind = "baseline" if controller.law == "baseline" else ("sac" if controller.lv_fixed == 0.0 else "clsac")
    if controller.options:
        parser.error(f"--controller {controller.name} is not flown on a square MIMO plant (clsac, sac, baseline)")
    lim1 = math.radians(args.u_limit_deg)
    lim2 = math.radians(args.u_limit2_deg) if args.u_limit2_deg is not None else lim1
    try:
        return mimo.from_values(
            kind, load_file(args.params), control_rate_hz=args.rate, limits=(lim1, lim2), lv=args.lv
        )
    except OSError as exc:
        parser.error(f"--params {args.params}: {exc.strerror or exc}")
    except (ParamError, ConfigError) as exc:
        parser.error(f"--params {args.params}: {exc}")


def _print_summary(stats: dict) -> None:
    from autopilot.shared.link import format_counters

    t = stats["timing"]
    lockstep = stats["mode"] == "lockstep"

    def f(d):
        return "-" if not d else f"p50 {d['p50']:.3f} p99 {d['p99']:.3f} max {d['max']:.3f} ms"

    ev = {k: v for k, v in stats["events"].items() if v not in (0, [], None)}
    print(
        f"autopilot: {stats['steps']} steps ({stats['exit_reason']}); metrics "
        + ", ".join(f"{k}={v:.6g}" for k, v in stats["metrics"].items()),
        flush=True,
    )
    print(
        f"autopilot: timing: jitter {f(t['period_jitter_ms'])}; compute {f(t['compute_ms'])}; "
        f"{'in-to-out latency' if lockstep else 'attitude age at servo out'} {f(t['latency_ms'])}; "
        f"missed deadlines {t['missed_deadlines']}"
        + ("" if lockstep else f"; steps later than the attitude timeout {stats['late_steps']}"),
        flush=True,
    )
    print(f"autopilot: events: {ev}", flush=True)
    print(f"autopilot: envelope: {stats['controlled']['reason']}", flush=True)
    for name, c in stats["links"].items():
        print(format_counters(f"autopilot {name} link", c), flush=True)


if __name__ == "__main__":
    crash.install("autopilot")
    sys.exit(main())
