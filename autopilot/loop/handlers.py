"""The autopilot's link handlers (``LinkHandlers``, a part of ``autopilot.loop.Autopilot``): inputs from the SITL
and the ground stations, outputs, housekeeping, failsafe and envelope transitions; both schedulers call them.
"""

from __future__ import annotations

import math
import select
import time

from autopilot.loop.common import (
    _TELEMETRY_IDS,
    ANNOUNCE_FAST_FOR_S,
    ANNOUNCE_FAST_S,
    ANNOUNCE_SLOW_S,
    ATTITUDE,
    ATTITUDE_AHEAD_MS,
    COMMAND_ACK,
    GCS_SLOT_EXPIRE_S,
    HEARTBEAT_PERIOD_S,
    SET_ATTITUDE_TARGET,
    SITL_RESTART_MS,
    STATUSTEXT,
    AutopilotOptions,
    M,
)
from autopilot.schedule import NEW, UNLINKED
from autopilot.shared.cli import SIDESLIP_ENVELOPE_DEG
from autopilot.shared.fastmav import AOA_SSA_ID
from autopilot.shared.link import ANY_COMPONENT
from autopilot.shared.mavlink import (
    GCS_SYSTEMS,
    SETPOINT_TYPEMASK,
    TYPEMASK_IGNORE_ATTITUDE,
    quaternion_to_roll,
    roll_to_quaternion,
)
from autopilot.step import Failsafe, StepResult

NAMED_VALUE_FLOAT = M.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT
SIDESLIP_SETPOINT = "SSA_SP"  # tools.gcs.SIDESLIP_SETPOINT: a square MIMO plant's sideslip command (deg)


def refusal_text(reason: str, sysid: int, compid: int, addr, opts: AutopilotOptions) -> str:
    """Why the GCS link refused a would-be ground station's packet, in one line (docs/spec.md, "Which ground
    stations are admitted")."""
    if reason == "unsigned":
        why = "unsigned; this vehicle takes only packets signed with its key"
    elif reason == "bad_signature":
        why = "signed with another key than this vehicle's"
    elif reason == "not_peer" and opts.signing_key:  # signed: over the bound
        why = (
            f"its address is not admitted: {opts.max_gcs} ground stations are already, each sending HEARTBEAT "
            f"(a slot is freed after {GCS_SLOT_EXPIRE_S:g} s without one)"
        )
    elif reason == "not_peer":
        why = "its address is not admitted (add it with --gcs-peer, or sign with the vehicle's key)"
    elif opts.learn_gcs:
        systems = ", ".join(str(s) for s in GCS_SYSTEMS)
        why = f"system {sysid} is not a ground station's ({systems}) and sent no MAV_TYPE_GCS HEARTBEAT first"
    else:
        ids = ", ".join(f"{s}:{'any' if c is ANY_COMPONENT else c}" for s, c in opts.gcs_ids)
        why = f"not one of the accepted --gcs-id {ids}"
    return f"GCS {sysid}:{compid} at {addr[0]}:{addr[1]} refused: {why}"


class LinkHandlers:
    """The autopilot's link handlers, whichever scheduler drives it: what it does with each message from the SITL
    and the ground stations, what it sends, housekeeping, the failsafe and envelope transitions."""

    # ================================================================== inputs
    def _on_sitl(self, msg, t_rx):
        mid = msg.get_msgId()
        if mid == ATTITUDE:
            # the fields in wire order, as the link's hot path hands them to _on_attitude
            self._on_attitude(
                t_rx,
                (msg.time_boot_ms, msg.roll, msg.pitch, msg.yaw, msg.rollspeed, msg.pitchspeed, msg.yawspeed),
            )
        elif mid == AOA_SSA_ID:  # a square MIMO plant's sideslip (deg on the wire), for the next step
            ssa = msg.SSA
            if ssa - ssa == 0.0 and -90.0 <= ssa <= 90.0:
                self.ctrl.y2 = math.radians(ssa)
            else:
                self.sitl.reject("nonfinite_attitude")
        elif mid == STATUSTEXT:
            text = self._sitl_texts.add(msg)  # a long text arrives in chunks (autopilot.shared.events)
            if text is not None:
                self._event(msg.severity, f"SITL: {text}")
        elif mid == COMMAND_ACK:
            self.vehicle.failures.on_ack(msg, t_rx)  # the answer to a relayed MAV_CMD_INJECT_FAILURE

    def _on_attitude(self, t_rx, values):
        """An ATTITUDE from the SITL, ``values`` in wire order (time_boot_ms, roll, pitch, yaw, rollspeed,
        pitchspeed, yawspeed): the SITL link's hot path (``UdpLink.on_hot``) hands them so, ``_on_sitl`` too."""
        ms, roll, pitch, yaw, p, q, r = values
        # NaN/Inf anywhere in the message is a broken sensor frame: reject (x - x != 0 for NaN and Inf)
        if (roll - roll) or (p - p) or (r - r) or (pitch - pitch) or (yaw - yaw) or (q - q):
            self.sitl.reject("nonfinite_attitude")
            return
        if not -3.1416 <= roll <= 3.1416:
            self.sitl.reject("roll_out_of_range")
            return
        self.att.yaw = yaw  # heading, for the GCS's ATTITUDE only (the law flies roll)
        if self.opts.lockstep:
            self.scheduler.on_frame(ms, t_rx, roll, p, r)
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

    def _on_gcs(self, msg, t_rx):
        if self._side_pending and (
            msg.get_msgId() != SET_ATTITUDE_TARGET or self._side_pending[0][0] != self.gcs.rx_datagrams
        ):
            self._flush_sideslip(True)  # not followed by a roll point of its datagram: taken as sent
        if msg.get_msgId() != SET_ATTITUDE_TARGET:
            if self.pwm2 is not None and msg.get_msgId() == NAMED_VALUE_FLOAT and msg.name == SIDESLIP_SETPOINT:
                self._on_sideslip_setpoint(msg)
                return
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
        if self._schedule_lost(msg, now_us):
            self._flush_sideslip(False)  # the roll point's copy or a lost datagram's follower: its sideslip too
            return
        if self._side_pending:
            self._flush_sideslip(True)  # the roll point continues the schedule: its sideslip is taken before it
        elif self.pwm2 is not None and self.opts.lockstep and self._side_seen:
            self.events["sideslip_unpaired"] += 1  # a MIMO schedule's roll point without its SSA_SP: counted
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
            self.scheduler.try_step(t_rx)

    def _on_sideslip_setpoint(self, msg) -> None:
        """A square MIMO plant's second setpoint (NAMED_VALUE_FLOAT ``SSA_SP``, deg, sent by the ground station just
        before the roll setpoint of the same ``time_boot_ms``): queued on sim time like the roll's (0: now), flown
        as the sideslip command ``ctrl.um2`` from its time on.  Past the sideslip envelope (+-SIDESLIP_ENVELOPE_DEG,
        the verdict's limit) it is clamped to it, as a roll setpoint is to the roll limit: counted, and said at most
        once a second."""
        value = float(msg.value)
        if value - value != 0.0:
            self.gcs.reject("nonfinite_setpoint")
            return
        if abs(value) > SIDESLIP_ENVELOPE_DEG:
            sent, value = value, math.copysign(SIDESLIP_ENVELOPE_DEG, value)
            self.events["sideslip_setpoints_clamped"] += 1
            now = time.monotonic()
            if now - self._last_side_clamp_report > 1.0:
                self._last_side_clamp_report = now
                self._event(M.MAV_SEVERITY_WARNING, f"sideslip setpoint {sent:.1f} deg clamped to {value:.0f}")
        ms = msg.time_boot_ms if self.opts.setpoint_time == "sim" else 0
        now_us = self._now_sim_us()
        t_us = (now_us or 0.0) if ms == 0 else ms * 1000.0
        if self.opts.lockstep and self.gcs.rx_more:
            # Lockstep: the GCS sends each SSA_SP just before the roll point of its time in the roll's linked
            # datagram (tools.gcs._send_linked); it shares that point's verdict (autopilot.schedule): taken with
            # it, dropped with it when a copy or after a lost datagram (then the GCS sends both again).
            self._side_seen = True
            dg, n = self._side_in_dg
            self._side_in_dg = (self.gcs.rx_datagrams, n + 1 if dg == self.gcs.rx_datagrams else 1)
            self._side_pending.append((self.gcs.rx_datagrams, t_us, math.radians(value)))
            return
        self._push_sideslip(t_us, math.radians(value))

    def _push_sideslip(self, t_us: float, value: float) -> None:
        if not self.setpoints2.push(t_us, value):
            self.gcs.reject("setpoint_queue_full")
            return
        self.events["sideslip_setpoints"] += 1

    def _flush_sideslip(self, take: bool) -> None:
        """The SSA_SP waiting for its roll point: queued (``take``) or dropped with it (after a lost datagram it is
        counted in ``sideslip_setpoints_unlinked``, by ``_schedule_lost``)."""
        pending, self._side_pending = self._side_pending, []
        if take:
            for _, t_us, value in pending:
                self._push_sideslip(t_us, value)

    def _schedule_lost(self, msg, now_us: float | None) -> bool:
        """Lockstep: whether this setpoint is a copy of one held or follows a lost datagram (``autopilot.schedule``:
        it is dropped, counted, and the ground station sends it again), by the wire time it carries."""
        if not self.opts.lockstep:
            return False
        g = self.gcs
        dg, sides = self._side_in_dg  # the SSA_SP before it in its datagram are not roll points
        verdict = self._chain.take(
            (msg.get_srcSystem(), msg.get_srcComponent()),
            g.rx_datagrams,
            g.rx_packet_index - (sides if dg == g.rx_datagrams else 0),
            g.rx_more,
            msg.time_boot_ms * 1000.0,
            now_us,
        )
        if verdict == NEW:
            return False
        if verdict == UNLINKED:
            self.events["setpoints_unlinked"] += 1
            self.events["sideslip_setpoints_unlinked"] += len(self._side_pending)
        elif g.rx_packet_index:  # a datagram's first point is the one it links to: expected, not counted
            self.events["setpoints_resent"] += 1
        return True

    def _on_refused_gcs(self, reason: str, sysid: int, compid: int, addr) -> None:
        """The first refused packet of a would-be ground station (``UdpLink.on_refused_gcs``): say why, once."""
        self.events["refused_gcs"] += 1
        self._event(M.MAV_SEVERITY_WARNING, refusal_text(reason, sysid, compid, addr, self.opts))

    def _on_expired_gcs(self, addr, silent_s: float) -> None:
        """A ground station admitted by its signature went silent (no HEARTBEAT for ``GCS_SLOT_EXPIRE_S``): its slot
        is free again (``UdpLink.expire``)."""
        self.events["gcs_slots_expired"] += 1
        self._event(
            M.MAV_SEVERITY_NOTICE,
            f"GCS at {addr[0]}:{addr[1]} dropped: no HEARTBEAT for {silent_s:.1f} s (its slot is free)",
            kind="ground station dropped",
        )

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
        """SERVO_OUTPUT_RAW fields in wire order: time_usec, servo1..8, port, servo9..16 (those after time_usec
        kept per PWM value: at most the map's range of them)."""
        rest = self._wire_rest.get(pwm)
        if rest is None:
            s = self.pwm.servo_fields(pwm)
            rest = self._wire_rest[pwm] = (*s[:8], 0, *s[8:])
        return (time_usec, *rest)

    def _servo_payload(self, time_usec: int, pwm: int) -> bytes:
        """SERVO_OUTPUT_RAW's payload in its struct layout: time_usec (uint32 first, little-endian), then the
        bytes of the fields after it, packed once per PWM value (``_servo_wire``)."""
        tail = self._servo_tails.get(pwm)
        if tail is None:
            wire = self._servo_wire(0, pwm)
            tail = self._servo_tails[pwm] = M.MAVLink_servo_output_raw_message.unpacker.pack(*wire)[4:]
        return time_usec.to_bytes(4, "little") + tail

    def _servo_wire_mimo(self, time_usec: int, pwm: int) -> tuple:
        """``_servo_wire`` of a square MIMO plant: the second surface's pulse (``ctrl.u2`` through ``pwm2``) on its
        own channel beside the first's."""
        s = list(self.pwm.servo_fields(pwm))
        s[self.pwm2.channel - 1] = self.pwm2.to_pwm(self.ctrl.u2)
        return (time_usec, *s[:8], 0, *s[8:])

    def _servo_payload_mimo(self, time_usec: int, pwm: int) -> bytes:
        return M.MAVLink_servo_output_raw_message.unpacker.pack(*self._servo_wire_mimo(time_usec, pwm))

    def _start_announcing(self, now: float) -> None:
        """The run's first HEARTBEAT, now; the next ones as ``_heartbeat_period`` says."""
        self._announce_fast_until = now + ANNOUNCE_FAST_FOR_S
        self._send_heartbeat()
        self._next_heartbeat = now + self._heartbeat_period(now)

    def _heartbeat_period(self, now: float) -> float:
        """1 Hz once the SITL and a ground station have answered; until then fast for the first seconds of the run,
        so that a SITL or GCS that bound its socket just after our first HEARTBEAT finds us at once
        (``ANNOUNCE_FAST_S``, autopilot/loop/common.py), then every ``ANNOUNCE_SLOW_S``."""
        if self.sitl.rx_packets and self.gcs.rx_packets:
            return HEARTBEAT_PERIOD_S
        return ANNOUNCE_FAST_S if now < self._announce_fast_until else ANNOUNCE_SLOW_S

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
            self._next_heartbeat = now + self._heartbeat_period(now)
            self._send_heartbeat()
            if not self.opts.lockstep and self.att.valid:
                self.gcs.send(M.MAVLink_system_time_message(time.time_ns() // 1000, self.att.ms))
        self.vehicle.housekeeping(now)
        if now >= self._next_expiry:  # silent ground stations' slots, and the events held back for a summary
            self._next_expiry = now + 0.5
            self.gcs.expire(now)
            self._event.tick()
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

    def _read_ready(self, ready) -> None:
        """Read the links a ``poll(2)`` found ready (``ready``: its (fd, events) pairs, the SITL's first): an empty
        link is not read (its ``recvfrom`` would only raise)."""
        for fd, _ev in ready:
            if fd == self._sitl_fd:
                self.sitl.poll(self._sitl_handler)
            else:
                self.gcs.poll(self._gcs_handler)

    def _judge_envelope(self, res: StepResult) -> None:
        """One step against the envelope (``autopilot.envelope``): measured roll, the law's limited command, the
        limit in force, the commanded response y_m,ol when the law flew the step on an attitude (a hold, disarmed
        or in MANUAL, is not the loop's tracking: its reference model stands still), and whether a ground station
        had disarmed the vehicle or selected MANUAL.  Leaving it is announced once per excursion: a STATUSTEXT
        warning to the ground stations, the status event hooks (Rerun's ``/autopilot/events``) and the log."""
        control = self.control
        if control.law_failure is not None and not self._law_failure_said:
            self._law_failed()
        armed, manual = control.armed, control.manual is not None
        law_flew = armed and not manual and res.failsafe not in (Failsafe.NO_ATTITUDE, Failsafe.LAW_ERROR)
        ref = control.law.ym_ol if law_flew else None
        text = self.envelope.add(res.t, res.phi, res.u_cmd, control.config.u_limit_rad, ref, armed=armed, manual=manual)
        if text is not None:
            self.events["envelope_exits"] += 1
            self._event(M.MAV_SEVERITY_WARNING, text)

    def _law_failed(self) -> None:
        """The law raised or returned NaN/inf (``ControlStep.law_failure``): said once, as a critical event and one
        line in the log, with the traceback after it in the log (never on a console: the launcher's is the verdict);
        the flight goes on with the rudder neutral and ends not controlled (``stats``)."""
        from autopilot.shared import crash

        self._law_failure_said = True
        control = self.control
        text = f"FAILSAFE {control.law_failure} at {control.law_failure_t:.3f} s: rudder neutral from then on"
        self.events["law_failures"] += 1
        self._event(M.MAV_SEVERITY_CRITICAL, text)  # also its line in the log
        exc = control.law_exception
        if exc is not None and exc.__cause__ is not None:  # the law raised: its traceback in the log only
            crash.keep("autopilot", exc.__cause__, file=self.out)

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
