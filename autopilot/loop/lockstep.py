"""The lockstep scheduler (``LockstepScheduler``, a part of ``autopilot.loop.Autopilot``): frame k of the SITL is
answered with the command of control step k, with pacing on the ground station's schedule.
"""

from __future__ import annotations

import time

from autopilot.loop.common import SELF_STALL_S, SERVO_OUTPUT_RAW, M, StepRecord
from autopilot.shared.mavlink import (
    frame_from_ms,
    frame_ms,
    frame_usec,
)


class LockstepScheduler:
    """Lockstep: one control step per SITL frame, answered at once (docs/spec.md, "Lockstep")."""

    # =============================================================== lockstep
    def _on_frame(self, ms: int, t_rx: float, roll: float, p: float, r: float):
        """One lockstep frame.  The SITL sends frames one after the other, so only the next one is taken: one
        late, repeated or forged frame index can neither skip frames nor end the run."""
        irate = self._irate
        k = -((-ms * irate) // 1000) if irate else frame_from_ms(ms, self.rate)  # frame_from_ms, inline if integer
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
        if self._steps_to_fly and self.steps >= self._steps_to_fly:
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
        # The critical path, which the SITL waits for: the law, encode, sign, send.  Everything after the send
        # (timing, telemetry, the gains stream, hooks, the envelope, the tlog's queue) is done while the SITL
        # computes the next frame (docs/spec.md, "Lockstep").
        t0 = time.perf_counter()
        att = self.att
        control = self.control
        if self.setpoints2 is not None:  # MIMO: the sideslip command in force
            self.ctrl.um2 = self.setpoints2.at(k / self.rate)
        pwm = control.command(k / self.rate, att.roll, p=att.p, r=att.r)  # the pulse width that flies (autopilot.step)
        us = self._usec_per_frame
        usec = (k * us) & 0xFFFFFFFF if us else frame_usec(k, self.rate)  # frame_usec, whole us per frame inline
        sitl = self.sitl
        raw = sitl.frame_fast(self._pk_servo_sitl, self._servo_payload(usec, pwm))
        sent = sitl.send_now(raw)
        t_sent = time.perf_counter()
        # ---- off the critical path from here
        sitl.account_sent(raw, SERVO_OUTPUT_RAW, sent)  # the send clock, the counters, the tlog
        res = control.finish()  # the law's own step to k+1, the metrics, the StepResult
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
            self._send_telemetry(att.ms, att.roll, att.p, att.r, self._servo_wire(usec, res.pwm))
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
        if self.tlog is not None:
            self.tlog.drain()  # this frame's ATTITUDE, SERVO_OUTPUT_RAW and GCS stream, stamped when they went

    def run_lockstep(self) -> int:
        opts = self.opts
        self._status_state = M.MAV_STATE_STANDBY
        now = time.perf_counter()
        self._start_announcing(now)
        last_warn = now
        silent_reported = False
        lockstep_spin = opts.lockstep_spin_s
        perf = time.perf_counter
        poll = self._poller.poll
        read = self._read_ready
        prev_pass = now
        while not self.stop_requested and not self.finished:
            self._read_unix_us = time.time_ns() // 1000  # what was in the sockets now is read in this pass
            if lockstep_spin > 0:
                # Busy-poll briefly before sleeping: the SITL's next frame usually comes within tens of us,
                # and a sleep/wake-up costs more than that on a virtual machine.  One poll(2) of both sockets
                # per turn (an empty recvfrom costs twice that, and raises); only the links it finds ready are read.
                n0 = self.sitl.rx_datagrams + self.gcs.rx_datagrams
                t_end = perf() + lockstep_spin
                while perf() < t_end:
                    ready = poll(0)
                    if ready:
                        read(ready)
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
                    # time_unix_usec: when the links were last read, so a ground station that had sent the frame's
                    # setpoint before then knows it was lost and sends it again (autopilot.schedule)
                    self.gcs.send(
                        M.MAVLink_system_time_message(self._read_unix_us, frame_ms(self.pending_frame, self.rate))
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
