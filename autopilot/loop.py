"""The autopilot process's schedulers: the control step between a SITL link and a GCS link.

The step itself (setpoint, law, rudder limit, PWM map, metrics) is ``autopilot.step.ControlStep``; the links
are ``autopilot.shared.link``; this module reads the links, decides *when* to step and sends the answer
(docs/design.md, "Timing modes").  Two modes:

* real time (:meth:`Autopilot.run_realtime`): one control step per period on a fixed grid of
  deadlines (sleep in ``select`` until shortly before the deadline, then spin; never ``sleep(period)``),
  using the newest ATTITUDE.  Failsafes: no attitude for ``attitude_timeout_s`` (wall clock) ->
  rudder neutral, adaptation frozen (``ClSac.hold``), HEARTBEAT CRITICAL, STATUSTEXT; recovers by
  itself.  No setpoint for ``setpoint_timeout_s`` -> wings level (0 deg), STATUSTEXT.
* lockstep (:meth:`Autopilot.run_lockstep`): one step per SITL frame.  Frame k is recovered from
  ATTITUDE.time_boot_ms and the control rate; the answer is SERVO_OUTPUT_RAW with time_usec =
  t_k in us mod 2**32.  A duplicate frame is answered by resending the stored answer (signed again; no second step),
  an older frame is counted and ignored.  With pacing on (default), frame k waits until a GCS has
  scheduled setpoints up to t_k (the schedule horizon), so results do not depend on speed.

Per-step hook point for telemetry (Rerun, series): ``Autopilot.hooks`` is a list of callables called
with one :class:`StepRecord` after the servo command has been sent (outside the critical path), and
``Autopilot.event_hooks`` with ``(severity, text)`` for every status event (failsafe, clamp, ...).
"""

from __future__ import annotations

import gc
import math
import random
import select
import sys
import time
from array import array
from collections import Counter
from dataclasses import dataclass, field

from autopilot.clsac import GAIN_FIELDS, MODEL_FIELDS, ClSac, gains_of, model_of
from autopilot.config import ClSacConfig
from autopilot.envelope import Envelope, EnvelopeMonitor
from autopilot.params import ParamTable
from autopilot.shared.events import StatusEvents, StatusTextAssembler
from autopilot.shared.link import ANY_COMPONENT, SendClock, UdpLink
from autopilot.shared.mavlink import (
    GCS_SYSTEMS,
    SETPOINT_TYPEMASK,
    TYPEMASK_IGNORE_ATTITUDE,
    frame_from_ms,
    frame_ms,
    frame_usec,
    mavlink,
    quaternion_to_roll,
    roll_to_quaternion,
    vehicle_ids,
)
from autopilot.shared.pwm import PwmMap
from autopilot.shared.series import SeriesRecorder
from autopilot.shared.signing import SIGNING_LINK_GCS, SIGNING_LINK_SITL, Signing
from autopilot.step import ControlStep, Failsafe, StepResult
from autopilot.vehicle import MSGIDS as VEHICLE_MSGIDS
from autopilot.vehicle import Mode, Vehicle

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
SITL_RESTART_MS = 1000  # real time: an ATTITUDE this far behind the one held is a restarted SITL's clock
ATTITUDE_AHEAD_MS = 50.0  # real time: an ATTITUDE this far ahead of the held one's clock is rejected
SELF_STALL_S = 1.0  # lockstep: a pass of the loop this long means the autopilot itself did not run
TIMING_SAMPLES_MAX = 100_000  # per timing series: a uniform sample of all steps (reservoir), for the percentiles


@dataclass
class AutopilotOptions:
    rate_hz: float = 100.0
    lockstep: bool = False
    duration_s: float = (
        0.0  # 0 = until stopped; lockstep: sim seconds from the first frame; real time: seconds of control
    )
    telemetry_rate_hz: float = 50.0
    attitude_timeout_s: float = 0.1
    setpoint_timeout_s: float = 1.0
    max_roll_rad: float = math.radians(45.0)
    setpoint_ahead_s: float = 10.0  # a SET_ATTITUDE_TARGET scheduled further ahead of sim time is rejected
    # SET_ATTITUDE_TARGET.time_boot_ms: "sim" = a schedule on sim time (0 or past = now; the GCS script's lockstep
    # schedule); "now" = ignored, every setpoint flies on arrival (as ArduPilot and PX4 do), for ground stations
    # that stamp their own clock (MAVSDK stamps its host's uptime)
    setpoint_time: str = "sim"
    pace: bool = True  # lockstep: wait for the GCS schedule horizon
    spin_s: float = 0.0003  # real time: busy-wait (serving the links) this long before each deadline; inf = never sleep
    sitl: tuple = ("127.0.0.1", 14560)
    sitl_bind: tuple = ("127.0.0.1", 0)
    gcs: tuple = ("127.0.0.1", 14550)
    gcs_bind: tuple = ("127.0.0.1", 0)
    sysid: int = 1  # the vehicle's MAVLink system id (--sysid): 1:1 to the ground stations, 1:140 to the SITL
    gcs_ids: tuple = tuple((s, ANY_COMPONENT) for s in GCS_SYSTEMS)  # (sys, comp); comp ANY_COMPONENT = any
    learn_gcs: bool = True  # also take any system that sends a MAV_TYPE_GCS HEARTBEAT (off with --gcs-id)
    gcs_peers: tuple = ()  # ground-station addresses admitted from the start (--gcs-peer)
    max_gcs: int = 8  # admitted ground-station addresses at most (docs/design.md, "Trust model")
    signing_key: bytes | None = None  # MAVLink 2 signing on both links (autopilot.shared.signing); None = off
    lockstep_spin_s: float = 0.0  # lockstep: busy-poll this long for the next frame before sleeping in select
    lockstep_idle_exit_s: float = (
        0.0  # lockstep: exit after the last frame if the SITL stays silent this long (0 = never)
    )
    name: str = "clsac"
    verbose: bool = True
    envelope: Envelope = Envelope()  # the limits of a controlled flight (autopilot.envelope), judged every step


@dataclass(slots=True, kw_only=True)
class StepRecord:
    """What one control step did, handed to every ``Autopilot.hooks`` callable after the servo went out.

    ``result``: the :class:`autopilot.step.StepResult` (sim time ``t``, ``um``, ``phi``, ``u``, ``pwm``,
    ``failsafe`` ...).  The scheduler adds: ``frame`` (lockstep frame index, None in real time), ``wall``
    (``time.perf_counter()`` at the start of the step), the measured rates ``p``, ``r`` (rad/s), and timing in
    s: ``period`` since the previous step's start, ``lateness`` start minus deadline (0 in lockstep),
    ``compute`` start to servo sent, ``latency`` attitude (or unblocking setpoint) received to servo sent (in
    real time that is the attitude's age, including the wait for the deadline), ``missed`` (a deadline was
    missed).  ``ctrl`` is the ``ClSac`` (``ctrl.telemetry()``), ``ap`` the Autopilot (links, counters).
    """

    result: StepResult
    frame: int | None
    wall: float
    p: float
    r: float
    period: float | None
    lateness: float
    compute: float
    latency: float | None
    missed: bool
    ctrl: ClSac
    ap: "Autopilot"


@dataclass
class _Attitude:
    ms: int = -1
    roll: float = 0.0
    yaw: float = 0.0  # heading (ATTITUDE.yaw), relayed to the GCS
    p: float = 0.0
    r: float = 0.0
    t_rx: float = -1.0  # perf_counter when received
    valid: bool = False


@dataclass
class TimingStats:
    """Per-step timing (seconds) and summary percentiles, in bounded memory whatever the flight's length: each
    series keeps a uniform random sample of at most TIMING_SAMPLES_MAX of its values (reservoir sampling,
    Vitter's algorithm R) and its exact maximum; ``last_compute`` is the newest step's compute time."""

    period: array = field(default_factory=lambda: array("d"))
    lateness: array = field(default_factory=lambda: array("d"))
    compute: array = field(default_factory=lambda: array("d"))
    latency: array = field(default_factory=lambda: array("d"))
    missed: int = 0
    last_compute: float = 0.0
    seen: dict = field(default_factory=dict)  # series name -> values offered so far
    maxima: dict = field(default_factory=dict)  # series name -> exact maximum
    minima: dict = field(default_factory=dict)  # series name -> exact minimum
    _rng: random.Random = field(default_factory=lambda: random.Random(0), repr=False)

    def _sample(self, name: str, values: array, v: float) -> None:
        n = self.seen.get(name, 0) + 1
        self.seen[name] = n
        if v > self.maxima.get(name, -math.inf):
            self.maxima[name] = v
        if v < self.minima.get(name, math.inf):
            self.minima[name] = v
        if len(values) < TIMING_SAMPLES_MAX:
            values.append(v)
        else:
            j = int(self._rng.random() * n)
            if j < TIMING_SAMPLES_MAX:
                values[j] = v

    def add(self, period, lateness, compute, latency):
        self.last_compute = compute
        if period is not None:
            self._sample("period", self.period, period)
        if lateness is not None:
            self._sample("lateness", self.lateness, lateness)
        self._sample("compute", self.compute, compute)
        if latency is not None:
            self._sample("latency", self.latency, latency)

    def summary(self, nominal_period: float) -> dict:
        def pct(values, name=None, top=None, scale=1e3):
            if not values:
                return None
            s = sorted(values)
            n = len(s)

            def q(p):
                return s[min(n - 1, int(math.ceil(p / 100.0 * n)) - 1 if p > 0 else 0)] * scale

            top = self.maxima[name] if top is None else top  # exact, not the sample's
            return {"p50": q(50), "p99": q(99), "max": top * scale, "n": self.seen.get(name, n)}

        jitter = [abs(p - nominal_period) for p in self.period]
        jitter_max = (
            max(self.maxima["period"] - nominal_period, nominal_period - self.minima["period"]) if jitter else None
        )
        return {
            "period_ms": nominal_period * 1e3,
            "period_jitter_ms": pct(jitter, "period", jitter_max),
            "lateness_ms": pct(self.lateness, "lateness"),
            "compute_ms": pct(self.compute, "compute"),
            "latency_ms": pct(self.latency, "latency"),
            "missed_deadlines": self.missed,
        }


class Autopilot:
    def __init__(
        self,
        opts: AutopilotOptions,
        ctrl_config: ClSacConfig,
        pwm: PwmMap,
        tlog=None,
        out=None,
        *,
        params: ParamTable | None = None,
        mode: Mode = Mode.CLSAC,
        armed: bool = True,
    ):
        """``ctrl_config``: the law at start; ``params``: the parameter table (default: from ``ctrl_config`` and
        ``opts``; its CLSAC_LV is the configured L_v, which mode SAC flies as 0); ``mode``, ``armed``: at start."""
        self.opts = opts
        self.pwm = pwm
        self.tlog = tlog
        self.out = out or sys.stdout
        self.rate = float(opts.rate_hz)
        self.period = 1.0 / self.rate
        # The control step: setpoint queue, law, limit, PWM map, metrics from what flew (autopilot.step).
        self.control = ControlStep(ctrl_config, pwm)
        self.ctrl = self.control.law
        self.setpoints = self.control.setpoints
        self.send_clock = SendClock()  # both links: when this process last sent anything (the verdict's evidence)
        self.ids, sitl_src, sitl_id = vehicle_ids(opts.sysid)  # GCS link N:1, SITL link N:140, the SITL N:200
        self.sitl = UdpLink(
            "sitl",
            sitl_src,  # its own component: tlog readers separate it from the GCS link (N:1)
            opts.sitl_bind,
            opts.sitl,
            peers=[sitl_id],
            msgids=[ATTITUDE, HEARTBEAT, STATUSTEXT],
            signing=Signing(opts.signing_key, SIGNING_LINK_SITL) if opts.signing_key else None,
            tlog=tlog,
            send_clock=self.send_clock,
        )
        self.gcs = UdpLink(
            "gcs",
            self.ids,
            opts.gcs_bind,
            opts.gcs,
            peers=opts.gcs_ids,
            learn_gcs=opts.max_gcs if opts.learn_gcs else 0,
            gcs_systems=GCS_SYSTEMS,
            msgids=[SET_ATTITUDE_TARGET, HEARTBEAT, *VEHICLE_MSGIDS],
            admit=opts.max_gcs,
            peer_addrs=opts.gcs_peers,
            signing=Signing(opts.signing_key, SIGNING_LINK_GCS) if opts.signing_key else None,
            tlog=tlog,
            send_clock=self.send_clock,
        )
        self.hooks: list = []  # callables(StepRecord), after each step
        self.events = Counter()  # autopilot-level counters (failsafes, setpoints, frames)
        self._event = StatusEvents("autopilot", self.gcs, self.events, verbose=opts.verbose, out=self.out)
        self.event_hooks = self._event.hooks  # callables(severity, text), for each status event
        self.gcs.on_refused_gcs = self._on_refused_gcs
        self._sitl_texts = StatusTextAssembler()
        self.timing = TimingStats()
        # "Controlled": every step flown on an attitude against the envelope; each excursion announced once.
        self.envelope = EnvelopeMonitor(opts.envelope)
        self.stop_requested = False
        self.exit_reason = ""
        self.peer_lost = None  # the peer whose silence ended the run early ("sitl"), for the launcher's verdict
        self.hold_steps = 0  # real time: steps flown as a hold for want of attitude (all episodes)
        # real time: steps that came later than the attitude timeout (after their deadline, or after the step
        # before: a stall after a send moves the grid on, so only the gap shows it), and the worst of either
        self.late_steps = 0
        self.max_lateness_s = 0.0
        # attitude
        self.att = _Attitude()
        self.horizon_us = -1.0  # newest scheduled setpoint time received
        self.last_setpoint_wall = None
        self.setpoint_lost = False
        self._last_clamp_report = -1e9
        # state
        self.steps = 0
        self.failsafe = Failsafe.NONE  # the attitude failsafe (setpoint loss is self.setpoint_lost)
        self.failsafe_steps = 0
        self.failsafe_entries: list = []  # attitude age (s) when each failsafe began
        self.recoveries = 0
        self._telemetry_every = (
            max(1, int(round(self.rate / opts.telemetry_rate_hz))) if opts.telemetry_rate_hz > 0 else 0
        )
        self._next_heartbeat = 0.0
        self._next_flush = 0.0
        self._status_state = M.MAV_STATE_STANDBY
        # The ground-station protocol (autopilot.vehicle): modes, parameters, commands, streams.
        if params is None:
            params = ParamTable(
                ctrl_config,
                {k: getattr(opts, k) for k in ("attitude_timeout_s", "setpoint_timeout_s", "max_roll_rad")},
            )
        self.params = params
        self.vehicle = Vehicle(self, params, mode, armed)
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
            if (
                (roll - roll)
                or (p - p)
                or (r - r)
                or (msg.pitch - msg.pitch)
                or (msg.yaw - msg.yaw)
                or (msg.pitchspeed - msg.pitchspeed)
            ):
                self.sitl.reject("nonfinite_attitude")
                return
            if not -3.1416 <= roll <= 3.1416:
                self.sitl.reject("roll_out_of_range")
                return
            self.att.yaw = msg.yaw  # heading, for the GCS's ATTITUDE only (the law flies roll)
            ms = msg.time_boot_ms
            if self.opts.lockstep:
                self._on_frame(ms, t_rx, roll, p, r)
                return
            att = self.att
            if att.valid and t_rx - att.t_rx < self.opts.attitude_timeout_s:
                # Checked against the clock of the attitude held, which runs with the wall clock in real time.
                # (After attitude_timeout without one anything goes: the clock is re-synchronised.)
                if ms <= att.ms:
                    if att.ms - ms < SITL_RESTART_MS:
                        self.sitl.reject("stale_attitude")  # out of order or repeated: keep the newest
                        return
                    self.events["sitl_clock_restarts"] += 1  # went back by over a second: a new SITL, re-sync
                elif ms - att.ms > (t_rx - att.t_rx) * 1e3 + ATTITUDE_AHEAD_MS:
                    self.sitl.reject("future_attitude")  # ahead of the clock by more than a few periods
                    return
            att.ms, att.roll, att.p, att.r, att.t_rx, att.valid = ms, roll, p, r, t_rx, True
        elif mid == STATUSTEXT:
            text = self._sitl_texts.add(msg)  # a long text arrives in chunks (autopilot.shared.events)
            if text is not None:
                self._event(msg.severity, f"SITL: {text}")

    def _on_gcs(self, msg, t_rx):
        if msg.get_msgId() != SET_ATTITUDE_TARGET:
            self.vehicle.handle(msg)  # commands, parameters, modes, manual input (autopilot.vehicle)
            return
        ev = self.events
        if msg.target_system not in (0, self.ids[0]) or msg.target_component not in (0, self.ids[1]):
            self.gcs.reject("wrong_target")
            return
        if msg.type_mask & TYPEMASK_IGNORE_ATTITUDE:
            self.gcs.reject("no_attitude_in_setpoint")
            return
        roll = quaternion_to_roll(msg.q)
        if roll - roll != 0.0 or not all(math.isfinite(v) for v in msg.q):
            self.gcs.reject("nonfinite_setpoint")
            return
        ms = msg.time_boot_ms if self.opts.setpoint_time == "sim" else 0
        now_us = self._now_sim_us()
        t_us = (now_us or 0.0) if ms == 0 else ms * 1000.0  # 0 means now
        if ms and (now_us is None or t_us > now_us + self.opts.setpoint_ahead_s * 1e6):
            # scheduled further ahead of the current sim time than any schedule needs (or before there is a
            # clock): it could only fill the queue
            self.gcs.reject("future_setpoint")
            self._report_future_setpoint(msg, now_us)
            return
        lim = self.opts.max_roll_rad
        clamped = math.copysign(lim, roll) if (roll > lim or roll < -lim) else None
        if not self.setpoints.push(t_us, roll if clamped is None else clamped):
            self.gcs.reject("setpoint_queue_full")
            return
        # accepted: only now does it count (and reset the setpoint timeout)
        if clamped is not None:
            ev["setpoints_clamped"] += 1
            if t_rx - self._last_clamp_report > 1.0:
                self._last_clamp_report = t_rx
                self._event(
                    M.MAV_SEVERITY_WARNING,
                    f"setpoint {math.degrees(roll):.1f} deg clamped to {math.degrees(clamped):.0f}",
                )
        ev["setpoints"] += 1
        self.last_setpoint_wall = t_rx
        if ms == 0:
            ev["setpoints_now"] += 1
        elif t_us > self.horizon_us:
            self.horizon_us = t_us
        if self.opts.lockstep and self.pending_frame is not None:
            self._try_step(t_rx)

    def _on_refused_gcs(self, reason: str, sysid: int, compid: int, addr) -> None:
        """The first refused packet of a would-be ground station (``UdpLink.on_refused_gcs``): say why, once."""
        self.events["refused_gcs"] += 1
        self._event(M.MAV_SEVERITY_WARNING, refusal_text(reason, sysid, compid, addr, self.opts))

    def _report_future_setpoint(self, msg, now_us: float | None) -> None:
        """The first ``future_setpoint`` of the run, said once: most likely a ground station that stamps its own
        clock, which ``--setpoint-time now`` serves."""
        if self.events["future_setpoint_reported"]:
            return
        self.events["future_setpoint_reported"] = 1
        clock = "before the vehicle has a clock" if now_us is None else f"sim time is {now_us * 1e-6:.1f} s"
        self._event(
            M.MAV_SEVERITY_WARNING,
            f"setpoint from {msg.get_srcSystem()}:{msg.get_srcComponent()} stamped {msg.time_boot_ms / 1000:.1f} s "
            f"refused ({clock}, at most {self.opts.setpoint_ahead_s:g} s ahead); a ground station stamping its own "
            f"clock (MAVSDK) needs --setpoint-time now",
        )

    def _now_sim_us(self) -> float | None:
        """The current sim time in us (None before the first attitude)."""
        if self.opts.lockstep and self.pending_frame is not None:
            return self.pending_frame * 1e6 / self.rate
        if self.last_frame is not None and self.opts.lockstep:
            return self.last_frame * 1e6 / self.rate
        return self.att.ms * 1000.0 if self.att.valid else None

    # ================================================================ outputs
    def _servo_wire(self, time_usec: int, pwm: int) -> tuple:
        """SERVO_OUTPUT_RAW fields in wire order: time_usec, servo1..8, port, servo9..16."""
        s = self.pwm.servo_fields(pwm)
        return (time_usec, *s[:8], 0, *s[8:])

    def _send_heartbeat(self, status=None):
        hb = self.vehicle.heartbeat(self._status_state if status is None else status)
        for link in (self.gcs, self.sitl):
            link.send(hb)

    def _send_telemetry(self, t_ms: int, phi: float, p: float, r: float, servo_wire: tuple):
        """ATTITUDE (heading from the SITL), ATTITUDE_TARGET and SERVO_OUTPUT_RAW to every GCS, in one datagram."""
        g = self.gcs
        q = roll_to_quaternion(self.setpoints.current)
        bufs = [
            g.pack_fast(self._pk_att, t_ms, phi, 0.0, self.att.yaw, p, 0.0, r),
            g.pack_fast(self._pk_att_target, t_ms, q[0], q[1], q[2], q[3], 0.0, 0.0, 0.0, 0.0, SETPOINT_TYPEMASK),
            g.pack_fast(self._pk_servo_gcs, *servo_wire),
        ]
        self.vehicle.stream(bufs, _TELEMETRY_IDS)

    # ============================================================ housekeeping
    def _housekeeping(self, now: float):
        if now >= self._next_heartbeat:
            # 1 Hz; every 0.25 s while a peer has not answered yet, so a late-starting SITL or GCS finds us soon.
            self._next_heartbeat = now + (1.0 if (self.sitl.rx_packets and self.gcs.rx_packets) else 0.25)
            self._send_heartbeat()
            if not self.opts.lockstep and self.att.valid:
                self.gcs.send(M.MAVLink_system_time_message(time.time_ns() // 1000, self.att.ms))
        self.vehicle.housekeeping(now)
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
    def _on_frame(self, ms: int, t_rx: float, roll: float, p: float, r: float):
        """One lockstep frame.  The SITL sends frames one after the other, so only the next one is taken: one
        late, repeated or forged frame index can neither skip frames nor end the run."""
        k = frame_from_ms(ms, self.rate)
        last = self.last_frame
        pending = self.pending_frame
        if last is not None and k == last:
            # Duplicate of the frame we answered (our answer was lost or late): resend it, do not step.
            self.events["duplicate_frames"] += 1
            self.sitl.resend(self._last_answer, SERVO_OUTPUT_RAW)  # re-signed: not a replay
            return
        if pending is not None and k == pending:
            self.events["duplicate_pending_frames"] += 1
            return
        expected = pending if pending is not None else (None if last is None else last + 1)
        if expected is not None and k != expected:
            self.sitl.reject("stale_frame" if k < expected else "future_frame")
            return
        if self.first_frame is None:
            self.first_frame = k
        att = self.att
        att.ms, att.roll, att.p, att.r, att.t_rx, att.valid = ms, roll, p, r, t_rx, True
        self.pending_frame = k
        self.pending_t_rx = t_rx
        self._try_step(t_rx)

    def _try_step(self, t_ready: float):
        k = self.pending_frame
        t_us = k * 1e6 / self.rate
        opts = self.opts
        if opts.duration_s > 0 and self.steps >= round(opts.duration_s * self.rate):
            # The frame after the last step is the SITL's end-of-run frame (t = t0 + duration): not a control
            # step.  The run ends by the count of frames flown, never by one frame's index.
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
        res = self.control(k / self.rate, att.roll)
        wire = self._servo_wire(frame_usec(k, self.rate), res.pwm)
        raw = self.sitl.pack_fast(self._pk_servo_sitl, *wire)
        self.sitl.send_raw(raw, SERVO_OUTPUT_RAW)
        t_sent = time.perf_counter()
        self._last_answer = raw
        self.last_frame = k
        prev = self.t_last_step
        self.t_last_step = t0
        if self.t_first_step is None:
            self.t_first_step = t0
        latency = t_sent - max(t_ready, self.pending_t_rx)
        self.timing.add(None, None, t_sent - t0, latency)
        self.steps += 1
        if self._telemetry_every and self.steps % self._telemetry_every == 1 % self._telemetry_every:
            self._send_telemetry(att.ms, att.roll, att.p, att.r, wire)
        self.vehicle.on_step(self.steps, att.ms)
        if self.hooks:
            rec = StepRecord(
                result=res,
                frame=k,
                wall=t0,
                p=att.p,
                r=att.r,
                period=None if prev is None else t0 - prev,
                lateness=0.0,
                compute=t_sent - t0,
                latency=latency,
                missed=False,
                ctrl=self.ctrl,
                ap=self,
            )
            for h in self.hooks:
                h(rec)
        self._judge_envelope(res)

    def run_lockstep(self) -> int:
        opts = self.opts
        self._status_state = M.MAV_STATE_STANDBY
        self._send_heartbeat()
        now = time.perf_counter()
        self._next_heartbeat = now + 1.0
        last_warn = now
        silent_reported = False
        lockstep_spin = opts.lockstep_spin_s
        prev_pass = now
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
                    self.gcs.send(
                        M.MAVLink_system_time_message(time.time_ns() // 1000, frame_ms(self.pending_frame, self.rate))
                    )
                if now - self._blocked_since > 5.0 and now - last_warn > 5.0:
                    last_warn = now
                    print(
                        f"autopilot: lockstep frame t={self.pending_frame / self.rate:.3f} s waits for GCS "
                        f"setpoints (schedule horizon {self.horizon_us * 1e-6:.3f} s); run a GCS "
                        f"(python -m tools.gcs --lockstep) or pass --no-pace",
                        file=self.out,
                        flush=True,
                    )
            # A pass takes ~20 ms: one of a second or more means this process did not run (stopped, starved), and
            # what the SITL sent meanwhile may still wait in the socket: its silence is judged after another look.
            own_stall = now - prev_pass >= SELF_STALL_S
            prev_pass = now
            if self.att.valid and not own_stall:
                self._status_state = M.MAV_STATE_ACTIVE
                silent = now - self.sitl.last_rx_wall
                if silent > 2.0 and not silent_reported and self.pending_frame is None:
                    silent_reported = True
                    self._event(M.MAV_SEVERITY_WARNING, f"lockstep: SITL silent for {silent:.1f} s")
                elif silent < 2.0:
                    silent_reported = False
                if (
                    opts.lockstep_idle_exit_s > 0
                    and self.last_frame is not None
                    and self.pending_frame is None
                    and silent > opts.lockstep_idle_exit_s
                ):
                    self.exit_reason = f"SITL silent for {silent:.1f} s after frame {self.last_frame}"
                    self.peer_lost = "sitl"
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
        control = self.control
        timing = self.timing
        sitl = self.sitl
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
            if age > opts.attitude_timeout_s:  # CLSAC_FS_ATT_TMO may change in flight
                # No (fresh) attitude: rudder neutral, PFC follows it, adaptation frozen.
                res = control.hold(att.ms * 1e-3, att.roll, self.failsafe if att.valid else Failsafe.NONE)
                wire = self._servo_wire(_wall_usec(), res.pwm)
                sitl.send_raw(sitl.pack_fast(pk_servo, *wire), SERVO_OUTPUT_RAW)
                t_sent = perf()
                if att.valid:  # before the first attitude ever it is stand-by, not a failsafe
                    self.failsafe_steps += 1
                    self.hold_steps += 1
                    if self.failsafe is Failsafe.NONE:
                        self.failsafe = res.failsafe = Failsafe.NO_ATTITUDE
                        self._enter_failsafe(age)
            else:
                if self.failsafe is not Failsafe.NONE:
                    self._leave_failsafe()
                elif self._status_state == M.MAV_STATE_STANDBY:
                    self._status_state = M.MAV_STATE_ACTIVE
                lost = t_wake - self.last_setpoint_wall > opts.setpoint_timeout_s
                if lost != self.setpoint_lost:
                    self._setpoint_stream(lost)
                res = control(att.ms * 1e-3, att.roll, wings_level=lost)
                wire = self._servo_wire(_wall_usec(), res.pwm)
                sitl.send_raw(sitl.pack_fast(pk_servo, *wire), SERVO_OUTPUT_RAW)
                t_sent = perf()
            # ---- bookkeeping, outside the critical path
            self.steps += 1
            if self.t_first_step is None:
                self.t_first_step = t_wake
            self.t_last_step = t_wake
            slot_end = deadline + period
            missed = t_sent > slot_end
            lateness = t_wake - deadline
            per = None if prev_wake is None else t_wake - prev_wake
            late = max(lateness, 0.0 if per is None else per - period)
            if late > opts.attitude_timeout_s:  # flown too late to count as flown (the verdict's "late")
                self.late_steps += 1
            if late > self.max_lateness_s:
                self.max_lateness_s = late
            prev_wake = t_wake
            latency = (t_sent - att.t_rx) if att.valid else None
            timing.add(per, lateness, t_sent - t_wake, latency)
            tel_every = self._telemetry_every  # SET_MESSAGE_INTERVAL / REQUEST_DATA_STREAM may change it
            if tel_every and self.steps % tel_every == 1 % tel_every:
                self._send_telemetry(att.ms if att.valid else 0, att.roll, att.p, att.r, wire)
            self.vehicle.on_step(self.steps, att.ms if att.valid else 0)
            if self.hooks:
                rec = StepRecord(
                    result=res,
                    frame=None,
                    wall=t_wake,
                    p=att.p,
                    r=att.r,
                    period=per,
                    lateness=lateness,
                    compute=t_sent - t_wake,
                    latency=latency,
                    missed=missed,
                    ctrl=self.ctrl,
                    ap=self,
                )
                for h in self.hooks:
                    h(rec)
            if att.valid:  # standby before the first attitude is not flight
                self._judge_envelope(res)
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

    def _judge_envelope(self, res: StepResult) -> None:
        """One step against the envelope (``autopilot.envelope``): measured roll, the law's limited command and the
        limit in force.  Leaving it is announced once per excursion: a STATUSTEXT warning to the ground stations,
        the status event hooks (Rerun's ``/autopilot/events``) and the log."""
        text = self.envelope.add(res.t, res.phi, res.u_cmd, self.control.config.u_limit_rad)
        if text is not None:
            self.events["envelope_exits"] += 1
            self._event(M.MAV_SEVERITY_WARNING, text)

    def _enter_failsafe(self, age: float):
        self._status_state = M.MAV_STATE_CRITICAL
        self.events["failsafes"] += 1
        self.failsafe_entries.append(age)
        self._send_heartbeat()
        self._event(M.MAV_SEVERITY_CRITICAL, f"FAILSAFE no attitude {age * 1e3:.1f} ms: rudder neutral")
        if self.opts.verbose:
            print(
                f"autopilot: failsafe entered at step {self.steps}: attitude age {age * 1e3:.1f} ms "
                f"(timeout {self.opts.attitude_timeout_s * 1e3:.0f} ms, period {self.period * 1e3:.2f} ms), "
                f"adaptation frozen",
                file=self.out,
                flush=True,
            )

    def _setpoint_stream(self, lost: bool):
        """The setpoint stream was lost (no setpoint for the timeout: fly wings level) or came back."""
        self.setpoint_lost = lost
        if lost:
            self.events["setpoint_timeouts"] += 1
            self._event(
                M.MAV_SEVERITY_WARNING, f"no setpoint for {self.opts.setpoint_timeout_s:.1f} s: holding wings level"
            )
        else:
            self._event(M.MAV_SEVERITY_INFO, "setpoints back")

    def _leave_failsafe(self):
        self.failsafe = Failsafe.NONE
        self.control.transfer()  # from neutral back to the law without a step
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
        self.params.flying = True  # CLSAC_RATE is read-only from now on
        try:
            return self.run_lockstep() if self.opts.lockstep else self.run_realtime()
        finally:
            self.shutdown()
            self.send_clock.end(time.monotonic())

    def shutdown(self):
        try:
            self.gcs.send(self.vehicle.heartbeat(M.MAV_STATE_POWEROFF))
        except OSError:
            pass
        if self.tlog is not None:
            self.tlog.flush()

    def stats(self) -> dict:
        wall = (self.t_last_step - self.t_first_step) if self.t_first_step is not None else 0.0
        ev = dict(self.events)
        if self.control.nonfinite_inputs:
            ev["controller_errors"] = self.control.nonfinite_inputs  # NaN/Inf reached the law: flown as a hold
        ev.update(failsafe_entries_ms=[a * 1e3 for a in self.failsafe_entries], recoveries=self.recoveries)
        return {
            "name": self.opts.name,
            "Lv": float(self.ctrl.config.lv) if isinstance(self.ctrl.config.lv, (int, float)) else None,
            "mode": "lockstep" if self.opts.lockstep else "realtime",
            "rate_hz": self.rate,
            "steps": self.steps,
            "metric_samples": self.control.metrics.n,
            "metrics": self.control.metrics.result(),
            "metrics_commanded": self.control.metrics_commanded.result(),
            "first_frame": self.first_frame,
            "last_frame": self.last_frame,
            "wall_s": wall,
            "timing": self.timing.summary(self.period),
            "events": ev,
            "links": {"sitl": self.sitl.counters(), "gcs": self.gcs.counters()},
            "exit_reason": self.exit_reason
            + (f"; {self.hold_steps} steps flown as a hold without attitude" if self.hold_steps else ""),
            # whose silence cost the run steps: the SITL (idle exit, attitude failsafe) or a GCS schedule (pacing)
            "peer_lost": self.peer_lost
            or ("gcs" if self._blocked_since is not None else None)
            or ("sitl" if self.hold_steps or not self.control.metrics.n else None),
            "controlled": self.envelope.result().to_dict(),  # the envelope verdict (autopilot.envelope)
            "hold_steps": self.hold_steps,
            "late_steps": self.late_steps,  # real time: started more than the attitude timeout after the deadline
            "max_lateness_s": self.max_lateness_s,
            "attitude_timeout_s": self.opts.attitude_timeout_s,
            "sent": self.send_clock.summary(),  # monotonic clock of its sends (the verdict's evidence)
            "setpoints_evicted": self.setpoints.evicted,
            "tlog_records": self.tlog.records if self.tlog is not None else 0,
        }

    def close(self):
        self.sitl.close()
        self.gcs.close()


# The autopilot's per-step series (``--series``): keys as tools.scenario.SERIES where the autopilot knows them.
SERIES_KEYS = (
    "t",
    "um",
    "phi",
    "p",
    "r",
    "u",
    "u_cmd",
    "pwm",
    "failsafe",
    *MODEL_FIELDS,
    *GAIN_FIELDS,
    "mode",
    "armed",
)


def _series_row(rec: StepRecord) -> tuple:
    r, c = rec.result, rec.ctrl
    return (
        r.t,
        r.um,
        r.phi,
        rec.p,
        rec.r,
        r.u,
        c.u,
        r.pwm,
        r.failsafe is not Failsafe.NONE,
        *model_of(c),
        *gains_of(c),
        int(rec.ap.vehicle.mode),  # HEARTBEAT.custom_mode (autopilot.vehicle.Mode)
        rec.ap.control.armed,
    )


def refusal_text(reason: str, sysid: int, compid: int, addr, opts: AutopilotOptions) -> str:
    """Why the GCS link refused a would-be ground station's packet, in one line (docs/design.md, "Which ground
    stations are admitted")."""
    if reason == "unsigned":
        why = "unsigned; this vehicle takes only packets signed with its key"
    elif reason == "bad_signature":
        why = "signed with another key than this vehicle's"
    elif reason == "not_peer" and opts.signing_key:
        why = f"its address is not admitted: {opts.max_gcs} ground stations are already"  # signed: over the bound
    elif reason == "not_peer":
        why = "its address is not admitted (add it with --gcs-peer, or sign with the vehicle's key)"
    elif opts.learn_gcs:
        systems = ", ".join(str(s) for s in GCS_SYSTEMS)
        why = f"system {sysid} is not a ground station's ({systems}) and sent no MAV_TYPE_GCS HEARTBEAT first"
    else:
        ids = ", ".join(f"{s}:{'any' if c is ANY_COMPONENT else c}" for s, c in opts.gcs_ids)
        why = f"not one of the accepted --gcs-id {ids}"
    return f"GCS {sysid}:{compid} at {addr[0]}:{addr[1]} refused: {why}"


def series_recorder() -> SeriesRecorder:
    """A step hook recording every control step (t, um, phi, p, r, u sent after PWM, the law's internals)."""
    return SeriesRecorder(SERIES_KEYS, _series_row)


def _wall_usec() -> int:
    """Real-time SERVO_OUTPUT_RAW.time_usec: Unix microseconds mod 2**32 (monotonic across restarts)."""
    return (time.time_ns() // 1000) & 0xFFFFFFFF
