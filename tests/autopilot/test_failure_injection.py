"""MAV_CMD_INJECT_FAILURE from a ground station, through the real autopilot process (autopilot.injection).

A pymavlink ground station sends the command to ``python -m autopilot`` over real UDP; a pymavlink socket bound to the
autopilot's ``--sitl`` address plays the SITL: it records every relayed COMMAND_LONG and answers it as each test
scripts (accepted, unsupported, silent, the first relay lost).  Checked: refused (DENIED) unless ``--failure-injection``
or SYS_FAILURE_EN = 1, the table's UNSUPPORTED and DENIED without a relay, the relay's ids, params and confirmation
count, the SITL's answer passed on, FAILED after three unanswered relays while the loop goes on sending its servo
commands, one injection for a command sent twice, COMMAND_INT refused, and on a signed flight only the key holder.
"""

from __future__ import annotations

import math
import os
import socket
import threading
import time

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import common as M  # noqa: E402

from autopilot.shared.events import StatusTextAssembler  # noqa: E402
from autopilot.shared.signing import load_key  # noqa: E402
from tests._mavlink_procs import Proc, free_ports, load_json, run_cli  # noqa: E402

pytestmark = pytest.mark.e2e
INJECT = M.MAV_CMD_INJECT_FAILURE
SERVO = M.FAILURE_UNIT_SYSTEM_SERVO
NAN = float("nan")


class FakeSitl:
    """The SITL's side of the autopilot's SITL link: a pymavlink endpoint as 1:200 on its own UDP port.  ``answer``:
    the MAV_RESULT for each relayed INJECT_FAILURE (None: no answer); ``drop_first``: the first relay is not
    answered (a lost datagram).  ``relays``: (wall time, message) of each one; ``servos``: wall times of the
    SERVO_OUTPUT_RAW the loop sent."""

    def __init__(self, port: int, answer: int | None = M.MAV_RESULT_ACCEPTED, key: bytes | None = None):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.05)
        self.mav = M.MAVLink(None, 1, 200)
        if key is not None:
            self.mav.signing.secret_key = key
            self.mav.signing.link_id = 3
            self.mav.signing.sign_outgoing = True
            self.mav.signing.allow_unsigned_callback = lambda _mav, _msgid: False
        self.answer = answer
        self.drop_first = False
        self.relays: list = []
        self.servos: list = []
        self.signed: list[bool] = []
        self._stop = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop:
            try:
                data, addr = self.sock.recvfrom(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            for msg in self.mav.parse_buffer(data) or []:
                if msg.get_type() == "SERVO_OUTPUT_RAW":
                    self.servos.append(time.monotonic())
                elif msg.get_type() == "COMMAND_LONG" and msg.command == INJECT:
                    self.relays.append((time.monotonic(), msg))
                    self.signed.append(bool(msg.get_signed()))
                    if self.answer is None or (self.drop_first and len(self.relays) == 1):
                        continue
                    src = (msg.get_srcSystem(), msg.get_srcComponent())  # the autopilot's SITL link, 1:140
                    ack = M.MAVLink_command_ack_message(INJECT, self.answer, 0, 0, *src)
                    self.sock.sendto(ack.pack(self.mav), addr)

    def close(self):
        self._stop = True
        self._thread.join(2)
        self.sock.close()


class Gcs:
    """A ground station (255:COMP) listening on its own UDP port, as MAVProxy is one, or (``to``) sending to the
    vehicle's port from an ephemeral one; ``key``: it signs."""

    def __init__(self, port: int, comp: int = 230, key: bytes | None = None, to: bool = False):
        where = f"{'udpout' if to else 'udpin'}:127.0.0.1:{port}"
        self.conn = mavutil.mavlink_connection(where, source_system=255, source_component=comp, dialect="common")
        if key is not None:
            self.conn.setup_signing(key, sign_outgoing=True)
        self.comp = comp
        self.texts: list[str] = []  # every STATUSTEXT from the vehicle, reassembled from its chunks
        self._chunks = StatusTextAssembler()

    def connect(self, timeout: float = 10.0):
        self.wait("HEARTBEAT", timeout)
        self.conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def wait(self, kind: str, timeout: float = 5.0, cond=None):
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            m = self.conn.recv_match(blocking=True, timeout=0.1)
            if m is None or m.get_srcSystem() != 1:
                continue
            if m.get_type() == "STATUSTEXT":
                self._text(m)
            if m.get_type() == kind and (cond is None or cond(m)):
                return m
        return None

    def send_inject(self, kind: int, instance: float = 0, value: float = NAN, unit: float = SERVO, conf: int = 0):
        self.conn.mav.command_long_send(1, 1, INJECT, conf, unit, kind, instance, NAN, value, NAN, NAN)

    def ack(self, timeout: float = 5.0):
        m = self.wait("COMMAND_ACK", timeout, cond=lambda m: m.command == INJECT and m.target_component == self.comp)
        return None if m is None else m.result

    def inject(self, kind: int, instance: float = 0, value: float = NAN, unit: float = SERVO, timeout: float = 5.0):
        self.drain()
        self.send_inject(kind, instance, value, unit)
        return self.ack(timeout)

    def text(self, needle: str, timeout: float = 3.0) -> str | None:
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            hit = next((t for t in self.texts if needle in t), None)
            if hit is not None:
                return hit
            self.wait("STATUSTEXT", 0.2)
        return None

    def drain(self):
        while (m := self.conn.recv_match(blocking=False)) is not None:
            if m.get_type() == "STATUSTEXT" and m.get_srcSystem() == 1:
                self._text(m)

    def _text(self, m) -> None:
        text = self._chunks.add(m)
        if text is not None:
            self.texts.append(text)

    def close(self):
        self.conn.close()


class Vehicle:
    """The real autopilot (real time, unsigned unless ``key_file``) between a FakeSitl and a Gcs."""

    def __init__(self, tmp_path, *extra, answer=M.MAV_RESULT_ACCEPTED, key_file=None):
        sitl_port, gcs_port, self.listen = free_ports(3)
        key = load_key(key_file) if key_file else None
        self.sitl = FakeSitl(sitl_port, answer, key)
        self.stats = tmp_path / "autopilot.json"
        args = ["--sitl", f"127.0.0.1:{sitl_port}", "--gcs", f"127.0.0.1:{gcs_port}", "--listen"]
        args += [f"127.0.0.1:{self.listen}", "--stats-json", str(self.stats)]
        if key_file:
            args += ["--signing-key", str(key_file)]
        self.gcs_port = gcs_port
        self.ap = Proc("autopilot", [*args, *extra], tmp_path / "autopilot.log")
        assert self.ap.wait_for("autopilot:", 30), self.ap.output()
        self.gcs = None if key_file else Gcs(gcs_port)
        if self.gcs is not None:
            self.gcs.connect()

    def stop(self) -> dict:
        self.ap.stop()
        self.sitl.close()
        if self.gcs is not None:
            self.gcs.close()
        return load_json(self.stats)


@pytest.fixture
def vehicle_factory(tmp_path):
    made = []

    def make(*extra, **kw):
        v = Vehicle(tmp_path, *extra, **kw)
        made.append(v)
        return v

    yield make
    for v in made:
        if v.ap.p.poll() is None:
            v.stop()


def test_refused_unless_enabled_then_enabled_by_the_parameter(vehicle_factory):
    v = vehicle_factory()
    gcs = v.gcs
    assert gcs.inject(M.FAILURE_TYPE_STUCK) == M.MAV_RESULT_DENIED
    assert "failure injection is off (SYS_FAILURE_EN 0; --failure-injection)" in gcs.text("INJECT_FAILURE from")
    gcs.conn.mav.param_set_send(1, 1, b"SYS_FAILURE_EN", 1.0, M.MAV_PARAM_TYPE_REAL32)
    pv = gcs.wait("PARAM_VALUE", cond=lambda m: m.param_id == "SYS_FAILURE_EN")
    assert pv is not None and pv.param_value == 1.0
    assert gcs.inject(M.FAILURE_TYPE_STUCK, 4) == M.MAV_RESULT_ACCEPTED
    assert gcs.text("failure injected by GCS 255:230") is not None
    gcs.conn.mav.param_set_send(1, 1, b"SYS_FAILURE_EN", 0.0, M.MAV_PARAM_TYPE_REAL32)
    assert gcs.wait("PARAM_VALUE", cond=lambda m: m.param_id == "SYS_FAILURE_EN" and m.param_value == 0.0)
    assert gcs.inject(M.FAILURE_TYPE_STUCK, 4, 6.0) == M.MAV_RESULT_DENIED  # off again: no new fault
    assert gcs.inject(M.FAILURE_TYPE_OK, 4) == M.MAV_RESULT_ACCEPTED  # but a clear is taken: the station ends its own
    stats = v.stop()
    assert [m.param2 for _, m in v.sitl.relays] == [M.FAILURE_TYPE_STUCK, M.FAILURE_TYPE_OK]  # refused: not relayed
    assert stats["events"]["failure_refused"] == 2 and stats["events"]["failures_injected"] == 2


def test_a_relayed_failure_carries_the_ground_stations_params_and_the_sitls_answer(vehicle_factory):
    v = vehicle_factory("--failure-injection")
    assert "failure injection on" in v.ap.output()
    gcs = v.gcs
    assert gcs.inject(M.FAILURE_TYPE_STUCK, 4, 5.0) == M.MAV_RESULT_ACCEPTED
    assert "servo stuck=5 deg" in gcs.text("failure injected by GCS 255:230")
    assert gcs.inject(M.FAILURE_TYPE_SLOW) == M.MAV_RESULT_ACCEPTED
    assert gcs.text("servo rate=20 deg/s") is not None  # the default of SLOW without a value
    assert gcs.inject(M.FAILURE_TYPE_DELAYED, 0, 0.0625) == M.MAV_RESULT_ACCEPTED
    assert gcs.inject(M.FAILURE_TYPE_OFF) == M.MAV_RESULT_ACCEPTED
    assert gcs.inject(M.FAILURE_TYPE_OK) == M.MAV_RESULT_ACCEPTED
    assert gcs.text("servo faults cleared by GCS 255:230") is not None
    v.sitl.answer = M.MAV_RESULT_UNSUPPORTED  # the SITL's own refusal (e.g. a plant that cannot) is passed on
    assert gcs.inject(M.FAILURE_TYPE_STUCK, 4, 7.0) == M.MAV_RESULT_UNSUPPORTED
    assert gcs.text("refused by the SITL: UNSUPPORTED") is not None
    stats = v.stop()
    relays = [m for _, m in v.sitl.relays]
    assert len(relays) == 6
    first = relays[0]
    assert (first.get_srcSystem(), first.get_srcComponent()) == (1, 140)  # the autopilot's SITL link
    assert (first.target_system, first.target_component, first.confirmation) == (1, 200, 0)
    assert (first.param1, first.param2, first.param3, first.param5) == (SERVO, M.FAILURE_TYPE_STUCK, 4, 5.0)
    assert math.isnan(first.param4) and math.isnan(first.param6) and math.isnan(first.param7)  # as the GCS sent them
    assert [m.param2 for m in relays] == [2, 5, 6, 1, 0, 2]
    assert relays[2].param5 == 0.0625  # float32 on the wire: exact
    recs = stats["failure_injections"]
    assert [r["fault"] for r in recs] == ["stuck=5.0", "rate=20.0", "delay=0.0625", "off", "clear", "stuck=7.0"]
    assert recs[0]["from"] == "255:230" and recs[0]["relays"] == 1
    assert [r["result"] for r in recs] == ["ACCEPTED"] * 5 + ["UNSUPPORTED"]


def test_what_the_table_does_not_implement_is_answered_without_a_relay(vehicle_factory):
    v = vehicle_factory("--failure-injection")
    gcs = v.gcs
    for args, result, why in (
        ((M.FAILURE_TYPE_STUCK, 0, NAN, M.FAILURE_UNIT_SENSOR_GYRO), M.MAV_RESULT_UNSUPPORTED, "failure unit 0 is"),
        ((M.FAILURE_TYPE_STUCK, 0, NAN, 11), M.MAV_RESULT_UNSUPPORTED, "failure unit 11 is"),  # MAVSDK 3's enum number
        ((M.FAILURE_TYPE_GARBAGE,), M.MAV_RESULT_UNSUPPORTED, "failure type 3 is not implemented for the servo"),
        ((M.FAILURE_TYPE_INTERMITTENT,), M.MAV_RESULT_UNSUPPORTED, "failure type 7 is not implemented"),
        ((M.FAILURE_TYPE_STUCK, 2), M.MAV_RESULT_UNSUPPORTED, "servo instance 2:"),
        ((M.FAILURE_TYPE_STUCK, 4.5), M.MAV_RESULT_UNSUPPORTED, "servo instance 4.5:"),
        ((M.FAILURE_TYPE_SLOW, 0, -5.0), M.MAV_RESULT_DENIED, "SLOW: the rate (param5) must be in (0, 1000] deg/s"),
        ((M.FAILURE_TYPE_SLOW, 0, math.inf), M.MAV_RESULT_DENIED, "SLOW: the rate"),
        ((M.FAILURE_TYPE_STUCK, 4, 1e30), M.MAV_RESULT_DENIED, "STUCK: the position (param5) must be within +-90 deg"),
        ((M.FAILURE_TYPE_STUCK, 0, -math.inf), M.MAV_RESULT_DENIED, "got -inf"),
        ((M.FAILURE_TYPE_DELAYED, 0, -0.1), M.MAV_RESULT_DENIED, "DELAYED: the delay (param5) must be in (0,"),
        ((M.FAILURE_TYPE_DELAYED, 0, 1e9), M.MAV_RESULT_DENIED, "DELAYED: the delay"),
    ):
        assert gcs.inject(*args) == result, why
        assert gcs.text(why) is not None, (why, gcs.texts)
    gcs.drain()
    gcs.conn.mav.command_int_send(1, 1, 0, INJECT, 0, 0, SERVO, M.FAILURE_TYPE_STUCK, 4, 0, 0, 0, 0)
    assert gcs.ack() == M.MAV_RESULT_COMMAND_LONG_ONLY
    v.stop()
    assert v.sitl.relays == []


def test_an_unanswered_relay_is_sent_three_times_then_failed_and_the_loop_goes_on(vehicle_factory):
    v = vehicle_factory("--failure-injection", answer=None)
    gcs = v.gcs
    gcs.drain()
    t0 = time.monotonic()
    gcs.send_inject(M.FAILURE_TYPE_STUCK, 4)
    result = gcs.ack(5.0)
    t1 = time.monotonic()
    assert result == M.MAV_RESULT_FAILED
    assert 0.5 <= t1 - t0 < 3.0, t1 - t0  # three relays 0.2 s apart, then the answer
    assert gcs.text("the SITL did not answer") is not None
    stats = v.stop()
    assert [m.confirmation for _, m in v.sitl.relays] == [0, 1, 2]
    gaps = [b[0] - a[0] for a, b in zip(v.sitl.relays, v.sitl.relays[1:])]
    assert all(0.15 < g < 0.6 for g in gaps), gaps
    # The loop did not wait for the answer: its servo commands (100 Hz) kept coming meanwhile.
    during = [t for t in v.sitl.servos if v.sitl.relays[0][0] < t < v.sitl.relays[-1][0] + 0.2]
    assert len(during) > 25, len(during)
    assert stats["failure_injections"][0]["result"] == "FAILED" and stats["failure_injections"][0]["relays"] == 3


def test_a_lost_relay_is_resent_and_a_command_sent_twice_is_injected_once(vehicle_factory):
    v = vehicle_factory("--failure-injection")
    v.sitl.drop_first = True
    gcs = v.gcs
    gcs.drain()
    gcs.send_inject(M.FAILURE_TYPE_STUCK, 4, 3.0)
    time.sleep(0.05)
    gcs.send_inject(M.FAILURE_TYPE_STUCK, 4, 3.0)  # a resend while the first is in flight (MAVSDK: after 0.5 s)
    assert gcs.ack() == M.MAV_RESULT_ACCEPTED
    assert gcs.ack(0.5) is None  # one answer for the two
    gcs.send_inject(M.FAILURE_TYPE_STUCK, 4, 3.0, conf=1)  # our answer was lost: the same answer, not a relay
    assert gcs.ack() == M.MAV_RESULT_ACCEPTED
    time.sleep(2.2)  # after DUPLICATE_S the same command is a new one
    assert gcs.inject(M.FAILURE_TYPE_STUCK, 4, 3.0) == M.MAV_RESULT_ACCEPTED
    stats = v.stop()
    assert [m.confirmation for _, m in v.sitl.relays] == [0, 1, 0]  # the first relay lost, resent once; the third
    assert stats["events"]["failure_duplicates"] == 2 and stats["events"]["failures_injected"] == 2


def test_on_a_signed_link_only_the_key_holder_injects(tmp_path, vehicle_factory):
    key_file = tmp_path / "flight.key"
    assert run_cli("tools.flight.keygen", str(key_file)).returncode == 0
    key = load_key(key_file)
    v = vehicle_factory("--failure-injection", key_file=key_file)
    holder = Gcs(v.gcs_port, 230, key)
    unsigned = Gcs(v.listen, 231, to=True)  # from a port of its own, straight to the vehicle's
    wrong = Gcs(v.listen, 232, bytes(32), to=True)
    try:
        holder.connect()  # the streams reach every station; only a signed packet is admitted back
        for g in (unsigned, wrong):
            g.drain()
            g.send_inject(M.FAILURE_TYPE_STUCK, 4)
            assert g.ack(1.5) is None  # dropped before it was decoded: nothing to answer
        assert holder.inject(M.FAILURE_TYPE_STUCK, 4) == M.MAV_RESULT_ACCEPTED
    finally:
        for g in (holder, unsigned, wrong):
            g.close()
    stats = v.stop()
    assert len(v.sitl.relays) == 1 and v.sitl.signed == [True]  # the relay is signed with the flight's key
    rejected = stats["links"]["gcs"]["rejected"]
    assert rejected.get("unsigned", 0) >= 1 and rejected.get("bad_signature", 0) >= 1, rejected
