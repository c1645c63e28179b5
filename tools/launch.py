"""``python -m tools.launch``: fly SITL + autopilot + GCS script together as real processes over UDP.

Real time by default, ``--lockstep`` for as fast as the machine allows (deterministic).  Writes
``DIR/flight.tlog`` (every packet the autopilot sent and received, standard tlog), ``DIR/summary.json``
(one run, metrics from what flew, plus counters, timing and file names), ``DIR/flight.rrd``, the per-step
series and each child's output in ``DIR/<name>.log``; prints a summary table.  Ctrl-C or a failing child stops
everything cleanly, leaves valid files and exits non-zero naming the process that failed.  The last line printed
is the outcome: ``OK`` (flown to the end and controlled, exit 0), ``OUT OF ENVELOPE`` (flown to the end, but not
controlled: ``autopilot.envelope``, exit 3) or ``FAILED`` (exit 1).

A command-line front end of ``tools.flight.Flight``: each long flag is a keyword of it.
"""

from __future__ import annotations

import sys

if __name__ == "__main__":
    import os

    from tools.flight.children import BLAS_THREADS

    # This process's numpy, loaded below, with the children's OpenBLAS threads (unless the user set them): the
    # launcher does no linear algebra worth a thread per core.
    for _name, _value in BLAS_THREADS.items():
        os.environ.setdefault(_name, _value)
    # python -m tools.launch: a lockstep flight's picture helper starts before this module's imports below (0.1-0.2 s
    # on one core, the other idle), so that its own imports (numpy, Pillow) run on the idle core meanwhile.
    from tools.view.flight_picture import PngHelper, helper_wanted

    EARLY_PNG_HELPER = PngHelper() if helper_wanted(sys.argv[1:]) else None

import argparse
import io
import logging
import os
from pathlib import Path

from autopilot import controllers
from autopilot.flags import add_controller_arguments, add_envelope_arguments, rate_arg
from autopilot.shared import crash
from autopilot.shared.cli import (
    MAX_SIM_S,
    OneLineArgumentParser,
    angle_deg,
    bounded,
    clock_s,
    duration_s,
    physics_rate_hz,
    rt_priority_arg,
    sensor_rate_hz,
    spin_us,
    stream_rate_or_0,
    sysid_arg,
    timeout_s,
    viewer_url,
)
from autopilot.shared.process import EXIT_FAILED, EXIT_USAGE, install_stop_handlers, survive_closed_stdout
from sitl import damage, disturbances
from sitl.plant_kinds import help_text as plant_help
from tools.flight import (
    LIVE_RATE_HZ,
    LIVE_WINDOW_S,
    LOCKSTEP_IDLE_EXIT_S,
    MERGE_MAX_MB,
    PROCESSES,
    PROFILES,
    VEHICLE_TIMEOUT_S,
    Flight,
    FlightConfigError,
    OutputError,
    recovery_text,
    write_refusal,
)
from tools.flight.web import DEFAULT_GRPC_PORT, DEFAULT_HOST, DEFAULT_HTTP_PORT, WebServerError, bind_host, tcp_port


def outcome_line(s: dict) -> str:
    """The last line the launcher prints: OK (flown to the end and controlled), OUT OF ENVELOPE (flown to the end,
    not controlled: the reason and numbers) or FAILED (what failed)."""
    outcome = s.get("outcome") or ("OK" if s.get("ok") else "FAILED")
    # a ground station took the loop (disarmed, MANUAL): said next to the outcome, never a plain OK
    note = (s.get("ground_station") or {}).get("note")
    head = f"{outcome} ({note})" if note else outcome
    after = "".join(f"; after {recovery_text(r)}" for r in s.get("recovery") or [])  # each fault's recovery
    if outcome == "OK":
        return f"{head}: flown to the end; {(s.get('controlled') or {}).get('reason', 'controlled')}{after}"
    if outcome == "OUT OF ENVELOPE" and s.get("diverged"):  # the SITL stopped it: its reason, with the flown share
        return f"{head}: {s['error'].removeprefix('out of envelope: ')}"
    if outcome == "OUT OF ENVELOPE":
        return f"{head}: {s['controlled']['reason']}{after}"
    return f"{head}: {s.get('error')}"


def _law(s: dict) -> str:
    """The law in the header: Lv means something for SAC and CL-SAC only, not for the fixed-gain PID; a Lv changed in
    flight is given as it started and as it ended."""
    c = controllers.get(s["controller"])
    if not c.adaptive:
        return f"{c.name} ({c.label})"
    end = s.get("Lv_end", s["Lv"])
    return f"{c.name} (Lv={s['Lv']:g}" + (f" -> {end:g}" if end != s["Lv"] else "") + ")"


def _plant(s: dict) -> str:
    """The plant and its surface in the header: "on c172x (aileron)"; a square MIMO plant's surfaces, each on its
    channel: "on c172x-aileron+rudder (aileron: roll, rudder: sideslip)"."""
    side = s.get("sideslip")
    if side and side.get("channels"):
        surfaces = ", ".join(f"{c['surface']}: {c['channel']}" for c in side["channels"])
    else:
        surfaces = s.get("surface", "rudder")
    return f" on {s.get('plant_name') or s.get('plant')} ({surfaces})"


def print_summary(s: dict) -> None:
    """The summary table of a flight's summary.json, ending with its outcome (``outcome_line``)."""
    print()
    print(f"== {s['mode']} flight, {_law(s)}{_plant(s)}, {s['rate_hz']:g} Hz, {s['duration_s']:g} s: {s['outcome']}")
    for c in (s.get("parameters") or {}).get("changes") or ():
        at = "before the first attitude" if c.get("t_s") is None else f"at {c['t_s']:.2f} s"
        print(f"   parameter changed in flight: {c['name']} {c['from']:.6g} -> {c['to']:.6g} {at}")
    if s["runs"]:
        m = s["runs"][0]["metrics"]
        print(f"   {'metric':<12}{'value':>14}")
        for k, v in m.items():
            print(f"   {k:<12}{v:>14.6g}")
        print(f"   {'steps':<12}{s['runs'][0]['steps']:>14d}")
    if s["rtf"] and s["mode"] == "lockstep":
        print(f"   real-time factor {s['rtf']:.1f}x (sim {s['sim_time_s']:.2f} s)")
    t = s.get("timing") or {}

    def fmt(d):
        return "-" if not d else f"p50 {d['p50']:.3f}  p99 {d['p99']:.3f}  max {d['max']:.3f} ms"

    if t:
        if s["mode"] == "realtime":
            print(
                f"   period jitter     {fmt(t.get('period_jitter_ms'))}; missed deadlines {t.get('missed_deadlines')}"
            )
            print(f"   compute           {fmt(t.get('compute_ms'))} (deadline to servo sent)")
            # Not the in-to-out latency: the newest ATTITUDE waits up to a sensor period for the next deadline.
            print(f"   attitude age      {fmt(t.get('latency_ms'))} (ATTITUDE read to servo sent)")
        else:
            print(f"   in-to-out latency {fmt(t.get('latency_ms'))}")
    c = s["counters"]
    for name in PROCESSES:
        links = c.get(name)
        if not links:
            continue
        if "rx_packets" in links:
            links = {"link": links}
        for lname, link in links.items():
            rej = ", ".join(f"{k}={v}" for k, v in link["rejected"].items()) or "none"
            print(
                f"   {name + ' ' + lname:<16} rx {link['rx_packets']:>7}  tx {link['tx_packets']:>7}  rejected: {rej}"
            )
    ev = (s["events"] or {}).get("autopilot") or {}
    ev = {k: v for k, v in ev.items() if v not in (0, [], None)}
    if ev:
        print(f"   autopilot events: {ev}")
    for direction, n in ((s.get("disturbances") or {}).get("injected") or {}).items():
        print(f"   link faults {direction:<9}" + "  ".join(f"{k} {v}" for k, v in n.items()))
    f = s["files"]
    rrd = " ".join(f["rrd"]) if isinstance(f.get("rrd"), list) else f.get("rrd")  # a long flight: side by side
    logs = Path(f["logs"]["autopilot"]).parent
    print(f"   files: {f['tlog']}{'  ' + rrd if rrd else ''}  {f['summary']}  logs: {logs}/*.log")
    if rrd:
        print(f"   open the flight in the Rerun viewer: rerun {rrd}")
    if f.get("png"):
        print(f"   picture: {f['png']}")
    c = s.get("controlled")
    if c:
        print(f"   envelope          {c['reason']}")
    note = (s.get("ground_station") or {}).get("note")
    if note:
        print(f"   ground station    {note}")
    for r in s.get("recovery") or []:
        print(f"   recovery          {recovery_text(r)}")


# A lockstep flight's busy-poll (docs/decisions.md, "A flight in about a second"): the peer answers within
# tens of us when it has a core, so 100 us catches nearly every answer; while the launcher's other processes
# start on the same two cores, each 500 us spin that waits for a peer with no core took that core from it.
LOCKSTEP_SPIN_US = 100.0


def build_parser() -> OneLineArgumentParser:
    p = OneLineArgumentParser(prog="python -m tools.launch", description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--lockstep", action="store_true", help="SITL as time master, as fast as possible (default: real time)"
    )
    p.add_argument(
        "--duration",
        type=duration_s,
        default=None,
        metavar="S",
        help="flight length in sim seconds (default 30; with --csv: the file's last breakpoint)",
    )
    p.add_argument("--rate", type=rate_arg, default=100.0, metavar="HZ", help="control rate (default 100)")
    p.add_argument(
        "--physics-rate",
        type=physics_rate_hz,
        default=None,
        metavar="HZ",
        help="default: the smallest whole multiple of --rate >= 1000 Hz (1000 at 100 Hz, 1200 at 400 Hz)",
    )
    p.add_argument(
        "--sensor-rate", type=sensor_rate_hz, default=200.0, metavar="HZ", help="real time ATTITUDE rate (default 200)"
    )
    p.add_argument(
        "--telemetry-rate",
        type=stream_rate_or_0,
        default=None,
        metavar="HZ",
        help="GCS stream rate (default 50 Hz in real time, 10 Hz of sim time in lockstep)",
    )
    p.add_argument(
        "--out", default=None, metavar="DIR", help="output folder (default: a new runs/<timestamp>-... folder)"
    )
    p.add_argument(
        "--base-port",
        type=int,
        default=None,
        metavar="PORT",
        help="SITL on PORT, GCS on PORT+1, the autopilot on PORT+2 (SITL link) and PORT+3 (GCS link); default: free "
        "ports chosen automatically",
    )
    p.add_argument("--start-time", type=clock_s, default=0.0, metavar="S", help="initial sim clock (default 0)")
    p.add_argument("profile", nargs="?", choices=PROFILES, default="square", help="GCS roll profile")
    p.add_argument(
        "--csv",
        default=None,
        metavar="FILE",
        help="GCS profile from a CSV file of 'time s, roll deg' rows, each held until the next (not interpolated); "
        "the flight ends at the last row's time unless --duration is given",
    )
    p.add_argument("--amplitude", type=angle_deg, default=10.0, metavar="DEG", help="profile amplitude (default 10)")
    p.add_argument("--period", type=timeout_s, default=10.0, metavar="S", help="profile period (default 10)")
    p.add_argument("--timeout", type=timeout_s, default=None, metavar="S", help="wall-clock limit of the whole flight")
    p.add_argument(
        "--rt-priority",
        type=rt_priority_arg,
        default=0,
        metavar="N",
        help="real time: run the autopilot under SCHED_FIFO priority N (SITL N-1); default 0 = normal",
    )
    p.add_argument(
        "--pin", action="store_true", help="give the autopilot CPU 1 to itself; the SITL and the GCS script share CPU 0"
    )
    p.add_argument(
        "--busy-wait",
        action="store_true",
        help="real time: the autopilot never sleeps between steps (one CPU at 100 %%; best with --pin; "
        "on a VM it avoids the hypervisor's wake-up delays, see docs/flying.md)",
    )
    p.add_argument(
        "--lockstep-spin-us",
        type=spin_us,
        default=LOCKSTEP_SPIN_US,
        metavar="US",
        help=f"lockstep: the autopilot and the SITL busy-poll this long for each other's frame before sleeping "
        f"(default {LOCKSTEP_SPIN_US:g}; the processes' own default is 500, see docs/decisions.md)",
    )
    p.add_argument(
        "--lockstep-idle-exit",
        type=timeout_s,
        default=LOCKSTEP_IDLE_EXIT_S,
        metavar="S",
        help=f"lockstep: the autopilot gives up after S s of SITL silence after a frame "
        f"(default {LOCKSTEP_IDLE_EXIT_S:g})",
    )
    p.add_argument(
        "--vehicle-timeout",
        type=timeout_s,
        default=VEHICLE_TIMEOUT_S,
        metavar="S",
        help=f"the GCS script gives up after S s without a word from the vehicle (default {VEHICLE_TIMEOUT_S:g})",
    )
    p.add_argument("--quiet", action="store_true", help="do not echo the processes' output (it is still in DIR/*.log)")
    p.add_argument(
        "--no-series",
        dest="series",
        action="store_false",
        help="do not record the per-step series (DIR/autopilot_series.npz, DIR/sitl_series.npz)",
    )
    g = p.add_argument_group("telemetry (Rerun)")
    g.add_argument(
        "--viewer", action="store_true", help="show the flight live: spawn a Rerun viewer (or reuse one on port 9876)"
    )
    g.add_argument(
        "--connect",
        type=viewer_url,
        metavar="URL",
        default=None,
        help="show the flight live in a running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy",
    )
    g.add_argument("--no-rrd", dest="rrd", action="store_false", help="do not write DIR/flight.rrd")
    g.add_argument(
        "--rrd-live",
        action="store_true",
        help="the autopilot and the SITL write their own parts of DIR/flight.rrd with rerun while they fly (by "
        "default they spool their rows, recorded by the launcher afterwards in sim-time order: the same rows, no "
        "rerun for the file in either process)",
    )
    g.add_argument(
        "--rrd-merge-max-mb",
        type=bounded(0.0, 1e6, "MB"),
        default=MERGE_MAX_MB,
        metavar="MB",
        help=f"telemetry up to this size (the processes' spools, or their --rrd-live parts) goes into an indexed "
        f"DIR/flight.rrd (spools: recorded in one pass; parts: merged, memory about twice their size); more is "
        f"concatenated into it without an index, in constant memory (default {MERGE_MAX_MB:g})",
    )
    g.add_argument(
        "--live-rate",
        type=bounded(0.0, 1e4, "Hz"),
        default=LIVE_RATE_HZ,
        metavar="HZ",
        help=f"a live viewer (--viewer, --connect, --web) gets at most HZ rows per second of sim time of each plot, "
        f"so that a software-rendered one keeps up (default {LIVE_RATE_HZ:g}; 0: every row); DIR/flight.rrd keeps "
        "every row",
    )
    g.add_argument(
        "--live-window",
        type=bounded(0.0, MAX_SIM_S, "s"),
        default=LIVE_WINDOW_S,
        metavar="S",
        help=f"a live viewer's plots show the last S seconds of sim time (default {LIVE_WINDOW_S:g}; 0: the whole "
        "flight); DIR/flight.rrd opens on the whole flight",
    )
    g.add_argument(
        "--web",
        action="store_true",
        help="serve the Rerun web viewer (HTTP --web-port, gRPC --web-grpc-port, on 127.0.0.1) and stream the flight "
        "to it; a browser elsewhere watches through ssh -L (docs/telemetry.md); the server ends with the launch",
    )
    g.add_argument(
        "--web-host",
        type=bind_host,
        default=DEFAULT_HOST,
        metavar="IP",
        help="the address --web binds (default 127.0.0.1); 0.0.0.0 exposes it on every interface, without "
        "authentication: anyone who reaches its ports can read and write the recording",
    )
    g.add_argument(
        "--web-port", type=tcp_port, default=DEFAULT_HTTP_PORT, metavar="PORT", help="--web: HTTP port (default 9090)"
    )
    g.add_argument(
        "--web-grpc-port",
        type=tcp_port,
        default=DEFAULT_GRPC_PORT,
        metavar="PORT",
        help="--web: gRPC port the processes stream to and the browser reads (default 9877)",
    )
    p.add_argument(
        "--no-png", dest="png", action="store_false", help="do not draw DIR/flight.png (roll, rudder, adaptive gains)"
    )
    p.add_argument(
        "--gcs-peer",
        action="append",
        default=[],
        metavar="HOST:PORT",
        help="one more ground station the autopilot streams to and accepts (repeatable), e.g. MAVProxy on "
        "127.0.0.1:14550 (with --no-signing, or a ground station that signs)",
    )
    p.add_argument(
        "--failure-injection",
        action="store_true",
        help="the autopilot takes MAV_CMD_INJECT_FAILURE from a ground station and relays it to the SITL "
        "(SYS_FAILURE_EN 1; default: refused with MAV_RESULT_DENIED, as PX4 does; docs/ground-stations.md)",
    )
    p.add_argument(
        "--sysid",
        type=sysid_arg,
        default=1,
        metavar="N",
        help="the vehicle's MAVLink system id, 1..254 (default 1): launches with different ids streaming to one "
        "ground-station port are different vehicles",
    )
    g = p.add_argument_group("MAVLink 2 signing (default: a new key for each flight, DIR/signing.key, mode 0600)")
    g.add_argument("--signing-key", default=None, metavar="FILE", help="sign every link with this key file instead")
    g.add_argument(
        "--no-signing", dest="signing", action="store_false", help="fly unsigned (anyone on the host can talk to it)"
    )
    p.add_argument(
        "--plant",
        default="kh2013a",
        metavar="PLANT",
        help=f"the SITL's plant: {plant_help()} (docs/plants.md)",  # from the kinds' records (sitl.plant_kinds)
    )
    p.add_argument(
        "--params",
        default=None,
        metavar="FILE",
        help="the autopilot's parameter file (default: the PFC designed for the plant, if it ships one)",
    )
    add_controller_arguments(p)
    add_envelope_arguments(p)
    disturbances.add_arguments(p)
    damage.add_argument(p)
    return p


def _flag(keyword: str) -> str:
    """The command-line spelling of a Flight keyword."""
    return keyword if keyword == "profile" else "--" + keyword.replace("_", "-")


# The process each flag configures: a value refused before the flight is reported as that process's failure.
_OWNERS = {
    "sitl": {"physics_rate", "sensor_rate", "start_time", "plant", "fault", *disturbances.FLAGS},
    "autopilot": {"rate", "lv", "pfc", "sigma_xu", "dead_zone_deg", "ki_max", "u_limit_deg", "controller"}
    | {
        "freeze_when_saturated",
        "rt_priority",
        "busy_wait",
        "lockstep_spin_us",
        "lockstep_idle_exit",
        "telemetry_rate",
        "gcs_peer",
        "failure_injection",
        "params",
        "baseline_gains",
    }
    | {"envelope_roll", "envelope_saturated", "lockstep_spin_us"},
    "gcs": {"profile", "csv", "amplitude", "period", "vehicle_timeout"},
}


def _owner(parser, message: str | None, dest: str | None = None) -> str:
    """The process a refused flag configures: ``dest``, or the flag an argparse error names (``argument --rate:
    ...``); else the launcher itself."""
    text = message or ""
    if dest is None and text.startswith("argument "):
        flag = text[len("argument ") :].split(":", 1)[0].split("/")[0].strip()
        action = parser._option_string_actions.get(flag)  # noqa: SLF001 (argparse keeps no public index of flags)
        dest = action.dest if action is not None else flag
    return next((name for name, dests in _OWNERS.items() if dest in dests), "launch")


def _parse(parser, argv) -> Flight:
    """The flight the command line asks for; a refused value exits 2 with one line on stderr and, when ``--out``
    was given, DIR/summary.json saying ``ok: false``, the process the value belongs to and nothing flown."""
    dest = None
    try:
        args = parser.parse_args(argv)
        try:
            return Flight(**vars(args))
        except FlightConfigError as exc:
            dest, message = exc.field, str(exc)
            parser.error(_flag(dest) + message[len(dest) :] if message.startswith(dest) else message)
    except SystemExit as exc:
        if exc.code == EXIT_USAGE:
            pre = argparse.ArgumentParser(add_help=False, exit_on_error=False)
            pre.add_argument("--out", default=None)
            try:
                out = pre.parse_known_args(argv)[0].out
            except (argparse.ArgumentError, SystemExit):  # --out itself is what was refused
                out = None
            if out:
                write_refusal(out, _owner(parser, parser.last_error, dest), parser.last_error or "refused")
        raise


def main(argv=None, png_helper=None) -> int:
    """The command; ``png_helper``: a picture helper started already (``Flight.adopt_png_helper``), closed if the
    command line is refused."""
    parser = build_parser()
    try:
        flight = _parse(parser, sys.argv[1:] if argv is None else list(argv))
    except BaseException:
        if png_helper is not None:
            png_helper.close()
        raise
    if png_helper is not None:
        flight.adopt_png_helper(png_helper)
    install_stop_handlers(flight.interrupt)
    try:
        res = flight.run()
    except WebServerError as exc:  # a --web port taken: nothing was started
        print(f"launch: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except OutputError as exc:  # the folder cannot take even the provisional summary (a full disk)
        print(f"FAILED: launch: {exc}; nothing was flown", flush=True)
        return EXIT_FAILED
    except Exception as exc:  # noqa: BLE001  an internal error: one line, its traceback in DIR/launch.log
        log = flight.out / "launch.log" if flight.out is not None and flight.out.is_dir() else None
        print("FAILED: " + crash.report("launch", exc, log=log, file=io.StringIO()), flush=True)  # the one line
        return EXIT_FAILED
    print_summary(res.summary)
    if not res.completed and not res.summary.get("diverged"):  # a plant that diverged is a result, not an error
        print(f"launch: error: {res.reason} (logs in {res.out})", file=sys.stderr, flush=True)
    print(outcome_line(res.summary), flush=True)  # the last line: OK, OUT OF ENVELOPE or FAILED
    return res.exit_code


def exit_without_teardown(code: int) -> None:
    """End the command once everything is written: stdout and stderr flushed, rerun's streams shut down (each was
    flushed and disconnected already), then ``os._exit``.  The interpreter's own teardown would only free the
    modules: after rerun and pyarrow were imported to record the flight that took 0.15-0.4 s of wall and CPU,
    measured, after the last file was written."""
    sys.stdout.flush()
    sys.stderr.flush()
    rerun = sys.modules.get("rerun")
    shutdown = getattr(rerun, "rerun_shutdown", None)  # None while a background import is still half done
    if shutdown is not None:
        shutdown()
    logging.shutdown()
    os._exit(code)


if __name__ == "__main__":
    crash.install("launch")
    survive_closed_stdout()
    exit_without_teardown(main(png_helper=EARLY_PNG_HELPER))
