"""A ground station's servo failure (MAV_CMD_INJECT_FAILURE, PX4's failure injection) as a fault spec: one table.

MAVLink common.xml, MAV_CMD_INJECT_FAILURE (420): param1 the unit (``FAILURE_UNIT``), param2 the type
(``FAILURE_TYPE``), param3 the instance (0 = all).  For the servo unit (FAILURE_UNIT_SYSTEM_SERVO, 102) the product
takes these types, each mapped to a fault of the SITL's ``--fault`` syntax (``sitl.damage``; docs/faults.md):

| FAILURE_TYPE | fault | param5 |
|---|---|---|
| OK (0) | every ground-station fault cleared | - |
| OFF (1) | ``off`` | - |
| STUCK (2) | ``stuck`` (where it is), or ``stuck=DEG`` | deg within +-``LIMITS["stuck"]``; 0 or NaN: where it is |
| SLOW (5) | ``rate=DEG_PER_S`` | deg/s in (0, ``LIMITS["rate"]``]; 0 or NaN: ``DEFAULT_RATE_DEG_S`` |
| DELAYED (6) | ``delay=S`` | s in (0, ``LIMITS["delay"]``]; 0 or NaN: ``DEFAULT_DELAY_S`` |

The instance is 0 (all the vehicle's surfaces) or a surface's SERVO_OUTPUT_RAW channel (4 by default,
``--rudder-channel``; a square MIMO plant's second surface on ``--channel2``: ``servo_instance``); any other
instance, any other unit or type is MAV_RESULT_UNSUPPORTED (:class:`FailureUnsupported`); a param5 that is not a
usable value (a negative rate, an infinite delay, a position beyond any surface's travel) is MAV_RESULT_DENIED
(:class:`FailureDenied`).  NaN is MAVLink's "not used" (MAVSDK's Failure plugin sends it), 0 the same; an infinite
value is no value and is DENIED.  The SITL then holds the value to its plant's own bounds (the surface's travel:
``sitl.plant.check_faults``).  The same bounds hold on the command line (the fault kinds' records,
``sitl.fault_kinds``, read ``LIMITS``).  Pure: the autopilot validates with this table before it relays the
command, the SITL maps with it when it applies it, neither imports the other.
"""

from __future__ import annotations

import math

from autopilot.shared.mavlink import mavlink as M

MAV_CMD_INJECT_FAILURE = M.MAV_CMD_INJECT_FAILURE  # 420
FAILURE_UNIT_SYSTEM_SERVO = M.FAILURE_UNIT_SYSTEM_SERVO  # 102
FAILURE_TYPE_OK = M.FAILURE_TYPE_OK  # 0
FAILURE_TYPE_OFF = M.FAILURE_TYPE_OFF  # 1
FAILURE_TYPE_STUCK = M.FAILURE_TYPE_STUCK  # 2
FAILURE_TYPE_SLOW = M.FAILURE_TYPE_SLOW  # 5
FAILURE_TYPE_DELAYED = M.FAILURE_TYPE_DELAYED  # 6
SERVO_TYPES = (FAILURE_TYPE_OK, FAILURE_TYPE_OFF, FAILURE_TYPE_STUCK, FAILURE_TYPE_SLOW, FAILURE_TYPE_DELAYED)
DEFAULT_RATE_DEG_S = 20.0  # SLOW without a rate (param5 0 or NaN)
DEFAULT_DELAY_S = 0.1  # DELAYED without a delay (param5 0 or NaN)
# The largest value of each servo fault, the same for a ground station and on the command line (sitl.damage): a
# stuck position (deg; no surface travels further, a plant's own travel is narrower), a rate limit (deg/s), an
# extra actuator delay (s): each servo kind's ``bound`` in ``sitl.fault_kinds.KINDS``.
LIMITS = {"stuck": 90.0, "rate": 1000.0, "delay": 10.0}
MAX_DELAY_S = LIMITS["delay"]  # a longer extra actuator delay is refused (DENIED)
# The SITL's STATUSTEXT when a fault starts or ends begins with this (``FAULT_PREFIX + "start: ..."``): the
# autopilot's telemetry marks its plots when it relays one (``SITL: fault ...``).
FAULT_PREFIX = "fault "
# The same COMMAND_LONG again within this many wall seconds is a resend (its ACK was lost), not a new fault.
DUPLICATE_WINDOW_S = 1.0


class FailureUnsupported(ValueError):
    """Not a failure this vehicle implements (unit, type or instance): MAV_RESULT_UNSUPPORTED."""

    result = M.MAV_RESULT_UNSUPPORTED


class FailureDenied(ValueError):
    """A servo failure this vehicle implements, with a value it cannot fly (param5): MAV_RESULT_DENIED."""

    result = M.MAV_RESULT_DENIED


def _given(v: float) -> bool:
    """param5 carries a value: not 0 and not NaN (MAVLink's "not used" spellings)."""
    return not (v == 0.0 or math.isnan(v))


def _nan_unset(param5: float, others) -> None:
    """A NaN param5 means "not used" only from a sender that left every unused param unset, as MAVSDK does (NaN in
    params 4 to 7: MAVLink's "optional/default value"); beside a number in param 4, 6 or 7 it is a value, and NaN is
    no position, rate or delay: FailureDenied.  ``others``: params 4, 6 and 7 (None: not known, NaN taken as unset)."""
    if others is None or not math.isnan(param5):
        return
    if not all(isinstance(v, float) and math.isnan(v) for v in others):
        raise FailureDenied(
            "param5 is NaN while params 4, 6 and 7 are set: give a finite value, or leave params 4 to 7 all unset "
            "(NaN) for the default"
        )


def is_clear(unit: float, failure_type: float) -> bool:
    """A servo FAILURE_TYPE_OK: the ground station's faults end (taken whether injection is on or off)."""
    return unit == FAILURE_UNIT_SYSTEM_SERVO and failure_type == FAILURE_TYPE_OK


def servo_instance(instance: float, channels) -> int | None:
    """Which surface an instance names: None for 0 (all of them), else the index of its channel in ``channels`` (the
    surfaces' SERVO_OUTPUT_RAW channels, in the plant's order; an int: one surface).  FailureUnsupported for any
    other instance."""
    chans = (int(channels),) if isinstance(channels, int) else tuple(int(c) for c in channels)
    if instance == 0:
        return None
    if instance in chans:
        return chans.index(int(instance))
    ok = " or ".join(str(c) for c in chans)
    one = "one surface" if len(chans) == 1 else f"{len(chans)} surfaces"
    raise FailureUnsupported(f"servo instance {instance:g}: the vehicle has {one}, instance 0 (all) or {ok}")


def servo_failure(
    unit: float, failure_type: float, instance: float, param5: float, channel=4, others=None
) -> str | None:
    """The ``--fault`` spec (``KIND[=VALUE]``, without ``@START``: the fault starts when it is applied) of a
    MAV_CMD_INJECT_FAILURE's params, or None for FAILURE_TYPE_OK (clear the ground-station faults).

    ``channel``: the surface's SERVO_OUTPUT_RAW channel, or a tuple of each surface's (``servo_instance``);
    ``others``: params 4, 6 and 7, which say whether a NaN param5 is "unset" (``_nan_unset``).  Raises
    FailureUnsupported (unit, type, instance) or FailureDenied (param5)."""
    if unit != FAILURE_UNIT_SYSTEM_SERVO:
        raise FailureUnsupported(f"failure unit {unit:g} is not implemented (only FAILURE_UNIT_SYSTEM_SERVO, 102)")
    if failure_type not in SERVO_TYPES:
        raise FailureUnsupported(
            f"failure type {failure_type:g} is not implemented for the servo (OK 0, OFF 1, STUCK 2, SLOW 5, DELAYED 6)"
        )
    servo_instance(instance, channel)
    if failure_type == FAILURE_TYPE_OK:
        return None
    if failure_type == FAILURE_TYPE_OFF:
        return "off"
    _nan_unset(float(param5), others)
    if failure_type == FAILURE_TYPE_STUCK:
        if not _given(param5):
            return "stuck"
        most = LIMITS["stuck"]
        if not (math.isfinite(param5) and abs(param5) <= most):
            raise FailureDenied(f"STUCK: the position (param5) must be within +-{most:g} deg, got {param5!r}")
        return f"stuck={param5!r}"
    if failure_type == FAILURE_TYPE_SLOW:
        rate = param5 if _given(param5) else DEFAULT_RATE_DEG_S
        most = LIMITS["rate"]
        if not (math.isfinite(rate) and 0 < rate <= most):
            raise FailureDenied(f"SLOW: the rate (param5) must be in (0, {most:g}] deg/s, got {param5!r}")
        return f"rate={rate!r}"
    delay = param5 if _given(param5) else DEFAULT_DELAY_S
    if not (math.isfinite(delay) and 0 < delay <= MAX_DELAY_S):
        raise FailureDenied(f"DELAYED: the delay (param5) must be in (0, {MAX_DELAY_S:g}] s, got {param5!r}")
    return f"delay={delay!r}"


__all__ = [
    "DEFAULT_DELAY_S",
    "DEFAULT_RATE_DEG_S",
    "DUPLICATE_WINDOW_S",
    "FAILURE_UNIT_SYSTEM_SERVO",
    "FAULT_PREFIX",
    "FailureDenied",
    "FailureUnsupported",
    "LIMITS",
    "MAV_CMD_INJECT_FAILURE",
    "is_clear",
    "servo_failure",
    "servo_instance",
]
