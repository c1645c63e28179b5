"""The SITL's faults in flight: the schedule flown step by step (``sitl.damage``), each start and end said as a
STATUSTEXT, and a ground station's MAV_CMD_INJECT_FAILURE relayed by the autopilot.

``FaultInjection.advance(u, n)`` is the endpoint's physics advance: it cuts the n steps where a fault starts or
ends, hands the plant the new ``Effect`` there (``set_effect``) and says what changed.  Without a fault it is the
plant's own advance, called once with the same arguments: a fault-free flight flies bit for bit as before.

``command(msg)``: a COMMAND_LONG from the autopilot's SITL link (the link takes it from that peer only) addressed
to the SITL.  MAV_CMD_INJECT_FAILURE is mapped with ``autopilot.shared.servo_failures`` (the autopilot validates
with the same table), applied from the current sim time (lockstep: from the next frame), recorded with the source
"ground station" and acknowledged (COMMAND_ACK: ACCEPTED, UNSUPPORTED for other units, types, instances and
commands, DENIED for a value the plant cannot fly).  The same command again within ``DUPLICATE_WINDOW_S`` wall
seconds is a resend whose ACK was lost: acknowledged with the same result, not applied twice.
"""

from __future__ import annotations

import time

from autopilot.shared.mavlink import mavlink as M
from autopilot.shared.mavlink import vehicle_ids
from autopilot.shared.servo_failures import (
    DUPLICATE_WINDOW_S,
    MAV_CMD_INJECT_FAILURE,
    FailureDenied,
    FailureUnsupported,
    servo_failure,
    servo_instance,
)
from sitl import damage
from sitl import plant as plants


class FaultInjection:
    """The faults of one ``sitl.endpoint.Sitl`` (``sitl``: its plant, advance, link, status events, options)."""

    def __init__(self, sitl, faults=()):
        self.sitl = sitl
        opts = sitl.opts
        self.dt = 1.0 / opts.physics_rate_hz
        k0 = int(round(opts.start_time_s * opts.rate_hz))
        self.t0 = k0 / opts.rate_hz if opts.lockstep else opts.start_time_s  # sim time of physics step 0
        self.surfaces = plants.surfaces_of(opts.plant)  # a fault record names the surface it hits
        pwm2 = getattr(sitl, "pwm2", None)
        self.channels = (sitl.pwm.channel,) + ((pwm2.channel,) if pwm2 is not None else ())  # instance of each
        self.schedule = damage.Schedule(faults, self.t0, self.dt, self.surfaces) if faults else None
        self.effect = damage.NOMINAL
        self.filter = damage.InjectionFilter(DUPLICATE_WINDOW_S)
        self._refusals = None  # the plant's fault refusals (sitl.plant.fault_refusals), read on the first command
        self._sitl_id = vehicle_ids(opts.sysid)[2]

    # ---------------------------------------------------------------------------------------------- physics
    def advance(self, u: float, n: int):
        sched = self.schedule
        if sched is None:
            return self.sitl._advance_plant(u, n)
        return damage.advance_scheduled(sched, self.sitl.aircraft, self.sitl._advance_plant, u, n, self._change)

    def _change(self, step: int, changes) -> None:
        effect = self.schedule.effect(step)
        if effect != self.effect:
            self.sitl.aircraft.set_effect(effect)
            self.effect = effect
        t = self.schedule.time_of(step)
        for fault, started in changes:
            severity = M.MAV_SEVERITY_WARNING if started else M.MAV_SEVERITY_NOTICE
            self.sitl.events["faults_started" if started else "faults_ended"] += 1
            self.sitl.say(severity, damage.status_text(fault, started, t, self.schedule.surface_name(fault)))

    def records(self) -> list[dict]:
        """``summary.json`` ``faults``: every fault scheduled or injected, SI, with its source."""
        return [] if self.schedule is None else self.schedule.records(self.sitl.aircraft.steps)

    # ---------------------------------------------------------------------------------------------- ground station
    def _now_step(self, t_rx: float) -> int:
        """The physics step a fault applied now starts at: the next one to fly (lockstep: the next frame's first;
        real time: the one due at the wall time it arrived, not before the next to fly)."""
        steps = self.sitl.aircraft.steps
        wall0 = self.sitl._wall0
        if self.sitl.opts.lockstep or wall0 is None:
            return steps
        return max(steps, int((t_rx - wall0) * self.sitl.opts.physics_rate_hz))

    def command(self, msg, t_rx: float) -> None:
        ev = self.sitl.events
        if (msg.target_system, msg.target_component) != self._sitl_id:
            self.sitl.link.reject("wrong_target")
            return
        if msg.command != MAV_CMD_INJECT_FAILURE:
            ev["commands_unsupported"] += 1
            self._ack(msg, M.MAV_RESULT_UNSUPPORTED)
            return
        params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        now = time.perf_counter()
        again = self.filter.resent(params, now)
        if again is not None:
            ev["inject_failure_resent"] += 1
            self._ack(msg, again)
            return
        result = self._inject(params, t_rx)
        self.filter.remember(params, now, result)
        ev["inject_failure_accepted" if result == M.MAV_RESULT_ACCEPTED else "inject_failure_refused"] += 1
        self._ack(msg, result)

    def _refuse(self, result: int, why: str) -> int:
        """``result`` (DENIED, UNSUPPORTED), with its reason said to the ground stations as a STATUSTEXT."""
        self.sitl.say(M.MAV_SEVERITY_WARNING, f"INJECT_FAILURE refused: {why}")
        return result

    def _inject(self, params: tuple, t_rx: float) -> int:
        try:
            spec = servo_failure(
                params[0], params[1], params[2], params[4], channel=self.channels, others=(params[3], *params[5:])
            )
            index = servo_instance(params[2], self.channels)  # None: all the surfaces (instance 0)
        except (FailureUnsupported, FailureDenied) as exc:
            return self._refuse(exc.result, str(exc))
        opts = self.sitl.opts
        if self._refusals is None:
            self._refusals = plants.fault_refusals(opts.plant)
        step = self._now_step(t_rx)
        if self.schedule is None:
            self.schedule = damage.Schedule((), self.t0, self.dt, self.surfaces)
        if spec is None:  # FAILURE_TYPE_OK: the ground station's faults on that surface (instance 0: all) end now
            self.schedule.clear(damage.GROUND_STATION, step, index)
            return M.MAV_RESULT_ACCEPTED
        try:
            kind, value = damage.parse_kind(spec, spec)
        except damage.FaultSpecError as exc:
            return self._refuse(M.MAV_RESULT_DENIED, str(exc))
        if kind in self._refusals:
            return self._refuse(M.MAV_RESULT_DENIED, f"{kind}: {self._refusals[kind]}")
        surface = damage.ALL if index is None else self.surfaces[index]
        fault = damage.Fault(kind, value, self.schedule.time_of(step), None, damage.GROUND_STATION, surface)
        why = plants.fault_value_refusal(opts.plant, fault, self.sitl.pwm.rudder_max_rad, index)
        if why is not None:
            return self._refuse(M.MAV_RESULT_DENIED, f"{fault.label}: {why}")
        self.schedule.add(fault, step)
        return M.MAV_RESULT_ACCEPTED

    def _ack(self, msg, result: int) -> None:
        self.sitl.link.send(
            M.MAVLink_command_ack_message(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        )
