"""sitl/fault_injection.py: the SITL's own checks of a MAV_CMD_INJECT_FAILURE, reached directly.

The autopilot validates a ground station's command before it relays it (tests/autopilot/test_injection.py); these tests
talk to a real ``sitl.endpoint.Sitl`` with pymavlink over real UDP, as the autopilot's SITL link (1:140) does, so that
each check behind the autopilot's is exercised on its own: the command's target system and component, the resend window,
the plant's own bounds (the surface's travel) with the reason said as a STATUSTEXT, overlapping faults (a re-jam at a
new angle, a clear), and a square MIMO plant's surfaces by instance.
"""

from __future__ import annotations

import math
import socket
import time

import pytest

from autopilot.shared.mavlink import mavlink as M
from autopilot.shared.pwm import PwmMap
from sitl import damage

STUCK, OK, OFF = M.FAILURE_TYPE_STUCK, M.FAILURE_TYPE_OK, M.FAILURE_TYPE_OFF
NAN = float("nan")


class _Link:
    """The autopilot's side of the SITL link: a pymavlink endpoint (1:140 unless ``src``) on its own UDP socket."""

    def __init__(self, sitl, src=(1, 140)):
        self.sitl = sitl
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.mav = M.MAVLink(None, *src)
        self.parser = M.MAVLink(None)
        self.parser.robust_parsing = True

    def inject(self, ftype, instance=0.0, p5=NAN, target=(1, 200)):
        msg = M.MAVLink_command_long_message(*target, 420, 0, 102.0, ftype, instance, NAN, p5, NAN, NAN)
        self.sock.sendto(msg.pack(self.mav), self.sitl.link.local)

    def poll(self, wait=0.3) -> tuple[list[int], list[str]]:
        """Poll the SITL's link as its loop does; (ACK results, STATUSTEXTs, chunks joined) it sent back."""
        acks, texts = [], []
        t_end = time.monotonic() + wait
        while time.monotonic() < t_end:
            self.sitl.link.poll(self.sitl._on_msg)
            try:
                data = self.sock.recv(65536)
            except BlockingIOError:
                time.sleep(0.005)
                continue
            for msg in self.parser.parse_buffer(data) or []:
                if msg.get_type() == "COMMAND_ACK":
                    acks.append(msg.result)
                elif msg.get_type() == "STATUSTEXT":
                    if getattr(msg, "chunk_seq", 0) > 0 and texts:
                        texts[-1] += msg.text
                    else:
                        texts.append(msg.text)
        return acks, texts

    def ask(self, *args, **kw) -> tuple[int | None, list[str]]:
        """One command and its answer: (the ACK's result or None, the STATUSTEXTs)."""
        self.inject(*args, **kw)
        acks, texts = self.poll()
        assert len(acks) <= 1, acks
        return (acks[0] if acks else None), texts

    def close(self):
        self.sock.close()


@pytest.fixture
def make_sitl():
    made = []

    def make(plant="kh2013a", pwm=None, pwm2=None):
        from sitl.endpoint import Sitl, SitlOptions

        sitl = Sitl(
            SitlOptions(listen=("127.0.0.1", 0), lockstep=True, verbose=False, plant=plant), pwm or PwmMap(), None, pwm2
        )
        link = _Link(sitl)
        made.append((sitl, link))
        return sitl, link

    yield make
    for sitl, link in made:
        link.close()
        sitl.close()


def _faults(sitl) -> list[tuple]:
    return [(f["kind"], f["surface"], f["value"], f["end"]) for f in sitl.stats()["faults"]]


# ---------------------------------------------------------------------------------------------- the command
def test_a_command_to_another_target_is_refused_by_the_sitl_itself(make_sitl):
    sitl, link = make_sitl()
    for target in ((1, 1), (2, 200), (1, 0)):  # the vehicle, another vehicle's SITL, broadcast: not this SITL
        assert link.ask(STUCK, 4, 3.0, target=target)[0] is None  # not answered
    assert sitl.link.rejected["wrong_target"] == 3 and sitl.stats()["faults"] == []
    assert link.ask(STUCK, 4, 3.0)[0] == M.MAV_RESULT_ACCEPTED  # the same to 1:200 is applied


def test_the_same_command_is_a_resend_within_the_window_and_a_new_fault_after_it(make_sitl):
    sitl, link = make_sitl()
    assert link.ask(STUCK, 4, 3.0)[0] == M.MAV_RESULT_ACCEPTED
    assert link.ask(STUCK, 4, 3.0)[0] == M.MAV_RESULT_ACCEPTED  # at once: its ACK was lost, not applied again
    assert len(sitl.stats()["faults"]) == 1 and sitl.events["inject_failure_resent"] == 1
    time.sleep(damage_window() + 0.05)
    assert link.ask(STUCK, 4, 3.0)[0] == M.MAV_RESULT_ACCEPTED  # after the window: a new command
    assert len(sitl.stats()["faults"]) == 2 and sitl.events["inject_failure_resent"] == 1


def damage_window() -> float:
    from autopilot.shared.servo_failures import DUPLICATE_WINDOW_S

    return DUPLICATE_WINDOW_S


def test_the_resend_window_is_inclusive_at_its_edge_and_tells_nan_apart_from_a_value():
    f = damage.InjectionFilter(1.0)
    params = (102.0, 2.0, 4.0, NAN, NAN, NAN, NAN)
    f.remember(params, 10.0, M.MAV_RESULT_ACCEPTED)
    assert f.resent(params, 11.0) == M.MAV_RESULT_ACCEPTED  # exactly window_s later: still its resend
    assert f.resent(params, 11.0 + 1e-9) is None
    assert f.resent((102.0, 2.0, 4.0, NAN, 0.0, NAN, NAN), 10.5) is None  # another param5: another command


# ---------------------------------------------------------------------------------------------- the plant's bounds
@pytest.mark.parametrize(
    "p5,result,why",
    [
        (45.0, M.MAV_RESULT_DENIED, "stuck=45: 45 deg is beyond the rudder's travel, +-30 deg"),
        (-31.0, M.MAV_RESULT_DENIED, "stuck=-31: -31 deg is beyond the rudder's travel, +-30 deg"),
        (1e30, M.MAV_RESULT_DENIED, "STUCK: the position (param5) must be within +-90 deg, got 1.0000000150474662e+30"),
        (math.inf, M.MAV_RESULT_DENIED, "STUCK: the position (param5) must be within +-90 deg, got inf"),
        (30.0, M.MAV_RESULT_ACCEPTED, None),
        (-29.5, M.MAV_RESULT_ACCEPTED, None),
    ],
)
def test_a_stuck_angle_beyond_the_surfaces_travel_is_denied_with_its_reason(make_sitl, p5, result, why):
    sitl, link = make_sitl()
    got, texts = link.ask(STUCK, 4, p5)
    assert got == result
    if why is None:
        assert [f[:3] for f in _faults(sitl)] == [("stuck", "rudder", pytest.approx(math.radians(p5), rel=1e-7))]
    else:
        assert texts == [f"INJECT_FAILURE refused: {why}"] and _faults(sitl) == []


def test_the_travel_is_the_servos_when_its_span_is_narrower(make_sitl):
    sitl, link = make_sitl(pwm=PwmMap(1000, 2000, 1500, math.radians(20.0), 4))  # --rudder-max-deg 20
    assert link.ask(STUCK, 4, 25.0) == (M.MAV_RESULT_DENIED, ["INJECT_FAILURE refused: stuck=25: 25 deg is beyond "
                                                             "the rudder's travel, +-20 deg"])  # fmt: skip
    assert link.ask(STUCK, 4, 20.0)[0] == M.MAV_RESULT_ACCEPTED


# ---------------------------------------------------------------------------------------------- overlapping faults
def test_a_rejam_takes_the_new_angle_and_a_clear_ends_the_jam(make_sitl):
    sitl, link = make_sitl()
    sitl._advance(0.0, 100)
    assert link.ask(STUCK, 4, 3.0)[0] == M.MAV_RESULT_ACCEPTED
    sitl._advance(math.radians(-10), 100)
    assert sitl.aircraft.truth[4] == pytest.approx(math.radians(3.0), abs=1e-12)  # jammed at 3 deg, not driven
    assert link.ask(STUCK, 4, 7.0)[0] == M.MAV_RESULT_ACCEPTED
    sitl._advance(math.radians(-10), 100)
    assert sitl.aircraft.truth[4] == pytest.approx(math.radians(7.0), abs=1e-12)  # the new angle, at once
    assert link.ask(OK, 4)[0] == M.MAV_RESULT_ACCEPTED
    sitl._advance(math.radians(-10), 300)
    assert sitl.aircraft.truth[4] < math.radians(-5.0)  # the servo drives it again (-10 deg, its 0.05 s lag)
    assert [(k, s, e) for k, s, _v, e in _faults(sitl)] == [("stuck", "rudder", 0.3), ("stuck", "rudder", 0.3)]


# ---------------------------------------------------------------------------------------------- two surfaces
MIMO = "jsbsim:c172x:surface=aileron+rudder"


def test_a_mimo_plants_surfaces_by_instance(make_sitl):
    pytest.importorskip("jsbsim")
    pwm1, pwm2 = PwmMap(channel=1), PwmMap(channel=4)  # the launcher's: aileron servo1, rudder servo4
    sitl, link = make_sitl(MIMO, pwm1, pwm2)
    sitl._advance(0.0, 100)
    got, texts = link.ask(STUCK, 4, 5.0)  # the rudder
    assert got == M.MAV_RESULT_ACCEPTED
    sitl.aircraft.u2 = math.radians(-8.0)
    sitl._advance(math.radians(4.0), 300)
    ac = sitl.aircraft
    assert ac.delta2 == pytest.approx(math.radians(5.0), abs=1e-12)  # the rudder jammed at 5 deg
    assert ac.delta == pytest.approx(math.radians(4.0), abs=2e-3)  # the aileron still follows its command
    _a, texts = link.poll(0.1)
    assert texts == ["fault start t=0.100: stuck=5 on the rudder (ground station)"]
    # beyond the rudder's travel (16 deg on the c172x) but within the aileron's (17.5 deg): denied for the rudder
    assert link.ask(STUCK, 4, 17.0)[0] == M.MAV_RESULT_DENIED
    assert link.ask(STUCK, 1, 17.0)[0] == M.MAV_RESULT_ACCEPTED  # the aileron's instance
    sitl._advance(math.radians(4.0), 10)
    assert ac.delta == pytest.approx(math.radians(17.0), abs=1e-12)
    assert link.ask(OK, 1)[0] == M.MAV_RESULT_ACCEPTED  # clears the aileron's only
    assert link.ask(OFF, 0)[0] == M.MAV_RESULT_ACCEPTED  # all: both servos driven with 0
    sitl.aircraft.u2 = math.radians(-8.0)
    sitl._advance(math.radians(4.0), 500)
    assert abs(ac.delta) < math.radians(0.5)  # the aileron floats to neutral
    assert ac.delta2 == pytest.approx(math.radians(5.0), abs=1e-12)  # the rudder is still jammed (stuck wins)
    assert [(k, s) for k, s, _v, _e in _faults(sitl)] == [
        ("stuck", "rudder"), ("stuck", "aileron"), ("off", "aileron+rudder")
    ]  # fmt: skip
