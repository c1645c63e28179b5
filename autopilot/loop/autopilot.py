"""``Autopilot``: the autopilot process: its links, control step and state, its link handlers, the scheduler it holds
(lockstep or real time) which drives it, its stats and its shutdown.
"""

from __future__ import annotations

import gc
import math
import select
import sys
import time
from collections import Counter

from autopilot.config import ClSacConfig
from autopilot.envelope import EnvelopeMonitor
from autopilot.loop.common import (
    ATTITUDE,
    COMMAND_ACK,
    GCS_SLOT_EXPIRE_S,
    HEARTBEAT,
    OTHERS_BUDGET,
    PEER_BUDGET,
    PEER_BURST,
    PEER_RATE_MIN,
    SET_ATTITUDE_TARGET,
    SITL_PEER_RATE,
    STATUSTEXT,
    AutopilotOptions,
    M,
    TimingStats,
    _Attitude,
)
from autopilot.loop.handlers import LinkHandlers
from autopilot.loop.lockstep import LockstepScheduler
from autopilot.loop.realtime import RealtimeScheduler
from autopilot.params import ParamTable
from autopilot.schedule import ScheduleChain
from autopilot.shared.events import StatusEvents, StatusTextAssembler
from autopilot.shared.fastmav import AOA_SSA_ID
from autopilot.shared.link import SendClock, UdpLink
from autopilot.shared.mavlink import (
    GCS_SYSTEMS,
    vehicle_ids,
)
from autopilot.shared.pwm import PwmMap
from autopilot.shared.signing import SIGNING_LINK_GCS, SIGNING_LINK_SITL, Signing
from autopilot.step import ControlStep, Failsafe, SetpointQueue
from autopilot.vehicle import MSGIDS as VEHICLE_MSGIDS
from autopilot.vehicle import Mode, Vehicle


class Autopilot(LinkHandlers):
    """The autopilot process: the control step between a SITL link and a GCS link, with its link handlers and its
    state, driven by the scheduler it holds (``scheduler``: a ``LockstepScheduler`` or a ``RealtimeScheduler``, as
    ``opts.lockstep`` asks); ``run()`` runs it."""

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
        law=None,
        pwm2: PwmMap | None = None,
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
        # ``law``: a law object instead of ``ctrl_config``'s (``autopilot.mimo.MimoLaw``: a square MIMO plant, whose
        # second surface flies on ``pwm2``'s channel and whose sideslip comes in AOA_SSA)
        self.control = ControlStep(ctrl_config, pwm, law=law)
        self.pwm2 = pwm2
        # MIMO: the second setpoint (the sideslip command, NAMED_VALUE_FLOAT SSA_SP), on sim time like the roll's
        self.setpoints2 = SetpointQueue() if pwm2 is not None else None
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
            msgids=[ATTITUDE, HEARTBEAT, STATUSTEXT, COMMAND_ACK, *((AOA_SSA_ID,) if pwm2 else ())],
            signing=Signing(opts.signing_key, SIGNING_LINK_SITL) if opts.signing_key else None,
            tlog=tlog,
            send_clock=self.send_clock,
            peer_rate=None if opts.lockstep else max(SITL_PEER_RATE, PEER_BUDGET * self.rate),
            peer_burst=PEER_BURST,
            others_rate=OTHERS_BUDGET * self.rate,
            others_burst=OTHERS_BUDGET,
        )
        self.gcs = UdpLink(
            "gcs",
            self.ids,
            opts.gcs_bind,
            opts.gcs,
            peers=opts.gcs_ids,
            learn_gcs=opts.max_gcs if opts.learn_gcs else 0,
            gcs_systems=GCS_SYSTEMS,
            # MIMO: NAMED_VALUE_FLOAT SSA_SP, the sideslip setpoint, too
            msgids=[
                SET_ATTITUDE_TARGET,
                HEARTBEAT,
                *VEHICLE_MSGIDS,
                *((M.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT,) if pwm2 else ()),
            ],
            admit=opts.max_gcs,
            peer_addrs=opts.gcs_peers,
            signing=Signing(opts.signing_key, SIGNING_LINK_GCS) if opts.signing_key else None,
            tlog=tlog,
            send_clock=self.send_clock,
            peer_rate=max(PEER_RATE_MIN, PEER_BUDGET * self.rate),
            peer_burst=PEER_BURST,
            others_rate=OTHERS_BUDGET * self.rate,
            others_burst=OTHERS_BUDGET,
            expire_s=GCS_SLOT_EXPIRE_S,
        )
        self.hooks: list = []  # callables(StepRecord), after each step
        self.events = Counter()  # autopilot-level counters (failsafes, setpoints, frames)
        self._law_failure_said = False  # ControlStep.law_failure announced (handlers._law_failed)
        self._event = StatusEvents("autopilot", self.gcs, self.events, verbose=opts.verbose, out=self.out)
        self.event_hooks = self._event.hooks  # callables(severity, text), for each status event
        self.gcs.on_refused_gcs = self._on_refused_gcs
        self.gcs.on_expired = self._on_expired_gcs
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
        self._chain = ScheduleChain()  # lockstep: which scheduled setpoints continue a station's schedule
        self._side_pending: list = []  # lockstep MIMO: SSA_SP (datagram, t_us, rad) waiting for its roll point
        self._side_seen = False  # lockstep MIMO: a station sends SSA_SP in the roll's linked datagrams
        self._side_in_dg = (-1, 0)  # (datagram, SSA_SP in it so far): the roll point's place among roll points
        self.last_setpoint_wall = None
        self.setpoint_lost = False
        self._last_clamp_report = -1e9
        self._last_side_clamp_report = -1e9  # monotonic s of the last "sideslip setpoint clamped" status text
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
        self._announce_fast_until = 0.0  # HEARTBEAT: fast until then while a peer has not answered (_heartbeat_period)
        self._next_flush = 0.0
        self._next_expiry = 0.0
        self._status_state = M.MAV_STATE_STANDBY
        # The ground-station protocol (autopilot.vehicle): modes, parameters, commands, streams.
        if params is None:
            params = ParamTable(
                ctrl_config,
                {k: getattr(opts, k) for k in ("attitude_timeout_s", "setpoint_timeout_s", "max_roll_rad")}
                | {"failure_injection": float(opts.failure_injection)},
            )
        self.params = params
        self.vehicle = Vehicle(self, params, mode, armed)
        # lockstep
        self.first_frame = None
        self.last_frame = None  # last frame answered
        self.pending_frame = None  # the frame received and not yet flown (waiting for the schedule)
        self._blocked_since = None  # since when the pending frame waits for the ground station's schedule
        self.finished = False
        self.t_first_step = None
        self.t_last_step = None
        # select(2) has microsecond timeouts (epoll rounds up to whole milliseconds: 1 ms of jitter)
        self._fds = [self.sitl.sock, self.gcs.sock]
        self._sitl_fd = self.sitl.sock.fileno()
        self._sitl_handler = self._on_sitl
        self._gcs_handler = self._on_gcs
        self.sitl.on_hot(ATTITUDE, self._on_attitude)  # the usual ATTITUDE datagram, without a message object
        # lockstep's busy poll asks the kernel about both sockets at once (one poll(2), no exception when empty)
        self._poller = select.poll()
        for sock in self._fds:
            self._poller.register(sock, select.POLLIN)
        # fast, byte-identical encoders for the per-step messages (autopilot.shared.fastmav)
        self._pk_servo_sitl = self.sitl.fast_packer(M.MAVLink_servo_output_raw_message)
        self._pk_servo_gcs = self.gcs.fast_packer(M.MAVLink_servo_output_raw_message)
        self._pk_att = self.gcs.fast_packer(M.MAVLink_attitude_message)
        self._pk_att_target = self.gcs.fast_packer(M.MAVLink_attitude_target_message)
        self._wire_rest: dict = {}  # PWM -> SERVO_OUTPUT_RAW's fields after time_usec (``_servo_wire``)
        self._servo_tails: dict = {}  # PWM -> their packed bytes (``_servo_payload``)
        if pwm2 is not None:  # MIMO: both surfaces in every SERVO_OUTPUT_RAW, each on its own channel
            self._servo_wire = self._servo_wire_mimo
            self._servo_payload = self._servo_payload_mimo
        # what drives it: one control step per SITL frame, or per period on a grid of deadlines
        self.scheduler = LockstepScheduler(self) if opts.lockstep else RealtimeScheduler(self)

    # ================================================================== exit
    def run(self) -> int:
        # Everything allocated so far (numpy, scipy, pymavlink tables) is long-lived: move it out of the cyclic
        # collector's reach so a full collection never walks it inside the loop (several ms on this heap).
        gc.collect()
        gc.freeze()
        self.params.flying = True  # CLSAC_RATE is read-only from now on
        try:
            return self.scheduler.run()
        finally:
            self.shutdown()
            self.send_clock.end(time.monotonic())

    def shutdown(self):
        self._event.tick(flush=True)  # the events held back for a summary are said before the end
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
            "Lv": float(lv) if isinstance(lv := getattr(self.ctrl.config, "lv", None), (int, float)) else None,
            "law": getattr(self.ctrl, "name", None),  # a law on autopilot.law's interface: its registered name
            # ... and its own telemetry after the last step, by name (None where not finite)
            "law_telemetry": {
                f: (v if math.isfinite(v) else None) for f, v in zip(self.ctrl.fields, self.ctrl.law_row())
            }
            if hasattr(self.ctrl, "law_row")
            else None,
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
            "controlled": self._controlled(),  # the envelope verdict (autopilot.envelope)
            # MAV_CMD_INJECT_FAILURE relayed to the SITL, each with its answer (autopilot.injection)
            "failure_injections": self.vehicle.failures.records,
            "params_start": self.vehicle.params_start,  # every parameter as the flight started
            "param_changes": self.vehicle.param_changes,  # each value a ground station changed, with its sim time
            "u_limit_rad": float(self.control.config.u_limit_rad),  # the command limit in force at the end
            "hold_steps": self.hold_steps,
            "late_steps": self.late_steps,  # real time: started more than the attitude timeout after the deadline
            "max_lateness_s": self.max_lateness_s,
            "attitude_timeout_s": self.opts.attitude_timeout_s,
            "sent": self.send_clock.summary(),  # monotonic clock of its sends (the verdict's evidence)
            "setpoints_evicted": self.setpoints.evicted,
            "tlog_records": self.tlog.records if self.tlog is not None else 0,
        }

    def _controlled(self) -> dict:
        """The envelope's verdict; not controlled whatever it says when the law failed (``ControlStep.law_failure``):
        the reason names the law and when."""
        out = self.envelope.result().to_dict()
        control = self.control
        if control.law_failure is not None:
            why = f"{control.law_failure} at {control.law_failure_t:.3f} s; the failsafe flew the rudder neutral"
            out = {**out, "ok": False, "reason": why, "law_failure": control.law_failure}
        return out

    def close(self):
        self.sitl.close()
        self.gcs.close()
