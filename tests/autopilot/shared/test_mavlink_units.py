"""MAVLink plumbing without processes: frame clock and its uint32 wrap, PWM calibration, tlog format,
and the link's framing/filtering on real UDP sockets."""

from __future__ import annotations

import math
import os
import random
import subprocess
import time

import pytest

from autopilot.shared import mavlink as P
from autopilot.shared.link import UdpLink
from autopilot.shared.pwm import PwmConfigError, PwmMap
from autopilot.shared.tlog import TlogWriter, packet_payload, payload_streams, read_tlog
from tests._mavlink_procs import PY, mav, mavlink, pack, udp
from tools.flight.profiles import from_csv, hold, square


# ------------------------------------------------------------------------------------------- frames
@pytest.mark.parametrize("rate", [100, 400, 250, 1000, 300, 50, 120.0])
def test_frame_ms_round_trip(rate):
    for k in list(range(0, 5000)) + list(range(1_700_000, 1_720_000, 7)):
        assert P.frame_from_ms(P.frame_ms(k, rate), rate) == k


def test_frame_usec_wraps_at_2_pow_32():
    rate = 100
    k_wrap = (1 << 32) // 10_000  # last frame before the wrap at 100 Hz (10 ms frames)
    before = P.frame_usec(k_wrap, rate)
    after = P.frame_usec(k_wrap + 1, rate)
    assert before > 4_294_900_000 and after < 10_000
    assert P.usec_newer(after, before) and not P.usec_newer(before, after)
    assert P.usec_diff(after, before) == 10_000
    assert P.usec_diff(before, after) == -10_000
    assert P.frame_usec(k_wrap + 1, rate) == (k_wrap + 1) * 10_000 - (1 << 32)
    # the frame index itself survives the wrap: recovered from time_boot_ms, which does not wrap for 49 days
    for k in range(k_wrap - 3, k_wrap + 3):
        assert P.frame_from_ms(P.frame_ms(k, rate), rate) == k
    # 400 Hz: 2500 us frames
    assert P.frame_usec(1_717_987, 400) == (1_717_987 * 2500) % (1 << 32)


def test_usec_newer_is_wrap_aware():
    assert P.usec_newer(5, 0xFFFFFFF0)
    assert not P.usec_newer(0xFFFFFFF0, 5)
    assert not P.usec_newer(7, 7)
    assert P.usec_newer(2_000_000, 1_000_000)


def test_quaternion_roll_round_trip():
    for deg in (-179, -45, -10, 0, 0.001, 10, 44.9, 90, 170):
        r = math.radians(deg)
        assert P.quaternion_to_roll(P.roll_to_quaternion(r)) == pytest.approx(r, abs=1e-12)
    assert math.isnan(P.quaternion_to_roll([math.nan, 0, 0, 0]))
    assert math.isnan(P.quaternion_to_roll([0, 0, 0, 0]))
    assert math.isnan(P.quaternion_to_roll([math.inf, 1, 0, 0]))
    # a non-normalised quaternion is normalised
    assert P.quaternion_to_roll([2 * math.cos(0.1), 2 * math.sin(0.1), 0, 0]) == pytest.approx(0.2)


# --------------------------------------------------------------------------------------------- pwm
def test_pwm_default_calibration():
    m = PwmMap()
    assert m.to_pwm(0.0) == 1500
    assert m.to_pwm(math.radians(30)) == 2000 and m.to_pwm(math.radians(-30)) == 1000
    assert m.to_pwm(math.radians(90)) == 2000 and m.to_pwm(-9.0) == 1000  # clamped
    assert m.to_rad(1500) == 0.0 and m.to_rad(2000) == pytest.approx(math.radians(30))
    # 1 us resolution: 0.06 deg
    assert m.to_rad(1501) == pytest.approx(math.radians(0.06))
    for u in (-0.5, -0.01, 0.0, 0.002, 0.3):
        assert (
            abs(m.to_rad(m.to_pwm(u)) - max(-m.rudder_max_rad, min(m.rudder_max_rad, u))) <= math.radians(0.03) + 1e-12
        )
    assert m.servo_fields(1600)[3] == 1600 and sum(m.servo_fields(1600)) == 1600


def test_pwm_asymmetric_and_invalid():
    m = PwmMap(pwm_min=1100, pwm_max=1900, pwm_trim=1520, rudder_max_rad=math.radians(25), channel=2)
    assert m.to_pwm(0.0) == 1520 and m.to_pwm(math.radians(25)) == 1900 and m.to_pwm(math.radians(-25)) == 1100
    assert m.servo_fields(1700)[1] == 1700
    for bad in (dict(pwm_min=1600), dict(pwm_trim=2100), dict(channel=0), dict(rudder_max_rad=0.0)):
        with pytest.raises(PwmConfigError):
            PwmMap(**bad)


# -------------------------------------------------------------------------------------------- tlog
def test_tlog_round_trip_and_mavlogdump(tmp_path):
    path = tmp_path / "t.tlog"
    w = TlogWriter(str(path))
    m = mav(1, 1)
    raws = []
    for k in range(50):
        raw = pack(m, mavlink.MAVLink_attitude_message(k * 10, 0.01 * k, 0, 0, 0.1, 0, 0.2))
        w.write(raw, t_us=1_700_000_000_000_000 + k)
        raws.append(raw)
    w.close()
    recs = list(read_tlog(str(path)))
    assert [r for _t, r in recs] == raws and recs[0][0] == 1_700_000_000_000_000
    # a truncated tail (killed run) is ignored by the reader
    with open(path, "ab") as f:
        f.write(b"\x00\x01\x02\x03\x04\x05\x06\x07\xfd\x1c")
    assert len(list(read_tlog(str(path)))) == 50
    dump = subprocess.run(
        [PY, "-m", "pymavlink.tools.mavlogdump", str(path)], capture_output=True, text=True, timeout=60
    )
    assert dump.returncode == 0
    assert dump.stdout.count("ATTITUDE {") == 50
    streams = payload_streams(str(path))
    assert len(streams[(1, 1, 30)]) == 50
    assert packet_payload(raws[3])[:3] == b"\x1e\x00\x00"


# -------------------------------------------------------------------------------------------- link
def _link(**kw):
    kw.setdefault("learn_remote", True)
    return UdpLink(
        "t", (1, 1), ("127.0.0.1", 0), None, peers=[(1, 200)], msgids=[mavlink.MAVLINK_MSG_ID_ATTITUDE], **kw
    )


def _deliver(link, tx, payloads):
    for p in payloads:
        tx.sendto(p, link.local)
    got = []
    t0 = time.monotonic()
    while link.rx_datagrams < len(payloads) and time.monotonic() - t0 < 5:
        link.poll(lambda msg, t: got.append(msg))
        time.sleep(0.001)
    return got


def test_link_accepts_valid_and_rejects_each_kind_of_bad_input():
    link = _link()
    tx = udp()
    good = mav(1, 200)
    ok = pack(good, mavlink.MAVLink_attitude_message(1, 0.1, 0, 0, 0, 0, 0))
    bad_crc = bytearray(ok)
    bad_crc[12] ^= 0x55
    wrong = pack(mav(3, 200), mavlink.MAVLink_attitude_message(1, 0.1, 0, 0, 0, 0, 0))
    other = pack(good, mavlink.MAVLink_heartbeat_message(1, 0, 0, 0, 0, 3))
    unknown = bytearray(pack(good, mavlink.MAVLink_heartbeat_message(1, 0, 0, 0, 0, 3)))
    unknown[7:10] = b"\xee\xee\x00"  # msgid 61166: not in the common dialect
    v1 = mavlink.MAVLink_attitude_message(1, 0.2, 0, 0, 0, 0, 0).pack(good, force_mavlink1=True)
    wrong_crc_and_id = bytearray(wrong)
    wrong_crc_and_id[12] ^= 0x55  # a bit flip in a packet with the wrong IDs: the CRC is checked first
    payloads = [ok, ok + ok, b"\x00hello", ok[:9], ok[:-3], bytes(bad_crc), wrong, other, bytes(unknown), v1]
    payloads += [b"", bytes(wrong_crc_and_id), ok + b"\x00junk"]
    got = _deliver(link, tx, payloads)
    assert len(got) == 4  # ok, the two packets of ok+ok, the one before the junk; never the MAVLink 1 packet
    assert all(m.roll == pytest.approx(0.1) for m in got)
    assert link.rejected == {
        "empty": 1,
        "bad_magic": 1,
        "mavlink1": 1,
        "truncated": 2,
        "bad_crc": 2,
        "wrong_id": 1,
        "ignored_msg": 1,
        "unknown_msg": 1,
    }
    # every datagram once, under exactly one outcome
    assert link.rx_accepted == 3 and link.rx_packets == 4 and link.rx_datagrams == len(payloads)
    assert link.rx_datagrams == link.rx_accepted + sum(link.rejected.values())
    link.close()
    tx.close()


def test_other_dialects_messages_are_checked_by_their_crc_whether_known_by_heart_or_loaded():
    """The vehicle's CURRENT_MODE (development) and AOA_SSA (ardupilotmega) are checked by the table of
    ``OTHER_DIALECT_MESSAGES``, any other dialect's message (ardupilotmega's MEMINFO) by pymavlink's ``all`` dialect
    loaded at its first one: valid ones are ignored_msg, a flipped bit is bad_crc.  The table is pymavlink's."""
    from pymavlink.dialects.v20 import all as every

    for mid, (name, extra) in P.OTHER_DIALECT_MESSAGES.items():
        cls = every.mavlink_map[mid]
        assert (cls.msgname, cls.crc_extra) == (name, extra) and mid not in mavlink.mavlink_map
    m = every.MAVLink(None, 1, 200)
    msgs = [
        every.MAVLink_current_mode_message(every.MAV_STANDARD_MODE_NON_STANDARD, 3, 3),
        every.MAVLink_aoa_ssa_message(5, 1.5, -0.5),
        every.MAVLink_meminfo_message(100, 2000, 3000),
    ]
    assert every.MAVLINK_MSG_ID_MEMINFO not in P.OTHER_DIALECT_MESSAGES
    good = [bytes(msg.pack(m)) for msg in msgs]
    bad = []
    for raw in good:
        b = bytearray(raw)
        b[11] ^= 0x01  # a payload bit
        bad.append(bytes(b))
    link = _link()
    tx = udp()
    _deliver(link, tx, good + bad)
    assert link.rejected == {"ignored_msg": 3, "bad_crc": 3}
    link.close()
    tx.close()


def test_link_survives_random_bytes():
    link = _link()
    tx = udp()
    rng = random.Random(1)
    payloads = [bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300))) for _ in range(500)]
    payloads += [b"\xfd" + bytes(rng.randrange(256) for _ in range(rng.randrange(1, 60))) for _ in range(500)]
    got = _deliver(link, tx, payloads)
    assert got == []
    assert link.rx_datagrams == 1000 and sum(link.rejected.values()) == 1000
    link.close()
    tx.close()


def test_link_send_writes_tlog(tmp_path):
    w = TlogWriter(str(tmp_path / "x.tlog"))
    rx = udp()
    link = UdpLink("t", (1, 1), ("127.0.0.1", 0), rx.getsockname(), peers=[], msgids=[], tlog=w)
    raw = link.send(mavlink.MAVLink_heartbeat_message(1, 0, 0, 0, 0, 3))
    link.send(mavlink.MAVLink_heartbeat_message(1, 0, 0, 0, 0, 3))
    w.close()
    assert rx.recv(100) == raw
    recs = list(read_tlog(str(tmp_path / "x.tlog")))
    assert len(recs) == 2 and recs[0][1] == raw and recs[1][1][4] == 1  # sequence numbers advance
    link.close()
    rx.close()


# ---------------------------------------------------------------------------------------- profiles
def test_csv_profile(tmp_path):
    p = tmp_path / "p.csv"
    p.write_text("time_s,roll_deg\n0,0\n1.5,10\n# comment\n3,-5\n")
    t, r = from_csv(str(p))
    assert t == [0.0, 1.5, 3.0] and r[1] == pytest.approx(math.radians(10))
    assert hold(1.49, t, r) == 0.0 and hold(1.5, t, r) == r[1] and hold(99, t, r) == r[2]
    bad = tmp_path / "bad.csv"
    bad.write_text("0,0\n2,1\n1,1\n")
    with pytest.raises(ValueError, match="increase"):
        from_csv(str(bad))
    assert square(5.0, 1.0, 10.0) == -1.0 and square(4.99, 1.0, 10.0) == 1.0
    os.remove(p)


# ----------------------------------------------------------------------------------------- fastmav
def test_fast_codec_is_byte_identical_to_pymavlink():
    from autopilot.shared.fastmav import FAST_DECODERS, FastPacker

    m = mav(1, 1)
    rng = random.Random(5)
    cases = [
        (
            mavlink.MAVLink_attitude_message,
            lambda: (
                rng.randrange(1 << 32),
                rng.uniform(-3, 3),
                0.0,
                0.0,
                rng.uniform(-9, 9),
                0.0,
                rng.choice([0.0, rng.uniform(-1, 1)]),
            ),
            lambda a: a,
        ),
        (
            mavlink.MAVLink_servo_output_raw_message,
            lambda: (
                rng.randrange(1 << 32),
                0,
                0,
                0,
                0,
                rng.choice([0, 1000, 1500, 2000, rng.randrange(65536)]),
                0,
                0,
                0,
                0,
            ),
            lambda a: (a[0], *a[2:10], a[1], *([0] * 8)),
        ),
        (
            mavlink.MAVLink_attitude_target_message,
            lambda: (
                rng.randrange(1 << 32),
                71,
                [rng.uniform(-1, 1), rng.uniform(-1, 1), 0.0, 0.0],
                0.0,
                0.0,
                0.0,
                0.0,
            ),
            lambda a: (a[0], *a[2], a[3], a[4], a[5], a[6], a[1]),
        ),
    ]
    for cls, gen, wire in cases:
        fp = FastPacker(cls, 1, 1)
        for i in range(300):
            args = gen()
            m.seq = i % 256
            ref = cls(*args).pack(m)
            assert fp(i % 256, *wire(args)) == ref
            dec = FAST_DECODERS.get(fp.msgid)
            if dec is not None:
                a, b = dec(ref), m.decode(bytearray(ref))
                assert a.to_dict() == b.to_dict() and a.get_msgId() == b.get_msgId() and a.get_seq() == b.get_seq()
                bad = bytearray(ref)
                bad[-1] ^= 1
                with pytest.raises(mavlink.MAVError):
                    dec(bytes(bad))
