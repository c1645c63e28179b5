"""MAV_CMD_INJECT_FAILURE from a ground station, the way PX4 takes it (docs/spec.md, "Faults from a ground station").

:class:`FailureRelay` is a part of the vehicle (``autopilot.vehicle``).  A ground station's COMMAND_LONG is refused
with MAV_RESULT_DENIED unless failure injection is on (``--failure-injection``, or the parameter SYS_FAILURE_EN = 1),
but for a clear (FAILURE_TYPE_OK), which is taken either way: a station can always end the faults it gave.  The
instance names a surface by its SERVO_OUTPUT_RAW channel (a square MIMO plant's two: ``pwm`` and ``pwm2``), 0 all;
on a signed GCS link only a station with the vehicle's key gets this far (the link drops every other packet before it
is decoded).  The failure is checked against the table both processes share (``autopilot.shared.servo_failures``):
what is not implemented is answered MAV_RESULT_UNSUPPORTED, a value out of range MAV_RESULT_DENIED.  An implemented
one is relayed to the SITL over the autopilot's own (signed) SITL link as the same COMMAND_LONG from N:140, and the
ground station gets the SITL's answer (COMMAND_ACK ACCEPTED, UNSUPPORTED or DENIED), or MAV_RESULT_FAILED if the
SITL answered none of ``TRIES`` sends ``RESEND_S`` apart.

Nothing here waits: the command in flight is state, resent and timed out by the loop's housekeeping
(:meth:`FailureRelay.housekeeping`), so the control loop never blocks on it.  A command sent again by the same
station (a lost COMMAND_ACK: MAVSDK resends every 0.5 s, with confirmation 0) is never injected twice: while it is in
flight the copy is ignored (the SITL's answer goes to the station), and within ``DUPLICATE_S`` of the answer it gets
the same answer again.  The relay's resends count confirmation up (0, 1, 2), as the MAVLink command protocol does.
"""

from __future__ import annotations

from dataclasses import dataclass

from autopilot.shared import servo_failures as sf
from autopilot.shared.mavlink import mavlink as M
from autopilot.shared.mavlink import vehicle_ids

RESEND_S = 0.2  # wall seconds between relays of one command to the SITL
TRIES = 3  # relays before the ground station is answered MAV_RESULT_FAILED
DUPLICATE_S = 2.0  # the same command from the same station this soon after its answer is a resend (MAVSDK: 1.5 s)
_RESULTS = M.enums["MAV_RESULT"]
_UNITS = {"stuck": "deg", "rate": "deg/s", "delay": "s"}  # of a --fault spec's value (sitl.damage)


def result_name(result: int) -> str:
    """``ACCEPTED`` for MAV_RESULT_ACCEPTED, etc.; the number for one the dialect does not know."""
    e = _RESULTS.get(result)
    return e.name.removeprefix("MAV_RESULT_") if e is not None else str(result)


def describe(spec: str | None) -> str:
    """A fault spec of the table in a user's words: ``stuck``, ``stuck=5 deg``, ``rate=20 deg/s``, ``cleared``."""
    if spec is None:
        return "cleared"
    kind, _, value = spec.partition("=")
    return f"{kind}={float(value):g} {_UNITS.get(kind, '')}".rstrip() if value else kind


@dataclass
class _Command:
    """A ground station's INJECT_FAILURE: who sent it (sysid, compid), its seven params, the fault it names (a
    ``--fault`` spec without its time, None: clear the ground station's faults)."""

    src: tuple[int, int]
    params: tuple[float, ...]
    spec: str | None
    t_sim: float | None  # sim time when it came (s), None before the first attitude
    tries: int = 0
    next_try: float = 0.0
    answered: float = 0.0  # wall time of the answer
    result: int = M.MAV_RESULT_FAILED

    @property
    def key(self) -> tuple:
        return (self.src, tuple(repr(float(p)) for p in self.params))  # repr: NaN equals NaN here


class FailureRelay:
    """The ground-station side of failure injection for the autopilot ``ap`` (an ``autopilot.loop.Autopilot``):
    ``command(msg, now)`` for each COMMAND_LONG MAV_CMD_INJECT_FAILURE (its MAV_RESULT now, or None: answered later),
    ``on_ack(msg, now)`` for each COMMAND_ACK from the SITL, ``housekeeping(now)`` once a loop turn (``now``: wall
    clock, ``time.perf_counter``).  ``records``: every command relayed, with its answer (the autopilot's stats)."""

    def __init__(self, ap):
        self.ap = ap
        self.target = vehicle_ids(ap.opts.sysid)[2]  # the SITL, N:200
        pwm2 = getattr(ap, "pwm2", None)  # a square MIMO plant's second surface: its own instance
        self.channels = (ap.pwm.channel,) + ((pwm2.channel,) if pwm2 is not None else ())
        self.pending: _Command | None = None
        self.last: _Command | None = None
        self.records: list[dict] = []

    @property
    def enabled(self) -> bool:
        return self.ap.params.option("failure_injection") == 1.0

    # ------------------------------------------------------------------ from the ground station
    def command(self, msg, now: float) -> int | None:
        ap = self.ap
        params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        cmd = _Command((msg.get_srcSystem(), msg.get_srcComponent()), params, None, _sim_s(ap))
        who = f"GCS {cmd.src[0]}:{cmd.src[1]}"
        if self.pending is not None and self.pending.key == cmd.key:
            ap.events["failure_duplicates"] += 1  # in flight: the SITL's answer goes to the station
            return None
        last = self.last
        if last is not None and last.key == cmd.key and now - last.answered < DUPLICATE_S:
            ap.events["failure_duplicates"] += 1  # its answer was lost: the same answer, not a second injection
            return last.result
        if not self.enabled and not sf.is_clear(msg.param1, msg.param2):  # a clear is taken either way
            ap.events["failure_refused"] += 1
            ap._event(
                M.MAV_SEVERITY_WARNING,
                f"INJECT_FAILURE from {who} refused: failure injection is off (SYS_FAILURE_EN 0; --failure-injection)",
            )
            return M.MAV_RESULT_DENIED
        try:
            cmd.spec = sf.servo_failure(
                msg.param1,
                msg.param2,
                msg.param3,
                msg.param5,
                self.channels,
                others=(msg.param4, msg.param6, msg.param7),
            )
        except (sf.FailureUnsupported, sf.FailureDenied) as exc:
            ap.events["failure_refused"] += 1
            ap._event(M.MAV_SEVERITY_WARNING, f"INJECT_FAILURE from {who} refused: {exc}")
            return exc.result
        if self.pending is not None:
            ap.events["failure_refused"] += 1
            return M.MAV_RESULT_TEMPORARILY_REJECTED  # one at a time: the one in flight is answered first
        self.pending = cmd
        self._relay(now)
        return None

    # ------------------------------------------------------------------ to and from the SITL
    def _relay(self, now: float) -> None:
        cmd = self.pending
        p = cmd.params
        self.ap.sitl.send(M.MAVLink_command_long_message(*self.target, sf.MAV_CMD_INJECT_FAILURE, cmd.tries, *p))
        cmd.tries += 1
        cmd.next_try = now + RESEND_S
        self.ap.events["failure_relays"] += 1

    def on_ack(self, msg, now: float) -> None:
        """A COMMAND_ACK on the SITL link: the answer to the command in flight, if it is one."""
        if msg.command != sf.MAV_CMD_INJECT_FAILURE or self.pending is None or msg.result == M.MAV_RESULT_IN_PROGRESS:
            self.ap.events["sitl_acks_unmatched"] += 1  # e.g. the answer to a resend, after the first one's
            return
        self._answer(msg.result, now)

    def housekeeping(self, now: float) -> None:
        cmd = self.pending
        if cmd is None or now < cmd.next_try:
            return
        if cmd.tries < TRIES:
            self._relay(now)
        else:
            self._answer(M.MAV_RESULT_FAILED, now)

    def _answer(self, result: int, now: float) -> None:
        ap = self.ap
        cmd, self.pending = self.pending, None
        cmd.result, cmd.answered = result, now
        self.last = cmd
        src = cmd.src
        ap.vehicle.reply(M.MAVLink_command_ack_message(sf.MAV_CMD_INJECT_FAILURE, result, 0, 0, *src))
        what = f"servo {describe(cmd.spec)}"
        who = f"GCS {src[0]}:{src[1]}"
        when = "" if cmd.t_sim is None else f" at {cmd.t_sim:.2f} s"
        if result == M.MAV_RESULT_ACCEPTED:
            ap.events["failures_injected"] += 1
            text = f"failure injected by {who}{when}: {what}" if cmd.spec is not None else None
            ap._event(M.MAV_SEVERITY_NOTICE, text or f"servo faults cleared by {who}{when}")
        elif result == M.MAV_RESULT_FAILED:
            ap.events["failure_unanswered"] += 1
            ap._event(M.MAV_SEVERITY_WARNING, f"INJECT_FAILURE from {who} ({what}): the SITL did not answer")
        else:
            ap.events["failure_refused"] += 1
            ap._event(
                M.MAV_SEVERITY_WARNING, f"INJECT_FAILURE from {who} ({what}) refused by the SITL: {result_name(result)}"
            )
        self.records.append(
            {
                "t_s": cmd.t_sim,  # sim time when the command came (the SITL's fault says when it started)
                "from": f"{src[0]}:{src[1]}",
                "fault": cmd.spec or "clear",
                "result": result_name(result),
                "relays": cmd.tries,
            }
        )


def _sim_s(ap) -> float | None:
    us = ap._now_sim_us()
    return None if us is None else us * 1e-6
