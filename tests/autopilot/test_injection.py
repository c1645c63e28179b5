"""autopilot/injection.py, fast: the FailureRelay between a ground station's MAV_CMD_INJECT_FAILURE and the SITL.

The relay is driven as the loop drives it (``command(msg, now)``, ``on_ack(msg, now)``, ``housekeeping(now)``) with
real pymavlink messages that went through the wire format (float32 params, as a station's arrive) and the real
parameter table (SYS_FAILURE_EN); the clock is the test's, so every timing limit is checked at its exact edge.  What
it sends to the SITL and answers the station is recorded by the vehicle's two sinks (the end to end tests:
tests/autopilot/test_failure_injection.py).
"""

from __future__ import annotations

import math
from collections import Counter
from types import SimpleNamespace

import pytest

from autopilot import injection as inj
from autopilot.config import ClSacConfig
from autopilot.params import ParamTable
from autopilot.shared import servo_failures as sf
from autopilot.shared.mavlink import mavlink as M

NAN = float("nan")
OPTIONS = {"attitude_timeout_s": 0.1, "setpoint_timeout_s": 1.0, "max_roll_rad": 0.7}
STUCK, OK, OFF, SLOW = M.FAILURE_TYPE_STUCK, M.FAILURE_TYPE_OK, M.FAILURE_TYPE_OFF, M.FAILURE_TYPE_SLOW


class _Sink:
    """Where the relay's messages go (the SITL link, the vehicle's replies): each message through the wire format."""

    def __init__(self, src: tuple[int, int]):
        self.mav = M.MAVLink(None, *src)
        self.parser = M.MAVLink(None)
        self.sent: list = []

    def send(self, msg) -> None:
        self.sent.append(self.parser.decode(bytearray(msg.pack(self.mav))))

    reply = send


class _Ap:
    """The parts of ``autopilot.loop.Autopilot`` the relay reads: ids, the parameter table, the servo channels, the
    event counters and status events, the SITL link and the vehicle's replies, the sim clock."""

    def __init__(self, enabled: bool = False, channel2: int | None = None):
        self.opts = SimpleNamespace(sysid=1)
        self.params = ParamTable(ClSacConfig(), {**OPTIONS, "failure_injection": 1.0 if enabled else 0.0})
        self.pwm = SimpleNamespace(channel=4)
        self.pwm2 = None if channel2 is None else SimpleNamespace(channel=channel2)
        self.events: Counter = Counter()
        self.texts: list[str] = []
        self.sitl = _Sink((1, 140))
        self.vehicle = _Sink((1, 1))
        self.relay = inj.FailureRelay(self)

    def _event(self, _severity, text, **_kw) -> None:
        self.texts.append(text)

    def _now_sim_us(self) -> int:
        return 4_520_000

    def command(self, ftype, instance=0.0, p5=NAN, unit=sf.FAILURE_UNIT_SYSTEM_SERVO, src=(255, 230), now=0.0):
        """A station's COMMAND_LONG, through the wire, handed to the relay; its immediate answer (None: later)."""
        mav = M.MAVLink(None, *src)
        cmd = sf.MAV_CMD_INJECT_FAILURE
        raw = M.MAVLink_command_long_message(1, 1, cmd, 0, unit, ftype, instance, NAN, p5, NAN, NAN)
        return self.relay.command(M.MAVLink(None).decode(bytearray(raw.pack(mav))), now)

    def sitl_ack(self, result, now):
        self.relay.on_ack(M.MAVLink_command_ack_message(sf.MAV_CMD_INJECT_FAILURE, result, 0, 0, 1, 140), now)

    def answers(self) -> list[int]:
        return [m.result for m in self.vehicle.sent if m.get_type() == "COMMAND_ACK"]


# ---------------------------------------------------------------------------------------------- injection on or off
def test_off_refuses_a_fault_without_a_relay_but_a_clear_is_relayed():
    ap = _Ap(enabled=False)
    assert ap.command(STUCK, 4, 3.0) == M.MAV_RESULT_DENIED and ap.sitl.sent == []
    assert "failure injection is off (SYS_FAILURE_EN 0; --failure-injection)" in ap.texts[-1]
    for instance in (0, 4):  # a station can always end its own faults, on the surface or on all
        assert ap.command(OK, instance, now=10.0 * (instance + 1)) is None
        relayed = ap.sitl.sent[-1]
        assert (relayed.param1, relayed.param2, relayed.param3) == (sf.FAILURE_UNIT_SYSTEM_SERVO, OK, instance)
        ap.sitl_ack(M.MAV_RESULT_ACCEPTED, 10.0 * (instance + 1) + 0.01)
    assert ap.answers() == [M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_ACCEPTED]
    assert ap.texts[-1] == "servo faults cleared by GCS 255:230 at 4.52 s"
    # a clear of something not implemented is still refused as such: OK of another unit is no clear
    assert ap.command(OK, 0, unit=M.FAILURE_UNIT_SENSOR_GYRO, now=50.0) == M.MAV_RESULT_DENIED


def test_the_parameter_turns_it_on_and_off():
    ap = _Ap(enabled=False)
    ap.params.set("SYS_FAILURE_EN", 1.0)
    assert ap.command(STUCK, 4, 3.0) is None and len(ap.sitl.sent) == 1
    ap.sitl_ack(M.MAV_RESULT_ACCEPTED, 0.05)
    ap.params.set("SYS_FAILURE_EN", 0.0)
    assert ap.command(OFF, 4, now=5.0) == M.MAV_RESULT_DENIED and len(ap.sitl.sent) == 1


# ---------------------------------------------------------------------------------------------- the values
@pytest.mark.parametrize(
    "ftype,p5,why",
    [
        (STUCK, 1e30, "STUCK: the position (param5) must be within +-90 deg, got 1.0000000150474662e+30"),
        (STUCK, 90.5, "within +-90 deg"),
        (STUCK, -math.inf, "got -inf"),
        (STUCK, math.inf, "got inf"),
        (SLOW, -5.0, "SLOW: the rate (param5) must be in (0, 1000] deg/s"),
        (SLOW, 1000.5, "SLOW: the rate"),
        (M.FAILURE_TYPE_DELAYED, 10.5, "DELAYED: the delay (param5) must be in (0, 10] s"),
    ],
)
def test_a_value_beyond_every_surface_is_denied_without_a_relay(ftype, p5, why):
    ap = _Ap(enabled=True)
    assert ap.command(ftype, 4, p5) == M.MAV_RESULT_DENIED
    assert ap.sitl.sent == [] and why in ap.texts[-1] and ap.events["failure_refused"] == 1


@pytest.mark.parametrize(
    "ftype,p5,spec",
    [
        (STUCK, NAN, "stuck"),  # NaN: MAVLink's "not used" (MAVSDK's Failure plugin): where it is
        (STUCK, 0.0, "stuck"),
        (STUCK, 90.0, "stuck=90.0"),  # the edge: beyond no surface's travel; the SITL holds it to its plant's
        (STUCK, -45.0, "stuck=-45.0"),
        (SLOW, NAN, "rate=20.0"),
        (SLOW, 1000.0, "rate=1000.0"),
        (M.FAILURE_TYPE_DELAYED, 10.0, "delay=10.0"),
    ],
)
def test_a_value_within_the_table_is_relayed_as_sent(ftype, p5, spec):
    ap = _Ap(enabled=True)
    assert ap.command(ftype, 4, p5) is None
    (relayed,) = ap.sitl.sent
    assert relayed.param5 == p5 or (math.isnan(p5) and math.isnan(relayed.param5))
    assert ap.relay.pending.spec == spec


# ---------------------------------------------------------------------------------------------- instances
def test_the_instances_are_the_surfaces_channels():
    one = _Ap(enabled=True)
    assert one.command(STUCK, 1, 3.0) == M.MAV_RESULT_UNSUPPORTED
    assert "servo instance 1: the vehicle has one surface, instance 0 (all) or 4" in one.texts[-1]
    mimo = _Ap(enabled=True, channel2=1)  # a square MIMO plant: the aileron on 4 here, its second surface on 1
    for k, instance in enumerate((0, 1, 4)):
        assert mimo.command(OFF, instance, now=10.0 * k) is None
        mimo.sitl_ack(M.MAV_RESULT_ACCEPTED, 10.0 * k + 0.01)
    assert [m.param3 for m in mimo.sitl.sent] == [0, 1, 4]
    assert mimo.command(OFF, 7, now=40.0) == M.MAV_RESULT_UNSUPPORTED
    assert "servo instance 7: the vehicle has 2 surfaces, instance 0 (all) or 4 or 1" in mimo.texts[-1]


# ---------------------------------------------------------------------------------------------- relays and resends
def test_a_relay_is_resent_every_resend_s_then_failed_after_tries():
    ap = _Ap(enabled=True)
    t = 100.0
    assert ap.command(STUCK, 4, now=t) is None
    for k in range(1, inj.TRIES):
        t += inj.RESEND_S
        ap.relay.housekeeping(t - 1e-6)  # not yet
        assert len(ap.sitl.sent) == k
        ap.relay.housekeeping(t)  # at the edge: resent
        assert len(ap.sitl.sent) == k + 1
    assert [m.confirmation for m in ap.sitl.sent] == list(range(inj.TRIES))  # 0, 1, 2 as the command protocol counts
    ap.relay.housekeeping(t + inj.RESEND_S - 1e-6)
    assert ap.answers() == []  # the last relay still has its RESEND_S
    ap.relay.housekeeping(t + inj.RESEND_S)
    assert ap.answers() == [M.MAV_RESULT_FAILED] and ap.relay.pending is None
    assert ap.relay.records[-1] | {} == {
        "t_s": 4.52, "from": "255:230", "fault": "stuck", "result": "FAILED", "relays": inj.TRIES
    }  # fmt: skip


def test_a_command_again_is_one_injection_within_duplicate_s_of_its_answer_and_a_new_one_from_then():
    ap = _Ap(enabled=True)
    assert ap.command(STUCK, 4, 3.0, now=0.0) is None
    assert ap.command(STUCK, 4, 3.0, now=0.1) is None  # in flight: ignored, the SITL's answer goes to the station
    assert ap.command(STUCK, 4, 5.0, now=0.1) == M.MAV_RESULT_TEMPORARILY_REJECTED  # another: one at a time
    ap.sitl_ack(M.MAV_RESULT_ACCEPTED, 0.5)
    t = 0.5 + inj.DUPLICATE_S
    assert ap.command(STUCK, 4, 3.0, now=t - 1e-6) == M.MAV_RESULT_ACCEPTED  # its answer lost: the same answer
    assert ap.command(STUCK, 4, 3.0, src=(255, 190), now=1.0) is None  # another station's is its own command
    ap.sitl_ack(M.MAV_RESULT_ACCEPTED, 1.1)
    assert ap.command(STUCK, 4, 3.0, src=(255, 190), now=1.1 + inj.DUPLICATE_S) is None  # at the edge: a new one
    assert len(ap.sitl.sent) == 3 and ap.events["failure_duplicates"] == 2


def test_an_ack_that_answers_nothing_in_flight_is_counted_not_passed_on():
    ap = _Ap(enabled=True)
    ap.sitl_ack(M.MAV_RESULT_ACCEPTED, 0.0)
    assert ap.answers() == [] and ap.events["sitl_acks_unmatched"] == 1
    ap.command(STUCK, 4, now=1.0)
    ap.sitl_ack(M.MAV_RESULT_IN_PROGRESS, 1.01)  # not an answer yet
    assert ap.relay.pending is not None and ap.answers() == []
    ap.sitl_ack(M.MAV_RESULT_DENIED, 1.02)  # the SITL's refusal (a plant's bound) is passed on as it is
    assert ap.answers() == [M.MAV_RESULT_DENIED] and "refused by the SITL: DENIED" in ap.texts[-1]
