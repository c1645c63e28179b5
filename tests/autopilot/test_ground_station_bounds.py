"""Ground stations cannot starve, flood or lock out the loop (issue 31, items 6 and 7; docs/security.md, "A ground
station that holds the key"): real UDP sockets on 127.0.0.1, real MAVLink 2 signatures, real processes, every flood
bounded in count and time.

* budgets: each admitted peer's datagrams are checked within its own budget per control period, the rest read and
  dropped (``over_budget``), and one peer's flood costs another peer nothing;
* slots: a station admitted by its signature that sends no HEARTBEAT for MAVLink's heartbeat timeout (5 s) loses its
  slot, so squatters cannot lock a station out, and a refused station is told why;
* lockstep: setpoints lost between the GCS script and the autopilot (a relay that drops them) are sent again, and
  neither loss nor a flood changes a single bit of the result (``summary.json`` metrics) nor stalls the run;
* a key holder flooding requests: the answers, the log and the tlog stay bounded, the result is the same.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import time
from pathlib import Path

import pytest

from tests._mavlink_procs import PY, Proc, free_base_port, free_ports, load_json, run_cli
from tests._udp_relay import DroppingRelay

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as M  # noqa: E402

from autopilot.loop.common import GCS_SLOT_EXPIRE_S, PEER_BUDGET, PEER_BURST  # noqa: E402
from autopilot.shared.link import UdpLink  # noqa: E402
from autopilot.shared.signing import SIGNING_LINK_GCS, Signing  # noqa: E402
from autopilot.vehicle import REPLY_BURST, REPLY_RATE  # noqa: E402

SIGNING_EPOCH = 1420070400  # MAVLink 2 signing timestamps count 10 us from 2015-01-01


def _station(key: bytes | None, sysid: int = 255, compid: int = 230):
    """A pymavlink sender on its own socket, signing with ``key`` as MAVProxy does."""
    m = M.MAVLink(None, sysid, compid)
    if key is not None:
        m.signing.secret_key, m.signing.link_id, m.signing.sign_outgoing = key, 1, True
        m.signing.timestamp = int((time.time() - SIGNING_EPOCH) * 1e5)
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))

    def pack(msg) -> bytes:
        buf = msg.pack(m)
        m.seq = (m.seq + 1) & 0xFF
        return buf

    return s, pack


def _heartbeat():
    return M.MAVLink_heartbeat_message(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)


def _gcs_link(key: bytes, **kw) -> UdpLink:
    return UdpLink(
        "gcs",
        (1, 1),
        ("127.0.0.1", 0),
        ("127.0.0.1", 9),
        peers=[(255, None)],
        msgids=[M.MAVLINK_MSG_ID_HEARTBEAT, M.MAVLINK_MSG_ID_PARAM_REQUEST_LIST],
        admit=8,
        signing=Signing(key, SIGNING_LINK_GCS),
        **kw,
    )


def _read(link: UdpLink, n: int, timeout: float = 5.0) -> None:
    t0 = time.monotonic()
    while link.rx_datagrams < n and time.monotonic() - t0 < timeout:
        link.poll(lambda msg, t: None)


# ---------------------------------------------------------------------------------------------- budgets
def test_each_peer_is_checked_within_its_own_budget_and_a_floods_rest_is_dropped():
    """Two admitted stations; one sends 500 datagrams at once, the other 5.  The flooder gets its burst checked and
    the rest dropped unchecked (``over_budget``, counted per address), the other station every one of its five."""
    key = os.urandom(32)
    link = _gcs_link(key, peer_rate=0.01, peer_burst=20)  # nothing refills during the test
    (a, pack_a), (b, pack_b) = _station(key, compid=230), _station(key, compid=231)
    try:
        for s, pack in ((a, pack_a), (b, pack_b)):
            s.sendto(pack(_heartbeat()), link.local)
        _read(link, 2)
        assert len(link.admitted) == 2
        flood = [pack_a(M.MAVLink_param_request_list_message(1, 1)) for _ in range(500)]
        for d in flood:
            a.sendto(d, link.local)
        for _ in range(5):
            b.sendto(pack_b(_heartbeat()), link.local)
        _read(link, 507)
        # the first HEARTBEATs came from addresses not yet admitted (the others' budget): then 20 tokens each
        assert link.rx_datagrams == 507 and link.rejected == {"over_budget": 480}
        assert link.over_budget_peers == {a.getsockname(): 480} and link.rx_accepted == 2 + 20 + 5
        assert link.rx_datagrams == link.rx_accepted + sum(link.rejected.values())
    finally:
        for s in (a, b):
            s.close()
        link.close()


def test_the_autopilots_budgets_are_per_control_period():
    """What the autopilot asks of its links: 16 datagrams per control period for each ground station (256 at once),
    256 for all other addresses together; at 100 Hz, 1,600 and 25,600 a second."""
    assert (PEER_BUDGET, PEER_BURST) == (16, 256) and (REPLY_RATE, REPLY_BURST) == (50.0, 60.0)


# ------------------------------------------------------------------------------------------------- slots
def test_a_silent_signed_station_loses_its_slot_and_the_next_station_gets_it():
    """Eight stations signing with the key take the eight slots; seven keep sending HEARTBEAT, one goes silent.
    A ninth is refused while every slot is held, and takes the silent one's slot once it has been silent for
    GCS_SLOT_EXPIRE_S (the link's clock is moved on, the packets are real)."""
    key = os.urandom(32)
    link = _gcs_link(key, expire_s=GCS_SLOT_EXPIRE_S)
    expired = []
    link.on_expired = lambda addr, silent: expired.append((addr, silent))
    stations = [_station(key, compid=200 + i) for i in range(9)]
    try:
        for s, pack in stations[:8]:
            s.sendto(pack(_heartbeat()), link.local)
        _read(link, 8)
        t_admitted = time.perf_counter()
        assert len(link.admitted) == 8
        time.sleep(0.3)
        for s, pack in stations[1:8]:  # the first stays silent
            s.sendto(pack(_heartbeat()), link.local)
        ninth, pack9 = stations[8]
        ninth.sendto(pack9(_heartbeat()), link.local)
        _read(link, 16)
        assert link.rejected == {"not_peer": 1} and ninth.getsockname() not in link.admitted
        later = t_admitted + GCS_SLOT_EXPIRE_S + 0.2  # the silent one 5.2 s, the others 4.9 s at most
        assert [a for a, _ in link.expire(later)] == [stations[0][0].getsockname()]
        assert [a for a, _ in expired] == [stations[0][0].getsockname()] and expired[0][1] > GCS_SLOT_EXPIRE_S
        ninth.sendto(pack9(_heartbeat()), link.local)
        _read(link, 17)
        assert ninth.getsockname() in link.admitted and len(link.admitted) == 8
        assert link.counters()["expired"][0][0] == "%s:%d" % stations[0][0].getsockname()
    finally:
        for s, _ in stations:
            s.close()
        link.close()


@pytest.mark.e2e
def test_squatters_that_go_silent_do_not_lock_a_station_out_of_a_running_autopilot(tmp_path):
    """The issue's attack on a real autopilot process (lockstep, waiting for its SITL, its loop running): eight
    sockets signing with the key take every slot and go silent.  A station joining at once is refused and told why
    (the log line); within MAVLink's heartbeat timeout it is admitted and its PARAM_REQUEST_READ answered."""
    key = os.urandom(32)
    key_file = tmp_path / "k.key"
    key_file.write_text(key.hex())
    key_file.chmod(0o600)
    gcs_port, own = free_ports(2)
    ap = Proc(
        "autopilot",
        ["--lockstep", "--signing-key", str(key_file), "--listen", f"127.0.0.1:{own}", "--gcs",
         f"127.0.0.1:{gcs_port}", "--stats-json", str(tmp_path / "autopilot.json")],
        tmp_path / "autopilot.log",
    )  # fmt: skip
    squatters = [_station(key, compid=200 + i) for i in range(8)]
    late, pack = _station(key, compid=250)
    late_addr = "127.0.0.1:%d" % late.getsockname()[1]
    try:
        assert ap.wait_for("GCS link", 30)
        for s, p in squatters:
            s.sendto(p(_heartbeat()), ("127.0.0.1", own))
        time.sleep(0.5)
        late.settimeout(0.2)
        t0 = time.monotonic()
        answered = None
        while time.monotonic() - t0 < GCS_SLOT_EXPIRE_S + 5.0 and answered is None:
            late.sendto(pack(_heartbeat()), ("127.0.0.1", own))
            late.sendto(pack(M.MAVLink_param_request_read_message(1, 1, b"CLSAC_LV", -1)), ("127.0.0.1", own))
            try:
                while True:
                    data = late.recv(4096)
                    if data[7] == M.MAVLINK_MSG_ID_PARAM_VALUE:  # one packet per datagram for an answer
                        answered = time.monotonic() - t0
                        break
            except TimeoutError:
                pass
        assert answered is not None and 3.5 < answered < GCS_SLOT_EXPIRE_S + 3.0, answered
        log = ap.output()
        assert "refused: its address is not admitted: 8 ground stations are already" in log, log[-3000:]
        assert "dropped: no HEARTBEAT for" in log and "(its slot is free)" in log
    finally:
        ap.stop()
        for s, _ in squatters:
            s.close()
        late.close()
    stats = load_json(tmp_path / "autopilot.json")
    assert stats["events"]["gcs_slots_expired"] >= 1
    assert late_addr in stats["links"]["gcs"]["admitted"]


# --------------------------------------------------------------------------------- lockstep: loss and floods
def _by_hand(out: Path, drop: float, seed: int, duration: float = 10.0, gcs_args: tuple = ()) -> dict:
    """A signed lockstep flight of the three processes by hand, the GCS script behind a ``DroppingRelay`` losing
    setpoints."""
    out.mkdir(parents=True, exist_ok=True)
    key = out / "k.key"
    key.write_text(os.urandom(32).hex())
    key.chmod(0o600)
    sitl_p, ap_sitl_p, ap_gcs_p, gcs_p = free_ports(4)
    relay = DroppingRelay(ap_gcs_p, gcs_p, M.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET, drop, seed)
    common = ["--lockstep", "--signing-key", str(key)]
    procs = [
        Proc("sitl", ["--listen", f"127.0.0.1:{sitl_p}", "--autopilot", f"127.0.0.1:{ap_sitl_p}", "--duration",
                      str(duration), *common], out / "sitl.log"),
        Proc("tools.gcs", ["--listen", f"127.0.0.1:{gcs_p}", "--vehicle", "%s:%d" % relay.b.getsockname(),
                           "--duration", str(duration), "--quiet", "--stats-json", str(out / "gcs.json"), *common,
                           *gcs_args],
             out / "gcs.log"),
        Proc("autopilot", ["--sitl", f"127.0.0.1:{sitl_p}", "--sitl-bind", f"127.0.0.1:{ap_sitl_p}", "--listen",
                           f"127.0.0.1:{ap_gcs_p}", "--gcs", "%s:%d" % relay.a.getsockname(), "--gcs-peer",
                           "%s:%d" % relay.a.getsockname(), "--duration", str(duration), "--telemetry-rate", "10",
                           "--lockstep-idle-exit", "5", "--quiet", "--stats-json", str(out / "autopilot.json"),
                           *common], out / "autopilot.log"),
    ]  # fmt: skip
    try:
        codes = [p.p.wait(120) for p in reversed(procs)]
    finally:
        for p in procs:
            p.stop(5)
        relay.close()
    ap, gcs = load_json(out / "autopilot.json"), load_json(out / "gcs.json")
    return {"codes": codes, "ap": ap, "gcs": gcs, "relay": (relay.matched, relay.dropped)}


@pytest.mark.e2e
def test_setpoints_lost_in_lockstep_are_sent_again_and_change_no_bit(tmp_path):
    """A relay drops 40 % of the GCS script's setpoint datagrams (seeded).  The autopilot takes only setpoints that
    continue the schedule it holds, the GCS script sends again what the autopilot's SYSTEM_TIME shows it lacks:
    the flight completes, with the very metrics of the flight through a relay that drops nothing."""
    clean = _by_hand(tmp_path / "clean", 0.0, 1)
    lossy = _by_hand(tmp_path / "lossy", 0.4, 7)
    for run in (clean, lossy):
        assert run["codes"][0] == 0 and run["codes"][1] == 0, run["codes"]  # the autopilot and the GCS script
        assert run["ap"]["steps"] == 1000 and run["ap"]["exit_reason"].startswith("end of run")
    assert clean["relay"][1] == 0 and clean["gcs"]["schedule_resends"] == 0
    assert lossy["relay"][1] >= 5 and lossy["gcs"]["schedule_resends"] >= 1, (lossy["relay"], lossy["gcs"])
    assert lossy["ap"]["metrics"] == clean["ap"]["metrics"]  # every bit (json round-trips floats exactly)
    assert lossy["ap"]["events"]["setpoints"] == clean["ap"]["events"]["setpoints"] == 101


def _launch(out: Path, base_port: int, *extra: str, duration: str = "20") -> dict:
    r = run_cli(
        "tools.launch", "--lockstep", "--duration", duration, "--base-port", str(base_port), "--out", str(out),
        "--quiet", "--no-png", "--no-rrd", "--timeout", "240", *extra, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    return json.loads((out / "summary.json").read_text())


_UNSIGNED_FLOOD = r"""
import socket, sys, time
port, secs, count = int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
pkt = bytes.fromhex("fd0900000bffbe000000000000000006080000000356a1")  # a HEARTBEAT from 255:190, unsigned
socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(200)]
t_end, n = time.monotonic() + secs, 0
while time.monotonic() < t_end and n < count:
    for s in socks:
        try:
            s.sendto(pkt, ("127.0.0.1", port))
        except OSError:
            pass
    n += len(socks)
print(n)
"""


@pytest.mark.e2e
def test_a_flood_without_the_key_from_200_sockets_changes_no_bit_of_a_lockstep_flight(tmp_path):
    """200 sockets flood the autopilot's ground-station port with unsigned packets (at most 3 million datagrams or
    60 s) through a 20 s lockstep flight: every metric is the unflooded flight's."""
    clean = _launch(tmp_path / "clean", free_base_port())
    base = free_base_port()
    flood = subprocess.Popen([PY, "-c", _UNSIGNED_FLOOD, str(base + 3), "60", "3000000"], stdout=subprocess.PIPE)
    try:
        flooded = _launch(tmp_path / "flooded", base)
    finally:
        flood.kill()
        flood.wait()
    assert flooded["runs"][0]["metrics"] == clean["runs"][0]["metrics"]
    rejected = load_json(tmp_path / "flooded" / "autopilot.json")["links"]["gcs"]["rejected"]
    assert sum(rejected.values()) > 10_000, rejected  # the flood was there


_KEY_FLOOD = r"""
import os, socket, sys, time
os.environ["MAVLINK20"] = "1"
from pymavlink.dialects.v20 import common as M
port, secs, key = int(sys.argv[1]), float(sys.argv[2]), bytes.fromhex(open(sys.argv[3]).read().strip())
mav = M.MAVLink(None, 255, 230)
mav.signing.secret_key, mav.signing.link_id, mav.signing.sign_outgoing = key, 7, True
mav.signing.timestamp = int((time.time() - 1420070400) * 1e5)
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
msgs = [M.MAVLink_param_request_list_message(1, 1),
        M.MAVLink_param_set_message(1, 1, b"CLSAC_AM", 3.0, M.MAV_PARAM_TYPE_REAL32),  # refused: A_m < 0
        M.MAVLink_command_long_message(1, 1, 31000, 0, 0, 0, 0, 0, 0, 0, 0),  # unsupported
        M.MAVLink_statustext_message(6, b"flood", 0, 0),
        M.MAVLink_heartbeat_message(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)]
t_end, n = time.monotonic() + secs, 0
while time.monotonic() < t_end:
    for m in msgs:
        try:
            s.sendto(m.pack(mav), ("127.0.0.1", port))
        except OSError:
            pass
        mav.seq = (mav.seq + 1) & 255
        n += 1
print(n)
"""


@pytest.mark.e2e
def test_a_key_holder_flooding_requests_is_bounded_and_changes_no_bit(tmp_path):
    """A station with the flight's key floods PARAM_REQUEST_LIST, a refused PARAM_SET, an unsupported COMMAND_LONG
    and STATUSTEXT through a 20 s lockstep flight (at most 60 s).  The result is the unflooded flight's to the bit;
    the answers are at most the reply budget's (REPLY_BURST + REPLY_RATE per wall second); the refusals are five log
    lines and a summary per 10 s, not one per PARAM_SET; the tlog grows by at most what the peer budget lets in."""
    key = tmp_path / "k.key"
    key.write_text(os.urandom(32).hex())
    key.chmod(0o600)
    clean = _launch(tmp_path / "clean", free_base_port(), "--signing-key", str(key))
    base = free_base_port()
    flood = subprocess.Popen([PY, "-c", _KEY_FLOOD, str(base + 3), "60", str(key)], stdout=subprocess.PIPE)
    try:
        time.sleep(0.5)  # the flooder's imports
        flooded = _launch(tmp_path / "flooded", base, "--signing-key", str(key))
    finally:
        flood.kill()
        flood.wait()
    assert flooded["runs"][0]["metrics"] == clean["runs"][0]["metrics"]
    ap = load_json(tmp_path / "flooded" / "autopilot.json")
    gcs, wall = ap["links"]["gcs"], ap["sent"]["ended_mono"] - ap["sent"]["first_mono"]  # the loop's whole run
    assert ap["events"]["param_rejected"] > 100 and gcs["rejected"]["over_budget"] > 1000, (ap["events"], gcs)
    # each answer goes to every ground station: the GCS script and the flooder (counted once per address)
    answers = (gcs["tx_by_type"].get("PARAM_VALUE", 0) + gcs["tx_by_type"].get("PARAM_ERROR", 0)) / 2
    # less the parameter list the GCS script itself asks for once on connecting (the unflooded flight's, to it alone)
    own = load_json(tmp_path / "clean" / "autopilot.json")["links"]["gcs"]["tx_by_type"].get("PARAM_VALUE", 0)
    assert 0 < answers - own <= REPLY_BURST + REPLY_RATE * wall, (answers, own, wall)
    log = (tmp_path / "flooded" / "autopilot.log").read_text().splitlines()
    refusals = [ln for ln in log if "CLSAC_AM=3 rejected" in ln]
    assert 5 <= len(refusals) <= 5 + wall / 10 + 1, refusals
    assert any("more refused PARAM_SET events in the last" in ln for ln in log)
    clean_tlog = (tmp_path / "clean" / "flight.tlog").stat().st_size
    grown = (tmp_path / "flooded" / "flight.tlog").stat().st_size - clean_tlog
    let_in = PEER_BURST + PEER_BUDGET * 100 * wall  # datagrams the flooder's budget takes, one packet each
    assert grown <= (let_in + REPLY_BURST + REPLY_RATE * wall) * (8 + 12 + 255 + 13), (grown, let_in)


@pytest.mark.e2e
def test_a_profile_that_starts_after_the_first_frame_is_recovered_too(tmp_path):
    """The GCS script started by hand with ``--start-time 1`` against a SITL at 0 s: its schedule begins after the
    frame the autopilot waits at, so its first datagram leads with that frame and the command flown until the
    profile starts (0).  It used to be refused as unlinked and resent without end; now the flight completes, with
    and without 40 % of the setpoint datagrams lost, to the same bits."""
    clean = _by_hand(tmp_path / "clean", 0.0, 1, gcs_args=("--start-time", "1"))
    lossy = _by_hand(tmp_path / "lossy", 0.4, 3, gcs_args=("--start-time", "1"))
    for run in (clean, lossy):
        assert run["codes"][:2] == [0, 0] and run["ap"]["steps"] == 1000, run["codes"]
    assert lossy["relay"][1] >= 3 and lossy["ap"]["metrics"] == clean["ap"]["metrics"]
