"""MAV_CMD_INJECT_FAILURE, PX4's failure injection: the failures this testbed implements and what their values mean.

This is the one table that both processes import: the autopilot checks a ground station's command against it before
relaying the command to the SITL, and the SITL applies the failure it names (docs/design.md, "Faults from a ground
station").  A COMMAND_LONG carries the failure unit in param1, the FAILURE_TYPE in param2 and the instance in param3;
MAVSDK's Failure plugin sends exactly these three, with NaN in param4..7.  Our extension is param5, a value:

* FAILURE_TYPE_STUCK: the surface jams at param5 deg if that is finite and not 0, else where it is now;
* FAILURE_TYPE_SLOW: the actuator slews at most param5 deg/s (20 when 0 or NaN);
* FAILURE_TYPE_DELAYED: param5 s of extra actuator delay (0.1 when 0 or NaN);
* FAILURE_TYPE_OFF: the surface floats to neutral and has no authority; FAILURE_TYPE_OK clears the surface's faults.

Only FAILURE_UNIT_SYSTEM_SERVO with instance 0 (every servo) or the rudder's SERVO_OUTPUT_RAW channel (default 4) is
implemented; anything else is MAV_RESULT_UNSUPPORTED, a value out of range MAV_RESULT_DENIED (:func:`decode`).
No I/O here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from autopilot.shared.mavlink import mavlink as M

INJECT_FAILURE = M.MAV_CMD_INJECT_FAILURE  # 420
UNIT_SERVO = M.FAILURE_UNIT_SYSTEM_SERVO  # 102
# FAILURE_TYPE_* -> the kind of surface fault (the names of the SITL's --fault kinds; "clear" ends the faults)
KINDS = {
    M.FAILURE_TYPE_OK: "clear",
    M.FAILURE_TYPE_OFF: "off",
    M.FAILURE_TYPE_STUCK: "stuck",
    M.FAILURE_TYPE_SLOW: "rate",
    M.FAILURE_TYPE_DELAYED: "delay",
}
DEFAULT_RATE_DEG_S = 20.0  # SLOW without a value (the 20 deg/s servo rate limit of issue 29's check)
DEFAULT_DELAY_S = 0.1  # DELAYED without a value
MAX_DELAY_S = 1.0  # DELAYED: the most extra delay a ground station may ask for (ten times the study's 100 ms)
MAX_STUCK_DEG = 90.0  # STUCK: the farthest position one may name (a surface's own stops limit it further)


class Refused(ValueError):
    """A command the table refuses: ``result`` is the MAV_RESULT to answer with, the message says why."""

    def __init__(self, result: int, why: str):
        super().__init__(why)
        self.result = result


@dataclass(frozen=True)
class Injection:
    """One failure a ground station asked for: ``kind`` (a value of :data:`KINDS`) and ``value`` in SI units (stuck:
    the position in rad, None = where it is; rate: rad/s; delay: s; clear and off: None)."""

    kind: str
    value: float | None = None

    def describe(self) -> str:
        """In a user's units: ``stuck at 5 deg``, ``stuck where it is``, ``rate 20 deg/s``, ``delay 0.1 s``."""
        if self.kind == "stuck":
            return "stuck where it is" if self.value is None else f"stuck at {math.degrees(self.value):g} deg"
        if self.kind == "rate":
            return f"rate {math.degrees(self.value):g} deg/s"
        if self.kind == "delay":
            return f"delay {self.value:g} s"
        return self.kind


def _whole(v: float, name: str) -> int:
    if not (math.isfinite(v) and v == int(v)):
        raise Refused(M.MAV_RESULT_DENIED, f"{name} must be a whole number, got {v!r}")
    return int(v)


def _value(v: float) -> float | None:
    """param5: None when it is NaN or 0 (the default), else the number (may be Inf: the caller's range refuses it)."""
    return None if (v != v or v == 0.0) else float(v)


def decode(param1: float, param2: float, param3: float, param5: float, channel: int = 4) -> Injection:
    """The failure of a COMMAND_LONG MAV_CMD_INJECT_FAILURE (param1 unit, param2 type, param3 instance, param5 our
    value; ``channel``: the rudder's SERVO_OUTPUT_RAW channel).  Raises :class:`Refused` with MAV_RESULT_UNSUPPORTED
    for a unit, type or instance not implemented and MAV_RESULT_DENIED for a value out of range."""
    unit = _whole(param1, "param1 (failure unit)")
    kind_id = _whole(param2, "param2 (failure type)")
    instance = _whole(param3, "param3 (instance)")
    if unit != UNIT_SERVO:
        raise Refused(M.MAV_RESULT_UNSUPPORTED, f"failure unit {unit} not implemented (only {UNIT_SERVO}, servo)")
    kind = KINDS.get(kind_id)
    if kind is None:
        names = ", ".join(f"{k} {v}" for k, v in KINDS.items())
        raise Refused(M.MAV_RESULT_UNSUPPORTED, f"servo failure type {kind_id} not implemented (only {names})")
    if instance not in (0, channel):
        raise Refused(
            M.MAV_RESULT_UNSUPPORTED, f"servo instance {instance}: only 0 (all) or {channel} (the rudder) exists"
        )
    v = _value(param5)
    if kind == "stuck":
        if v is not None and not abs(v) <= MAX_STUCK_DEG:
            raise Refused(M.MAV_RESULT_DENIED, f"stuck position must be within +-{MAX_STUCK_DEG:g} deg, got {v!r}")
        return Injection(kind, None if v is None else math.radians(v))
    if kind == "rate":
        rate = DEFAULT_RATE_DEG_S if v is None else v
        if not (math.isfinite(rate) and rate > 0):
            raise Refused(M.MAV_RESULT_DENIED, f"servo rate must be > 0 deg/s and finite, got {v!r}")
        return Injection(kind, math.radians(rate))
    if kind == "delay":
        delay = DEFAULT_DELAY_S if v is None else v
        if not 0 < delay <= MAX_DELAY_S:
            raise Refused(M.MAV_RESULT_DENIED, f"servo delay must be in (0, {MAX_DELAY_S:g}] s, got {v!r}")
        return Injection(kind, delay)
    return Injection(kind)
