"""The real-time scheduler (``RealtimeScheduler``, a part of ``autopilot.loop.Autopilot``): deadlines on a fixed
grid, the newest attitude, the attitude and setpoint failsafes.
"""

from __future__ import annotations

import math
import time

from autopilot.loop.common import _SPIN_TIGHT_S, SERVO_OUTPUT_RAW, M, StepRecord, _wall_usec
from autopilot.step import Failsafe


class RealtimeScheduler:
    """Real time: one control step per period on a fixed grid of deadlines (docs/spec.md, "Real time")."""

    # ============================================================== real time
    def run_realtime(self) -> int:
        opts = self.opts
        period = self.period
        spin = opts.spin_s
        spin_tight = min(spin, _SPIN_TIGHT_S)
        perf = time.perf_counter
        n_steps = round(opts.duration_s * self.rate) if opts.duration_s > 0 else 0
        start = perf()
        self._start_announcing(start)
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
                if self.setpoints2 is not None:  # MIMO: the sideslip command in force (0 with the setpoints lost)
                    self.ctrl.um2 = 0.0 if lost else self.setpoints2.at(att.ms * 1e-3)
                res = control(att.ms * 1e-3, att.roll, wings_level=lost, p=att.p, r=att.r)
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
