"""MAVLink benchmarks: SITL + autopilot + GCS as real processes over loopback UDP.

    python -m tools.bench mavlink [--quick] [-- --lockstep-only ...]   (or: python -m tools.bench.mavlink ...)

Figures (medians over --runs flights where it says so):
* the lockstep floor: round trips per second of a bare ATTITUDE -> SERVO_OUTPUT_RAW ping-pong between two
  processes over loopback UDP (the same packets, ``UdpLink`` decoding, busy-poll and pinning as a lockstep
  flight; no physics, control law, tlog or GCS), as a floor real-time factor at 100 and 400 Hz; each lockstep
  flight below is also given as a fraction of a floor window measured just before its round (the load of a
  shared machine moves during a run), median over the rounds: target >= 0.6 at 100 and 400 Hz, signed, with
  the .rrd (stretch 0.75);
* lockstep real-time factor, 100 Hz control / 1 kHz physics, tlog and GCS on: target >= 50x (stretch
  100x; ArduPilot's SITL documents 1-10x, PX4's 6-10x), given as wall ms per sim second (<= 20 ms);
* the same at 400 Hz control (1.2 kHz physics, a whole number of steps per frame): target >= 15x
  (<= 66.7 ms per sim second);
  both as the issue states them (tlog on, Rerun telemetry off: ``--no-rrd``) and, for information, as
  the launcher flies by default (tlog and ``flight.rrd``);
* attitude-in to servo-out latency inside the autopilot (lockstep: ATTITUDE datagram read -> SERVO_OUTPUT_RAW
  sent), p99: target <= 0.3 ms; p50 at 100 Hz, signed, with the .rrd (the critical path of a typical frame:
  decode, law, encode, sign, send): target <= 10 us;
* real time at 100 and 400 Hz for 60 s (--quick: 10 s): control-period jitter |period - nominal| p50/p99/max
  (target p99 <= 0.5 ms) and missed deadlines (target 0 at 100 Hz), in the deployed set-up: autopilot
  alone on CPU 1, never sleeping between steps (``--pin --busy-wait``); for comparison, one flight per rate
  pinned under SCHED_FIFO (``--pin --rt-priority 50``) and one with neither. On a VM a sleeping vCPU can
  take milliseconds to be run again (the baseline figure shows it), which only the busy wait avoids;
* a lockstep flight across the 71.6-minute SERVO_OUTPUT_RAW.time_usec wrap (start 4290 s, 10 s);
* lockstep-vs-in-process metric agreement for clsac (largest relative difference of ise_ref, ise_crm,
  energy, max_abs_u: target <= 2 %; tv reported apart, PWM quantisation moves it by ~13 %).

By default (``--pin``) the autopilot has CPU 1 to itself and the SITL, the GCS script and the launcher
share CPU 0 (--no-pin to let the scheduler place them); timings on a loaded machine are inflated (the load
average and the hypervisor's steal time are printed).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

from autopilot.shared.process import standard_json
from tools.bench import figure, machine_load, report
from tools.flight import Flight

QUICK_ARGV = ["--quick"]


def _fly(tmp: Path, name: str, **kw) -> dict:
    """summary.json of one flight; series off, as the figures are measured without them."""
    res = Flight(out=tmp / name, quiet=True, series=False, **kw).run()
    if not res.ok:
        raise RuntimeError(f"{name}: {res.reason} (see {res.out})")
    return res.summary


def _lockstep(tmp: Path, rate: float, runs: int, pin: bool, duration: float, floor_s: float) -> list[dict]:
    """``runs`` rounds at ``rate``: a short floor (``lockstep_floor``, one window of ``floor_s``), then a flight
    with the tlog only (``--no-rrd``) and one with the ``.rrd`` too, one after the other, so each flight's fraction
    of the floor is read against a floor measured under the same load (a shared machine's load moves by more than
    the figures between the start of a run and its end).  Per round: floor rtf, and per set-up rtf and latency."""
    out = []
    for i in range(runs):
        floor = lockstep_floor(floor_s, 1, pin=pin, warmup_s=0.3)["round_trips_per_s"] / rate
        rnd = {"floor_rtf": floor}
        for rrd in (False, True):
            s = _fly(
                tmp,
                f"lockstep{rate:g}_{'rrd' if rrd else 'tlog'}_{i}",
                lockstep=True,
                rate=rate,
                duration=duration,
                pin=pin,
                rrd=rrd,
                physics_rate=rate * max(1, -(-1000 // int(rate))),
            )
            lat = s["timing"]["latency_ms"]
            rnd["rrd" if rrd else "tlog"] = {"rtf": s["rtf"], "lat_p50": lat["p50"], "lat_p99": lat["p99"]}
        out.append(rnd)
    return out


def steal_jiffies() -> int | None:
    """CPU time the hypervisor took from this VM (the 'steal' column of /proc/stat), in jiffies."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
        return int(fields[8])
    except (OSError, IndexError, ValueError):
        return None


def _realtime(tmp: Path, rate: float, duration: float, name: str, **setup) -> dict:
    import os

    st0 = steal_jiffies()
    s = _fly(tmp, f"realtime{rate:g}_{name}", lockstep=False, rate=rate, duration=duration, **setup)
    st1 = steal_jiffies()
    t = dict(s["timing"])
    if st0 is not None and st1 is not None:
        hz = os.sysconf("SC_CLK_TCK")
        t["steal_ms_per_s"] = (st1 - st0) * 1000.0 / hz / max(s["wall_s"], 1e-9)
    return t


def _baseline(rate: float, seconds: float, spin_s: float, cpu: int | None) -> dict:
    """``baseline_jitter`` on ``cpu`` (this thread only, restored after), with the hypervisor's steal."""
    import os
    import time

    old = os.sched_getaffinity(0)
    try:
        if cpu is not None and cpu in old:
            os.sched_setaffinity(0, {cpu})
        st0, t0 = steal_jiffies(), time.perf_counter()
        b = baseline_jitter(rate, seconds, spin_s)
        st1, t1 = steal_jiffies(), time.perf_counter()
    finally:
        os.sched_setaffinity(0, old)
    if st0 is not None and st1 is not None:
        b["steal_ms_per_s"] = (st1 - st0) * 1000.0 / os.sysconf("SC_CLK_TCK") / (t1 - t0)
    return b


def baseline_jitter(rate: float = 100.0, seconds: float = 5.0, spin_s: float = 0.0003) -> dict:
    """The machine's own timing floor: the autopilot's deadline wait (select until shortly before, then spin)
    with no work and no I/O.  If this misses 0.5 ms at p99, the host (e.g. hypervisor steal), not the code,
    sets the real-time figures."""
    import select
    import socket
    import time

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    per = 1.0 / rate
    perf = time.perf_counter
    deadline = perf() + per
    prev = None
    jit = []
    for _ in range(int(seconds * rate)):
        while True:
            rem = deadline - perf()
            if rem <= spin_s:
                break
            select.select([s], [], [], rem - spin_s)
        while perf() < deadline:
            pass
        t = perf()
        if prev is not None:
            jit.append(abs(t - prev - per) * 1e3)
        prev = t
        deadline += per
    s.close()
    jit.sort()
    return {
        "p50": jit[len(jit) // 2],
        "p99": jit[min(len(jit) - 1, int(0.99 * len(jit)))],
        "max": jit[-1],
        "n": len(jit),
    }


# ------------------------------------------------------------------------------------ the lockstep floor
# What any two-process lockstep over loopback UDP costs with no physics, no control law and no recording: a
# bare ping-pong of the two packets a lockstep frame exchanges, each side waiting the way the flights do.
FLOOR_ROUND_S = 1.0  # the floor window measured before each lockstep round (_lockstep)
FLOOR_FRACTION_TARGET = 0.6  # lockstep (signed, .rrd) at least this fraction of the floor, at 100 and 400 Hz ...
FLOOR_FRACTION_STRETCH = 0.75  # ... stretch goal
LATENCY_P50_TARGET_US = 10.0  # ATTITUDE in to SERVO_OUTPUT_RAW out inside the autopilot, p50
FLOOR_SPIN_S = 500e-6  # both sides busy-poll this long before select (sitl --spin-us, autopilot --lockstep-spin-us)
_FLOOR_RATE_HZ = 100.0  # frame clock of the stamps; a round trip costs the same at any rate
_FLOOR_GIVE_UP_S = 10.0
_FLOOR_RESEND_S = 0.25  # as SitlOptions.resend_timeout_s


def _floor_pin(cpu: int | None) -> None:
    import os

    if cpu is not None:
        try:
            os.sched_setaffinity(0, {cpu})
        except (AttributeError, OSError):
            pass  # not Linux, or that CPU is not ours: run unpinned


def _floor_sitl_side(conn, cpu: int | None, spin_s: float, seconds: float, runs: int, warmup_s: float) -> None:
    """The SITL side of the floor (a child process): send ATTITUDE for frame k as ``sitl.endpoint`` does
    (``pack_fast`` + ``send_raw``), busy-poll ``spin_s`` (one ``poll(2)`` a turn) for the SERVO_OUTPUT_RAW answering
    it, taken by the link's hot path (``UdpLink.on_hot``) as the SITL takes it, then ``select``;
    ``runs`` windows of ``seconds`` after ``warmup_s``.  Sends {rates, frames, ...} (or {error}) on ``conn``."""
    import select
    import time

    from autopilot.shared.fastmav import HOT_DECODERS
    from autopilot.shared.link import UdpLink
    from autopilot.shared.mavlink import AUTOPILOT_SITL_ID, SITL_ID, frame_ms, frame_usec, mavlink
    from autopilot.shared.pwm import PwmMap

    try:
        _floor_pin(cpu)
        att_id, servo_id = mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW
        link = UdpLink(
            "autopilot",
            SITL_ID,
            ("127.0.0.1", 0),
            None,
            peers=[AUTOPILOT_SITL_ID],
            msgids=[servo_id, mavlink.MAVLINK_MSG_ID_HEARTBEAT],
            learn_remote=True,
        )
        conn.send(link.local)
        pk_att = link.fast_packer(mavlink.MAVLink_attitude_message)
        pwm = PwmMap()
        servo_field = f"servo{pwm.channel}_raw"
        servo_index = HOT_DECODERS[servo_id].index(servo_field)
        servos: list = []  # (time_usec, pwm), as sitl.endpoint keeps them

        def on_msg(msg, t_rx):  # noqa: ARG001  (UdpLink handler signature)
            if msg.get_msgId() == servo_id:
                servos.append((msg.time_usec, getattr(msg, servo_field)))

        def on_servo(t_rx, values):  # noqa: ARG001  (the link's hot path, as the SITL takes SERVO_OUTPUT_RAW)
            servos.append((values[0], values[servo_index]))

        link.on_hot(servo_id, on_servo)
        poller = select.poll()
        poller.register(link.sock, select.POLLIN)
        poll = poller.poll
        fds = [link.sock]
        perf = time.perf_counter
        t_give_up = perf() + 60.0  # the autopilot side is still importing
        while link.remote is None:  # its HEARTBEAT tells us where it is
            if perf() > t_give_up:
                raise RuntimeError("no HEARTBEAT from the autopilot side")
            if select.select(fds, (), (), 0.05)[0]:
                link.poll(on_msg)
        servos.clear()
        k, stats = 0, {"stale": 0, "wrong_value": 0, "resends": 0}

        def window(duration: float) -> float:
            nonlocal k
            t0 = perf()
            t_end, n = t0 + duration, 0
            while perf() < t_end:
                raw = link.pack_fast(pk_att, frame_ms(k, _FLOOR_RATE_HZ), 0.1, 0.0, 0.0, 0.2, 0.0, 0.3)
                link.send_raw(raw, att_id)
                expected = frame_usec(k, _FLOOR_RATE_HZ)
                t_sent = perf()
                t_resend = t_sent + _FLOOR_RESEND_S
                while True:
                    if not servos:
                        t_spin = perf() + spin_s
                        while not servos and perf() < t_spin:
                            if poll(0):
                                link.poll(on_msg)
                        if servos:
                            continue
                        now = perf()
                        if now - t_sent > _FLOOR_GIVE_UP_S:
                            raise RuntimeError(f"no SERVO_OUTPUT_RAW for frame {k} after {_FLOOR_GIVE_UP_S:g} s")
                        if now >= t_resend:
                            link.send_raw(raw, att_id)
                            stats["resends"] += 1
                            t_resend = now + _FLOOR_RESEND_S
                        if select.select(fds, (), (), max(0.0, t_resend - now))[0]:
                            link.poll(on_msg)
                        continue
                    usec, got = servos.pop(0)
                    if usec != expected:
                        stats["stale"] += 1
                        continue
                    if got != pwm.neutral:
                        stats["wrong_value"] += 1
                    break
                k += 1
                n += 1
            return n / (perf() - t0)

        window(warmup_s)
        rates = [window(seconds) for _ in range(runs)]
        for _ in range(3):  # tell the autopilot side to stop (it exits on a HEARTBEAT)
            link.send(
                mavlink.MAVLink_heartbeat_message(
                    mavlink.MAV_TYPE_GENERIC, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
                )
            )
        conn.send({"rates": rates, "frames": k, **stats, "link": link.counters()})
        link.close()
    except Exception as exc:  # noqa: BLE001  (reported to the parent, which raises it)
        conn.send({"error": f"{type(exc).__name__}: {exc}"})


def _floor_autopilot_side(conn, cpu: int | None, spin_s: float) -> None:
    """The autopilot side of the floor (a child process): answer each ATTITUDE with the SERVO_OUTPUT_RAW of its
    frame as ``autopilot.loop`` does (ATTITUDE by the link's hot path, ``frame_from_ms`` -> ``frame_usec``, the
    cached payload framed by ``frame_fast`` + ``send_raw`` from the handler), busy-polling ``spin_s`` (one ``poll(2)``
    a turn) then ``select`` between frames.  Stops on the SITL side's HEARTBEAT
    and sends its link counters (or {error}) on ``conn``."""
    import select
    import time

    from autopilot.shared.link import UdpLink
    from autopilot.shared.mavlink import AUTOPILOT_SITL_ID, SITL_ID, frame_from_ms, frame_usec, mavlink
    from autopilot.shared.pwm import PwmMap

    try:
        _floor_pin(cpu)
        sitl_addr = tuple(conn.recv())
        att_id, hb_id = mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLINK_MSG_ID_HEARTBEAT
        servo_id = mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW
        link = UdpLink(
            "sitl",
            AUTOPILOT_SITL_ID,
            ("127.0.0.1", 0),
            sitl_addr,
            peers=[SITL_ID],
            msgids=[att_id, hb_id, mavlink.MAVLINK_MSG_ID_STATUSTEXT],
        )
        servo_cls = mavlink.MAVLink_servo_output_raw_message
        pk_servo = link.fast_packer(servo_cls)
        pwm = PwmMap()
        # the payload after time_usec (struct order: servo1..8, port, servo9..16), from pymavlink's own field lists,
        # packed once as the autopilot does (LinkHandlers._servo_payload)
        template = servo_cls(0, 0, *pwm.servo_fields(pwm.neutral))
        rest = tuple(getattr(template, name) for name in servo_cls.ordered_fieldnames[1:])
        tail = servo_cls.unpacker.pack(0, *rest)[4:]
        stop = []

        def on_att(t_rx, values):  # noqa: ARG001  (the link's hot path, as the autopilot takes ATTITUDE)
            usec = frame_usec(frame_from_ms(values[0], _FLOOR_RATE_HZ), _FLOOR_RATE_HZ)
            link.send_raw(link.frame_fast(pk_servo, usec.to_bytes(4, "little") + tail), servo_id)

        def on_msg(msg, t_rx):
            mid = msg.get_msgId()
            if mid == att_id:
                on_att(t_rx, (msg.time_boot_ms,))
            elif mid == hb_id and link.rx_by_type[att_id]:
                stop.append(True)

        link.on_hot(att_id, on_att)
        poller = select.poll()
        poller.register(link.sock, select.POLLIN)
        poll = poller.poll

        hb = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_GENERIC, 0, 0, mavlink.MAV_STATE_STANDBY, 3
        )
        fds = [link.sock]
        perf = time.perf_counter
        t_start = next_hb = perf()
        while not stop:
            now = perf()
            if not link.rx_packets and now >= next_hb:  # announce ourselves until the first frame
                link.send(hb)
                next_hb = now + 0.05
            n0 = link.rx_datagrams
            t_end = now + spin_s
            while perf() < t_end:
                if poll(0):
                    link.poll(on_msg)
                    if link.rx_datagrams != n0:
                        break
            else:
                if select.select(fds, (), (), 0.02)[0]:
                    link.poll(on_msg)
            silent = perf() - (link.last_rx_wall or t_start)
            if silent > _FLOOR_GIVE_UP_S + 60.0 * (not link.rx_packets):
                raise RuntimeError(f"the SITL side was silent for {silent:.1f} s")
        conn.send({"link": link.counters()})
        link.close()
    except Exception as exc:  # noqa: BLE001  (reported to the parent, which raises it)
        conn.send({"error": f"{type(exc).__name__}: {exc}"})


def lockstep_floor(
    seconds: float = 3.0, runs: int = 5, pin: bool = True, spin_s: float = FLOOR_SPIN_S, warmup_s: float = 0.5
) -> dict:
    """The floor of any two-process lockstep over loopback UDP: round trips per second of a bare ATTITUDE ->
    SERVO_OUTPUT_RAW ping-pong between two spawned processes (``_floor_sitl_side``, ``_floor_autopilot_side``),
    packed, received and decoded with ``UdpLink`` as the SITL and the autopilot do, with their busy-poll
    (``spin_s``) and, with ``pin``, their CPUs (autopilot side on CPU 1, SITL side on CPU 0).

    Returns ``round_trips_per_s`` (median of ``runs`` windows of ``seconds``), ``runs`` (each window's rate),
    the floor real-time factor at 100 and 400 Hz (``rtf_100hz``, ``rtf_400hz``: frames/s / rate), frame and
    error counts (``stale``, ``wrong_value``, ``resends``) and both links' counters.  Raises RuntimeError if
    a side fails."""
    import multiprocessing
    import os

    if not (seconds > 0 and runs >= 1):
        raise ValueError(f"need seconds > 0 and runs >= 1, got {seconds!r}, {runs!r}")
    two = pin and (os.cpu_count() or 1) >= 2
    ctx = multiprocessing.get_context("spawn")
    sitl_conn, sitl_child = ctx.Pipe()
    ap_conn, ap_child = ctx.Pipe()
    sitl = ctx.Process(
        target=_floor_sitl_side,
        args=(sitl_child, 0 if two else None, spin_s, seconds, runs, warmup_s),
        name="floor-sitl",
        daemon=True,
    )
    ap = ctx.Process(
        target=_floor_autopilot_side, args=(ap_child, 1 if two else None, spin_s), name="floor-autopilot", daemon=True
    )
    procs = (sitl, ap)
    timeout = 60.0 + warmup_s + runs * seconds + _FLOOR_GIVE_UP_S

    def receive(conn, who: str):
        if not conn.poll(timeout):
            raise RuntimeError(f"lockstep floor: no answer from the {who} side within {timeout:.0f} s")
        try:
            msg = conn.recv()
        except EOFError:
            raise RuntimeError(f"lockstep floor: the {who} side died") from None
        if isinstance(msg, dict) and "error" in msg:
            raise RuntimeError(f"lockstep floor, {who} side: {msg['error']}")
        return msg

    try:
        for p in procs:
            p.start()
        sitl_child.close()
        ap_child.close()
        ap_conn.send(receive(sitl_conn, "SITL"))  # the SITL side's address
        res = receive(sitl_conn, "SITL")
        ap_res = receive(ap_conn, "autopilot")
    finally:
        for p in procs:
            p.join(timeout=5.0)
            if p.is_alive():
                p.terminate()
                p.join(timeout=5.0)
    rate = statistics.median(res["rates"])
    return {
        "round_trips_per_s": rate,
        "runs": res["rates"],
        "rtf_100hz": rate / 100.0,
        "rtf_400hz": rate / 400.0,
        "seconds": seconds,
        "pinned": two,
        "spin_us": spin_s * 1e6,
        "frames": res["frames"],
        "stale": res["stale"],
        "wrong_value": res["wrong_value"],
        "resends": res["resends"],
        "sitl_link": res["link"],
        "autopilot_link": ap_res["link"],
    }


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m tools.bench.mavlink", description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="fewer, shorter runs")
    p.add_argument("--runs", type=int, default=None, help="lockstep flights per rate and set-up (default 5, quick 2)")
    p.add_argument("--realtime-s", type=float, default=None, help="real-time flight length (default 60, quick 10)")
    p.add_argument(
        "--realtime-runs",
        type=int,
        default=None,
        metavar="N",
        help="real-time flights per rate in the deployed set-up; figures are medians (default 3, quick 1)",
    )
    p.add_argument(
        "--no-pin",
        dest="pin",
        action="store_false",
        help="do not pin (default: autopilot alone on CPU 1, everything else on CPU 0)",
    )
    p.add_argument(
        "--no-busy-wait",
        dest="busy_wait",
        action="store_false",
        help="real-time flights: let the autopilot sleep between steps (default: --busy-wait)",
    )
    p.add_argument(
        "--rt-priority",
        type=int,
        default=50,
        metavar="N",
        help="also fly the real-time rates pinned under SCHED_FIFO priority N, for comparison (default 50; 0 = skip)",
    )
    p.add_argument(
        "--lockstep-only",
        action="store_true",
        help="only the lockstep figures (floor, real-time factor, latency, wrap, agreement): skip the "
        "real-time flights and their baselines, for quick before/after comparisons",
    )
    p.add_argument("--json", default=None, metavar="PATH", help="also write the figures to PATH")
    args = p.parse_args(argv or [])
    runs = args.runs or (2 if args.quick else 5)
    rt_s = args.realtime_s or (10.0 if args.quick else 60.0)
    rt_runs = args.realtime_runs or (1 if args.quick else 3)
    duration = 10.0 if args.quick else 30.0
    load_before = machine_load()
    figs: dict[str, dict] = {}
    floor_runs, floor_s = (3, 2.0) if args.quick else (5, 3.0)
    floor = lockstep_floor(floor_s, floor_runs, pin=args.pin)
    figs["lockstep_floor_round_trips_per_s"] = figure(
        floor["round_trips_per_s"],
        "1/s",
        runs=[round(x) for x in floor["runs"]],
        seconds=floor_s,
        pinned=floor["pinned"],
        spin_us=floor["spin_us"],
        note="bare ATTITUDE -> SERVO_OUTPUT_RAW ping-pong, two processes, as a lockstep flight waits",
    )
    for rate in (100, 400):
        figs[f"lockstep_floor_{rate}hz_rtf"] = figure(
            floor[f"rtf_{rate}hz"], "x", ms_per_sim_s=round(1000.0 / floor[f"rtf_{rate}hz"], 3)
        )
    with tempfile.TemporaryDirectory(prefix="bench-mavlink-") as d:
        tmp = Path(d)
        lat = {}
        for rate, target_rtf, stretch in ((100.0, 50.0, 100.0), (400.0, 15.0, None)):
            rounds = _lockstep(tmp, rate, runs, args.pin, duration, FLOOR_ROUND_S)
            for rrd in (False, True):
                key = "rrd" if rrd else "tlog"
                rtf = [r[key]["rtf"] for r in rounds]
                m = statistics.median(rtf)
                extra = {"rtf": round(m, 1), "rtf_runs": [round(x, 1) for x in rtf]}
                if stretch and not rrd:
                    extra["stretch_rtf"] = stretch
                name = f"lockstep_{rate:g}hz_ms_per_sim_s" + ("_with_rrd" if rrd else "")
                if rrd:  # the launcher's default set-up, for information: the target is with the tlog only
                    figs[name] = figure(
                        1000.0 / m, "ms", note=f"target {1000.0 / target_rtf:.1f} ms is for tlog only", **extra
                    )
                else:
                    figs[name] = figure(1000.0 / m, "ms", 1000.0 / target_rtf, **extra)
                # each flight against the floor measured just before it (_lockstep), median of the rounds
                fracs = [r[key]["rtf"] / r["floor_rtf"] for r in rounds]
                target = (
                    {
                        "stretch": FLOOR_FRACTION_STRETCH,
                        "meets_stretch": statistics.median(fracs) >= FLOOR_FRACTION_STRETCH,
                        "note": "signed, with the .rrd: target 0.6 of the floor, stretch 0.75",
                    }
                    if rrd
                    else {"note": "signed, tlog only (--no-rrd): for information"}
                )
                figs[f"lockstep_{rate:g}hz_fraction_of_floor" + ("_with_rrd" if rrd else "")] = figure(
                    statistics.median(fracs),
                    "frac",
                    FLOOR_FRACTION_TARGET if rrd else None,
                    higher=True,
                    runs=[round(x, 3) for x in fracs],
                    rtf=round(m, 1),
                    floor_rtf_runs=[round(r["floor_rtf"], 1) for r in rounds],
                    **target,
                )
                lat[(rate, rrd)] = [(r[key]["lat_p50"], r[key]["lat_p99"]) for r in rounds]
        figs["latency_in_to_out_p99"] = figure(
            statistics.median(p99 for _p50, p99 in lat[(100.0, False)]),
            "ms",
            0.3,
            runs_p99=[round(p99, 3) for _p50, p99 in lat[(100.0, False)]],
            at_400hz=round(statistics.median(p99 for _p50, p99 in lat[(400.0, False)]), 3),
            with_rrd_100hz=round(statistics.median(p99 for _p50, p99 in lat[(100.0, True)]), 3),
            with_rrd_400hz=round(statistics.median(p99 for _p50, p99 in lat[(400.0, True)]), 3),
        )
        # The critical path inside the autopilot (ATTITUDE datagram read -> SERVO_OUTPUT_RAW sent), typical frame:
        # 100 Hz, signed, with the .rrd (the launcher's default), median over the flights of each flight's p50.
        figs["latency_in_to_out_p50"] = figure(
            statistics.median(p50 for p50, _p99 in lat[(100.0, True)]) * 1e3,
            "us",
            LATENCY_P50_TARGET_US,
            runs_p50=[round(p50 * 1e3, 1) for p50, _p99 in lat[(100.0, True)]],
            at_400hz=round(statistics.median(p50 for p50, _p99 in lat[(400.0, True)]) * 1e3, 1),
            tlog_only_100hz=round(statistics.median(p50 for p50, _p99 in lat[(100.0, False)]) * 1e3, 1),
            note="100 Hz, signed, with the .rrd",
        )
        if not args.lockstep_only:  # the real-time flights and the baselines they are read against
            # The machine's floor: the autopilot's deadline wait with no work and no I/O, sleeping and busy.
            for kind, spin in (("sleeping", 0.0003), ("busy", float("inf"))):
                b = _baseline(100.0, 5.0, spin, cpu=1 if args.pin else None)
                figs[f"baseline_{kind}_loop_jitter_p99"] = figure(
                    b["p99"],
                    "ms",
                    p50=round(b["p50"], 4),
                    max=round(b["max"], 3),
                    vm_steal_ms_per_s=round(b.get("steal_ms_per_s", -1), 1),
                    note="no work, no I/O, normal priority: the machine's floor",
                )
            # The deployed set-up (target) first, then the alternatives for comparison (one flight each).
            setups = [("", dict(pin=args.pin, busy_wait=args.busy_wait))]
            if args.rt_priority:
                setups.append(("_pinned_fifo", dict(pin=args.pin, rt_priority=args.rt_priority)))
            if args.pin or args.busy_wait:
                setups.append(("_unpinned_normal", {}))
            for rate in (100.0, 400.0):
                for suffix, setup in setups:
                    main_setup = suffix == ""
                    # Several flights, median of each figure: one burst of hypervisor steal should not decide it.
                    ts = [
                        _realtime(tmp, rate, rt_s, suffix.lstrip("_") or "deployed", **setup)
                        for _ in range(rt_runs if main_setup else 1)
                    ]
                    p99s = [t["period_jitter_ms"]["p99"] for t in ts]
                    missed = [t["missed_deadlines"] for t in ts]
                    steal = [round(t.get("steal_ms_per_s", -1), 1) for t in ts]
                    figs[f"realtime_{rate:g}hz_jitter_p99{suffix}"] = figure(
                        statistics.median(p99s),
                        "ms",
                        0.5 if main_setup else None,
                        p50=round(statistics.median(t["period_jitter_ms"]["p50"] for t in ts), 4),
                        max=round(max(t["period_jitter_ms"]["max"] for t in ts), 3),
                        runs_p99=[round(x, 3) for x in p99s],
                        seconds=rt_s,
                        pinned=setup.get("pin", False),
                        busy_wait=setup.get("busy_wait", False),
                        sched_fifo=setup.get("rt_priority", 0),
                        vm_steal_ms_per_s=steal,
                    )
                    figs[f"realtime_{rate:g}hz_missed_deadlines{suffix}"] = figure(
                        statistics.median(missed),
                        "n",
                        0.0 if (rate == 100.0 and main_setup) else None,
                        runs=missed,
                        total=sum(missed),
                    )
        wrap = _fly(tmp, "wrap", lockstep=True, duration=10.0, start_time=4290.0, pin=args.pin)
        figs["wrap_lockstep_steps"] = figure(
            wrap["runs"][0]["steps"],
            "n",
            rtf=round(wrap["rtf"], 1),
            start_s=4290.0,
            wrap_at_s=4294.967296,
            ok=wrap["ok"],
        )
        figs.update(_agreement(tmp, args.pin))
    title = (
        f"MAVLink SITL benchmarks (load {load_before['load1']:.2f} on {load_before['cpus']} CPUs before; "
        f"floor {floor_runs} x {floor_s:g} s; {runs} lockstep runs per rate and set-up, {duration:g} s sim; "
        + ("real time skipped: --lockstep-only)" if args.lockstep_only else f"real time {rt_runs} x {rt_s:g} s)")
    )
    report(title, figs)
    if args.json:
        Path(args.json).write_text(standard_json(figs, indent=1))
    return figs


def _agreement(tmp: Path, pin: bool) -> dict:
    from tools.experiment.scenario import PAPER, PAPER_RUNS, run_inprocess

    s = _fly(tmp, "agreement", lockstep=True, duration=PAPER.duration_s, pin=pin)
    flown = s["runs"][0]["metrics"]
    ref = run_inprocess(PAPER, PAPER_RUNS[1]).metrics
    rel = {k: abs(flown[k] - ref[k]) / abs(ref[k]) * 100.0 for k in ref}
    worst = max(rel[k] for k in ("ise_ref", "ise_crm", "energy", "max_abs_u"))
    return {
        "clsac_vs_inprocess_max_diff": figure(worst, "%", 2.0, **{k: round(v, 3) for k, v in rel.items() if k != "tv"}),
        "clsac_vs_inprocess_tv_diff": figure(rel["tv"], "%", note="PWM quantisation (1 us = 1.05 mrad steps)"),
    }


if __name__ == "__main__":
    main(sys.argv[1:])
