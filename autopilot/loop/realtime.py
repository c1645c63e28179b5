"""The real-time scheduler (``RealtimeScheduler``, the object ``autopilot.loop.Autopilot`` holds as its ``scheduler``
in real time): deadlines on a fixed grid, the newest attitude, the attitude and setpoint failsafes.  The autopilot
owns the flight's state; the scheduler drives it.
"""

from __future__ import annotations

import math
import time

from autopilot.loop.common import _SPIN_TIGHT_S, SERVO_OUTPUT_RAW, M, StepRecord, _wall_usec
from autopilot.step import Failsafe


class RealtimeScheduler:
    """Real time: one control step of the autopilot ``ap`` per period on a fixed grid of deadlines (docs/spec.md,
    "Real time")."""

    def __init__(self, ap) -> None:
        self.ap = ap

    def run(self) -> int:
        """The real-time loop: wait for each deadline, fly the step on the newest attitude (or hold), until the
        run's duration or a stop."""
        ap = self.ap
        opts = ap.opts
        period = ap.period
        spin = opts.spin_s
        spin_tight = min(spin, _SPIN_TIGHT_S)
        perf = time.perf_counter
        n_steps = round(opts.duration_s * ap.rate) if opts.duration_s > 0 else 0
        start = perf()
        ap._start_announcing(start)
        ap.last_setpoint_wall = start  # the setpoint timeout counts from start-up
        deadline = start + period
        prev_wake = None
        att = ap.att
        control = ap.control
        timing = ap.timing
        sitl = ap.sitl
        pk_servo = ap._pk_servo_sitl
        sitl_handler = ap._sitl_handler
        while not ap.stop_requested:
            # ---- wait for the deadline: sleep in select while far, then spin (serving the links until the
            # last few tens of us). With spin >= period (--busy-wait) it never sleeps: the CPU never idles.
            while True:
                rem = deadline - perf()
                if rem <= spin_tight:
                    break
                if rem <= spin:
                    ap._wait(0.0)
                else:
                    ap._wait(rem - spin)
            while perf() < deadline:
                pass
            t_wake = perf()
            sitl.poll(sitl_handler)  # an attitude that came in during the spin is the freshest one
            # ---- the step (critical path: attitude -> controller -> servo out)
            age = t_wake - att.t_rx if att.valid else math.inf
            if age > opts.attitude_timeout_s:  # CLSAC_FS_ATT_TMO may change in flight
                # No (fresh) attitude: rudder neutral, PFC follows it, adaptation frozen.
                res = control.hold(att.ms * 1e-3, att.roll, ap.failsafe if att.valid else Failsafe.NONE)
                wire = ap._servo_wire(_wall_usec(), res.pwm)
                sitl.send_raw(sitl.pack_fast(pk_servo, *wire), SERVO_OUTPUT_RAW)
                t_sent = perf()
                if att.valid:  # before the first attitude ever it is stand-by, not a failsafe
                    ap.failsafe_steps += 1
                    ap.hold_steps += 1
                    if ap.failsafe is Failsafe.NONE:
                        ap.failsafe = res.failsafe = Failsafe.NO_ATTITUDE
                        ap._enter_failsafe(age)
            else:
                if ap.failsafe is not Failsafe.NONE:
                    ap._leave_failsafe()
                elif ap._status_state == M.MAV_STATE_STANDBY:
                    ap._status_state = M.MAV_STATE_ACTIVE
                lost = t_wake - ap.last_setpoint_wall > opts.setpoint_timeout_s
                if lost != ap.setpoint_lost:
                    ap._setpoint_stream(lost)
                if ap.setpoints2 is not None:  # MIMO: the sideslip command in force (0 with the setpoints lost)
                    ap.ctrl.um2 = 0.0 if lost else ap.setpoints2.at(att.ms * 1e-3)
                res = control(att.ms * 1e-3, att.roll, wings_level=lost, p=att.p, r=att.r)
                wire = ap._servo_wire(_wall_usec(), res.pwm)
                sitl.send_raw(sitl.pack_fast(pk_servo, *wire), SERVO_OUTPUT_RAW)
                t_sent = perf()
            # ---- bookkeeping, outside the critical path
            ap.steps += 1
            if ap.t_first_step is None:
                ap.t_first_step = t_wake
            ap.t_last_step = t_wake
            slot_end = deadline + period
            missed = t_sent > slot_end
            lateness = t_wake - deadline
            per = None if prev_wake is None else t_wake - prev_wake
            late = max(lateness, 0.0 if per is None else per - period)
            if late > opts.attitude_timeout_s:  # flown too late to count as flown (the verdict's "late")
                ap.late_steps += 1
            if late > ap.max_lateness_s:
                ap.max_lateness_s = late
            prev_wake = t_wake
            latency = (t_sent - att.t_rx) if att.valid else None
            timing.add(per, lateness, t_sent - t_wake, latency)
            tel_every = ap._telemetry_every  # SET_MESSAGE_INTERVAL / REQUEST_DATA_STREAM may change it
            if tel_every and ap.steps % tel_every == 1 % tel_every:
                ap._send_telemetry(att.ms if att.valid else 0, att.roll, att.p, att.r, wire)
            ap.vehicle.on_step(ap.steps, att.ms if att.valid else 0)
            if ap.hooks:
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
                    ctrl=ap.ctrl,
                    ap=ap,
                )
                for h in ap.hooks:
                    h(rec)
            if att.valid:  # standby before the first attitude is not flight
                ap._judge_envelope(res)
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
            ap._housekeeping(now)
            if n_steps and ap.steps >= n_steps:
                ap.exit_reason = "end of run (duration reached)"
                break
        if ap.stop_requested:
            ap.exit_reason = ap.exit_reason or "stopped by signal"
        return 0
