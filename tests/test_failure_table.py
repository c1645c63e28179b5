"""The MAV_CMD_INJECT_FAILURE table both processes import (autopilot.shared.failure), without I/O.

The expected failures are written out from the contract (docs/design.md, "Faults from a ground station"; PX4's
FAILURE_UNIT / FAILURE_TYPE numbers from common.xml), not read from the module.
"""

from __future__ import annotations

import math

import pytest

from autopilot.shared.failure import Injection, Refused, decode
from autopilot.shared.mavlink import mavlink as M

NAN = float("nan")
SERVO = 102  # FAILURE_UNIT_SYSTEM_SERVO in common.xml
ACCEPTED_CASES = [
    # (param2 type, param3 instance, param5 value) -> (kind, value in SI)
    ((0, 0, NAN), ("clear", None)),  # FAILURE_TYPE_OK
    ((1, 4, NAN), ("off", None)),
    ((2, 4, NAN), ("stuck", None)),  # where it is
    ((2, 4, 0.0), ("stuck", None)),  # 0 is "no value" too
    ((2, 0, -7.5), ("stuck", math.radians(-7.5))),
    ((2, 4, 90.0), ("stuck", math.pi / 2)),
    ((5, 4, NAN), ("rate", math.radians(20.0))),  # FAILURE_TYPE_SLOW, the default 20 deg/s
    ((5, 4, 0.0), ("rate", math.radians(20.0))),
    ((5, 4, 60.0), ("rate", math.radians(60.0))),
    ((6, 4, NAN), ("delay", 0.1)),  # FAILURE_TYPE_DELAYED, the default 0.1 s
    ((6, 4, 0.06), ("delay", 0.06)),
    ((6, 4, 1.0), ("delay", 1.0)),
]


@pytest.mark.parametrize(("args", "expected"), ACCEPTED_CASES)
def test_each_implemented_failure_decodes_to_its_kind_and_si_value(args, expected):
    got = decode(SERVO, *args)
    kind, value = expected
    assert got.kind == kind
    assert (got.value is None) if value is None else got.value == pytest.approx(value, rel=1e-12)


@pytest.mark.parametrize(
    ("params", "result", "match"),
    [
        ((0, 2, 0, NAN), M.MAV_RESULT_UNSUPPORTED, "failure unit 0 not implemented"),  # a gyro
        ((101, 1, 0, NAN), M.MAV_RESULT_UNSUPPORTED, "failure unit 101"),  # a motor
        ((11, 2, 4, NAN), M.MAV_RESULT_UNSUPPORTED, "failure unit 11"),  # MAVSDK 3's own enum number for a servo
        ((SERVO, 3, 4, NAN), M.MAV_RESULT_UNSUPPORTED, "servo failure type 3"),  # GARBAGE
        ((SERVO, 4, 4, NAN), M.MAV_RESULT_UNSUPPORTED, "servo failure type 4"),  # WRONG
        ((SERVO, 7, 4, NAN), M.MAV_RESULT_UNSUPPORTED, "servo failure type 7"),  # INTERMITTENT
        ((SERVO, 2, 1, NAN), M.MAV_RESULT_UNSUPPORTED, "servo instance 1"),
        ((SERVO, 2, 5, NAN), M.MAV_RESULT_UNSUPPORTED, "servo instance 5"),
        ((NAN, 2, 4, NAN), M.MAV_RESULT_DENIED, "param1 .* whole number"),
        ((SERVO, 2.5, 4, NAN), M.MAV_RESULT_DENIED, "param2 .* whole number"),
        ((SERVO, 2, math.inf, NAN), M.MAV_RESULT_DENIED, "param3 .* whole number"),
        ((SERVO, 2, 4, 90.5), M.MAV_RESULT_DENIED, "stuck position must be within"),
        ((SERVO, 2, 4, -math.inf), M.MAV_RESULT_DENIED, "stuck position"),
        ((SERVO, 5, 4, -5.0), M.MAV_RESULT_DENIED, "servo rate must be > 0"),
        ((SERVO, 5, 4, math.inf), M.MAV_RESULT_DENIED, "servo rate"),
        ((SERVO, 6, 4, -0.1), M.MAV_RESULT_DENIED, "servo delay must be in"),
        ((SERVO, 6, 4, 1.5), M.MAV_RESULT_DENIED, "servo delay"),
        ((SERVO, 6, 4, math.inf), M.MAV_RESULT_DENIED, "servo delay"),
    ],
)
def test_what_is_not_implemented_is_unsupported_and_a_bad_value_denied(params, result, match):
    with pytest.raises(Refused, match=match) as exc:
        decode(*params)
    assert exc.value.result == result


def test_the_rudder_is_the_instance_of_its_channel():
    assert decode(SERVO, 2, 3, NAN, channel=3).kind == "stuck"
    with pytest.raises(Refused, match="only 0 .* or 3"):
        decode(SERVO, 2, 4, NAN, channel=3)


@pytest.mark.parametrize(
    ("injection", "text"),
    [
        (Injection("stuck"), "stuck where it is"),
        (Injection("stuck", math.radians(5.0)), "stuck at 5 deg"),
        (Injection("rate", math.radians(20.0)), "rate 20 deg/s"),
        (Injection("delay", 0.06), "delay 0.06 s"),
        (Injection("off"), "off"),
    ],
)
def test_a_failure_is_described_in_a_users_units(injection, text):
    assert injection.describe() == text
