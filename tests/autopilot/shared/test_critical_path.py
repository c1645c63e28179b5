"""The lockstep critical path (docs/spec.md, "Lockstep", the critical path): what moved off it loses nothing.

* the link's hot path (``UdpLink.on_hot``) gives every datagram the verdict, the counters and the values of the
  checks it bypasses: the same datagrams over real UDP sockets to a link with the hot path and one without;
* the control step split around the send (``ControlStep.command`` / ``finish``, ``ClSac.command`` / ``advance``)
  gives the numbers of the step in one piece, to the last bit;
* a lockstep flight whose bookkeeping runs after the send still holds every step: each frame's ATTITUDE and
  SERVO_OUTPUT_RAW in the tlog in order, every step in both series and in the ``.rrd``, the GCS stream and the
  counters whole (not timed: the machine's speed is not what is tested).
"""

from __future__ import annotations

import json
import math
import random
import socket
import time

import numpy as np
import pytest

from autopilot.clsac import ClSac
from autopilot.config import ClSacConfig
from autopilot.shared.fastmav import HOT_DECODERS
from autopilot.shared.link import UdpLink
from autopilot.shared.mavlink import frame_ms, frame_usec, mavlink
from autopilot.shared.pwm import PwmMap
from autopilot.shared.signing import Signing
from autopilot.shared.tlog import packet_ids, read_tlog
from autopilot.step import ControlStep

ATT = mavlink.MAVLINK_MSG_ID_ATTITUDE
SERVO = mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW
KEY = bytes(range(32))


# ---------------------------------------------------------------------------------------------- hot path
def _sender(src, signing=None, link_id=7):
    """A MAVLink endpoint that packs with pymavlink itself (signed when ``signing``)."""
    m = mavlink.MAVLink(None, *src)
    if signing:
        m.signing.secret_key = KEY
        m.signing.link_id = link_id
        m.signing.sign_outgoing = True
        m.signing.timestamp = int((time.time() - 1420070400) * 100_000)
    return m


def _receivers(sender_addr, signed: bool, msgid: int, owner_rejects=None):
    """Two links pinned to ``sender_addr``, equal but for the hot path on one: (hot, generic, their deliveries).

    ``owner_rejects(values)`` -> a reason the owner rejects the packet for (the autopilot's nonfinite_attitude)."""
    got = {"hot": [], "generic": []}
    names = mavlink.mavlink_map[msgid].ordered_fieldnames
    links = {}
    for kind in ("hot", "generic"):
        link = UdpLink(
            kind,
            (1, 140),
            ("127.0.0.1", 0),
            sender_addr,
            peers=[(1, 200)],
            msgids=[msgid, mavlink.MAVLINK_MSG_ID_HEARTBEAT],
            signing=Signing(KEY, 1) if signed else None,
        )
        links[kind] = link

        def take(values, t_rx, kind=kind, link=link):
            why = owner_rejects(values) if owner_rejects else None
            if why:
                link.reject(why)
            got[kind].append(tuple(values))

        if kind == "hot":
            link.on_hot(msgid, lambda t_rx, values, take=take: take(values, t_rx))
        links[kind + "_handler"] = lambda msg, t_rx, take=take: (
            take(tuple(getattr(msg, n) for n in names), t_rx) if msg.get_msgId() == msgid else None
        )
    return links, got


def _datagrams(signed: bool) -> list[bytes]:
    """The usual packets and every unusual one the hot path must leave to the checks."""
    good = _sender((1, 200), signed)
    other_sys = _sender((9, 200), signed)
    forger = mavlink.MAVLink(None, 1, 200)
    if signed:
        forger.signing.secret_key = bytes(32)  # another key
        forger.signing.link_id = 7
        forger.signing.sign_outgoing = True
        forger.signing.timestamp = good.signing.timestamp + 10**6

    def att(m, k, roll=0.1, yawspeed=0.3):
        return m.attitude_encode(frame_ms(k, 100.0), roll, 0.0, 0.2, 0.05, 0.0, yawspeed).pack(m)

    out = []
    first = att(good, 0)
    out.append(first)
    out.append(att(good, 1, yawspeed=0.0))  # trailing zero bytes trimmed: a short payload
    out.append(att(good, 2, roll=0.0, yawspeed=0.0))
    out.append(first)  # the same bytes again: a replay when signed, accepted (a duplicate frame) when not
    bad = bytearray(att(good, 3))
    bad[12] ^= 0x40
    out.append(bytes(bad))  # bad CRC
    out.append(att(good, 4)[:-3])  # truncated
    out.append(att(good, 5) + att(good, 6))  # two packets in one datagram
    out.append(att(other_sys, 7))  # wrong_id
    out.append(att(forger, 8))  # another key (bad_signature), or just a good packet when unsigned
    out.append(att(good, 9, roll=math.nan))  # the owner rejects it (nonfinite_attitude)
    out.append(good.heartbeat_encode(6, 8, 0, 0, 4, 3).pack(good))  # not a hot id
    if signed:
        unsigned = mavlink.MAVLink(None, 1, 200)
        out.append(att(unsigned, 10))  # unsigned
        stale = _sender((1, 200), True)
        stale.signing.timestamp -= 2 * 60 * 100_000  # a new stream over a minute old: replay
        out.append(att(stale, 11))
    out.append(att(good, 12, roll=-0.25))
    return out


@pytest.mark.parametrize("signed", [False, True])
def test_hot_path_gives_the_checks_verdicts_counters_and_values(signed):
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx.bind(("127.0.0.1", 0))
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # right IDs, wrong address: not_peer
    stranger.bind(("127.0.0.1", 0))
    links, got = _receivers(
        tx.getsockname(), signed, ATT, owner_rejects=lambda v: "nonfinite_attitude" if v[1] != v[1] else None
    )
    hot, generic = links["hot"], links["generic"]
    grams = _datagrams(signed)
    try:
        for data in grams:
            for link in (hot, generic):
                tx.sendto(data, link.local)
        stranger_gram = _sender((1, 200), signed).attitude_encode(1, 0.1, 0, 0, 0, 0, 0).pack(_sender((1, 200), signed))
        for link in (hot, generic):
            stranger.sendto(stranger_gram, link.local)
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and (
            hot.rx_datagrams < len(grams) + 1 or generic.rx_datagrams < len(grams) + 1
        ):
            hot.poll(links["hot_handler"])
            generic.poll(links["generic_handler"])
        c_hot, c_gen = hot.counters(), generic.counters()
        for c in (c_hot, c_gen):
            c.pop("last_rx_mono")
        assert c_hot == c_gen
        assert repr(got["hot"]) == repr(got["generic"])  # NaN included
        assert c_hot["rx_datagrams"] == len(grams) + 1
        assert c_hot["rx_datagrams"] == c_hot["rx_accepted"] + sum(c_hot["rejected"].values())
        rejected = c_hot["rejected"]
        assert rejected["bad_crc"] == 1 and rejected["truncated"] == 1 and rejected["wrong_id"] == 1
        assert rejected["not_peer"] == 1 and rejected["nonfinite_attitude"] == 1
        if signed:
            assert rejected["bad_signature"] == 1 and rejected["unsigned"] == 1 and rejected["replay"] == 2
        # the values in wire order, as pymavlink decodes them (the trimmed payloads zero-padded)
        accepted = [v for v in got["hot"] if v[1] == v[1]]
        assert accepted[1][-1] == 0.0 and accepted[2][1] == 0.0
        assert accepted[-1][1] == pytest.approx(-0.25, abs=1e-7)
        assert hot.rx_by_type[ATT] == len(accepted)
    finally:
        for s in (hot, generic):
            s.close()
        tx.close()
        stranger.close()


def test_hot_path_is_only_for_hot_ids_the_link_takes():
    link = UdpLink("t", (1, 140), ("127.0.0.1", 0), None, peers=[(1, 200)], msgids=[ATT])
    try:
        with pytest.raises(ValueError, match="no hot path"):
            link.on_hot(SERVO, lambda t_rx, v: None)  # not taken by this link
        with pytest.raises(ValueError, match="no hot path"):
            link.on_hot(mavlink.MAVLINK_MSG_ID_HEARTBEAT, lambda t_rx, v: None)  # no hot decoder
    finally:
        link.close()
    dec = HOT_DECODERS[SERVO]
    assert dec.index("time_usec") == 0 and dec.index("servo4_raw") == 4 and dec.index("servo9_raw") == 10


def test_servo_payload_framed_from_the_cache_is_pymavlinks_packet():
    """The autopilot's SERVO_OUTPUT_RAW from the cached payload (``frame_fast``) is byte for byte pymavlink's."""
    from autopilot.loop import Autopilot, AutopilotOptions

    opts = AutopilotOptions(lockstep=True, signing_key=None, verbose=False)
    ap = Autopilot(opts, ClSacConfig(), PwmMap())
    try:
        ref = mavlink.MAVLink(None, ap.sitl.mav.srcSystem, ap.sitl.mav.srcComponent)
        for k, pwm in enumerate((1500, 1000, 2000, 1234, 1500)):
            usec = frame_usec(4_294_000 + k * 1000, 100.0)
            ref.seq = ap.sitl.mav.seq
            raw = ap.sitl.frame_fast(ap._pk_servo_sitl, ap._servo_payload(usec, pwm))
            expect = ref.servo_output_raw_encode(usec, 0, *PwmMap().servo_fields(pwm)).pack(ref)
            assert raw == expect
            assert ap._servo_wire(usec, pwm)[0] == usec
    finally:
        ap.close()


# ------------------------------------------------------------------------------------- the split step
def _script(n: int, seed: int):
    rng = random.Random(seed)
    roll = 0.0
    for k in range(n):
        roll = 0.9 * roll + rng.gauss(0.0, 0.05)
        yield k, (math.nan if k == 40 else roll)  # one broken measurement: flown as a hold


@pytest.mark.parametrize("config", [ClSacConfig(), ClSacConfig().sac(), ClSacConfig(dead_zone_rad=0.01, ki_max=2.0)])
def test_command_then_finish_is_the_step_to_the_last_bit(config):
    whole, split = ControlStep(config, PwmMap()), ControlStep(config, PwmMap())
    for c in (whole, split):
        c.setpoints.push(0.0, math.radians(10))
        c.setpoints.push(1.5e6, math.radians(-10))
    for k, roll in _script(400, 3):
        t = k / 100.0
        for c in (whole, split):
            if k == 120:
                c.manual = 0.05  # MANUAL: the ground station's rudder
            if k == 160:
                c.manual = None
                c.transfer()  # back to the law, bumpless
            if k == 250:
                c.armed = False
            if k == 260:
                c.armed = True
                c.transfer()
        a = whole(t, roll)
        pwm = split.command(t, roll)
        b = split.finish()
        assert pwm == b.pwm
        assert a == b
        _same_law(whole.law, split.law)
    assert whole.metrics.result() == split.metrics.result()
    assert whole.metrics_commanded.result() == split.metrics_commanded.result()
    assert whole.nonfinite_inputs == split.nonfinite_inputs == 1


def _same_law(a: ClSac, b: ClSac) -> None:
    """Every float of the two laws' states and internals equal to the last bit."""
    floats = {k: v for k, v in vars(a).items() if isinstance(v, float)}
    assert len(floats) > 20
    for name, v in floats.items():
        w = getattr(b, name)
        assert v == w or (v != v and w != w), name


def test_clsac_command_then_advance_is_step():
    a, b = ClSac(ClSacConfig()), ClSac(ClSacConfig())
    rng = np.random.default_rng(5)
    for _ in range(500):
        y, um = float(rng.normal(0, 0.2)), float(rng.normal(0, 0.2))
        u = a.step(y, um)
        assert b.command(y, um) == u
        b.advance()
        assert (a.xm, a.xm_ol, a.xd, a.ki_e, a.ki_x, a.ki_u, a.e, a.ym_ol, a.saturated) == (
            b.xm,
            b.xm_ol,
            b.xd,
            b.ki_e,
            b.ki_x,
            b.ki_u,
            b.e,
            b.ym_ol,
            b.saturated,
        )
    b.advance()  # nothing pending: no step
    assert a.steps == b.steps == 500


# ------------------------------------------------------------------------------------------- a flight
@pytest.mark.e2e
def test_deferred_bookkeeping_keeps_every_step(tmp_path):
    from autopilot.telemetry import layout as L
    from sitl import telemetry as S
    from tools.flight import Flight
    from tools.view import rrd_files as rrd

    rate, duration = 100.0, 3.0
    n = int(rate * duration)
    res = Flight(out=tmp_path / "f", quiet=True, lockstep=True, rate=rate, duration=duration, pin=True).run()
    assert res.ok, res.reason
    out = res.out
    summary = res.summary
    (run,) = summary["runs"]
    assert run["steps"] == n
    # the tlog: each frame's ATTITUDE received, then its SERVO_OUTPUT_RAW sent, in that order, stamps in order
    records = list(read_tlog(str(out / "flight.tlog")))
    ap_json = json.loads((out / "autopilot.json").read_text())
    assert ap_json["tlog_records"] == len(records)  # every record queued reached the file
    stamps = [t for t, _raw in records]
    assert stamps == sorted(stamps)
    frames = []
    for _t, raw in records:
        sysid, compid, msgid = packet_ids(raw)
        if (sysid, compid, msgid) == (1, 200, ATT):
            frames.append(("att", mavlink.MAVLink(None).decode(bytearray(raw)).time_boot_ms))
        elif (sysid, compid, msgid) == (1, 140, SERVO):
            frames.append(("servo", mavlink.MAVLink(None).decode(bytearray(raw)).time_usec))
    flown = frames[: 2 * n]
    assert flown == [x for k in range(n) for x in (("att", frame_ms(k, rate)), ("servo", frame_usec(k, rate)))]
    assert [f for f in frames[2 * n :] if f[0] == "servo"] == []  # the end-of-run frame is not answered
    # the GCS stream (every 10th step in lockstep) and the gains stream reached the tlog and the GCS
    gcs_att = [raw for _t, raw in records if packet_ids(raw) == (1, 1, ATT)]
    assert len(gcs_att) == n // 10
    counters = summary["counters"]
    assert counters["autopilot"]["sitl"]["tx_by_type"]["SERVO_OUTPUT_RAW"] == n
    assert counters["autopilot"]["sitl"]["rejected"] == {} and counters["sitl"]["rejected"] == {}
    assert counters["sitl"]["rx_by_type"]["SERVO_OUTPUT_RAW"] == n
    # both series: every step, at its sim time; the SITL's rows carry the state after each frame
    ap_series = np.load(out / "autopilot_series.npz")
    np.testing.assert_array_equal(ap_series["t"], np.arange(n) / rate)
    sitl_series = np.load(out / "sitl_series.npz")
    np.testing.assert_allclose(sitl_series["t"], np.arange(1, n + 1) / rate, rtol=0, atol=1e-12)
    sitl_json = json.loads((out / "sitl.json").read_text())
    final = [sitl_series[k][-1] for k in ("v", "p", "r", "phi", "delta_r", "delta_r_dot")]
    assert final == sitl_json["final_state"]
    pwm = PwmMap()
    np.testing.assert_array_equal(sitl_series["u"], [pwm.to_rad(int(p)) for p in ap_series["pwm"]])
    # what the autopilot recorded of each ATTITUDE is the SITL's state it was measured from, through float32
    # (step k flies on the state after frame k-1: the SITL's row k-1)
    for key in ("phi", "p", "r"):
        np.testing.assert_array_equal(ap_series[key][1:], sitl_series[key][:-1].astype(np.float32).astype(float))
    # the recording: one row per step from the autopilot, one per frame from the SITL
    data = rrd.load(out / "flight.rrd")
    assert len(data[L.AP_ROLL].t) == n and len(data[S.SITL_ROLL].t) == n
    # the metrics are the in-process ones with the wire model, to the last bit (the split step, as a whole step)
    from tools.experiment.scenario import PAPER_RUNS, Scenario, run_inprocess

    ref = run_inprocess(Scenario(duration_s=duration), PAPER_RUNS[1], wire=PwmMap()).metrics
    assert run["metrics"] == ref


def test_tlog_queue_keeps_order_and_stamps(tmp_path):
    from autopilot.shared.tlog import TlogWriter

    w = TlogWriter(str(tmp_path / "q.tlog"))
    m = mavlink.MAVLink(None, 1, 1)
    raws = [m.heartbeat_encode(1, 0, 0, k, 0, 3).pack(m) for k in range(10)]
    for k, raw in enumerate(raws[:5]):
        w.write(raw, t_us=1000 + k)
    w.drain()
    for raw in raws[5:8]:
        w.write(bytearray(raw))  # a mutable buffer is copied when queued
    w.flush()  # drains first
    w.write(raws[8], t_us=5)
    w.write(raws[9], t_us=6)
    assert w.records == 10
    w.close()  # drains first
    recs = list(read_tlog(str(tmp_path / "q.tlog")))
    assert [r for _t, r in recs] == raws
    assert [t for t, _r in recs[:5]] == [1000, 1001, 1002, 1003, 1004] and [t for t, _ in recs[8:]] == [5, 6]
    now_us = time.time_ns() // 1000
    assert all(abs(t - now_us) < 60e6 for t, _r in recs[5:8])
