"""``python -m tools.gcs``: a minimal ground station that flies a roll profile.

Listens like a ground station (default 127.0.0.1:14550), waits for the vehicle's HEARTBEAT (system --sysid,
default 1, component 1), then sends SET_ATTITUDE_TARGET setpoints for a roll profile: ``square`` (default
10 deg, 10 s period, +amplitude first), ``step``, ``sine`` or ``--csv FILE`` (rows ``time_s, roll_deg``,
held until the next row, never interpolated; the profile ends at the last row unless --duration is given).
Prints a live line (sim time, setpoint, roll, error) about twice a second.

Profile time 0 is the first sim time seen from the vehicle (ATTITUDE or SYSTEM_TIME), or --start-time.

* real time (default): every 1/--setpoint-rate s, the profile value at the newest sim time, with
  time_boot_ms = 0 ("now").
* --lockstep: the profile is scheduled on sim time: one setpoint every --point-dt s of sim time and one
  exactly at each discontinuity (square-wave switch, step, CSV row), each carrying time_boot_ms = the
  sim time it applies at, kept --lookahead s ahead of the newest sim time seen.  The autopilot does not
  step past the newest scheduled time, so the GCS paces the run and the result does not depend on speed.
  The points go out in linked datagrams (each begins with the last point of the one before) and are sent
  again when the vehicle says it waits for a frame they covered, so no lost datagram changes the run
  (``autopilot.schedule``).
"""

from __future__ import annotations

import math
import selectors
import sys
import time
from dataclasses import dataclass, fields, replace

from autopilot.shared import crash
from autopilot.shared.cli import (
    OneLineArgumentParser,
    add_cpu_argument,
    add_signing_argument,
    add_sysid_argument,
    angle_deg,
    check_output_files,
    clock_s,
    duration_or_0,
    endpoint,
    fmt_endpoint,
    message_rate_hz,
    peer_endpoint,
    signing_key_from_args,
    timeout_s,
)
from autopilot.shared.events import StatusTextAssembler
from autopilot.shared.link import UdpLink, format_counters
from autopilot.shared.mavlink import (
    GCS_ID,
    SETPOINT_TYPEMASK,
    mavlink,
    quaternion_to_roll,
    roll_to_quaternion,
    vehicle_ids,
)
from autopilot.shared.process import (
    apply_cpu,
    exit_code_for,
    install_stop_handlers,
    report_write_failures,
    reserve_for,
    write_failure,
    write_stats_json,
)
from autopilot.shared.signing import SIGNING_LINK_GROUND, Signing
from tools.flight.profiles import Profile

M = mavlink
_SET_ATTITUDE_TARGET = M.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET
SELF_STALL_S = 1.0  # one pass of the loop takes ~20 ms: a pass this long means this process did not run
CLOCK_RESTART_MS = 1000  # the vehicle's sim time this far behind the one held: its clock restarted
CLOCK_AHEAD_MS = 1000  # the bound on a sim time ahead of the clock held (see Gcs._sim)
# Lockstep: the wall time between two passes (reading the telemetry in batches, then scheduling): half the lookahead
# at the sim rate seen, within these bounds (Gcs._lockstep_nap); the shortest while sim time stands still.
LOCKSTEP_NAP_MIN_S = 0.004
LOCKSTEP_NAP_MAX_S = 0.02
# Lockstep schedule (autopilot.schedule): at most this many setpoints per datagram (40 signed SET_ATTITUDE_TARGET,
# 2.6 kB, within the 4 kB a link reads at once), each datagram beginning with the last point of the one before.
SCHEDULE_CHUNK = 40
# A square MIMO plant's schedule: each point's NAMED_VALUE_FLOAT SSA_SP (43 bytes signed) just before it in the
# same datagram, so fewer points a datagram (20 pairs, 2.1 kB signed).
SCHEDULE_CHUNK_MIMO = 20
SIDESLIP_SETPOINT = "SSA_SP"  # NAMED_VALUE_FLOAT name of a square MIMO plant's sideslip command (deg)
# The vehicle's SYSTEM_TIME says it waits for frame t and read its link at time_unix_usec: a point covering t sent
# more than RESEND_GRACE_US before that read was lost (the same host's clock); on another host's clock, after
# RESEND_AFTER_S of our own the schedule is sent again anyway.
RESEND_GRACE_US = 2000
RESEND_AFTER_S = 1.0


@dataclass(frozen=True)
class GcsOptions:
    """How the GCS flies its profile; times in s of sim time unless they say wall, rates in Hz (flags of the same
    names)."""

    listen: tuple[str, int] = ("127.0.0.1", 14550)
    lockstep: bool = False  # schedule the profile on sim time
    duration: float = 0.0  # profile length; 0 = until the vehicle powers off
    start_time: float | None = None  # sim time of the profile's start; None = the first sim time seen
    lookahead: float = 5.0  # lockstep: schedule this far ahead of the newest sim time seen
    point_dt: float = 0.1  # lockstep: one setpoint every point_dt besides the discontinuities
    setpoint_rate: float = 20.0  # real time: setpoints per wall second
    print_rate: float = 2.0  # live lines per wall second
    wait_timeout: float = 60.0  # wall s without the vehicle's HEARTBEAT before giving up; 0 = forever
    vehicle_timeout: float = 5.0  # wall s of vehicle silence before giving up
    quiet: bool = False  # no live line
    signing_key: bytes | None = None  # MAVLink 2 signing (autopilot.shared.signing); None = off
    vehicle: tuple[str, int] | None = None  # the vehicle's (host, port); None = the first that talks with its IDs
    sysid: int = 1  # the vehicle's system id (--sysid): the GCS flies vehicle N:1 and hears only it


def _deg(rad: float, width: int) -> str:
    """``rad`` in degrees, signed, ``width`` wide; ``-`` if it is not a number (not received yet)."""
    return f"{math.degrees(rad):+{width}.2f}" if math.isfinite(rad) else "-".rjust(width)


class Gcs:
    def __init__(self, opts: GcsOptions, profile: Profile, out=None):
        self.opts = opts
        self.profile = profile
        self.vehicle_id = vehicle_ids(opts.sysid)[0]
        self.out = out or sys.stdout
        # Everything the vehicle streams is taken (SERVO_OUTPUT_RAW only counted): a valid message the GCS
        # did not take would be reported among the link's rejections.
        ids = [
            M.MAVLINK_MSG_ID_HEARTBEAT,
            M.MAVLINK_MSG_ID_ATTITUDE,
            M.MAVLINK_MSG_ID_ATTITUDE_TARGET,
            M.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW,
            M.MAVLINK_MSG_ID_STATUSTEXT,
            M.MAVLINK_MSG_ID_SYSTEM_TIME,
            M.MAVLINK_MSG_ID_PARAM_VALUE,  # the answer to the PARAM_REQUEST_LIST sent on connect
        ]
        signing = Signing(opts.signing_key, SIGNING_LINK_GROUND) if opts.signing_key else None
        self.link = UdpLink(
            "vehicle",
            GCS_ID,
            opts.listen,
            opts.vehicle,
            peers=[self.vehicle_id],
            msgids=ids,
            learn_remote=opts.vehicle is None,
            signing=signing,
        )
        self.sel = selectors.DefaultSelector()
        self.sel.register(self.link.sock, selectors.EVENT_READ)
        self.stop_requested = False
        self.vehicle = False
        self.vehicle_status = None
        self.powered_off = False
        self.sim_ms = None  # newest sim time seen (ms)
        self.origin_ms = None if opts.start_time is None else int(round(opts.start_time * 1000))
        self.roll = math.nan
        self.target = math.nan
        self.next_point_rel_ms = 0
        self.points_sent = 0
        self.sent_schedule: list = []  # lockstep: [abs ms, roll, Unix us sent] of each point not passed yet, in order
        self.flown_ms = None  # lockstep: the newest sim time the vehicle is known to have flown
        self.first_sim_ms = None  # the first sim time seen (the frame the vehicle waited at first)
        self.resends = 0  # lockstep: times the schedule was sent again ...
        self.points_resent = 0  # ... and the points in them
        self._nap_from: tuple[float, int] | None = None  # lockstep: (wall, sim ms) at the last pass (_lockstep_nap)
        self.statustexts = []
        self._texts = StatusTextAssembler()
        self.last_vehicle_rx = None
        self._sim_rx = 0.0  # perf_counter when sim_ms was taken
        self.exit_reason = ""
        self.peer_lost = None
        self.clock_restarts = 0
        self.own_stalls = 0
        self.own_stall_max_s = 0.0
        self.parameters: dict[str, float] = {}  # the vehicle's PARAM_VALUEs (name -> value as sent), read on connect

    def _on_msg(self, msg, t_rx):
        mid = msg.get_msgId()
        self.last_vehicle_rx = t_rx
        if mid == M.MAVLINK_MSG_ID_HEARTBEAT:
            if not self.vehicle:
                self.vehicle = True
                print(
                    f"gcs: vehicle {self.vehicle_id[0]}:{self.vehicle_id[1]} at {fmt_endpoint(self.link.remote)} "
                    f"(type {msg.type}, status {msg.system_status})",
                    file=self.out,
                    flush=True,
                )
                self._heartbeat()
                # Read the vehicle's parameters, as MAVProxy and QGroundControl do on connect: the law's own table
                # (autopilot.law) is then in the flight's tlog, each PARAM_VALUE as the vehicle sent it.
                self.link.send(M.MAVLink_param_request_list_message(self.vehicle_id[0], self.vehicle_id[1]))
            self.vehicle_status = msg.system_status
            if msg.system_status == M.MAV_STATE_POWEROFF:
                self.powered_off = True
        elif mid == M.MAVLINK_MSG_ID_ATTITUDE:
            if self._sim(msg.time_boot_ms, t_rx):
                self.roll = msg.roll
                self.flown_ms = max(self.flown_ms or 0, msg.time_boot_ms)  # the stream follows a step flown
        elif mid == M.MAVLINK_MSG_ID_PARAM_VALUE:
            name = msg.param_id.decode("ascii", "replace") if isinstance(msg.param_id, bytes) else msg.param_id
            self.parameters[name.split("\x00", 1)[0]] = float(msg.param_value)
        elif mid == M.MAVLINK_MSG_ID_ATTITUDE_TARGET:
            self.target = quaternion_to_roll(msg.q)
        elif mid == M.MAVLINK_MSG_ID_SYSTEM_TIME:
            if self._sim(msg.time_boot_ms, t_rx) and self.opts.lockstep:
                self._resend_if_lost(msg.time_boot_ms, msg.time_unix_usec)
        elif mid == M.MAVLINK_MSG_ID_STATUSTEXT:
            # whole texts, reassembled from their chunks and made printable (no escape codes reach the terminal)
            text = self._texts.add(msg)
            if text is None:
                return
            self.statustexts.append(text)
            if len(self.statustexts) > 100:  # bounded on long flights: the stats keep the last 50
                del self.statustexts[:50]
            print(f"gcs: vehicle says: {text}", file=self.out, flush=True)

    def _sim(self, ms: int, t_rx: float) -> bool:
        """Take the vehicle's sim time ``ms`` if it fits the clock held; False (rejected, counted) if not.

        Checked against the current clock, with bounds: older by less than a second = out of order (ignored);
        older by more = the clock restarted (a new SITL): the profile origin moves with it, so the profile
        continues where it was instead of freezing; ahead by more than the bound (real time: the wall time since
        plus 0.5 s; lockstep: past the schedule sent plus a second) = rejected, never "newest"."""
        if self.origin_ms is None:
            self.origin_ms = ms
        held = self.sim_ms
        if held is not None:
            if ms < held:
                if held - ms < CLOCK_RESTART_MS:
                    self.link.reject("stale_time")
                    return False
                self.origin_ms += ms - held  # restart: profile time (sim - origin) goes on from where it was
                self.clock_restarts += 1
                print(f"gcs: the vehicle's clock went back {held - ms} ms: restarted, re-synchronised", file=self.out)
            elif self.opts.lockstep:
                if ms > self.origin_ms + self.next_point_rel_ms + CLOCK_AHEAD_MS:
                    self.link.reject("future_time")
                    return False
            elif ms - held > (t_rx - self._sim_rx) * 1e3 + CLOCK_AHEAD_MS / 2:
                self.link.reject("future_time")
                return False
        if held is not None and ms > held:
            self.flown_ms = max(self.flown_ms or 0, held)  # the vehicle moved past it: that frame was flown
        if self.first_sim_ms is None:
            self.first_sim_ms = ms
        self.sim_ms = ms
        self._sim_rx = t_rx
        return True

    def _heartbeat(self):
        self.link.send(
            M.MAVLink_heartbeat_message(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE, 3)
        )

    def _setpoint(self, time_boot_ms: int, roll: float):
        return M.MAVLink_set_attitude_target_message(
            time_boot_ms,
            self.vehicle_id[0],
            self.vehicle_id[1],
            SETPOINT_TYPEMASK,
            roll_to_quaternion(roll),
            0.0,
            0.0,
            0.0,
            0.0,
        )

    def _sideslip(self, time_boot_ms: int, rel_s: float):
        """A square MIMO plant's second setpoint: NAMED_VALUE_FLOAT ``SSA_SP`` (deg), the sideslip command at the
        same ``time_boot_ms`` as the roll's SET_ATTITUDE_TARGET it goes with (docs/spec.md, "Square MIMO CL-SAC")."""
        return M.MAVLink_named_value_float_message(
            time_boot_ms, SIDESLIP_SETPOINT.encode(), math.degrees(self.profile.sideslip(rel_s))
        )

    def _send_setpoint(self, time_boot_ms: int, roll: float):
        if self.profile.has_sideslip:  # before the roll's: the vehicle steps on the roll setpoint
            known = self.sim_ms is not None and self.origin_ms is not None
            rel = (self.sim_ms - self.origin_ms) / 1000.0 if known else 0.0
            self.link.send(self._sideslip(time_boot_ms, rel))
        self.link.send(self._setpoint(time_boot_ms, roll))
        self.points_sent += 1

    def _send_linked(self, points: list) -> None:
        """Lockstep: ``points`` ([abs ms, roll, ...] in order) as linked datagrams of at most SCHEDULE_CHUNK, each
        beginning with the last point of the one before (``autopilot.schedule``)."""
        link, i = self.link, 0
        side = self.profile.has_sideslip  # each point's sideslip setpoint just before it, in the same datagram
        size = SCHEDULE_CHUNK_MIMO if side else SCHEDULE_CHUNK
        while i < len(points):
            chunk = points[i : i + size]
            if side:  # SSA_SP, roll, SSA_SP, roll, ...: a datagram delivers both or neither, and is resent whole
                origin, bufs = self.origin_ms or 0, []
                for p in chunk:  # packed in the order sent: their signatures' timestamps increase along the datagram
                    bufs.append(link.pack(self._sideslip(p[0], (p[0] - origin) / 1000.0)))
                    bufs.append(link.pack(self._setpoint(p[0], p[1])))
                ids = [M.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT, _SET_ATTITUDE_TARGET] * len(chunk)
            else:
                bufs = [link.pack(self._setpoint(p[0], p[1])) for p in chunk]
                ids = [_SET_ATTITUDE_TARGET] * len(chunk)
            link.send_batch(bufs, ids)
            i += max(1, len(chunk) - 1)
            if i == len(points) - 1:
                break  # the last point closed this datagram: nothing new for another

    def _resend_if_lost(self, frame_ms: int, read_us: int) -> None:
        """Lockstep: the vehicle waits for ``frame_ms`` and read its link at ``read_us`` (its SYSTEM_TIME).  If a
        point covering that frame went out before that read (by RESEND_GRACE_US, or RESEND_AFTER_S of our own
        clock), it was lost: the schedule goes again from the point in force at the last frame known flown, which
        the vehicle holds, so the datagrams link (``autopilot.schedule``)."""
        sched = self.sent_schedule
        # a point past the frame's floored ms (the frame itself may lie between two ms at rates like 300 Hz)
        cover = next((p for p in sched if p[0] > frame_ms), None)
        if cover is None:
            return  # not scheduled that far yet: the vehicle waits for us, rightly
        now_us = time.time_ns() // 1000
        if read_us <= cover[2] + RESEND_GRACE_US and now_us - cover[2] < RESEND_AFTER_S * 1e6:
            return
        start = 0
        if self.flown_ms is not None:
            start = max(0, next((i for i, p in enumerate(sched) if p[0] > self.flown_ms), len(sched)) - 1)
        again = sched[start:]
        for p in again:
            p[2] = now_us
        self._send_linked(again)
        self.resends += 1
        self.points_resent += len(again)

    def _schedule(self):
        """Lockstep: send every scheduled point up to newest sim time + lookahead (and not past the end)."""
        o = self.opts
        if self.origin_ms is None or self.sim_ms is None:
            return
        end_rel = (self.sim_ms - self.origin_ms) + int(round(o.lookahead * 1000))
        end_ms = int(round(o.duration * 1000)) if o.duration > 0 else None
        if end_ms is not None:
            end_rel = min(end_rel, end_ms)
        if self.next_point_rel_ms > end_rel:
            return
        step = max(1, int(round(o.point_dt * 1000)))
        start = self.next_point_rel_ms
        grid = set(range(start - start % step + (step if start % step else 0), end_rel + 1, step))
        # The profile's last instant too: the vehicle flies no frame past its schedule, so a profile that ended
        # between two grid points (--duration 0.05, 30.05) left its last frames waiting for a point never sent.
        ends = [end_ms] if end_rel == end_ms else []
        pts = sorted(grid.union(self.profile.breakpoints_ms(start, end_rel), [start] if start == 0 else [], ends))
        now_us = time.time_ns() // 1000
        # time_boot_ms 0 means "now" to the autopilot; a schedule starting at sim time 0 uses that.
        new = [[self.origin_ms + rel, self.profile.value(rel / 1000.0), now_us] for rel in pts if rel >= start]
        sched = self.sent_schedule
        lead = []
        if new and not self.points_sent and self.first_sim_ms is not None and self.first_sim_ms < new[0][0]:
            # a profile that starts after the frame the vehicle waits at (--start-time): the schedule begins at that
            # frame with the command it flies until then (0, no setpoint yet), so the first datagram links to it
            lead = [[self.first_sim_ms, 0.0, now_us]]
        if self.flown_ms is not None:  # what the vehicle flew past is not sent again: keep the point in force
            keep = next((i for i, p in enumerate(sched) if p[0] > self.flown_ms), len(sched)) - 1
            del sched[: max(0, keep)]
        if new:
            self._send_linked(sched[-1:] + lead + new)
            sched.extend(lead + new)
            self.points_sent += len(new)
        self.next_point_rel_ms = end_rel + 1

    def _lockstep_nap(self, now: float) -> float:
        """Lockstep: how long to sleep before the next pass (wall s): half the lookahead at the sim rate seen since
        the last pass, within LOCKSTEP_NAP_MIN_S..LOCKSTEP_NAP_MAX_S; the shortest while sim time stands still
        (the vehicle may be waiting for this schedule).  Each wake-up takes a core from one of the two lockstep
        processes on a small machine, so the fewer the better, as long as the schedule stays ahead."""
        prev, sim = self._nap_from, self.sim_ms
        self._nap_from = None if sim is None else (now, sim)
        if prev is None or sim is None or sim <= prev[1] or now <= prev[0]:
            return LOCKSTEP_NAP_MIN_S
        sim_per_wall = (sim - prev[1]) * 1e-3 / (now - prev[0])
        return min(LOCKSTEP_NAP_MAX_S, max(LOCKSTEP_NAP_MIN_S, 0.5 * self.opts.lookahead / sim_per_wall))

    def run(self) -> int:
        try:
            return self._run()
        finally:
            self.link.send_clock.end(time.monotonic())

    def _run(self) -> int:
        o = self.opts
        perf = time.perf_counter
        t_start = perf()
        next_hb = t_start
        next_print = t_start
        next_sp = t_start
        sp_period = 1.0 / o.setpoint_rate
        print(
            f"gcs: listening on {fmt_endpoint(self.link.local)}; waiting for the vehicle's HEARTBEAT; profile "
            f"{self.profile.kind} ({'scheduled on sim time' if o.lockstep else 'real time'})",
            file=self.out,
            flush=True,
        )
        prev = perf()
        while not self.stop_requested:
            for _ in self.sel.select(0.02):
                self.link.poll(self._on_msg)
            now = perf()
            if now - prev >= SELF_STALL_S:
                # This process did not run (stopped, starved): what the vehicle sent meanwhile may still wait in
                # the socket, so its silence is not judged before another look (never "vehicle lost" for our stall).
                self._own_stall(now - prev)
                prev = now
                continue
            prev = now
            if not self.vehicle:
                if o.wait_timeout and now - t_start > o.wait_timeout:
                    self._end(f"no vehicle HEARTBEAT on {fmt_endpoint(self.link.local)} after {o.wait_timeout:g} s")
                    print(f"gcs: error: {self.exit_reason}", file=sys.stderr, flush=True)
                    return 1
                continue
            if self.powered_off:
                self.exit_reason = "end of run (vehicle powered off)"
                print("gcs: vehicle powered off (run over)", file=self.out, flush=True)
                return 0
            if now - self.last_vehicle_rx > o.vehicle_timeout:
                self._end(f"vehicle lost (nothing for {o.vehicle_timeout:g} s)")
                print(f"gcs: error: {self.exit_reason}", file=sys.stderr, flush=True)
                return 1
            if now >= next_hb:
                next_hb = now + 1.0
                self._heartbeat()
            if o.lockstep:
                self._schedule()
                # Lockstep runs many frames per millisecond: read the telemetry in batches rather than waking
                # for every datagram (the schedule is --lookahead of sim time ahead: the nap never stalls the run).
                time.sleep(self._lockstep_nap(now))
            elif now >= next_sp and self.sim_ms is not None:
                next_sp = max(next_sp + sp_period, now)
                self._send_setpoint(0, self.profile.value((self.sim_ms - self.origin_ms) / 1000.0))
            if not o.quiet and now >= next_print and self.sim_ms is not None:
                next_print = now + 1.0 / o.print_rate
                print(self.live_line(), file=self.out, flush=True)
            if (
                o.duration > 0
                and self.sim_ms is not None
                and self.origin_ms is not None
                and self.sim_ms - self.origin_ms >= o.duration * 1000
                and not o.lockstep
            ):
                self.exit_reason = "end of run (profile done)"
                print("gcs: profile done", file=self.out, flush=True)
                return 0
        self.exit_reason = "stopped by signal"
        return 0

    def _own_stall(self, gap: float) -> None:
        self.own_stalls += 1
        self.own_stall_max_s = max(self.own_stall_max_s, gap)
        print(
            f"gcs: this script did not run for {gap:.1f} s (stopped or starved); reading on", file=self.out, flush=True
        )

    def live_line(self) -> str:
        """The live line: sim time, the vehicle's setpoint and roll and their difference, in deg; a value not
        received yet (the first line can come from SYSTEM_TIME alone) reads ``-``, never ``nan``."""
        return (
            f"gcs: t={self.sim_ms / 1000.0:9.3f} s  setpoint={_deg(self.target, 7)} deg  roll={_deg(self.roll, 7)} deg"
            f"  error={_deg(self.target - self.roll, 6)} deg"
        )

    def _end(self, reason: str) -> None:
        """The vehicle went silent or never came: the launcher's verdict blames it (``peer_lost``)."""
        self.exit_reason = reason
        self.peer_lost = "autopilot"

    def stats(self) -> dict:
        return {
            "points_sent": self.points_sent,
            "schedule_resends": self.resends,  # lockstep: the schedule sent again after a loss (autopilot.schedule)
            "points_resent": self.points_resent,
            "origin_ms": self.origin_ms,
            "sim_ms": self.sim_ms,
            "clock_restarts": self.clock_restarts,
            "exit_reason": self.exit_reason,
            "peer_lost": self.peer_lost,
            "own_stalls": self.own_stalls,  # its own loop did not run for SELF_STALL_S or more (stopped, starved)
            "own_stall_max_s": self.own_stall_max_s,
            "sent": self.link.send_clock.summary(),  # monotonic clock of its sends (the verdict's evidence)
            "statustexts": self.statustexts[-50:],
            "parameters": len(self.parameters),  # PARAM_VALUEs read on connect
            "link": self.link.counters(),
        }


def profile_duration(duration: float | None, profile: Profile) -> float:
    """``--duration``, or when not given: a CSV profile's last breakpoint (it lasts to its end), else 0 (until the
    vehicle powers off)."""
    if duration is not None:
        return duration
    return profile.end or 0.0


def build_parser() -> OneLineArgumentParser:
    p = OneLineArgumentParser(prog="python -m tools.gcs", description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--listen",
        type=endpoint,
        default=("127.0.0.1", 14550),
        metavar="HOST:PORT",
        help="UDP address to listen on, like a ground station (default 127.0.0.1:14550)",
    )
    p.add_argument(
        "--vehicle",
        type=peer_endpoint,
        default=None,
        metavar="HOST:PORT",
        help="the vehicle's address: only it is heard (default: the first that talks with the vehicle's IDs)",
    )
    p.add_argument(
        "profile", nargs="?", choices=("square", "step", "sine"), default="square", help="roll profile (default square)"
    )
    p.add_argument(
        "--csv",
        default=None,
        metavar="FILE",
        help="fly a CSV profile: rows 'time_s, roll_deg', each held until the next (not interpolated), to the last",
    )
    p.add_argument("--amplitude", type=angle_deg, default=10.0, metavar="DEG", help="amplitude (default 10)")
    p.add_argument(
        "--sideslip",
        type=angle_deg,
        default=None,
        metavar="DEG",
        help="a square MIMO plant's second setpoint: a constant sideslip command, sent as NAMED_VALUE_FLOAT SSA_SP "
        "with every roll setpoint (default: none sent, the vehicle flies 0; a --csv file's third column sideslip_deg "
        "is a profile of it)",
    )
    p.add_argument("--period", type=timeout_s, default=10.0, metavar="S", help="square/sine period (default 10)")
    p.add_argument("--step-time", type=clock_s, default=1.0, metavar="S", help="step: switch time (default 1)")
    p.add_argument(
        "--duration",
        type=duration_or_0,
        default=None,
        metavar="S",
        help="profile length in sim seconds (0 = until the vehicle powers off; default 0, with --csv the file's "
        "last breakpoint)",
    )
    p.add_argument("--lockstep", action="store_true", help="schedule the profile on sim time (deterministic runs)")
    p.add_argument(
        "--start-time",
        type=clock_s,
        default=None,
        metavar="S",
        help="sim time of profile start (default: the first sim time seen)",
    )
    p.add_argument(
        "--lookahead",
        type=timeout_s,
        default=GcsOptions.lookahead,
        metavar="S",
        help="lockstep: schedule this far ahead of the newest sim time seen (default 5; the autopilot refuses "
        "setpoints more than 10 s ahead)",
    )
    p.add_argument(
        "--point-dt",
        type=timeout_s,
        default=0.1,
        metavar="S",
        help="lockstep: one scheduled setpoint every S s of sim time besides the discontinuities (default 0.1)",
    )
    p.add_argument(
        "--setpoint-rate",
        type=message_rate_hz,
        default=20.0,
        metavar="HZ",
        help="real time: setpoints per second (default 20)",
    )
    p.add_argument("--print-rate", type=message_rate_hz, default=2.0, metavar="HZ", help="live line rate (default 2)")
    p.add_argument(
        "--wait-timeout",
        type=clock_s,
        default=60.0,
        metavar="S",
        help="give up if no vehicle HEARTBEAT within S s (default 60, 0 = wait forever)",
    )
    p.add_argument(
        "--vehicle-timeout",
        type=timeout_s,
        default=5.0,
        metavar="S",
        help="error if the vehicle goes silent for S s (default 5)",
    )
    p.add_argument("--stats-json", default=None, metavar="PATH", help="write counters to this JSON file at exit")
    p.add_argument("--quiet", action="store_true", help="no live line")
    add_signing_argument(p)
    add_sysid_argument(p, "the system id of the vehicle to fly (its --sysid): only N:1 is heard and commanded")
    add_cpu_argument(p)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    check_output_files(parser, args, "stats_json")
    if args.csv and args.profile != "square":
        parser.error("give either a profile name or --csv, not both")
    try:
        profile = Profile.of(
            args.profile, amplitude_deg=args.amplitude, period=args.period, step_time=args.step_time, csv=args.csv
        )
    except (OSError, ValueError) as exc:
        parser.error(f"--csv: {exc}")
    if args.sideslip is not None:
        if profile.sideslips:
            parser.error("--sideslip and a --csv file with a sideslip column: give one")
        try:
            profile = replace(profile, sideslip_const=math.radians(args.sideslip))
        except ValueError as exc:
            parser.error(f"--sideslip: {exc}")
    args.duration = profile_duration(args.duration, profile)
    apply_cpu(parser, args.cpu)
    try:
        values = {f.name: getattr(args, f.name) for f in fields(GcsOptions)}
        gcs = Gcs(GcsOptions(**{**values, "signing_key": signing_key_from_args(parser, args)}), profile)
    except OSError as exc:
        print(f"gcs: error: cannot listen on {fmt_endpoint(args.listen)}: {exc.strerror or exc}", file=sys.stderr)
        return exit_code_for(exc)

    def stop():
        gcs.stop_requested = True

    install_stop_handlers(stop)
    reserve = reserve_for(args.stats_json) if args.stats_json else None  # the stats fit on a full disk
    code = 1
    try:
        code = gcs.run()
    except Exception as exc:  # noqa: BLE001
        crash.report("gcs", exc)  # one line; the traceback in gcs.log (autopilot.shared.crash)
        code = 1
    finally:
        stats = gcs.stats()
        gcs.link.close()
    print(f"gcs: {stats['points_sent']} setpoints sent", flush=True)
    print(format_counters("gcs link", stats["link"]), flush=True)
    if args.stats_json:
        failure = write_failure(args.stats_json, lambda: write_stats_json(args.stats_json, stats, reserve))
        reserve.release()
        return report_write_failures("gcs", [failure] if failure else [], code)
    return code


if __name__ == "__main__":
    crash.install("gcs")
    sys.exit(main())
