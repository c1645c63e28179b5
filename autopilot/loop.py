"""The autopilot process's loop: CL-SAC between a SITL link and a GCS link (DESIGN.md sections 5-6).

Transport lives in ``autopilot.shared.link``, the control law in ``autopilot.clsac``; this module schedules
them.  Two modes:

* real time (:meth:`Autopilot.run_realtime`): one control step per period on a fixed grid of
  deadlines (sleep in ``select`` until shortly before the deadline, then spin; never ``sleep(period)``),
  using the newest ATTITUDE.  Failsafes: no attitude for ``attitude_timeout_s`` (wall clock) ->
  rudder neutral, adaptation frozen (``ClSac.hold``), HEARTBEAT CRITICAL, STATUSTEXT; recovers by
  itself.  No setpoint for ``setpoint_timeout_s`` -> wings level (0 deg), STATUSTEXT.
* lockstep (:meth:`Autopilot.run_lockstep`): one step per SITL frame.  Frame k is recovered from
  ATTITUDE.time_boot_ms and the control rate; the answer is SERVO_OUTPUT_RAW with time_usec =
  t_k in us mod 2**32.  A duplicate frame is answered by resending the stored bytes (no second step),
  an older frame is counted and ignored.  With pacing on (default), frame k waits until a GCS has
  scheduled setpoints up to t_k (the schedule horizon), so results do not depend on speed.

Per-step hook point for telemetry (Rerun etc.): ``Autopilot.hooks`` is a list of callables called
with one :class:`StepRecord` after the servo command has been sent (outside the critical path), and
``Autopilot.event_hooks`` with ``(severity, text)`` for every status event (failsafe, clamp, ...).
"""

from __future__ import annotations

import gc
import math
import select
import sys
import time
from array import array
from bisect import insort
from collections import Counter
from dataclasses import dataclass, field

from autopilot.clsac import ClSac
from autopilot.config import ClSacConfig, NonFiniteInputError
from autopilot.shared.link import UdpLink
from autopilot.metrics import MetricsAccumulator
from autopilot.shared.mavlink import AUTOPILOT_ID, frame_from_ms, frame_ms, frame_usec, GCS_ID, mavlink, quaternion_to_roll, roll_to_quaternion, SETPOINT_TYPEMASK, SITL_ID, TYPEMASK_IGNORE_ATTITUDE
from autopilot.shared.pwm import PwmMap

M = mavlink
ATTITUDE = M.MAVLINK_MSG_ID_ATTITUDE
HEARTBEAT = M.MAVLINK_MSG_ID_HEARTBEAT
STATUSTEXT = M.MAVLINK_MSG_ID_STATUSTEXT
SET_ATTITUDE_TARGET = M.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET
SERVO_OUTPUT_RAW = M.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW

_TELEMETRY_IDS = (ATTITUDE, M.MAVLINK_MSG_ID_ATTITUDE_TARGET, SERVO_OUTPUT_RAW)
# Real time: the last stretch before a deadline is a pure spin (no syscalls), so an input handled while
# spinning cannot make the step late.
_SPIN_TIGHT_S = 50e-6
TIMING_SAMPLES_MAX = 2_000_000  # per-step timing samples kept for percentiles (about 1.4 h at 400 Hz)


@dataclass
class AutopilotOptions:
    rate_hz: float = 100.0
    lockstep: bool = False
    duration_s: float = 0.0  # 0 = until stopped; lockstep: sim seconds from the first frame; real time: seconds of control
    telemetry_rate_hz: float = 50.0
    attitude_timeout_s: float = 0.1
    setpoint_timeout_s: float = 1.0
    max_roll_rad: float = math.radians(45.0)
    pace: bool = True  # lockstep: wait for the GCS schedule horizon
    spin_s: float = 0.0003  # real time: busy-wait (serving the links) this long before each deadline; inf = never sleep
    sitl: tuple = ("127.0.0.1", 14560)
    sitl_bind: tuple = ("127.0.0.1", 0)
    gcs: tuple = ("127.0.0.1", 14550)
    gcs_bind: tuple = ("127.0.0.1", 0)
    gcs_ids: tuple = (GCS_ID,)
    lockstep_spin_s: float = 0.0  # lockstep: busy-poll this long for the next frame before sleeping in select
    lockstep_idle_exit_s: float = 0.0  # lockstep: exit after the last frame if the SITL stays silent this long (0 = never)
    name: str = "clsac"
    verbose: bool = True


class StepRecord:
    """What one control step did; handed to every ``Autopilot.hooks`` callable after the servo went out.

    Times: ``wall`` is time.perf_counter() at the start of the step; ``t_sim`` the sim time (s) of the
    attitude used; ``period`` the time since the previous step's start (s), ``lateness`` start minus
    scheduled deadline (real time; 0 in lockstep), ``compute`` start to servo sent, ``latency``
    attitude (or unblocking setpoint) received to servo sent: in real time that is the attitude's age,
    including the wait for the deadline (up to a sensor period), not the processing alone.  ``ctrl`` is
    the ClSac instance (``ctrl.telemetry()`` gives the internals), ``ap`` the Autopilot (links, counters,
    timing).
    """

    __slots__ = ("step", "frame", "t_sim", "wall", "um", "phi", "p", "r", "u", "pwm", "failsafe", "period",
                 "lateness", "compute", "latency", "missed", "ctrl", "ap")

    def __init__(self, step, frame, t_sim, wall, um, phi, p, r, u, pwm, failsafe, period, lateness, compute,
                 latency, missed, ctrl, ap):
        self.step, self.frame, self.t_sim, self.wall = step, frame, t_sim, wall
        self.um, self.phi, self.p, self.r, self.u, self.pwm = um, phi, p, r, u, pwm
        self.failsafe, self.period, self.lateness, self.compute = failsafe, period, lateness, compute
        self.latency, self.missed, self.ctrl, self.ap = latency, missed, ctrl, ap


@dataclass
class _Attitude:
    ms: int = -1
    roll: float = 0.0
    p: float = 0.0
    r: float = 0.0
    t_rx: float = -1.0  # perf_counter when received
    valid: bool = False


@dataclass
class TimingStats:
    """Per-step timing samples (seconds) and summary percentiles."""

    period: array = field(default_factory=lambda: array("d"))
    lateness: array = field(default_factory=lambda: array("d"))
    compute: array = field(default_factory=lambda: array("d"))
    latency: array = field(default_factory=lambda: array("d"))
    missed: int = 0

    def add(self, period, lateness, compute, latency):
        if len(self.compute) < TIMING_SAMPLES_MAX:
            if period is not None:
                self.period.append(period)
            if lateness is not None:
                self.lateness.append(lateness)
            self.compute.append(compute)
            if latency is not None:
                self.latency.append(latency)

    def summary(self, nominal_period: float) -> dict:
        def pct(values, scale=1e3):
            if not values:
                return None
            s = sorted(values)
            n = len(s)

            def q(p):
                return s[min(n - 1, int(math.ceil(p / 100.0 * n)) - 1 if p > 0 else 0)] * scale

            return {"p50": q(50), "p99": q(99), "max": s[-1] * scale, "n": n}

        jitter = [abs(p - nominal_period) for p in self.period]
        return {
            "period_ms": nominal_period * 1e3,
            "period_jitter_ms": pct(jitter),
            "lateness_ms": pct(self.lateness),
            "compute_ms": pct(self.compute),
            "latency_ms": pct(self.latency),
            "missed_deadlines": self.missed,
        }


class Autopilot:
    def __init__(self, opts: AutopilotOptions, ctrl_config: ClSacConfig, pwm: PwmMap, tlog=None, out=None):
        self.opts = opts
        self.pwm = pwm
        self.tlog = tlog
        self.out = out or sys.stdout
        self.rate = float(opts.rate_hz)
        self.period = 1.0 / self.rate
        self.ctrl = ClSac(ctrl_config)
        self.metrics = MetricsAccumulator(self.period)  # from what flew: phi received, command sent (after PWM)
        self.metrics_commanded = MetricsAccumulator(self.period)  # same, with the controller's u before PWM quantisation
        self.sitl = UdpLink("sitl", AUTOPILOT_ID, opts.sitl_bind, opts.sitl, peers=[SITL_ID],
                            msgids=[ATTITUDE, HEARTBEAT, STATUSTEXT], tlog=tlog)
        self.gcs = UdpLink("gcs", AUTOPILOT_ID, opts.gcs_bind, opts.gcs, peers=opts.gcs_ids,
                           msgids=[SET_ATTITUDE_TARGET, HEARTBEAT], learn_remote=True, tlog=tlog)
        self.hooks: list = []  # callables(StepRecord), after each step
        self.event_hooks: list = []  # callables(severity, text), for each status event
        self.events = Counter()  # autopilot-level counters (failsafes, setpoints, frames)
        self.timing = TimingStats()
        self.stop_requested = False
        self.exit_reason = ""
        # attitude
        self.att = _Attitude()
        # setpoints: sorted queue of (t_apply_us, seq, roll); current command
        self._sp_queue: list = []
        self._sp_seq = 0
        self.um = 0.0
        self.horizon_us = -1.0  # newest scheduled setpoint time received
        self.last_setpoint_wall = None
        self.setpoint_lost = False
        self._last_clamp_report = -1e9
        # state
        self.steps = 0
        self.failsafe = None  # None or a reason string
        self.failsafe_steps = 0
        self.failsafe_entries: list = []  # attitude age (s) when each failsafe began
        self.recoveries = 0
        self._telemetry_every = max(1, int(round(self.rate / opts.telemetry_rate_hz))) if opts.telemetry_rate_hz > 0 else 0
        self._next_heartbeat = 0.0
        self._next_flush = 0.0
        self._status_state = M.MAV_STATE_STANDBY
        # lockstep
        self.first_frame = None
        self.last_frame = None  # last frame answered
        self._last_answer = b""
        self.pending_frame = None
        self.pending_t_rx = 0.0
        self._next_systime = 0.0
        self._blocked_since = None
        self.finished = False
        self.t_first_step = None
        self.t_last_step = None
        # select(2) has microsecond timeouts (epoll rounds up to whole milliseconds: 1 ms of jitter)
        self._fds = [self.sitl.sock, self.gcs.sock]
        self._sitl_handler = self._on_sitl
        self._gcs_handler = self._on_gcs
        # fast, byte-identical encoders for the per-step messages (autopilot.shared.fastmav)
        self._pk_servo_sitl = self.sitl.fast_packer(M.MAVLink_servo_output_raw_message)
        self._pk_servo_gcs = self.gcs.fast_packer(M.MAVLink_servo_output_raw_message)
        self._pk_att = self.gcs.fast_packer(M.MAVLink_attitude_message)
        self._pk_att_target = self.gcs.fast_packer(M.MAVLink_attitude_target_message)

    # ================================================================== inputs
    def _on_sitl(self, msg, t_rx):
        mid = msg.get_msgId()
        if mid == ATTITUDE:
            roll, p, r = msg.roll, msg.rollspeed, msg.yawspeed
            # NaN/Inf anywhere in the message is a broken sensor frame: reject (x - x != 0 for NaN and Inf)
            if (roll - roll) or (p - p) or (r - r) or (msg.pitch - msg.pitch) or (msg.yaw - msg.yaw) \
                    or (msg.pitchspeed - msg.pitchspeed):
                self.sitl.rejected["nonfinite_attitude"] += 1
                return
            if not -3.1416 <= roll <= 3.1416:
                self.sitl.rejected["roll_out_of_range"] += 1
                return
            att = self.att
            if (not self.opts.lockstep and att.valid and msg.time_boot_ms <= att.ms
                    and t_rx - att.t_rx < self.opts.attitude_timeout_s):
                # Out of order or repeated while fresh data flows: keep the newest.  (After a loss anything
                # goes, so a restarted SITL whose clock went back is taken at once.)
                self.sitl.rejected["stale_attitude"] += 1
                return
            att.ms, att.roll, att.p, att.r, att.t_rx, att.valid = msg.time_boot_ms, roll, p, r, t_rx, True
            if self.opts.lockstep:
                self._on_frame(msg.time_boot_ms, t_rx)
        elif mid == STATUSTEXT:
            text = msg.text if isinstance(msg.text, str) else msg.text.decode("utf-8", "replace")
            self._event(msg.severity, f"SITL: {text}", forward=True)

    def _on_gcs(self, msg, t_rx):
        if msg.get_msgId() != SET_ATTITUDE_TARGET:
            return
        ev = self.events
        if msg.target_system not in (0, AUTOPILOT_ID[0]) or msg.target_component not in (0, AUTOPILOT_ID[1]):
            self.gcs.rejected["wrong_target"] += 1
            return
        if msg.type_mask & TYPEMASK_IGNORE_ATTITUDE:
            self.gcs.rejected["no_attitude_in_setpoint"] += 1
            return
        roll = quaternion_to_roll(msg.q)
        if roll - roll != 0.0 or not all(math.isfinite(v) for v in msg.q):
            self.gcs.rejected["nonfinite_setpoint"] += 1
            return
        lim = self.opts.max_roll_rad
        if roll > lim or roll < -lim:
            clamped = math.copysign(lim, roll)
            ev["setpoints_clamped"] += 1
            if t_rx - self._last_clamp_report > 1.0:
                self._last_clamp_report = t_rx
                self._event(M.MAV_SEVERITY_WARNING,
                            f"setpoint {math.degrees(roll):.1f} deg clamped to {math.degrees(clamped):.0f}")
            roll = clamped
        ev["setpoints"] += 1
        self.last_setpoint_wall = t_rx
        ms = msg.time_boot_ms
        if ms == 0:
            t_us = self._now_sim_us()  # 0 means now
            ev["setpoints_now"] += 1
        else:
            t_us = ms * 1000.0
            if t_us > self.horizon_us:
                self.horizon_us = t_us
        q = self._sp_queue
        if len(q) >= 100_000:
            self.gcs.rejected["setpoint_queue_full"] += 1
            return
        self._sp_seq += 1
        item = (t_us, self._sp_seq, roll)
        if not q or item >= q[-1]:
            q.append(item)
        else:
            insort(q, item)
        if self.opts.lockstep and self.pending_frame is not None:
            self._try_step(t_rx)

    def _now_sim_us(self) -> float:
        if self.opts.lockstep and self.pending_frame is not None:
            return self.pending_frame * 1e6 / self.rate
        if self.last_frame is not None and self.opts.lockstep:
            return self.last_frame * 1e6 / self.rate
        return self.att.ms * 1000.0 if self.att.valid else 0.0

    def _setpoint_at(self, t_us: float) -> float:
        """Pop every scheduled setpoint due at sim time t_us; the last one due becomes the command."""
        q = self._sp_queue
        if q and q[0][0] <= t_us + 1e-3:
            i = 0
            n = len(q)
            while i < n and q[i][0] <= t_us + 1e-3:
                i += 1
            self.um = q[i - 1][2]
            del q[:i]
        return self.um

    # ================================================================ outputs
    def _servo_wire(self, time_usec: int, pwm: int) -> tuple:
        """SERVO_OUTPUT_RAW fields in wire order: time_usec, servo1..8, port, servo9..16."""
        s = self.pwm.servo_fields(pwm)
        return (time_usec, *s[:8], 0, *s[8:])

    def _send_heartbeat(self, status=None):
        status = self._status_state if status is None else status
        base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | M.MAV_MODE_FLAG_STABILIZE_ENABLED | M.MAV_MODE_FLAG_SAFETY_ARMED
        for link in (self.gcs, self.sitl):
            link.send(M.MAVLink_heartbeat_message(M.MAV_TYPE_FIXED_WING, M.MAV_AUTOPILOT_GENERIC, base, 0, status, 3))

    def _event(self, severity: int, text: str, forward: bool = True):
        """A status event: printed, sent to the GCS as STATUSTEXT (50 chars), handed to event_hooks."""
        self.events["statustext"] += 1
        if self.opts.verbose:
            print(f"autopilot: {text}", file=self.out, flush=True)
        if forward:
            self.gcs.send(M.MAVLink_statustext_message(severity, text.encode("utf-8")[:50], 0, 0))
        for h in self.event_hooks:
            h(severity, text)

    def _send_telemetry(self, t_ms: int, phi: float, p: float, r: float, servo_wire: tuple):
        """ATTITUDE, ATTITUDE_TARGET and SERVO_OUTPUT_RAW to the GCS, in one datagram."""
        g = self.gcs
        if g.remote is None:
            return
        q = roll_to_quaternion(self.um)
        bufs = [
            g.pack_fast(self._pk_att, t_ms, phi, 0.0, 0.0, p, 0.0, r),
            g.pack_fast(self._pk_att_target, t_ms, q[0], q[1], q[2], q[3], 0.0, 0.0, 0.0, 0.0, SETPOINT_TYPEMASK),
            g.pack_fast(self._pk_servo_gcs, *servo_wire),
        ]
        g.send_batch(bufs, _TELEMETRY_IDS)

    # ============================================================ housekeeping
    def _housekeeping(self, now: float):
        if now >= self._next_heartbeat:
            # 1 Hz; every 0.25 s while a peer has not answered yet, so a late-starting SITL or GCS finds us soon.
            self._next_heartbeat = now + (1.0 if (self.sitl.rx_packets and self.gcs.rx_packets) else 0.25)
            self._send_heartbeat()
            if not self.opts.lockstep and self.att.valid:
                self.gcs.send(M.MAVLink_system_time_message(time.time_ns() // 1000, self.att.ms))
        if self.tlog is not None and now >= self._next_flush:
            self._next_flush = now + 0.5
            self.tlog.flush()

    def _wait(self, timeout: float):
        """Block up to ``timeout`` s for input, then drain every ready link."""
        ready, _, _ = select.select(self._fds, (), (), timeout)
        for sock in ready:
            if sock is self.sitl.sock:
                self.sitl.poll(self._sitl_handler)
            else:
                self.gcs.poll(self._gcs_handler)

    def _drain(self):
        self.sitl.poll(self._sitl_handler)
        self.gcs.poll(self._gcs_handler)

    # =============================================================== lockstep
    def _on_frame(self, ms: int, t_rx: float):
        k = frame_from_ms(ms, self.rate)
        last = self.last_frame
        if last is not None:
            if k == last:
                # Duplicate of the frame we answered (our answer was lost or late): resend it, do not step.
                self.events["duplicate_frames"] += 1
                self.sitl.send_raw(self._last_answer, SERVO_OUTPUT_RAW)
                return
            if k < last:
                self.events["stale_frames"] += 1
                return
        if self.pending_frame is not None:
            if k == self.pending_frame:
                self.events["duplicate_pending_frames"] += 1
                return
            if k < self.pending_frame:
                self.events["stale_frames"] += 1
                return
            self.events["superseded_frames"] += 1  # a newer frame replaces one never answered
        if self.first_frame is None:
            self.first_frame = k
        self.pending_frame = k
        self.pending_t_rx = t_rx
        self._try_step(t_rx)

    def _try_step(self, t_ready: float):
        k = self.pending_frame
        t_us = k * 1e6 / self.rate
        opts = self.opts
        if opts.duration_s > 0 and k - self.first_frame >= round(opts.duration_s * self.rate):
            # The SITL's end-of-run frame (t = t0 + duration): not a control step.
            self.pending_frame = None
            self.finished = True
            return
        if opts.pace and self.horizon_us + 1e-3 < t_us:
            if self._blocked_since is None:
                self._blocked_since = t_ready
                self.events["horizon_waits"] += 1
            return
        self._blocked_since = None
        self.pending_frame = None
        t0 = time.perf_counter()
        att = self.att
        phi = att.roll
        um = self._setpoint_at(t_us)
        try:
            u = self.ctrl(phi, um)
        except NonFiniteInputError:
            self.events["controller_errors"] += 1
            self.ctrl.hold(0.0)
            u = 0.0
        pwm = self.pwm.to_pwm(u)
        wire = self._servo_wire(frame_usec(k, self.rate), pwm)
        raw = self.sitl.pack_fast(self._pk_servo_sitl, *wire)
        self.sitl.send_raw(raw, SERVO_OUTPUT_RAW)
        t_sent = time.perf_counter()
        self._last_answer = raw
        self.last_frame = k
        u_sent = self.pwm.to_rad(pwm)
        ctrl = self.ctrl
        self.metrics.add(phi, ctrl.ym_ol, ctrl.e, u_sent)
        self.metrics_commanded.add(phi, ctrl.ym_ol, ctrl.e, u)
        prev = self.t_last_step
        self.t_last_step = t0
        if self.t_first_step is None:
            self.t_first_step = t0
        latency = t_sent - max(t_ready, self.pending_t_rx)
        self.timing.add(None, None, t_sent - t0, latency)
        self.steps += 1
        if self._telemetry_every and self.steps % self._telemetry_every == 1 % self._telemetry_every:
            self._send_telemetry(att.ms, phi, att.p, att.r, wire)
        if self.hooks:
            rec = StepRecord(self.steps, k, t_us * 1e-6, t0, um, phi, att.p, att.r, u_sent, pwm, None,
                             None if prev is None else t0 - prev, 0.0, t_sent - t0, latency, False, ctrl, self)
            for h in self.hooks:
                h(rec)

    def run_lockstep(self) -> int:
        opts = self.opts
        self._status_state = M.MAV_STATE_STANDBY
        self._send_heartbeat()
        now = time.perf_counter()
        self._next_heartbeat = now + 1.0
        last_warn = now
        silent_reported = False
        lockstep_spin = opts.lockstep_spin_s
        while not self.stop_requested and not self.finished:
            if lockstep_spin > 0:
                # Busy-poll briefly before sleeping: the SITL's next frame usually comes within tens of us,
                # and a sleep/wake-up costs more than that on a virtual machine.
                n0 = self.sitl.rx_datagrams + self.gcs.rx_datagrams
                t_end = time.perf_counter() + lockstep_spin
                while time.perf_counter() < t_end:
                    self._drain()
                    if self.sitl.rx_datagrams + self.gcs.rx_datagrams != n0:
                        break
                else:
                    self._wait(0.02)
            else:
                self._wait(0.02)
            now = time.perf_counter()
            if self.pending_frame is not None and self._blocked_since is not None:
                # Waiting for the GCS schedule: tell it where sim time is (SYSTEM_TIME, 20 Hz wall clock).
                if now >= self._next_systime:
                    self._next_systime = now + 0.05
                    self.gcs.send(M.MAVLink_system_time_message(time.time_ns() // 1000,
                                                                frame_ms(self.pending_frame, self.rate)))
                if now - self._blocked_since > 5.0 and now - last_warn > 5.0:
                    last_warn = now
                    print(f"autopilot: lockstep frame t={self.pending_frame / self.rate:.3f} s waits for GCS "
                          f"setpoints (schedule horizon {self.horizon_us * 1e-6:.3f} s); run a GCS "
                          f"(python -m tools.gcs --lockstep) or pass --no-pace", file=self.out, flush=True)
            if self.att.valid:
                self._status_state = M.MAV_STATE_ACTIVE
                silent = now - self.sitl.last_rx_wall
                if silent > 2.0 and not silent_reported and self.pending_frame is None:
                    silent_reported = True
                    self._event(M.MAV_SEVERITY_WARNING, f"lockstep: SITL silent for {silent:.1f} s")
                elif silent < 2.0:
                    silent_reported = False
                if (opts.lockstep_idle_exit_s > 0 and self.last_frame is not None and self.pending_frame is None
                        and silent > opts.lockstep_idle_exit_s):
                    self.exit_reason = f"SITL silent for {silent:.1f} s after frame {self.last_frame}"
                    break
            self._housekeeping(now)
        if self.finished:
            self.exit_reason = "end of run (duration reached)"
        elif self.stop_requested:
            self.exit_reason = self.exit_reason or "stopped by signal"
        return 0

    # ============================================================== real time
    def run_realtime(self) -> int:
        opts = self.opts
        period = self.period
        spin = opts.spin_s
        spin_tight = min(spin, _SPIN_TIGHT_S)
        perf = time.perf_counter
        n_steps = round(opts.duration_s * self.rate) if opts.duration_s > 0 else 0
        self._send_heartbeat()
        start = perf()
        self._next_heartbeat = start + 1.0
        self.last_setpoint_wall = start  # the setpoint timeout counts from start-up
        deadline = start + period
        prev_wake = None
        att = self.att
        ctrl = self.ctrl
        pwm_map = self.pwm
        timing = self.timing
        sitl = self.sitl
        att_timeout = opts.attitude_timeout_s
        sp_timeout = opts.setpoint_timeout_s
        tel_every = self._telemetry_every
        pk_servo = self._pk_servo_sitl
        sitl_handler = self._sitl_handler
        while not self.stop_requested:
            # ---- wait for the deadline: sleep in select while far, then spin (serving the links until the
            # last few tens of us). With spin >= period (--busy-wait) it never sleeps: the CPU never idles.
            while True:
                rem = deadline - perf()
                if rem <= spin_tight:
                    break
                if rem <= spin:
                    self._wait(0.0)
                else:
                    self._wait(rem - spin)
            while perf() < deadline:
                pass
            t_wake = perf()
            sitl.poll(sitl_handler)  # an attitude that came in during the spin is the freshest one
            # ---- the step (critical path: attitude -> controller -> servo out)
            age = t_wake - att.t_rx if att.valid else math.inf
            if age > att_timeout:
                # No (fresh) attitude: rudder neutral, PFC follows it, adaptation frozen.
                ctrl.hold(0.0)
                pwm = pwm_map.neutral
                u_sent = 0.0
                um = self.um
                wire = self._servo_wire(_wall_usec(), pwm)
                sitl.send_raw(sitl.pack_fast(pk_servo, *wire), SERVO_OUTPUT_RAW)
                t_sent = perf()
                if att.valid:  # before the first attitude ever it is stand-by, not a failsafe
                    self.failsafe_steps += 1
                    if self.failsafe is None:
                        self.failsafe = "no attitude"
                        self._enter_failsafe(age)
                fs = self.failsafe
            else:
                if self.failsafe is not None:
                    self._leave_failsafe()
                elif self._status_state == M.MAV_STATE_STANDBY:
                    self._status_state = M.MAV_STATE_ACTIVE
                t_sim_us = att.ms * 1000.0
                um = self._setpoint_at(t_sim_us)
                if self.last_setpoint_wall is not None and t_wake - self.last_setpoint_wall > sp_timeout:
                    if not self.setpoint_lost:
                        self.setpoint_lost = True
                        self.events["setpoint_timeouts"] += 1
                        self._event(M.MAV_SEVERITY_WARNING,
                                    f"no setpoint for {sp_timeout:.1f} s: holding wings level")
                    um = self.um = 0.0
                elif self.setpoint_lost:
                    self.setpoint_lost = False
                    self._event(M.MAV_SEVERITY_INFO, "setpoints back")
                phi = att.roll
                try:
                    u = ctrl(phi, um)
                except NonFiniteInputError:
                    self.events["controller_errors"] += 1
                    ctrl.hold(0.0)
                    u = 0.0
                pwm = pwm_map.to_pwm(u)
                wire = self._servo_wire(_wall_usec(), pwm)
                sitl.send_raw(sitl.pack_fast(pk_servo, *wire), SERVO_OUTPUT_RAW)
                t_sent = perf()
                u_sent = pwm_map.to_rad(pwm)
                self.metrics.add(phi, ctrl.ym_ol, ctrl.e, u_sent)
                self.metrics_commanded.add(phi, ctrl.ym_ol, ctrl.e, u)
                fs = None
            # ---- bookkeeping, outside the critical path
            self.steps += 1
            if self.t_first_step is None:
                self.t_first_step = t_wake
            self.t_last_step = t_wake
            slot_end = deadline + period
            missed = t_sent > slot_end
            lateness = t_wake - deadline
            per = None if prev_wake is None else t_wake - prev_wake
            prev_wake = t_wake
            latency = (t_sent - att.t_rx) if att.valid else None
            timing.add(per, lateness, t_sent - t_wake, latency)
            if tel_every and self.steps % tel_every == 1 % tel_every:
                self._send_telemetry(att.ms if att.valid else 0, att.roll, att.p, att.r, wire)
            if self.hooks:
                rec = StepRecord(self.steps, None, att.ms * 1e-3, t_wake, um, att.roll, att.p, att.r, u_sent, pwm, fs,
                                 per, lateness, t_sent - t_wake, latency, missed, ctrl, self)
                for h in self.hooks:
                    h(rec)
            deadline += period
            if missed:
                timing.missed += 1
            now = perf()
            if now > deadline:
                # More than a period behind: skip the slots already gone (each a missed deadline), stay on the grid.
                behind = int((now - deadline) / period)
                if behind:
                    deadline += behind * period
                    timing.missed += behind
            self._housekeeping(now)
            if n_steps and self.steps >= n_steps:
                self.exit_reason = "end of run (duration reached)"
                break
        if self.stop_requested:
            self.exit_reason = self.exit_reason or "stopped by signal"
        return 0

    def _enter_failsafe(self, age: float):
        self._status_state = M.MAV_STATE_CRITICAL
        self.events["failsafes"] += 1
        self.failsafe_entries.append(age)
        self._send_heartbeat()
        self._event(M.MAV_SEVERITY_CRITICAL, f"FAILSAFE no attitude {age * 1e3:.1f} ms: rudder neutral")
        if self.opts.verbose:
            print(f"autopilot: failsafe entered at step {self.steps}: attitude age {age * 1e3:.1f} ms "
                  f"(timeout {self.opts.attitude_timeout_s * 1e3:.0f} ms, period {self.period * 1e3:.2f} ms), "
                  f"adaptation frozen", file=self.out, flush=True)

    def _leave_failsafe(self):
        self.failsafe = None
        self.recoveries += 1
        self._status_state = M.MAV_STATE_ACTIVE
        self._send_heartbeat()
        self._event(M.MAV_SEVERITY_NOTICE, f"attitude back after {self.failsafe_steps} failsafe steps")
        self.failsafe_steps = 0

    # ================================================================== exit
    def run(self) -> int:
        # Everything allocated so far (numpy, scipy, pymavlink tables) is long-lived: move it out of the cyclic
        # collector's reach so a full collection never walks it inside the loop (several ms on this heap).
        gc.collect()
        gc.freeze()
        try:
            return self.run_lockstep() if self.opts.lockstep else self.run_realtime()
        finally:
            self.shutdown()

    def shutdown(self):
        try:
            self.gcs.send(M.MAVLink_heartbeat_message(M.MAV_TYPE_FIXED_WING, M.MAV_AUTOPILOT_GENERIC, 0, 0,
                                                      M.MAV_STATE_POWEROFF, 3))
        except OSError:
            pass
        if self.tlog is not None:
            self.tlog.flush()

    def stats(self) -> dict:
        wall = (self.t_last_step - self.t_first_step) if self.t_first_step is not None else 0.0
        ev = dict(self.events)
        ev.update(failsafe_entries_ms=[a * 1e3 for a in self.failsafe_entries], recoveries=self.recoveries)
        return {
            "name": self.opts.name,
            "Lv": float(self.ctrl.config.lv) if isinstance(self.ctrl.config.lv, (int, float)) else None,
            "mode": "lockstep" if self.opts.lockstep else "realtime",
            "rate_hz": self.rate,
            "steps": self.steps,
            "metric_samples": self.metrics.n,
            "metrics": self.metrics.result(),
            "metrics_commanded": self.metrics_commanded.result(),
            "first_frame": self.first_frame,
            "last_frame": self.last_frame,
            "wall_s": wall,
            "timing": self.timing.summary(self.period),
            "events": ev,
            "links": {"sitl": self.sitl.counters(), "gcs": self.gcs.counters()},
            "exit_reason": self.exit_reason,
            "tlog_records": self.tlog.records if self.tlog is not None else 0,
        }

    def close(self):
        self.sitl.close()
        self.gcs.close()


class SeriesRecorder:
    """A step hook that keeps one row per control step and saves them as .npz (keys as tools.scenario.SERIES
    where the autopilot knows them: t, um, phi, p, r, u (sent, after PWM), the controller internals)."""

    KEYS = ("t", "um", "phi", "p", "r", "u", "u_cmd", "pwm", "failsafe", "ym", "ym_ol", "ya", "y_pfc", "e",
            "kpe", "kie", "ke", "kpx", "kix", "kx", "kpu", "kiu", "ku")

    def __init__(self):
        self.rows: list = []

    def __call__(self, rec: StepRecord):
        c = rec.ctrl
        self.rows.append((rec.t_sim, rec.um, rec.phi, rec.p, rec.r, rec.u, c.u, rec.pwm, rec.failsafe is not None,
                          c.ym, c.ym_ol, c.ya, c.y_pfc, c.e, c.kpe, c.kie, c.ke, c.kpx, c.kix, c.kx, c.kpu, c.kiu, c.ku))

    def save(self, path: str):
        import numpy as np

        arr = np.asarray(self.rows, dtype=float).reshape(-1, len(self.KEYS))
        np.savez(path, **{k: arr[:, i] for i, k in enumerate(self.KEYS)})


def _wall_usec() -> int:
    """Real-time SERVO_OUTPUT_RAW.time_usec: Unix microseconds mod 2**32 (monotonic across restarts)."""
    return (time.time_ns() // 1000) & 0xFFFFFFFF
