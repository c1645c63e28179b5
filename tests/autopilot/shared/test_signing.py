"""MAVLink 2 signing: the bytes against pymavlink's own signing, the checks by reason, key files, and a signed flight
that rejects an unsigned, a wrong-key and a replayed SET_ATTITUDE_TARGET while the same flight unsigned obeys them."""

from __future__ import annotations

import math
import os
import threading
import time

import pytest

from autopilot.shared.link import UdpLink
from autopilot.shared.mavlink import roll_to_quaternion
from autopilot.shared.signing import KeyFileError, Signing, load_key, now_stamp, write_key
from tests._mavlink_procs import Proc, free_ports, load_json, mavlink, run_cli, udp

KEY = bytes(range(32))
OTHER = bytes(range(1, 33))


def _pymavlink(key: bytes | None, sysid=255, compid=190, link_id=7, stamp=None):
    """An independent signer: pymavlink's MAVLink.signing."""
    m = mavlink.MAVLink(None, sysid, compid)
    if key is not None:
        m.signing.secret_key = key
        m.signing.link_id = link_id
        m.signing.sign_outgoing = True
        m.signing.timestamp = now_stamp() if stamp is None else stamp
    return m


def _setpoint(m, roll_deg: float) -> bytes:
    q = roll_to_quaternion(math.radians(roll_deg))
    buf = mavlink.MAVLink_set_attitude_target_message(0, 1, 1, 71, q, 0.0, 0.0, 0.0, 0.0).pack(m)
    m.seq = (m.seq + 1) & 0xFF
    return buf


def test_fast_packer_signs_byte_identically_to_pymavlink():
    stamp = now_stamp() + 10_000_000  # ahead of the clock: both use exactly this timestamp
    sig = Signing(KEY, link_id=3)
    sig._ts = stamp - 1
    link = UdpLink("t", (1, 200), ("127.0.0.1", 0), ("127.0.0.1", 9), peers=[], msgids=[], signing=sig)
    fast = link.pack_fast(link.fast_packer(mavlink.MAVLink_attitude_message), 1234, 0.5, 0.0, 0.0, 0.1, 0.0, -0.2)
    ref = mavlink.MAVLink_attitude_message(1234, 0.5, 0.0, 0.0, 0.1, 0.0, -0.2).pack(
        _pymavlink(KEY, 1, 200, link_id=3, stamp=stamp)
    )
    assert fast == bytes(ref) and fast[2] & 1 and len(fast) == 12 + fast[1] + 13
    link.close()


def test_check_by_reason():
    packet = bytes(_setpoint(_pymavlink(KEY), 5.0))
    rx = Signing(KEY)
    assert rx.check(packet, 255, 190) is None
    assert rx.check(packet, 255, 190) == "replay"  # the same timestamp again
    assert Signing(OTHER).check(packet, 255, 190) == "bad_signature"
    old = bytes(_setpoint(_pymavlink(KEY, stamp=now_stamp() - 2 * 60 * 100_000), 5.0))  # recorded 2 min ago
    assert Signing(KEY).check(old, 255, 190) == "replay"
    forged = bytearray(_setpoint(_pymavlink(OTHER, stamp=now_stamp() + 10**9), 5.0))
    fresh = Signing(KEY)
    assert fresh.check(bytes(forged), 255, 190) == "bad_signature" and not fresh.streams  # cannot move the clock


def test_link_rejects_unsigned_wrong_key_and_replayed_packets():
    rx = UdpLink(
        "t",
        (1, 1),
        ("127.0.0.1", 0),
        None,
        peers=[(255, 190)],
        msgids=[mavlink.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET],
        learn_remote=True,
        signing=Signing(KEY),
    )
    tx = udp()
    good = _setpoint(_pymavlink(KEY), 5.0)
    payloads = [good, good, _setpoint(_pymavlink(None), 5.0), _setpoint(_pymavlink(OTHER), 5.0)]
    for p in payloads:
        tx.sendto(p, rx.local)
    got = []
    t0 = time.monotonic()
    while rx.rx_datagrams < len(payloads) and time.monotonic() - t0 < 5:
        rx.poll(lambda msg, t: got.append(msg))
    assert len(got) == 1
    assert rx.rejected == {"replay": 1, "unsigned": 1, "bad_signature": 1}
    rx.close()
    tx.close()


def test_key_files(tmp_path):
    path = tmp_path / "k"
    key = write_key(path)
    assert load_key(path) == key and os.stat(path).st_mode & 0o777 == 0o600
    with pytest.raises(FileExistsError):
        write_key(path)
    os.chmod(path, 0o644)
    with pytest.raises(KeyFileError, match="chmod 600"):
        load_key(path)
    short = tmp_path / "short"
    short.write_text("abcd\n")
    os.chmod(short, 0o600)
    with pytest.raises(KeyFileError, match="2 bytes, expected 32"):
        load_key(short)
    with pytest.raises(KeyFileError, match="no such file"):
        load_key(tmp_path / "none")


@pytest.mark.e2e
def test_keygen_and_bad_keys_are_one_line_errors(tmp_path):
    key = tmp_path / "flight.key"
    r = run_cli("tools.flight.keygen", str(key))
    assert r.returncode == 0 and os.stat(key).st_mode & 0o777 == 0o600
    assert run_cli("tools.flight.keygen", str(key)).returncode == 2  # never overwrites a key
    open_key = tmp_path / "open.key"
    open_key.write_text(key.read_text())
    os.chmod(open_key, 0o644)
    for module in ("sitl", "autopilot", "tools.gcs", "tools.launch"):
        for bad, needle in ((tmp_path / "missing.key", "no such file"), (open_key, "lets others read it")):
            r = run_cli(module, "--signing-key", str(bad), timeout=60)
            assert r.returncode == 2, (module, r.stderr)
            lines = r.stderr.strip().splitlines()
            assert len(lines) == 1 and needle in lines[0] and "--signing-key" in lines[0], (module, r.stderr)


def _flight_with_attacks(tmp_path, signed: bool) -> dict:
    """Real-time SITL + autopilot; the test is the ground station: a legit stream of signed 0 deg setpoints, one
    legit 50 deg setpoint, then N unsigned, N wrong-key and N replayed (the legit 50 deg bytes) 50 deg ones."""
    key_file = tmp_path / "k.key"
    write_key(key_file, KEY)
    sign = ["--signing-key", str(key_file)] if signed else []
    sitl_port = free_ports(1)[0]
    gcs = udp()
    sitl_args = ["--listen", f"127.0.0.1:{sitl_port}", "--stats-json", str(tmp_path / "sitl.json"), *sign]
    sitl = Proc("sitl", sitl_args, tmp_path / "sitl.log")
    assert sitl.wait_for("listening on")
    ap_port = free_ports(1)[0]
    ap = Proc(
        "autopilot",
        ["--sitl", f"127.0.0.1:{sitl_port}", "--listen", f"127.0.0.1:{ap_port}", "--gcs"]
        + [f"127.0.0.1:{gcs.getsockname()[1]}", "--duration", "4", "--stats-json", str(tmp_path / "ap.json"), *sign],
        tmp_path / "ap.log",
    )
    assert ap.wait_for("autopilot:")
    to = ("127.0.0.1", ap_port)
    legit = _pymavlink(KEY if signed else None)
    n = 10
    gcs.sendto(_setpoint(legit, 0.0), to)
    time.sleep(0.5)
    fifty = _setpoint(legit, 50.0)
    gcs.sendto(fifty, to)  # legit: clamped to 45 deg once
    attacks = [_setpoint(_pymavlink(None), 50.0) for _ in range(n)]  # unsigned
    attacks += [_setpoint(_pymavlink(OTHER, link_id=9), 50.0) for _ in range(n)]  # signed with a wrong key
    attacks += [fifty] * n  # replayed
    for pkt in attacks:
        gcs.sendto(_setpoint(legit, 0.0), to)
        gcs.sendto(pkt, to)
        time.sleep(0.02)
    while ap.p.poll() is None:
        gcs.sendto(_setpoint(legit, 0.0), to)
        time.sleep(0.05)
    assert ap.p.wait(30) == 0, ap.output()
    ap.stop()
    assert sitl.stop() == 0
    gcs.close()
    return load_json(tmp_path / "ap.json")


@pytest.mark.e2e
def test_signed_flight_rejects_unsigned_wrong_key_and_replayed_setpoints(tmp_path):
    ap = _flight_with_attacks(tmp_path, signed=True)
    rej = ap["links"]["gcs"]["rejected"]
    assert rej.get("unsigned") == 10 and rej.get("bad_signature") == 10 and rej.get("replay") == 10, rej
    assert ap["events"]["setpoints_clamped"] == 1, ap["events"]  # only the legit 50 deg setpoint was flown
    sitl_rej = ap["links"]["sitl"]["rejected"]
    assert not {"unsigned", "bad_signature", "replay"} & set(sitl_rej), sitl_rej  # the SITL link signed both ways
    assert ap["links"]["sitl"]["rx_by_type"]["ATTITUDE"] > 300


@pytest.mark.e2e
def test_the_same_flight_unsigned_obeys_them(tmp_path):
    ap = _flight_with_attacks(tmp_path, signed=False)
    rej = ap["links"]["gcs"]["rejected"]
    assert not {"unsigned", "bad_signature", "replay"} & set(rej)
    assert ap["events"]["setpoints_clamped"] == 1 + 30  # every forged 50 deg setpoint was obeyed


class _LossyProxy:
    """A UDP relay between a lockstep SITL and its autopilot that drops the ``drop_at``-th datagram carrying
    message ``msgid`` (one real lost datagram, whatever the direction)."""

    def __init__(self, sitl_addr, msgid: int, drop_at: int):
        self.sitl_addr, self.msgid, self.drop_at = sitl_addr, msgid, drop_at
        self.to_sitl, self.to_ap = udp(), udp()  # the SITL hears the autopilot at to_sitl; the autopilot's --sitl
        self.ap_addr = None
        self.seen = 0
        self.dropped = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    @property
    def for_autopilot(self) -> str:
        return f"127.0.0.1:{self.to_ap.getsockname()[1]}"

    @property
    def for_sitl(self) -> str:
        return f"127.0.0.1:{self.to_sitl.getsockname()[1]}"

    def _lose(self, data: bytes) -> bool:
        if len(data) > 10 and data[0] == 0xFD and (data[7] | data[8] << 8 | data[9] << 16) == self.msgid:
            self.seen += 1
            if self.seen == self.drop_at:
                self.dropped += 1
                return True
        return False

    def _run(self) -> None:
        import select

        while not self._stop.is_set():
            for sock in select.select([self.to_sitl, self.to_ap], [], [], 0.05)[0]:
                data, addr = sock.recvfrom(4096)
                if self._lose(data):
                    continue
                if sock is self.to_ap:  # from the autopilot
                    self.ap_addr = addr
                    self.to_sitl.sendto(data, self.sitl_addr)
                elif self.ap_addr is not None:  # from the SITL
                    self.to_ap.sendto(data, self.ap_addr)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.to_sitl.close()
        self.to_ap.close()


@pytest.mark.e2e
@pytest.mark.parametrize("lost", ["SERVO_OUTPUT_RAW", "ATTITUDE"])
def test_signed_lockstep_recovers_a_lost_datagram(tmp_path, lost):
    """One datagram lost between a signed lockstep SITL and autopilot: the SITL resends the frame and, when the
    answer was the one lost, the autopilot resends its answer.  Both resends are signed again, so neither is taken
    for a replay, and the flight flies every frame (with byte-identical resends it stalled: ``replay``)."""
    key_file = tmp_path / "k.key"
    write_key(key_file, KEY)
    sign = ["--signing-key", str(key_file)]
    sitl_port = free_ports(1)[0]
    msgid = {"SERVO_OUTPUT_RAW": mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW, "ATTITUDE": mavlink.MAVLINK_MSG_ID_ATTITUDE}
    proxy = _LossyProxy(("127.0.0.1", sitl_port), msgid[lost], drop_at=200)
    procs = []
    try:
        sitl = Proc(
            "sitl",
            ["--lockstep", "--listen", f"127.0.0.1:{sitl_port}", "--autopilot", proxy.for_sitl, "--duration", "5"]
            + ["--give-up", "3", "--stats-json", str(tmp_path / "sitl.json"), *sign],
            tmp_path / "sitl.log",
        )
        procs.append(sitl)
        assert sitl.wait_for("listening on")
        ap = Proc(
            "autopilot",
            ["--lockstep", "--no-pace", "--sitl", proxy.for_autopilot, "--listen", f"127.0.0.1:{free_ports(1)[0]}"]
            + ["--duration", "5", "--stats-json", str(tmp_path / "ap.json"), *sign],
            tmp_path / "ap.log",
        )
        procs.append(ap)
        assert ap.p.wait(60) == 0, ap.output()
        assert sitl.p.wait(30) == 0, sitl.output()
    finally:
        for proc in procs:
            proc.stop()
        proxy.close()
    assert proxy.dropped == 1
    ap_stats, sitl_stats = load_json(tmp_path / "ap.json"), load_json(tmp_path / "sitl.json")
    assert ap_stats["steps"] == 500 and sitl_stats["frames"] == 500  # every frame flown, one step each
    assert sitl_stats["events"]["resends"] >= 1
    if lost == "SERVO_OUTPUT_RAW":
        assert ap_stats["events"]["duplicate_frames"] >= 1  # the frame came again: the answer was resent
    for rej in (ap_stats["links"]["sitl"]["rejected"], sitl_stats["link"]["rejected"]):
        assert not {"replay", "bad_signature", "unsigned"} & set(rej), rej
