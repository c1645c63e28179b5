"""The lockstep scheduler (``LockstepScheduler``, the object ``autopilot.loop.Autopilot`` holds as its ``scheduler``
in lockstep): frame k of the SITL is answered with the command of control step k, with pacing on the ground
station's schedule.  The autopilot owns the flight's state (links, control step, counters, frames); the scheduler
drives it and keeps only its own pacing bookkeeping.
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
    """Lockstep: one control step of the autopilot ``ap`` per SITL frame, answered at once (docs/spec.md,
    "Lockstep").  ``on_frame`` takes a frame's attitude, ``try_step`` flies the pending frame when the ground
    station's schedule allows, ``run`` is the loop."""

    def __init__(self, ap) -> None:
        self.ap = ap
        rate = ap.rate
        self._steps_to_fly = round(ap.opts.duration_s * rate) if ap.opts.duration_s > 0 else 0  # 0 = until stopped
        # frame_from_ms and frame_usec (autopilot.shared.mavlink) inline for an integer rate: its ms and us per frame
        self._irate = int(rate) if rate.is_integer() else 0
        self._usec_per_frame = 1_000_000 // self._irate if self._irate and 1_000_000 % self._irate == 0 else 0
        self._last_answer = b""  # the last frame's SERVO_OUTPUT_RAW, resent for its duplicate
        self.pending_t_rx = 0.0
        self._next_systime = 0.0
        self._read_unix_us = 0  # wall time (Unix us) of the last read of the links (SYSTEM_TIME says it)

    def on_frame(self, ms: int, t_rx: float, roll: float, p: float, r: float):
        """One lockstep frame.  The SITL sends frames one after the other, so only the next one is taken: one
        late, repeated or forged frame index can neither skip frames nor end the run."""
        ap = self.ap
        irate = self._irate
        k = -((-ms * irate) // 1000) if irate else frame_from_ms(ms, ap.rate)  # frame_from_ms, inline if integer
        last = ap.last_frame
        pending = ap.pending_frame
        if last is not None and k == last:
            # Duplicate of the frame we answered (our answer was lost or late): resend it, do not step.
            ap.events["duplicate_frames"] += 1
            ap.sitl.resend(self._last_answer, SERVO_OUTPUT_RAW)  # re-signed: not a replay
            return
        if pending is not None and k == pending:
            ap.events["duplicate_pending_frames"] += 1
            return
        expected = pending if pending is not None else (None if last is None else last + 1)
        if expected is not None and k != expected:
            ap.sitl.reject("stale_frame" if k < expected else "future_frame")
            return
        if ap.first_frame is None:
            ap.first_frame = k
        att = ap.att
        att.ms, att.roll, att.p, att.r, att.t_rx, att.valid = ms, roll, p, r, t_rx, True
        ap.pending_frame = k
        self.pending_t_rx = t_rx
        self.try_step(t_rx)

    def try_step(self, t_ready: float):
        """Fly the pending frame, unless the ground station's schedule does not reach it yet (pacing) or the run
        has flown its frames."""
        ap = self.ap
        k = ap.pending_frame
        t_us = k * 1e6 / ap.rate
        opts = ap.opts
        if self._steps_to_fly and ap.steps >= self._steps_to_fly:
            # The frame after the last step is the SITL's end-of-run frame (t = t0 + duration): not a control
            # step.  The run ends by the count of frames flown, never by one frame's index.
            ap.pending_frame = None
            ap.finished = True
            return
        if opts.pace and ap.horizon_us + 1e-3 < t_us:
            if ap._blocked_since is None:
                ap._blocked_since = t_ready
                ap.events["horizon_waits"] += 1
            return
        ap._blocked_since = None
        ap.pending_frame = None
        # The critical path, which the SITL waits for: the law, encode, sign, send.  Everything after the send
        # (timing, telemetry, the gains stream, hooks, the envelope, the tlog's queue) is done while the SITL
        # computes the next frame (docs/spec.md, "Lockstep").
        t0 = time.perf_counter()
        att = ap.att
        control = ap.control
        if ap.setpoints2 is not None:  # MIMO: the sideslip command in force
            ap.ctrl.um2 = ap.setpoints2.at(k / ap.rate)
        pwm = control.command(k / ap.rate, att.roll, p=att.p, r=att.r)  # the pulse width that flies (autopilot.step)
        us = self._usec_per_frame
        usec = (k * us) & 0xFFFFFFFF if us else frame_usec(k, ap.rate)  # frame_usec, whole us per frame inline
        sitl = ap.sitl
        raw = sitl.frame_fast(ap._pk_servo_sitl, ap._servo_payload(usec, pwm))
        sent = sitl.send_now(raw)
        t_sent = time.perf_counter()
        # ---- off the critical path from here
        sitl.account_sent(raw, SERVO_OUTPUT_RAW, sent)  # the send clock, the counters, the tlog
        res = control.finish()  # the law's own step to k+1, the metrics, the StepResult
        self._last_answer = raw
        ap.last_frame = k
        prev = ap.t_last_step
        ap.t_last_step = t0
        if ap.t_first_step is None:
            ap.t_first_step = t0
        latency = t_sent - max(t_ready, self.pending_t_rx)
        ap.timing.add(None, None, t_sent - t0, latency)
        ap.steps += 1
        if ap._telemetry_every and ap.steps % ap._telemetry_every == 1 % ap._telemetry_every:
            ap._send_telemetry(att.ms, att.roll, att.p, att.r, ap._servo_wire(usec, res.pwm))
        ap.vehicle.on_step(ap.steps, att.ms)
        if ap.hooks:
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
                ctrl=ap.ctrl,
                ap=ap,
            )
            for h in ap.hooks:
                h(rec)
        ap._judge_envelope(res)
        if ap.tlog is not None:
            ap.tlog.drain()  # this frame's ATTITUDE, SERVO_OUTPUT_RAW and GCS stream, stamped when they went

    def run(self) -> int:
        """The lockstep loop: read the links, fly each frame as it comes, until the run's frames are flown, a stop,
        or the SITL's silence."""
        ap = self.ap
        opts = ap.opts
        ap._status_state = M.MAV_STATE_STANDBY
        now = time.perf_counter()
        ap._start_announcing(now)
        last_warn = now
        silent_reported = False
        lockstep_spin = opts.lockstep_spin_s
        perf = time.perf_counter
        poll = ap._poller.poll
        read = ap._read_ready
        prev_pass = now
        while not ap.stop_requested and not ap.finished:
            self._read_unix_us = time.time_ns() // 1000  # what was in the sockets now is read in this pass
            if lockstep_spin > 0:
                # Busy-poll briefly before sleeping: the SITL's next frame usually comes within tens of us,
                # and a sleep/wake-up costs more than that on a virtual machine.  One poll(2) of both sockets
                # per turn (an empty recvfrom costs twice that, and raises); only the links it finds ready are read.
                n0 = ap.sitl.rx_datagrams + ap.gcs.rx_datagrams
                t_end = perf() + lockstep_spin
                while perf() < t_end:
                    ready = poll(0)
                    if ready:
                        read(ready)
                        if ap.sitl.rx_datagrams + ap.gcs.rx_datagrams != n0:
                            break
                else:
                    ap._wait(0.02)
            else:
                ap._wait(0.02)
            now = time.perf_counter()
            if ap.pending_frame is not None and ap._blocked_since is not None:
                # Waiting for the GCS schedule: tell it where sim time is (SYSTEM_TIME, 20 Hz wall clock).
                if now >= self._next_systime:
                    self._next_systime = now + 0.05
                    # time_unix_usec: when the links were last read, so a ground station that had sent the frame's
                    # setpoint before then knows it was lost and sends it again (autopilot.schedule)
                    ap.gcs.send(M.MAVLink_system_time_message(self._read_unix_us, frame_ms(ap.pending_frame, ap.rate)))
                if now - ap._blocked_since > 5.0 and now - last_warn > 5.0:
                    last_warn = now
                    print(
                        f"autopilot: lockstep frame t={ap.pending_frame / ap.rate:.3f} s waits for GCS "
                        f"setpoints (schedule horizon {ap.horizon_us * 1e-6:.3f} s); run a GCS "
                        f"(python -m tools.gcs --lockstep) or pass --no-pace",
                        file=ap.out,
                        flush=True,
                    )
            # A pass takes ~20 ms: one of a second or more means this process did not run (stopped, starved), and
            # what the SITL sent meanwhile may still wait in the socket: its silence is judged after another look.
            own_stall = now - prev_pass >= SELF_STALL_S
            prev_pass = now
            if ap.att.valid and not own_stall:
                ap._status_state = M.MAV_STATE_ACTIVE
                silent = now - ap.sitl.last_rx_wall
                if silent > 2.0 and not silent_reported and ap.pending_frame is None:
                    silent_reported = True
                    ap._event(M.MAV_SEVERITY_WARNING, f"lockstep: SITL silent for {silent:.1f} s")
                elif silent < 2.0:
                    silent_reported = False
                if (
                    opts.lockstep_idle_exit_s > 0
                    and ap.last_frame is not None
                    and ap.pending_frame is None
                    and silent > opts.lockstep_idle_exit_s
                ):
                    ap.exit_reason = f"SITL silent for {silent:.1f} s after frame {ap.last_frame}"
                    ap.peer_lost = "sitl"
                    break
            ap._housekeeping(now)
        if ap.finished:
            ap.exit_reason = "end of run (duration reached)"
        elif ap.stop_requested:
            ap.exit_reason = ap.exit_reason or "stopped by signal"
        return 0
