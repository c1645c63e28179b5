"""A hostile peer on the same host, with real sockets against real processes (issue #11, one test per bullet).

Each forged or faulty input is rejected and counted under its reason, the real stream keeps control, the flight is
OK and (lockstep) its metrics are within 1 % of an undisturbed flight (in fact identical: lockstep is
deterministic).  The flights here are unsigned (``signing=False``): pinned peers and bounded clocks alone must
hold; ``tests/autopilot/shared/test_signing.py`` adds the signatures.
"""

from __future__ import annotations

import math
import random
import re
import socket
import threading
import time
from pathlib import Path

import pytest

from autopilot.metrics import METRIC_NAMES
from autopilot.shared import mavlink as ids
from autopilot.shared.mavlink import roll_to_quaternion
from tests._mavlink_procs import Proc, free_ports, load_json, mav, mavlink, pack, udp
from tools.flight import Flight

pytestmark = pytest.mark.e2e  # real processes over loopback UDP

DURATION = 60.0  # lockstep sim seconds: a few wall seconds, long enough to attack during the flight
AP_GCS_ID = ids.AUTOPILOT_ID
AP_SITL_ID = getattr(ids, "AUTOPILOT_SITL_ID", ids.AUTOPILOT_ID)  # the autopilot's IDs on its SITL link
_LINE = re.compile(r"SITL link [\d.]+:(\d+) -> [\d.]+:(\d+); GCS link [\d.]+:(\d+) -> [\d.]+:(\d+)")


def _kwargs(out: Path) -> dict:
    return dict(lockstep=True, duration=DURATION, out=out, quiet=True, rrd=False, series=False, signing=False)


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> dict:
    res = Flight(**_kwargs(tmp_path_factory.mktemp("reference"))).run()
    assert res.ok, res.reason
    return res.summary


def _ports(out: Path, timeout: float = 60.0) -> dict:
    """The four UDP ports of a running flight, from the autopilot's start line."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        try:
            m = _LINE.search((out / "autopilot.log").read_text())
        except OSError:
            m = None
        if m and "gcs: vehicle " in (out / "gcs.log").read_text():  # the GCS script has found the vehicle
            a_sitl, sitl, a_gcs, gcs = (int(g) for g in m.groups())
            return {"ap_sitl": a_sitl, "sitl": sitl, "ap_gcs": a_gcs, "gcs": gcs}
        time.sleep(0.01)
    raise AssertionError(f"no autopilot start line in {out}")


class Attacker(threading.Thread):
    """Sends its packets round-robin to the given ports (from its own port) until stopped."""

    def __init__(self, ports: dict, packets: dict):
        super().__init__(daemon=True)
        self.targets = [(("127.0.0.1", ports[where]), pkts) for where, pkts in packets.items()]
        self.sock = udp()
        self.sent = 0
        self._halt = threading.Event()

    def run(self):
        k = 0
        while not self._halt.is_set():
            for addr, pkts in self.targets:
                for _ in range(20):
                    self.sock.sendto(pkts[k % len(pkts)], addr)
                    self.sent += 1
                    k += 1
            time.sleep(0.005)

    def stop(self):
        self._halt.set()
        self.join(5)
        self.sock.close()


def hostile_flight(tmp_path: Path, packets: dict, reference: dict) -> dict:
    """A lockstep flight attacked during its whole length; asserts it is OK, every link's counters add up, the
    links kept their one real peer, and the metrics match the undisturbed flight; returns summary.json."""
    with Flight(**_kwargs(tmp_path)) as flight:
        attacker = Attacker(_ports(flight.out), packets)
        attacker.start()
        res = flight.wait(timeout=600)
        attacker.stop()
    assert res.ok, res.reason
    assert attacker.sent > 100
    s = res.summary
    assert s["flown"]["fraction"] == 1.0 and s["flown"]["frames"] == s["flown"]["steps_asked"]
    links = [*s["counters"]["autopilot"].values(), s["counters"]["sitl"], s["counters"]["gcs"]]
    for c in links:  # every datagram counted once, under exactly one outcome
        assert c["rx_datagrams"] == c["rx_accepted"] + sum(c["rejected"].values()), c
        assert len(c["admitted"]) == 1, c  # still the one real peer
    for key in METRIC_NAMES:
        assert s["runs"][0]["metrics"][key] == pytest.approx(reference["runs"][0]["metrics"][key], rel=0.01), key
    return s


def _setpoint(m, roll: float, ms: int = 0) -> bytes:
    q = roll_to_quaternion(roll)
    return pack(m, mavlink.MAVLink_set_attitude_target_message(ms, 1, 1, 71, q, 0.0, 0.0, 0.0, 0.0))


def _attitude(m, ms: int, roll: float) -> bytes:
    return pack(m, mavlink.MAVLink_attitude_message(ms, roll, 0.0, 0.0, 0.0, 0.0, 0.0))


def _servo(m, usec: int, pwm: int) -> bytes:
    s = [0] * 16
    s[3] = pwm
    return pack(m, mavlink.MAVLink_servo_output_raw_message(usec % (1 << 32), 0, *s))


def _rejected(s: dict, link: str) -> dict:
    c = s["counters"]
    return {"ap_sitl": c["autopilot"]["sitl"], "ap_gcs": c["autopilot"]["gcs"], "sitl": c["sitl"], "gcs": c["gcs"]}[
        link
    ]["rejected"]


# ------------------------------------------------------------------------------------------ lockstep flights
def test_forged_setpoint_from_another_port_is_not_obeyed(tmp_path, reference):
    g = mav(255, 190)
    s = hostile_flight(tmp_path, {"ap_gcs": [_setpoint(g, math.radians(50))]}, reference)
    assert _rejected(s, "ap_gcs")["not_peer"] > 0


def test_forged_servo_ahead_in_time_is_not_applied(tmp_path, reference):
    now = time.time_ns() // 1000
    pkts = [_servo(mav(*ident), now + k * 10_000, 2000) for k in range(50) for ident in {AP_SITL_ID, AP_GCS_ID}]
    s = hostile_flight(tmp_path, {"sitl": pkts}, reference)
    assert _rejected(s, "sitl")["not_peer"] > 0


def test_forged_attitude_at_the_end_of_time_is_not_used(tmp_path, reference):
    s = hostile_flight(tmp_path, {"ap_sitl": [_attitude(mav(1, 200), 0xFFFFFFFF, 2.0)]}, reference)
    assert _rejected(s, "ap_sitl")["not_peer"] > 0


def test_forged_poweroff_does_not_stop_the_gcs(tmp_path, reference):
    hb = mavlink.MAVLink_heartbeat_message(1, 0, 0, 0, mavlink.MAV_STATE_POWEROFF, 3)
    s = hostile_flight(tmp_path, {"gcs": [pack(mav(*AP_GCS_ID), hb)]}, reference)
    assert _rejected(s, "gcs")["not_peer"] > 0


def test_spoofed_ids_do_not_redirect_streams(tmp_path, reference):
    rng = random.Random(5)
    common = [cls for cls in mavlink.mavlink_map.values() if not any(cls.array_lengths)]

    def junk(ident, n=200):
        out = []
        while len(out) < n:
            cls = rng.choice(common)
            try:
                out.append(pack(mav(*ident), cls(*[rng.randrange(2) for _ in cls.fieldnames])))
            except Exception:  # noqa: BLE001  (a field that wants another type: pick another message)
                continue
        return out

    packets = {"ap_sitl": junk((1, 200)), "ap_gcs": junk((255, 190)), "sitl": junk(AP_SITL_ID), "gcs": junk(AP_GCS_ID)}
    s = hostile_flight(tmp_path, packets, reference)
    for link in packets:
        assert _rejected(s, link).get("not_peer", 0) > 0, link
    # the streams still go only to the real peers: the GCS script got every telemetry datagram of the flight
    assert s["counters"]["gcs"]["rx_by_type"]["ATTITUDE"] == reference["counters"]["gcs"]["rx_by_type"]["ATTITUDE"]


def test_late_or_forged_frames_do_not_end_a_lockstep_run(tmp_path, reference):
    end = int(DURATION * 1000)
    pkts = [_attitude(mav(1, 200), ms, 0.3) for ms in (end, end - 10, end + 10, 100_000, 10)]
    s = hostile_flight(tmp_path, {"ap_sitl": pkts}, reference)
    assert _rejected(s, "ap_sitl")["not_peer"] > 0
    assert s["runs"][0]["steps"] == round(DURATION * 100)


# ------------------------------------------------------------------------ processes driven by the test itself
class Procs:
    """The autopilot (and a SITL) in real time, with the test as the ground station (and as the SITL)."""

    def __init__(self, tmp_path: Path, *, sitl: bool = True, duration: float = 4.0, ap_args=()):
        self.dir = tmp_path
        self.sitl_port, self.ap_gcs_port = free_ports(2)
        self.gcs = udp()  # the ground station: the first to talk to the autopilot's GCS link
        self.sitl = None
        if sitl:
            self.sitl = Proc(
                "sitl",
                ["--listen", f"127.0.0.1:{self.sitl_port}", "--stats-json", str(tmp_path / "sitl.json")],
                tmp_path / "sitl.log",
            )
            assert self.sitl.wait_for("listening on")
        self.ap = Proc(
            "autopilot",
            [
                "--sitl",
                f"127.0.0.1:{self.sitl_port}",
                "--listen",
                f"127.0.0.1:{self.ap_gcs_port}",
                "--gcs",
                "127.0.0.1:%d" % self.gcs.getsockname()[1],
                "--duration",
                str(duration),
                "--stats-json",
                str(tmp_path / "ap.json"),
                *ap_args,
            ],
            tmp_path / "ap.log",
        )
        assert self.ap.wait_for("autopilot:")

    def finish(self) -> dict:
        assert self.ap.p.wait(60) == 0, self.ap.output()
        self.ap.stop()
        if self.sitl is not None:
            assert self.sitl.stop() == 0, self.sitl.output()
        self.gcs.close()
        return load_json(self.dir / "ap.json")


def test_setpoint_queue_cannot_be_exhausted(tmp_path):
    """An admitted station floods setpoints 46 days ahead while another flies its real stream: the flood is checked
    within its own budget per control period (the rest ``over_budget``) and refused (``future_setpoint``), the
    queue never fills, and the real stream, within its own budget, flies every point."""
    real, flooder = udp(), udp()
    peers = [a for s in (real, flooder) for a in ("--gcs-peer", "127.0.0.1:%d" % s.getsockname()[1])]
    p = Procs(tmp_path, duration=4.0, ap_args=peers)
    g, f = mav(255, 190), mav(255, 191)
    to = ("127.0.0.1", p.ap_gcs_port)
    far = [_setpoint(f, math.radians(40), ms) for ms in range(4_000_000_000, 4_000_100_050)]  # 100,050, ~46 days
    t0 = time.monotonic()
    k = 0
    while time.monotonic() - t0 < 3.5:
        real.sendto(_setpoint(g, math.radians(5)), to)  # the real stream: "now", 50 Hz ...
        for _ in range(2000):  # ... and the flood in between, from the other admitted address
            if k < len(far):
                flooder.sendto(far[k], to)
                k += 1
            if k % 200 == 0:
                time.sleep(0.001)  # at most a poll's budget at once: the flood is not dropped unread
        time.sleep(0.02)
    real.close()
    flooder.close()
    ap = p.finish()
    rej = ap["links"]["gcs"]["rejected"]
    assert k == len(far) and rej.get("future_setpoint", 0) + rej.get("over_budget", 0) >= 0.9 * k
    assert "setpoint_queue_full" not in rej
    assert ap["events"]["setpoints"] >= 50  # every real one got in: no setpoint timeout
    assert ap["events"].get("setpoints_lost", 0) == 0 and "setpoint stream lost" not in p.ap.output()
    assert ap["metrics"]["max_abs_u"] < 0.3  # it flew 5 deg, never the 40 deg of the flood


def test_setpoint_queue_full_evicts_the_furthest_point(tmp_path):
    from autopilot.step import SetpointQueue

    q = SetpointQueue(limit=100)
    for k in range(100):
        assert q.push(5e6 + k, 0.7)  # far points fill the queue
    assert not q.push(6e6, 0.7)  # a point beyond all of them is refused ...
    assert q.push(0.0, 0.1) and q.evicted == 1  # ... a nearer one (a "now" point) always gets in
    assert q.at(0.0) == 0.1 and len(q) == 99


def test_sitl_restart_the_gcs_profile_continues(tmp_path):
    sitl_port, gcs_port = free_ports(2)

    def start_sitl(tag):
        return Proc(
            "sitl",
            ["--listen", f"127.0.0.1:{sitl_port}", "--stats-json", str(tmp_path / f"sitl{tag}.json")],
            tmp_path / f"sitl{tag}.log",
        )

    sitl = start_sitl(1)
    assert sitl.wait_for("listening on")
    gcs = Proc(
        "tools.gcs",
        ["--listen", f"127.0.0.1:{gcs_port}", "--period", "2", "--stats-json", str(tmp_path / "gcs.json")],
        tmp_path / "gcs.log",
    )
    assert gcs.wait_for("listening on")
    ap = Proc(
        "autopilot",
        ["--sitl", f"127.0.0.1:{sitl_port}", "--gcs", f"127.0.0.1:{gcs_port}", "--duration", "7"]
        + ["--stats-json", str(tmp_path / "ap.json")],
        tmp_path / "ap.log",
    )
    time.sleep(3.5)
    assert sitl.stop() == 0
    sitl = start_sitl(2)  # a new SITL on the same port: its clock starts again at 0
    assert ap.p.wait(60) == 0, ap.output()
    assert gcs.p.wait(30) == 0, gcs.output()
    sitl.stop()
    g = load_json(tmp_path / "gcs.json")
    a = load_json(tmp_path / "ap.json")
    assert g["clock_restarts"] >= 1
    # the profile went on through the restart (not frozen at the 3.5 s of the first SITL)
    assert (g["sim_ms"] - g["origin_ms"]) / 1000.0 > 5.0
    assert a["events"].get("recoveries", 0) >= 1 or a["events"].get("sitl_clock_restarts", 0) >= 1
    assert load_json(tmp_path / "sitl2.json")["events"].get("servo_applied", 0) > 100  # it flies again


def test_roll_through_inverted_is_wrapped_by_the_sitl(tmp_path):
    port = free_ports(1)[0]
    sitl = Proc("sitl", ["--listen", f"127.0.0.1:{port}", "--servo-timeout", "5"], tmp_path / "sitl.log")
    assert sitl.wait_for("listening on")
    s = udp()
    s.settimeout(0.05)
    m = mav(*AP_SITL_ID)
    rolls = []
    t0 = time.monotonic()
    while time.monotonic() - t0 < 20 and not (rolls and min(rolls) < -3.0 and max(rolls) > 3.0):
        s.sendto(_servo(m, time.time_ns() // 1000, 2000), ("127.0.0.1", port))  # full rudder: it rolls over
        t_read = time.monotonic()
        while time.monotonic() - t_read < 0.02:
            try:
                msg = mavlink.MAVLink(None).decode(bytearray(s.recv(4096)))
            except (TimeoutError, mavlink.MAVError):
                continue
            if msg.get_msgId() == mavlink.MAVLINK_MSG_ID_ATTITUDE:
                rolls.append(msg.roll)
    sitl.stop()
    s.close()
    assert rolls and all(-math.pi < r <= math.pi + 1e-6 for r in rolls)
    assert min(rolls) < -3.0 and max(rolls) > 3.0  # it went through +-180 deg, reported wrapped


def test_inverted_attitude_keeps_the_autopilot_out_of_failsafe(tmp_path):
    p = Procs(tmp_path, sitl=False, duration=3.0)
    s = udp_at(p.sitl_port)  # the test is the SITL, on the port the autopilot was given
    addr = _ap_sitl_addr(p, s)
    m = mav(1, 200)
    t0 = time.monotonic()
    while p.ap.p.poll() is None and time.monotonic() - t0 < 30:
        ms = int((time.monotonic() - t0) * 1000)
        roll = math.remainder(2.5 + 1.5 * ms / 1000.0, math.tau)  # rolling through +-180 deg, wrapped
        s.sendto(_attitude(m, ms, roll), addr)
        time.sleep(0.005)
    ap = p.finish()
    s.close()
    rej = ap["links"]["sitl"]["rejected"]
    assert "roll_out_of_range" not in rej and ap["events"].get("failsafes", 0) == 0
    assert ap["metric_samples"] > 0.9 * ap["steps"]


def udp_at(port: int) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", port))
    return sock


def _ap_sitl_addr(p: Procs, s) -> tuple:
    """The autopilot's SITL-link address: where its HEARTBEAT and SERVO_OUTPUT_RAW come from."""
    if getattr(p, "_ap_sitl", None) is None:
        s.settimeout(5)
        _data, addr = s.recvfrom(4096)
        s.settimeout(None)
        p._ap_sitl = addr
    return p._ap_sitl


def test_statustext_escapes_are_sanitised(tmp_path):
    p = Procs(tmp_path, sitl=False, duration=2.0)
    s = udp_at(p.sitl_port)  # the test is the autopilot's SITL
    g = mav(255, 190)
    p.gcs.sendto(_setpoint(g, 0.0), ("127.0.0.1", p.ap_gcs_port))  # and its ground station
    evil = b"evil\x1b[2J\x1b]0;owned\x07\nFAKE LINE\r"
    text = pack(mav(1, 200), mavlink.MAVLink_statustext_message(4, evil, 0, 0))
    addr = _ap_sitl_addr(p, s)
    for _ in range(3):
        s.sendto(text, addr)
        time.sleep(0.05)
    p.gcs.settimeout(0.2)
    forwarded = []
    t0 = time.monotonic()
    while time.monotonic() - t0 < 1.5:
        try:
            data = p.gcs.recv(4096)
        except TimeoutError:
            continue
        for msg in mavlink.MAVLink(None).parse_buffer(bytearray(data)) or []:
            if msg.get_msgId() == mavlink.MAVLINK_MSG_ID_STATUSTEXT:
                text = msg.text if isinstance(msg.text, str) else msg.text.decode("latin-1")
                if "evil" in text:
                    forwarded.append(text)
    ap = p.finish()
    s.close()
    log = p.ap.output()
    assert "evil" in log and "\x1b" not in log and "\x07" not in log and "FAKE LINE" in log
    assert "\nFAKE LINE" not in log  # the newline did not start a forged log line
    assert forwarded and all(t.isprintable() for t in forwarded), forwarded
    assert ap["events"]["statustext"] >= 3
