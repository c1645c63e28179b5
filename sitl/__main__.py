"""``python -m sitl``: the simulated plant (``--plant``: the KH2013A, a plant file or a JSBSim aircraft) behind a
MAVLink endpoint on UDP.

Listens for the autopilot (default 127.0.0.1:14560) and answers whoever talks to it with the
autopilot's IDs (1:1): HEARTBEAT 1 Hz, ATTITUDE (real time: at the sensor rate; --lockstep: one per
control frame, waiting for that frame's SERVO_OUTPUT_RAW).  Prints its counters at exit.
"""

from __future__ import annotations

import argparse
import sys

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
    default_physics_rate,
    duration_or_0,
    endpoint,
    fmt_endpoint,
    peer_endpoint,
    physics_rate_hz,
    pwm2_from_args,
    pwm_from_args,
    rate_hz,
    sensor_rate_hz,
    signing_key_from_args,
    spin_us,
    timeout_s,
)
from autopilot.shared.process import (
    apply_cpu,
    apply_rt_priority,
    exit_code_for,
    install_stop_handlers,
    report_write_failures,
    reserve_for,
    write_failure,
    write_stats_json,
)
from autopilot.shared.telemetry.flags import add_arguments as add_telemetry_arguments
from autopilot.shared.telemetry.flags import check_arguments as check_telemetry_arguments
from sitl import damage, disturbances
from sitl import plant as plants
from sitl.plant_kinds import help_text as plant_help
from sitl.telemetry import attach as attach_telemetry


def plant_arg(text: str) -> str:
    """A --plant value, checked (sitl.plant.check): one-line error on a bad file, spec or model (a file's physics step
    is checked when the plant is built, at --physics-rate)."""
    try:
        return plants.check(text, None)
    except plants.PlantError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_plant_argument(p) -> None:
    p.add_argument(
        "--plant",
        type=plant_arg,
        default=plants.KH2013A,
        metavar="PLANT",
        help=f"{plant_help()} (docs/plants.md)",  # from the kinds' records (sitl.plant_kinds.KINDS)
    )


def build_parser() -> OneLineArgumentParser:
    p = OneLineArgumentParser(prog="python -m sitl", description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--listen",
        type=endpoint,
        default=("127.0.0.1", 14560),
        metavar="HOST:PORT",
        help="UDP address to listen on for the autopilot (default 127.0.0.1:14560)",
    )
    p.add_argument(
        "--autopilot",
        type=peer_endpoint,
        default=None,
        metavar="HOST:PORT",
        help="the autopilot's address: only it is heard (default: the first that talks with the autopilot's IDs)",
    )
    p.add_argument("--lockstep", action="store_true", help="SITL is the time master, one frame per control step")
    p.add_argument(
        "--rate", type=rate_hz, default=100.0, metavar="HZ", help="lockstep frame (control) rate (default 100)"
    )
    p.add_argument(
        "--physics-rate",
        type=physics_rate_hz,
        default=None,
        metavar="HZ",
        help="physics rate (default: the smallest whole multiple of --rate >= 1000, i.e. 1000 at 100 Hz)",
    )
    p.add_argument(
        "--sensor-rate", type=sensor_rate_hz, default=200.0, metavar="HZ", help="real time: ATTITUDE rate (default 200)"
    )
    p.add_argument(
        "--duration", type=duration_or_0, default=0.0, metavar="S", help="sim seconds to run (0 = until stopped)"
    )
    p.add_argument(
        "--start-time",
        type=clock_s,
        default=0.0,
        metavar="S",
        help="initial sim clock, e.g. 4290 to cross the 71.6-min time_usec wrap soon (default 0)",
    )
    p.add_argument(
        "--servo-timeout",
        type=timeout_s,
        default=0.5,
        metavar="S",
        help="real time: rudder neutral after S s without servo command (default 0.5)",
    )
    p.add_argument(
        "--resend-timeout",
        type=timeout_s,
        default=0.25,
        metavar="S",
        help="lockstep: resend the frame's ATTITUDE after S s without answer (default 0.25)",
    )
    p.add_argument(
        "--give-up",
        type=timeout_s,
        default=10.0,
        metavar="S",
        help="lockstep: exit with an error after S s without answer (default 10)",
    )
    p.add_argument(
        "--connect-timeout",
        type=clock_s,
        default=0.0,
        metavar="S",
        help="lockstep: exit with an error if no autopilot shows up within S s (default 0 = wait)",
    )
    # See autopilot --lockstep-spin-us: polling before sleeping saves the wake-up latency of each frame.
    p.add_argument(
        "--spin-us",
        type=spin_us,
        default=500.0,
        metavar="US",
        help="lockstep: busy-poll this long for each answer before sleeping (default 500)",
    )
    p.add_argument("--stats-json", default=None, metavar="PATH", help="write counters to this JSON file at exit")
    p.add_argument(
        "--series",
        default=None,
        metavar="PATH.npz",
        help="record the truth state after every frame / sensor message to this .npz at exit",
    )
    p.add_argument("--quiet", action="store_true", help="only the start line and the counters")
    add_plant_argument(p)
    damage.add_argument(p)
    disturbances.add_arguments(p)
    add_telemetry_arguments(p)
    add_pwm_arguments(p)
    add_signing_argument(p)
    add_sysid_argument(p, "the vehicle's system id, as the autopilot's --sysid: the SITL is N:200, talks to N:140")
    add_cpu_argument(p)
    add_rt_priority_argument(p)
    return p


def ending(exit_reason: str) -> str:
    """How the run ended, for the last line.  A real-time SITL has no end of its own: it flies until asked to stop
    (the launcher sends SIGINT once the autopilot is done), so a stop by signal is said as the normal end it is;
    summary.json and --stats-json keep the exit reason as it was."""
    return "stopped on request (SIGINT/SIGTERM)" if exit_reason == "stopped by signal" else exit_reason


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    check_output_files(parser, args, "stats_json", "series", "rrd", "telemetry_spool")
    check_telemetry_arguments(parser, args)
    pwm = pwm_from_args(parser, args)
    apply_cpu(parser, args.cpu)
    if args.physics_rate is None:
        args.physics_rate = default_physics_rate(args.rate)
    ratio = args.physics_rate / args.rate
    if args.lockstep and (abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1):
        parser.error(f"--physics-rate ({args.physics_rate:g}) must be a whole multiple of --rate ({args.rate:g})")
    k0 = args.start_time * args.rate
    if args.lockstep and abs(k0 - round(k0)) > 1e-6:
        parser.error(f"--start-time ({args.start_time:g}) must be a whole number of frames at --rate {args.rate:g}")
    dist = None
    given = {k: v for k, v in vars(args).items() if k in disturbances.FLAGS and v is not None}
    try:
        plants.check_disturbances(args.plant, given)
        plants.check_faults(args.plant, args.fault or (), pwm.rudder_max_rad)  # a stuck angle: within the servo's span
    except plants.PlantError as exc:
        parser.error(str(exc))
    if set(given) - {"seed"}:
        try:
            dist = disturbances.from_values(given)
        except disturbances.ERRORS as exc:
            parser.error(str(exc))
    from sitl.endpoint import LockstepGiveUp, Sitl, SitlOptions, series_recorder

    opts = SitlOptions(
        listen=args.listen,
        lockstep=args.lockstep,
        rate_hz=args.rate,
        physics_rate_hz=args.physics_rate,
        sensor_rate_hz=args.sensor_rate,
        duration_s=args.duration,
        start_time_s=args.start_time,
        servo_timeout_s=args.servo_timeout,
        resend_timeout_s=args.resend_timeout,
        give_up_s=args.give_up,
        connect_timeout_s=args.connect_timeout,
        spin_s=args.spin_us * 1e-6,
        verbose=not args.quiet,
        signing_key=signing_key_from_args(parser, args),
        peer=args.autopilot,
        disturbances=dist,
        sysid=args.sysid,
        plant=args.plant,
        faults=tuple(args.fault or ()),
    )
    try:
        sitl = Sitl(opts, pwm, pwm2=pwm2_from_args(parser, args))
    except plants.PlantError as exc:
        parser.error(str(exc))
    except OSError as exc:
        print(f"sitl: error: cannot listen on {fmt_endpoint(args.listen)}: {exc.strerror or exc}", file=sys.stderr)
        return exit_code_for(exc)

    recorder = None
    if args.series:
        recorder = series_recorder(mimo=sitl.mimo)
        sitl.hooks.append(recorder)
    tel = attach_telemetry(args, sitl)
    rt_note = apply_rt_priority(args.rt_priority, "sitl")  # after the helper threads exist: they stay normal

    def stop():
        sitl.stop_requested = True

    install_stop_handlers(stop)
    mode = f"lockstep at {args.rate:g} Hz" if args.lockstep else f"real time, ATTITUDE at {args.sensor_rate:g} Hz"
    print(
        f"sitl: listening on {fmt_endpoint(sitl.link.local)}; {mode}; physics {args.physics_rate:g} Hz; "
        f"start t={args.start_time:g} s{rt_note}",
        flush=True,
    )
    reserve = reserve_for(args.stats_json) if args.stats_json else None  # the stats fit on a full disk
    code = 0
    try:
        code = sitl.run()
        if sitl.diverged is not None:  # the flight stopped: out of the envelope, the plant's own doing
            print(f"sitl: OUT OF ENVELOPE: {args.plant}: {sitl.exit_reason}", file=sys.stderr, flush=True)
    except LockstepGiveUp as exc:
        print(f"sitl: error: {exc}", file=sys.stderr, flush=True)
        code = 1
    except Exception as exc:  # noqa: BLE001
        crash.report("sitl", exc)  # one line; the traceback in sitl.log (autopilot.shared.crash)
        code = 1
    finally:
        stats = sitl.stats()
        sitl.close()
        if tel is not None:
            tel.close()
    from autopilot.shared.link import format_counters

    failed = [tel.write_error] if tel is not None and tel.write_error else []  # a full disk mid-flight: say which
    if recorder is not None:
        failed += filter(None, [write_failure(args.series, lambda: recorder.save(args.series))])
    stats["output_errors"] = list(failed)

    rtf = f"{stats['rtf']:.1f}x" if stats["rtf"] else "-"
    print(
        f"sitl: {stats['frames']} frames, sim {stats['sim_time_s']:.3f} s in {stats['wall_s']:.3f} s wall "
        f"(real-time factor {rtf}); {ending(stats['exit_reason'])}; events {stats['events']}"
        + (f"; {stats['servo_timeout_s']:.3f} s flown on the servo timeout" if stats["servo_timeout_s"] else ""),
        flush=True,
    )
    print(format_counters("sitl link", stats["link"]), flush=True)
    if args.stats_json:
        write = lambda: write_stats_json(args.stats_json, stats, reserve)  # noqa: E731
        failed += filter(None, [write_failure(args.stats_json, write)])
    if reserve is not None:
        reserve.release()
    return report_write_failures("sitl", failed, code)


if __name__ == "__main__":
    crash.install("sitl")
    sys.exit(main())
