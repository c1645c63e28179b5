"""A ground station takes the loop away and gives it back (issue 35): MANUAL or disarmed for longer than a tracking
window (20 s), on an aircraft that rolled off meanwhile, then any law re-engaged, never crashes the autopilot.

Before, the envelope's tracking windows divided by their count of samples: a window of 20 blocks in which the law
flew no step (MANUAL or disarmed for more than 20 s) raised ZeroDivisionError, and the autopilot exited ("error:
ZeroDivisionError: float division by zero") about 2 s after the ground station re-engaged the law.

The autopilot here is the real ``autopilot.loop.Autopilot`` in this process: its lockstep scheduler's frame handler
(``LockstepScheduler.on_frame``: the control step, the envelope, the hooks) fed the KH2013A's roll
(``sitl.Aircraft``, wrapped at +-180 deg as the SITL's ATTITUDE is), and the ground station's commands real MAVLink
datagrams on its real UDP GCS link, read by its own handler.  The real-time flights with a pymavlink ground station
are in tests/autopilot/test_vehicle.py.
"""

from __future__ import annotations

import math
import os
import re
import socket
import time
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as M  # noqa: E402

from autopilot import controllers  # noqa: E402
from autopilot.envelope import TRACK_BLOCKS  # noqa: E402
from autopilot.loop import Autopilot, AutopilotOptions  # noqa: E402
from autopilot.shared.numerics import wrap_pi  # noqa: E402
from autopilot.shared.pwm import PwmMap  # noqa: E402
from autopilot.vehicle import Mode  # noqa: E402
from sitl.aircraft import Aircraft, AircraftConfig  # noqa: E402

RATE = 100  # control steps per second
U_LIMIT = math.radians(30.0)


class Bench:
    """One in-process autopilot flying ``controller`` on the KH2013A, a ground station on its GCS link, and the
    flight's step results."""

    def __init__(self, controller: str):
        ctl = controllers.get(controller)
        cfg = ctl.config(control_rate_hz=float(RATE), u_limit_rad=U_LIMIT)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the ground station
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(30.0)  # a hang, not a speed
        self.sitl = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # where the servo commands go, unread
        self.sitl.bind(("127.0.0.1", 0))
        opts = AutopilotOptions(
            lockstep=True, pace=False, signing_key=None, verbose=False, name=controller,
            gcs=self.sock.getsockname(), sitl=self.sitl.getsockname(),
        )  # fmt: skip
        self.ap = Autopilot(opts, cfg, PwmMap(), mode=Mode[ctl.mode])
        self.law_mode = Mode[ctl.mode]
        self.mav = M.MAVLink(None, 255, 190)
        self.plant = Aircraft(AircraftConfig(physics_rate_hz=1000.0))
        self.results: list = []
        self.ap.hooks.append(lambda rec: self.results.append(rec.result))
        self.k = 0
        self.send(M.MAVLink_heartbeat_message(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))

    def send(self, msg) -> None:
        """A datagram to the autopilot's GCS link, read by its own handler (as its loop reads it)."""
        self.sock.sendto(msg.pack(self.mav), self.ap.gcs.local)
        before = self.ap.gcs.rx_datagrams
        t_end = time.monotonic() + 30.0  # a hang, not a speed
        while self.ap.gcs.rx_datagrams == before:
            assert time.monotonic() < t_end, "the datagram never arrived"
            self.ap.gcs.poll(self.ap._gcs_handler)

    def command(self, cmd: int, *params: float) -> int:
        p = [*params, *[0.0] * (7 - len(params))]
        self.sock.setblocking(False)  # the streams of the seconds flown, unread: the answer would be dropped
        try:
            while True:
                self.sock.recv(65535)
        except BlockingIOError:
            pass
        self.sock.settimeout(30.0)
        self.send(M.MAVLink_command_long_message(1, 1, cmd, 0, *p))
        while True:  # the COMMAND_ACK, on the ground station's socket
            data, _ = self.sock.recvfrom(65535)
            for m in self.mav.parse_buffer(data) or []:
                if m.get_type() == "COMMAND_ACK" and m.command == cmd:
                    return m.result

    def mode(self, mode: Mode) -> None:
        assert self.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, int(mode)) == 0
        assert self.ap.vehicle.selected is mode

    def arm(self, arm: bool) -> None:
        assert self.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0 if arm else 0.0) == 0
        assert self.ap.control.armed is arm

    def fly(self, seconds: int) -> None:
        """``seconds`` of control steps, with the paper's +-10 deg square wave of period 10 s as the setpoint."""
        for _ in range(seconds * RATE):
            k = self.k
            if k % 50 == 0:  # a setpoint every 0.5 s, "now" on sim time
                deg = 10.0 if (k // (5 * RATE)) % 2 == 0 else -10.0
                q = [math.cos(math.radians(deg) / 2), math.sin(math.radians(deg) / 2), 0.0, 0.0]
                self.send(M.MAVLink_set_attitude_target_message(0, 1, 1, 71, q, 0, 0, 0, 0))
            x = self.plant.truth
            self.ap.scheduler.on_frame(k * 1000 // RATE, time.perf_counter(), wrap_pi(float(x[3])), float(x[0]), 0.0)
            assert len(self.results) == k + 1, "the step was not flown"
            self.plant.advance(self.results[-1].u, 1000 // RATE)
            self.k += 1

    def close(self) -> None:
        self.sock.close()
        self.sitl.close()
        self.ap.close()


def _windows(law_blocks: set[int], last_block: int) -> int:
    """Hand count of the tracking windows judged: each run of TRACK_BLOCKS one-second blocks ending at block
    TRACK_BLOCKS - 1 .. ``last_block`` in which the law flew at least one step (a block of ``law_blocks``)."""
    ends = range(TRACK_BLOCKS - 1, last_block + 1)
    return sum(1 for e in ends if any(j in law_blocks for j in range(e - TRACK_BLOCKS + 1, e + 1)))


def _law_flies_after(bench: Bench, k0: int) -> None:
    """From step ``k0`` the law flies: finite commands within the limit, no step at the switch (bumpless)."""
    after = bench.results[k0:]
    assert after and all(math.isfinite(r.u) and abs(r.u) <= U_LIMIT for r in after)
    assert abs(after[0].u - bench.results[k0 - 1].u) <= math.radians(1.0)  # the transfer starts where it was


LAWS = ["sac", "clsac", "baseline", "pid-ff"]


@pytest.mark.parametrize("controller", LAWS)
def test_a_law_re_engaged_after_21_s_of_manual_on_a_rolled_off_aircraft_flies_on(controller):
    """The issue's sequence for every law: 5 s flown, MANUAL (the station's rudder held at +9 deg) for 21 s, in
    which the KH2013A rolls off, then the law's mode again; the flight goes on to 40 s."""
    b = Bench(controller)
    try:
        b.fly(5)
        b.mode(Mode.MANUAL)
        b.send(M.MAVLink_manual_control_message(1, 0, 0, 0, 300, 0))  # r = 300 of 1000: +9 deg
        b.fly(21)
        rolled = abs(b.results[-1].phi)
        b.mode(b.law_mode)
        b.fly(14)
        assert b.ap.vehicle.mode is b.law_mode and rolled > math.radians(90.0), math.degrees(rolled)
        _law_flies_after(b, 26 * RATE)
        verdict = b.ap.envelope.result()
        gs = verdict.ground_station
        assert gs["manual_s"] == pytest.approx(21.0) and gs["disarmed_s"] == 0.0  # 2100 steps of 0.01 s
        assert not verdict.ok and "|roll| reached" in verdict.reason  # it rolled past 60 deg: said, not crashed
        law = set(range(0, 5)) | set(range(26, 40))
        assert verdict.tracking.windows == _windows(law, 39) == 19
    finally:
        b.close()


@pytest.mark.parametrize("controller", LAWS)
def test_a_law_re_armed_after_26_s_disarmed_flies_on(controller):
    """DISARM (rudder neutral) for 26 s, then ARM: the law flies from neutral, bumpless, to the end.  (The KH2013A
    levels itself at neutral rudder: a rolled-off aircraft re-armed is the test below.)"""
    b = Bench(controller)
    try:
        b.fly(4)
        b.arm(False)
        b.fly(26)
        b.arm(True)
        b.fly(10)
        assert all(r.u == 0.0 for r in b.results[4 * RATE : 30 * RATE])  # disarmed: neutral
        _law_flies_after(b, 30 * RATE)
        gs = b.ap.envelope.result().ground_station
        assert gs["disarmed_s"] == pytest.approx(26.0) and gs["manual_s"] == 0.0
        law = set(range(0, 4)) | set(range(30, 40))
        assert b.ap.envelope.result().tracking.windows == _windows(law, 39) == 14
    finally:
        b.close()


@pytest.mark.parametrize(
    ("controller", "other"),
    [("clsac", Mode.SAC), ("sac", Mode.CLSAC), ("baseline", Mode.BASELINE), ("pid-ff", Mode.BASELINE)],
)
def test_manual_then_the_other_mode_of_the_law_after_25_s(controller, other):
    """MANUAL -> each mode of the law: from MANUAL (25 s, rolled off) to the mode the flight did not start in (the
    CL-SAC law's other one; the PIDs have one), and back to the first one after 10 s; then MANUAL, disarmed for 22 s
    (the KH2013A levels itself at neutral rudder), armed in MANUAL and rolled off by the station's rudder for 4 s,
    and the other mode again."""
    b = Bench(controller)
    try:
        b.fly(3)
        b.mode(Mode.MANUAL)
        b.send(M.MAVLink_manual_control_message(1, 0, 0, 0, -300, 0))
        b.fly(25)
        assert abs(b.results[-1].phi) > math.radians(60.0), math.degrees(b.results[-1].phi)  # rolled off
        b.mode(other)
        b.fly(10)
        b.mode(b.law_mode)
        b.fly(5)
        b.mode(Mode.MANUAL)
        b.arm(False)
        b.fly(22)
        b.arm(True)
        b.send(M.MAVLink_manual_control_message(1, 0, 0, 0, -1000, 0))  # full rudder, -30 deg
        b.fly(4)
        assert abs(b.results[-1].phi) > math.radians(60.0), math.degrees(b.results[-1].phi)  # past the envelope
        b.mode(other)
        b.fly(5)
        _law_flies_after(b, 28 * RATE)
        _law_flies_after(b, 69 * RATE)
        gs = b.ap.envelope.result().ground_station
        assert gs["manual_s"] == pytest.approx(29.0) and gs["disarmed_s"] == pytest.approx(22.0)
        law = set(range(0, 3)) | set(range(28, 43)) | set(range(69, 74))
        assert b.ap.envelope.result().tracking.windows == _windows(law, 73)
    finally:
        b.close()


@pytest.mark.parametrize("controller", ["clsac", "sac"])
def test_law_to_law_after_a_long_time(controller):
    """SAC <-> CL-SAC (the law's two modes) after 30 s of each: every window judged, none skipped."""
    b = Bench(controller)
    other = Mode.SAC if controller == "clsac" else Mode.CLSAC
    try:
        b.fly(30)
        b.mode(other)
        b.fly(30)
        b.mode(b.law_mode)
        b.fly(5)
        _law_flies_after(b, 30 * RATE)
        _law_flies_after(b, 60 * RATE)
        verdict = b.ap.envelope.result()
        assert verdict.tracking.windows == 65 - TRACK_BLOCKS + 1 and verdict.ground_station["note"] is None
    finally:
        b.close()


ROOT = Path(__file__).resolve().parents[2]


# -------------------------------------------------------------------------------------------- mode numbers
def test_mode_numbers_are_the_documented_ones():
    """HEARTBEAT.custom_mode: MANUAL = 0 (ArduPlane's MANUAL too), SAC 100, CLSAC 101, FAILSAFE 102, BASELINE 103,
    as docs/spec.md and the manual (docs/ground-stations.md) say; none of 100..103 has a name in ArduPlane's table."""
    from pymavlink import mavutil

    from autopilot.vehicle import Mode

    documented = {}
    for doc in ("docs/spec.md", "docs/ground-stations.md"):
        text = (ROOT / doc).read_text()
        found = dict(re.findall(r"`?\b(MANUAL|SAC|CLSAC|FAILSAFE|BASELINE|MRAC|CRM_MRAC|L1|INDI|LAW)`? = (\d+)", text))
        documented[doc] = {k: int(v) for k, v in found.items()}
    assert documented["docs/spec.md"] == {
        "MANUAL": 0,
        "SAC": 100,
        "CLSAC": 101,
        "FAILSAFE": 102,
        "BASELINE": 103,
        "MRAC": 104,
        "CRM_MRAC": 105,
        "L1": 106,
        "INDI": 107,
        "LAW": 108,
    }
    assert {m.name: m.value for m in Mode} == documented["docs/spec.md"]
    assert documented["docs/ground-stations.md"]  # the manual names the modes it lets a user select
    assert documented["docs/ground-stations.md"].items() <= documented["docs/spec.md"].items()
    plane = mavutil.mode_mapping_apm  # ArduPlane: number -> name
    assert plane[Mode.MANUAL] == "MANUAL" and not {100, 101, 102, 103} & set(plane)
