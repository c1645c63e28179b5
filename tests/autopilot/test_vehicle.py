"""The autopilot as a MAVLink vehicle: a real pymavlink client over UDP against the real autopilot process.

Parameters (download, read, accepted and rejected sets, save/load and ``--params``), commands (acks, unsupported,
REQUEST_MESSAGE, SET_MESSAGE_INTERVAL), mission count, TIMESYNC, PING, arming, modes with a bumpless rudder, two
ground stations, and a lockstep CLSAC_LV change mid-flight (autopilot.vehicle, autopilot.params).
"""

from __future__ import annotations

import math
import os
import struct
import time

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import all as mavall  # noqa: E402

from autopilot.config import ClSacConfig  # noqa: E402
from autopilot.params import PARAMS, load_file, save_file  # noqa: E402
from autopilot.shared.fastmav import crc16  # noqa: E402
from autopilot.shared.tlog import payload_streams  # noqa: E402
from autopilot.vehicle import Mode  # noqa: E402
from tests._mavlink_procs import Proc, free_ports  # noqa: E402
from tools.flight.outcome import STARVED  # the launcher's own finding (realtime_advice)

pytestmark = pytest.mark.e2e
A = mavall


class Gcs:
    """A ground station as MAVProxy is one: 255:230, listening on its UDP port, all-dialect decoder."""

    def __init__(self, port: int, comp: int = 230):
        self.conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{port}", source_system=255, source_component=comp, dialect="all"
        )
        self.mav = self.conn.mav
        self.texts: list[str] = []  # every STATUSTEXT seen
        self.comp = comp

    def wait(self, kind: str, timeout: float = 5.0, cond=None):
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            m = self.conn.recv_match(blocking=True, timeout=0.2)
            if m is None or m.get_srcSystem() != 1:
                continue
            if m.get_type() == "STATUSTEXT":
                self.texts.append(m.text)
            if m.get_type() == kind and (cond is None or cond(m)):
                return m
        raise AssertionError(f"no {kind} within {timeout} s")

    def connect(self):
        self.wait("HEARTBEAT")
        self.mav.heartbeat_send(A.MAV_TYPE_GCS, A.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def command(self, cmd, *params, timeout=5.0):
        p = list(params) + [0.0] * (7 - len(params))
        self.drain()  # a socket left unread for seconds is full: the answer would be dropped by the kernel
        self.mav.command_long_send(1, 1, cmd, 0, *p)
        # every ground station sees every answer: ours names us in its target fields
        return self.wait("COMMAND_ACK", timeout, cond=lambda m: m.command == cmd and m.target_component == self.comp)

    def drain(self):
        while (m := self.conn.recv_match(blocking=False)) is not None:
            if m.get_type() == "STATUSTEXT":
                self.texts.append(m.text)

    def close(self):
        self.conn.close()


def _start_autopilot(tmp_path, name, gcs_port, *extra, sitl_port=None):
    sitl_port = sitl_port or free_ports(1)[0]
    args = ["--sitl", f"127.0.0.1:{sitl_port}", "--gcs", f"127.0.0.1:{gcs_port}", *extra]
    ap = Proc("autopilot", args, tmp_path / f"{name}.log")
    assert ap.wait_for("autopilot:", 30), ap.output()
    return ap


@pytest.fixture
def vehicle(tmp_path):
    """An autopilot process alone (stand-by: no SITL) and a ground station on its default GCS port."""
    port = free_ports(1)[0]
    gcs = Gcs(port)
    ap = _start_autopilot(tmp_path, "autopilot", port)
    gcs.connect()
    yield gcs, ap
    gcs.close()
    ap.stop()


def _download(gcs: Gcs) -> dict:
    gcs.drain()
    gcs.mav.param_request_list_send(1, 1)
    got = {}
    count = None
    t_end = time.monotonic() + 10
    while time.monotonic() < t_end and (count is None or len(got) < count):
        m = gcs.conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
        if m is not None:
            count = m.param_count
            got[m.param_index] = (m.param_id, m.param_value, m.param_type)
    assert count is not None and len(got) == count, got
    return {name: value for name, value, _ in got.values()}


def _f32(x: float) -> float:
    return float(np.float32(x))


def test_full_parameter_download_and_reads(vehicle):
    gcs, _ = vehicle
    values = _download(gcs)
    assert list(values) == [p.name for p in PARAMS]
    assert all(len(n) <= 16 for n in values)
    cfg = ClSacConfig()
    expect = {
        "CLSAC_LV": cfg.lv,
        "CLSAC_SIGMA": cfg.sigma,
        "CLSAC_GAM_PE": 10.0,
        "CLSAC_GAM_IU": 10.0,
        "CLSAC_AM": -5.0,
        "CLSAC_BM": 5.0,
        "CLSAC_PFC_NUM": 10.0,
        "CLSAC_PFC_DEN1": 4.0,
        "CLSAC_PFC_DEN0": 40.0,
        "CLSAC_U_LIMIT": math.radians(30),
        "CLSAC_RATE": 100.0,
        "CLSAC_FS_ATT_TMO": 0.1,
        "CLSAC_SIGMA_X": 0.0,
    }
    for name, v in expect.items():
        assert values[name] == _f32(v), name
    # by name and by index
    gcs.mav.param_request_read_send(1, 1, b"CLSAC_SIGMA", -1)
    m = gcs.wait("PARAM_VALUE", cond=lambda m: m.param_id == "CLSAC_SIGMA")
    assert m.param_value == 5.0 and m.param_index == 1
    gcs.mav.param_request_read_send(1, 1, b"", 10)
    m = gcs.wait("PARAM_VALUE", cond=lambda m: m.param_index == 10)
    assert m.param_id == "CLSAC_AM" and m.param_value == -5.0
    gcs.mav.param_request_read_send(1, 1, b"NO_SUCH_PARAM", -1)
    e = gcs.wait("PARAM_ERROR")
    assert e.error == A.MAV_PARAM_ERROR_DOES_NOT_EXIST


def _int32(x: float) -> int:
    """The integer a PARAM_VALUE carries bytewise (PX4's encoding) in its float field."""
    return struct.unpack("<i", struct.pack("<f", x))[0]


def test_sys_failure_en_is_an_int32_sent_bytewise_and_set_either_way(vehicle):
    gcs, _ = vehicle
    gcs.mav.param_request_read_send(1, 1, b"SYS_FAILURE_EN", -1)
    m = gcs.wait("PARAM_VALUE", cond=lambda m: m.param_id == "SYS_FAILURE_EN")
    assert m.param_type == A.MAV_PARAM_TYPE_INT32 and _int32(m.param_value) == 0
    one = struct.unpack("<f", struct.pack("<i", 1))[0]  # 1.4e-45: MAVSDK's set_param_int("SYS_FAILURE_EN", 1)
    for value, mav_type, want_type, want in (
        (one, A.MAV_PARAM_TYPE_INT32, A.MAV_PARAM_TYPE_INT32, one),  # bytewise, answered bytewise
        (0.0, A.MAV_PARAM_TYPE_REAL32, A.MAV_PARAM_TYPE_REAL32, 0.0),  # MAVProxy's REAL32, answered as it came
        (1.0, A.MAV_PARAM_TYPE_INT32, A.MAV_PARAM_TYPE_INT32, one),  # the integer cast to a float: 1
    ):
        gcs.drain()
        gcs.mav.param_set_send(1, 1, b"SYS_FAILURE_EN", value, mav_type)
        m = gcs.wait("PARAM_VALUE", cond=lambda m: m.param_id == "SYS_FAILURE_EN")
        assert m is not None and (m.param_type, m.param_value) == (want_type, want), (value, m)
    gcs.drain()
    gcs.mav.param_set_send(
        1, 1, b"SYS_FAILURE_EN", struct.unpack("<f", struct.pack("<i", 2))[0], A.MAV_PARAM_TYPE_INT32
    )
    assert gcs.wait("PARAM_ERROR") is not None  # 2, bytewise: neither 0 nor 1
    gcs.mav.param_request_read_send(1, 1, b"SYS_FAILURE_EN", -1)
    m = gcs.wait("PARAM_VALUE", cond=lambda m: m.param_id == "SYS_FAILURE_EN")
    assert _int32(m.param_value) == 1  # unchanged


def test_accepted_and_rejected_sets(vehicle):
    gcs, ap = vehicle
    gcs.mav.param_set_send(1, 1, b"CLSAC_LV", 50.0, A.MAV_PARAM_TYPE_REAL32)
    m = gcs.wait("PARAM_VALUE", cond=lambda m: m.param_id == "CLSAC_LV")
    assert m.param_value == 50.0
    # A_m = +1 is not Hurwitz: rejected, answered with the unchanged value and PARAM_ERROR
    gcs.mav.param_set_send(1, 1, b"CLSAC_AM", 1.0, A.MAV_PARAM_TYPE_REAL32)
    m = gcs.wait("PARAM_VALUE", cond=lambda m: m.param_id == "CLSAC_AM")
    e = gcs.wait("PARAM_ERROR")
    assert m.param_value == -5.0 and e.param_id == "CLSAC_AM"
    assert e.error == A.MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE
    # the control rate is read-only while flying
    gcs.mav.param_set_send(1, 1, b"CLSAC_RATE", 200.0, A.MAV_PARAM_TYPE_REAL32)
    m = gcs.wait("PARAM_VALUE", cond=lambda m: m.param_id == "CLSAC_RATE")
    e = gcs.wait("PARAM_ERROR")
    assert m.param_value == 100.0 and e.error == A.MAV_PARAM_ERROR_READ_ONLY
    # beyond the parameter table's bounds (the flags' and the files' too): refused, the value unchanged
    for name, value, held in (("CLSAC_LV", 1e30, 50.0), ("CLSAC_FS_ATT_TMO", 1e30, _f32(0.1))):
        gcs.mav.param_set_send(1, 1, name.encode(), value, A.MAV_PARAM_TYPE_REAL32)
        m = gcs.wait("PARAM_VALUE", cond=lambda m, name=name: m.param_id == name)
        e = gcs.wait("PARAM_ERROR")
        assert m.param_value == held and e.error == A.MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE, name
    values = _download(gcs)
    assert values["CLSAC_LV"] == 50.0 and values["CLSAC_AM"] == -5.0
    ap.stop()
    assert "CLSAC_AM must be in [-10000, 0) 1/s, got 1" in ap.output()
    assert "CLSAC_FS_ATT_TMO must be in [0.001, 86400] s, got 1e+30" in ap.output()


def test_save_load_round_trip_and_params_flag(vehicle, tmp_path):
    gcs, _ = vehicle
    values = _download(gcs)
    for qgc in (False, True):
        path = tmp_path / ("qgc.params" if qgc else "mavproxy.parm")
        save_file(path, values.items(), qgc=qgc)
        assert {k: _f32(v) for k, v in load_file(path).items()} == values  # float32 on the wire, exact in files
    values["CLSAC_LV"] = 35.0
    values["CLSAC_FS_SP_TMO"] = 2.5
    path = tmp_path / "tuned.parm"
    save_file(path, values.items())
    port = free_ports(1)[0]
    gcs2 = Gcs(port)
    ap2 = _start_autopilot(tmp_path, "autopilot2", port, "--params", str(path))
    try:
        gcs2.connect()
        again = _download(gcs2)
        assert again["CLSAC_LV"] == 35.0 and again["CLSAC_FS_SP_TMO"] == 2.5
        assert again == values
    finally:
        gcs2.close()
        ap2.stop()
    # a bad file is refused with one line naming it
    bad = tmp_path / "bad.parm"
    bad.write_text("CLSAC_AM 3\n")
    p = Proc("autopilot", ["--params", str(bad)], tmp_path / "bad.log")
    assert p.p.wait(30) == 2
    assert "--params" in p.output() and "CLSAC_AM" in p.output()


def test_the_pids_old_names_are_aliases_over_mavlink_and_in_files(tmp_path):
    """The PID's parameters are PID_KP, _KI, _KD (its own prefix, issue 37); CLSAC_PID_*, their names before, keep
    working: a --params file by the old names loads, PARAM_REQUEST_LIST lists each parameter once by its own name,
    PARAM_REQUEST_READ and PARAM_SET by an old name act on it and are answered by the name asked (at the parameter's
    index), a set then by its own name too; a refused set by an old name is answered by the old name."""
    path = tmp_path / "old.parm"
    path.write_text("CLSAC_PID_KP 0.3\nCLSAC_PID_KI 0.05\n")  # a file written before the rename
    port = free_ports(1)[0]
    gcs = Gcs(port)
    ap = _start_autopilot(tmp_path, "autopilot", port, "--controller", "baseline", "--params", str(path))
    try:
        gcs.connect()
        gcs.drain()
        gcs.mav.param_request_list_send(1, 1)
        listed = []  # every PARAM_VALUE of the list, in order: no name twice
        while len(listed) < (listed[0].param_count if listed else 1):
            listed.append(gcs.wait("PARAM_VALUE"))
        names = [m.param_id for m in listed]
        assert names[-3:] == ["PID_KP", "PID_KI", "PID_KD"] and len(set(names)) == len(names) == 7
        assert not any(n.startswith("CLSAC_PID") for n in names)
        assert [m.param_value for m in listed[-3:]] == [_f32(0.3), _f32(0.05), _f32(0.02)]  # the file's, default KD
        gcs.mav.param_request_read_send(1, 1, b"CLSAC_PID_KI", -1)
        m = gcs.wait("PARAM_VALUE", cond=lambda m: m.param_id != "PID_KD")
        assert (m.param_id, m.param_value, m.param_index, m.param_count) == ("CLSAC_PID_KI", _f32(0.05), 5, 7)
        gcs.mav.param_set_send(1, 1, b"CLSAC_PID_KD", 0.04, A.MAV_PARAM_TYPE_REAL32)
        old = gcs.wait("PARAM_VALUE")
        own = gcs.wait("PARAM_VALUE")
        assert (old.param_id, own.param_id) == ("CLSAC_PID_KD", "PID_KD")
        assert old.param_value == own.param_value == _f32(0.04) and old.param_index == own.param_index == 6
        gcs.mav.param_request_read_send(1, 1, b"PID_KD", -1)
        assert gcs.wait("PARAM_VALUE").param_value == _f32(0.04)  # the same parameter
        gcs.mav.param_set_send(1, 1, b"CLSAC_PID_KP", -1.0, A.MAV_PARAM_TYPE_REAL32)
        m = gcs.wait("PARAM_VALUE")
        e = gcs.wait("PARAM_ERROR")
        assert (m.param_id, m.param_value) == ("CLSAC_PID_KP", _f32(0.3))
        assert (e.param_id, e.param_index, e.error) == ("CLSAC_PID_KP", 4, A.MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE)
    finally:
        gcs.close()
        ap.stop()


def test_disarmed_at_start_until_armed(tmp_path):
    port = free_ports(1)[0]
    gcs = Gcs(port)
    ap = _start_autopilot(tmp_path, "autopilot", port, "--disarmed", "--controller", "sac")
    try:
        hb = gcs.wait("HEARTBEAT")
        assert not hb.base_mode & A.MAV_MODE_FLAG_SAFETY_ARMED and hb.custom_mode == Mode.SAC
        assert mavutil.mode_string_v10(hb) == "Mode(100)"
        gcs.connect()
        assert gcs.command(A.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == A.MAV_RESULT_ACCEPTED
        assert gcs.wait("HEARTBEAT", cond=lambda m: m.base_mode & A.MAV_MODE_FLAG_SAFETY_ARMED)
        assert gcs.command(A.MAV_CMD_COMPONENT_ARM_DISARM, 0.5).result == A.MAV_RESULT_DENIED
    finally:
        gcs.close()
        ap.stop()


def test_commands_answers_and_unsupported(vehicle):
    gcs, _ = vehicle
    ack = gcs.command(A.MAV_CMD_GET_HOME_POSITION)
    assert ack.result == A.MAV_RESULT_UNSUPPORTED
    ack = gcs.command(31999)  # not a command anybody knows: still answered
    assert ack.result == A.MAV_RESULT_UNSUPPORTED
    gcs.mav.command_int_send(1, 1, 0, A.MAV_CMD_DO_SET_MODE, 0, 0, 1, Mode.SAC, 0, 0, 0, 0, 0)  # COMMAND_INT too
    ack = gcs.wait("COMMAND_ACK", cond=lambda m: m.command == A.MAV_CMD_DO_SET_MODE)
    assert ack.result == A.MAV_RESULT_ACCEPTED and gcs.wait("HEARTBEAT", cond=lambda m: m.custom_mode == Mode.SAC)
    assert gcs.command(A.MAV_CMD_DO_SET_MODE, 1, Mode.CLSAC).result == A.MAV_RESULT_ACCEPTED
    ack = gcs.command(A.MAV_CMD_REQUEST_MESSAGE, A.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    assert ack.result == A.MAV_RESULT_ACCEPTED
    v = gcs.wait("AUTOPILOT_VERSION")
    assert (
        v.capabilities & A.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT and v.capabilities & A.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    )
    ack = gcs.command(A.MAV_CMD_REQUEST_MESSAGE, A.MAVLINK_MSG_ID_AVAILABLE_MODES, 0)
    modes = {}
    for _ in range(4):
        m = gcs.wait("AVAILABLE_MODES")
        modes[m.mode_name] = m
    assert set(modes) == {"MANUAL", "SAC", "CLSAC", "FAILSAFE"} and modes["CLSAC"].number_modes == 4
    assert modes["FAILSAFE"].properties & A.MAV_MODE_PROPERTY_NOT_USER_SELECTABLE
    assert modes["SAC"].custom_mode == Mode.SAC
    assert gcs.command(A.MAV_CMD_REQUEST_MESSAGE, A.MAVLINK_MSG_ID_CURRENT_MODE).result == A.MAV_RESULT_ACCEPTED
    assert gcs.wait("CURRENT_MODE").custom_mode == Mode.CLSAC
    # PROTOCOL_VERSION is in no pymavlink dialect: check the raw frame (id 300, CRC extra 217 from its definition)
    gcs.conn.mav.robust_parsing = True
    sock = gcs.conn.port
    gcs.mav.command_long_send(1, 1, A.MAV_CMD_REQUEST_PROTOCOL_VERSION, 0, 1, 0, 0, 0, 0, 0, 0)
    t_end = time.monotonic() + 5
    frame = None
    while time.monotonic() < t_end and frame is None:
        try:
            data, _ = sock.recvfrom(4096)
        except BlockingIOError:
            time.sleep(0.01)
            continue
        i = 0
        while i + 12 <= len(data) and data[i] == 0xFD:
            n = 12 + data[i + 1]
            if data[i + 7] | data[i + 8] << 8 | data[i + 9] << 16 == 300:
                frame = data[i : i + n]
            i += n
    assert frame is not None
    c = crc16(frame[1:-2] + bytes([217]))
    assert frame[-2:] == bytes((c & 0xFF, c >> 8))
    assert int.from_bytes(frame[10:12], "little") == 200  # MAVLink 2.0
    # the file-transfer protocol (MAVProxy asks for the parameter file first): NAK FileNotFound, seq + 1
    req = bytes([7, 0, 1, 4, 0, 0, 0, 0, 0, 0, 0, 0]) + b"@PARAM/param.pck"  # seq 7, session 1, OpenFileRO
    gcs.mav.file_transfer_protocol_send(0, 1, 1, list(req + bytes(251 - len(req))))
    nak = bytes(gcs.wait("FILE_TRANSFER_PROTOCOL").payload)
    assert nak[:6] == bytes([8, 0, 1, 129, 1, 4]) and nak[12] == 10  # NAK, size 1, for OpenFileRO: FileNotFound
    # mission count, timesync, ping
    gcs.mav.mission_request_list_send(1, 1)
    assert gcs.wait("MISSION_COUNT").count == 0
    gcs.mav.timesync_send(0, 12345)
    ts = gcs.wait("TIMESYNC", cond=lambda m: m.ts1 == 12345)
    assert ts.tc1 > 0
    gcs.mav.ping_send(777, 5, 0, 0)
    p = gcs.wait("PING", cond=lambda m: m.time_usec == 777)
    assert p.seq == 5 and p.target_system == 255 and p.target_component == 230
    # stream rates: ATTITUDE at 5 Hz, then off
    ack = gcs.command(A.MAV_CMD_SET_MESSAGE_INTERVAL, A.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT, 200000)
    assert ack.result == A.MAV_RESULT_ACCEPTED
    ack = gcs.command(A.MAV_CMD_SET_MESSAGE_INTERVAL, A.MAVLINK_MSG_ID_GPS_RAW_INT, 200000)
    assert ack.result == A.MAV_RESULT_UNSUPPORTED


def test_stream_rates_follow_set_message_interval_and_request_data_stream(vehicle):
    gcs, _ = vehicle
    assert _count(gcs, "ATTITUDE", 1.0) == pytest.approx(50, abs=8)  # --telemetry-rate default
    ack = gcs.command(A.MAV_CMD_SET_MESSAGE_INTERVAL, A.MAVLINK_MSG_ID_ATTITUDE, 100000)  # 10 Hz
    assert ack.result == A.MAV_RESULT_ACCEPTED
    assert _count(gcs, "ATTITUDE", 2.0) == pytest.approx(20, abs=4)
    assert _count(gcs, "NAMED_VALUE_FLOAT", 1.0) == pytest.approx(40, abs=8)  # Ke, Kx, Ku, e at 10 Hz
    gcs.mav.request_data_stream_send(1, 1, A.MAV_DATA_STREAM_EXTRA1, 2, 1)  # 2 Hz
    assert _count(gcs, "ATTITUDE", 2.0) == pytest.approx(4, abs=2)
    assert _count(gcs, "SYS_STATUS", 2.05) in (2, 3)  # 1 Hz
    gcs.mav.request_data_stream_send(1, 1, A.MAV_DATA_STREAM_ALL, 0, 0)  # everything off
    time.sleep(0.2)
    assert _count(gcs, "ATTITUDE", 1.0) == 0 and _count(gcs, "NAMED_VALUE_FLOAT", 1.0) == 0
    assert _count(gcs, "HEARTBEAT", 1.5) >= 1  # the heartbeat is not a stream


def _count(gcs: Gcs, kind: str, seconds: float) -> int:
    gcs.drain()
    n = 0
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        m = gcs.conn.recv_match(type=kind, blocking=True, timeout=0.1)
        if m is not None:
            n += 1
    return n


@pytest.fixture
def flight(tmp_path):
    """SITL and autopilot in real time, two ground stations admitted with --gcs-peer (the first one also on the
    default --gcs port)."""
    sitl_port, port, port2 = free_ports(3)
    sitl_args = ["--listen", f"127.0.0.1:{sitl_port}"]
    sitl = Proc("sitl", sitl_args, tmp_path / "sitl.log")
    assert sitl.wait_for("sitl: listening", 30)
    gcs, gcs2 = Gcs(port), Gcs(port2, comp=190)
    series = tmp_path / "series.npz"
    ap = _start_autopilot(
        tmp_path,
        "autopilot",
        port,
        "--gcs-peer",
        f"127.0.0.1:{port}",
        "--gcs-peer",
        f"127.0.0.1:{port2}",
        "--series",
        str(series),
        "--setpoint-timeout",
        "30",
        sitl_port=sitl_port,
    )
    gcs.connect()
    procs = {"sitl": sitl}

    def restart_sitl():
        procs["sitl"].kill()
        time.sleep(1.0)
        procs["sitl"] = Proc("sitl", sitl_args, tmp_path / "sitl2.log")

    yield gcs, gcs2, ap, series, restart_sitl
    gcs.close()
    gcs2.close()
    ap.stop()
    procs["sitl"].stop()


def _setpoint(gcs: Gcs, deg: float):
    q = [math.cos(math.radians(deg) / 2), math.sin(math.radians(deg) / 2), 0.0, 0.0]
    gcs.mav.set_attitude_target_send(0, 1, 1, 71, q, 0, 0, 0, 0)


def _fly(gcs: Gcs, seconds: float, deg: float):
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        _setpoint(gcs, deg)
        gcs.drain()
        time.sleep(0.05)


def test_modes_bumpless_arming_and_two_ground_stations(flight):
    gcs, gcs2, ap, series, restart_sitl = flight
    hb = gcs.wait("HEARTBEAT")
    assert hb.type == A.MAV_TYPE_FIXED_WING and hb.custom_mode == Mode.CLSAC
    assert mavutil.mode_string_v10(hb) == "Mode(101)"  # never a wrong ArduPlane name
    # both ground stations get the stream (the second one is admitted by --gcs-peer)
    assert _count(gcs, "ATTITUDE", 1.0) > 20 and _count(gcs2, "ATTITUDE", 1.0) > 20
    assert gcs2.wait("NAMED_VALUE_FLOAT", cond=lambda m: m.name == "Ke")
    att = gcs.wait("ATTITUDE")
    assert att.pitch == 0.0
    _fly(gcs, 3.0, 10.0)
    # heading: the SITL integrates psi' = r; over 2 s of the stream, yaw moves by the integral of yawspeed
    gcs.drain()
    att = []
    t_end = time.monotonic() + 2.0
    while time.monotonic() < t_end:
        _setpoint(gcs, 10.0)
        m = gcs.conn.recv_match(type="ATTITUDE", blocking=True, timeout=0.05)
        if m is not None:
            att.append((m.time_boot_ms * 1e-3, m.yaw, m.yawspeed))
    t, yaw, r = (np.array(c) for c in zip(*att))
    turned = np.unwrap(yaw)[-1] - yaw[0]
    assert abs(turned) > 0.05  # a 10 deg bank turns the aircraft
    assert turned == pytest.approx(np.trapezoid(r, t), rel=0.05)
    # MANUAL from MANUAL_CONTROL: the rudder goes to -15 deg (r = -500 of 1000, limit 30 deg) without a step
    ack = gcs.command(A.MAV_CMD_DO_SET_MODE, A.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, Mode.MANUAL)
    assert ack.result == A.MAV_RESULT_ACCEPTED
    hb = gcs.wait("HEARTBEAT", cond=lambda m: m.custom_mode == Mode.MANUAL)
    assert mavutil.mode_string_v10(hb) == "MANUAL" and hb.base_mode & A.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
    assert "mode MANUAL" in gcs.texts
    t_end = time.monotonic() + 0.5
    while time.monotonic() < t_end:  # RC_CHANNELS_OVERRIDE on the rudder channel: 1550 us = +3 deg
        gcs.mav.rc_channels_override_send(1, 1, 0, 0, 0, 1550, 0, 0, 0, 0)
        _setpoint(gcs, 10.0)
        time.sleep(0.05)
    t_end = time.monotonic() + 1.5
    while time.monotonic() < t_end:
        gcs.mav.manual_control_send(1, 0, 0, 0, -500, 0)
        _setpoint(gcs, 10.0)
        time.sleep(0.05)
    # SAC by SET_MODE, then CLSAC again by COMMAND_LONG (from the second station)
    gcs.mav.set_mode_send(1, A.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, Mode.SAC)
    assert gcs.wait("COMMAND_ACK", cond=lambda m: m.command == A.MAV_CMD_DO_SET_MODE).result == 0
    assert "mode SAC" in gcs.texts
    _fly(gcs, 1.5, 10.0)
    assert gcs2.command(A.MAV_CMD_DO_SET_MODE, 1, Mode.CLSAC).result == A.MAV_RESULT_ACCEPTED
    ack = gcs.command(A.MAV_CMD_DO_SET_MODE, 1, Mode.FAILSAFE)  # entered by itself only
    assert ack.result == A.MAV_RESULT_DENIED
    _fly(gcs, 1.5, 10.0)
    # disarm: rudder neutral; arm again
    ack = gcs.command(A.MAV_CMD_COMPONENT_ARM_DISARM, 0)
    assert ack.result == A.MAV_RESULT_ACCEPTED
    hb = gcs.wait("HEARTBEAT", cond=lambda m: not m.base_mode & A.MAV_MODE_FLAG_SAFETY_ARMED)
    time.sleep(0.2)
    gcs.drain()
    srv = gcs.wait("SERVO_OUTPUT_RAW")
    assert srv.servo4_raw == 1500
    ack = gcs.command(A.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ack.result == A.MAV_RESULT_ACCEPTED
    assert gcs.wait("HEARTBEAT", cond=lambda m: m.base_mode & A.MAV_MODE_FLAG_SAFETY_ARMED)
    _fly(gcs, 1.0, 10.0)
    # FAILSAFE: entered by itself when the SITL vanishes, left by itself when a SITL is back
    restart_sitl()
    hb = gcs.wait("HEARTBEAT", cond=lambda m: m.custom_mode == Mode.FAILSAFE)
    assert mavutil.mode_string_v10(hb) == "Mode(102)" and hb.system_status == A.MAV_STATE_CRITICAL
    assert gcs.wait("HEARTBEAT", timeout=15, cond=lambda m: m.custom_mode == Mode.CLSAC)
    _fly(gcs, 1.0, 10.0)
    ap.stop()
    out = ap.output()
    for text in ("mode MANUAL", "mode SAC", "mode CLSAC", "DISARMED", "ARMED", "mode FAILSAFE"):
        assert text in out
    assert "mode FAILSAFE" in gcs.texts
    s = np.load(series)
    u, mode, armed, fs = s["u"], s["mode"], s["armed"].astype(bool), s["failsafe"].astype(bool)
    lsb = math.radians(30) / 500  # one microsecond of PWM
    switches = [k for k in range(1, len(u)) if mode[k] != mode[k - 1]]
    modes = [Mode.MANUAL, Mode.SAC, Mode.CLSAC, Mode.FAILSAFE, Mode.CLSAC]
    assert [int(mode[k]) for k in switches] == modes
    # out of the failsafe (rudder neutral) the law takes over from neutral, without a step
    k_back = int(np.flatnonzero(fs[:-1] & ~fs[1:])[-1]) + 1
    assert abs(u[k_back]) <= 2 * lsb and fs[k_back - 1] and u[k_back - 1] == 0.0
    switches = switches[:3]  # the ones the ground station made
    # MANUAL -> SAC: the manual rudder was -15 deg (r = -500 of 1000, limit 30 deg), the law wanted another
    # command: a plain switch would have stepped by that much; the transfer flies on from the last command
    manual = u[switches[0] : switches[1]]
    assert np.isclose(manual, math.radians(3), atol=lsb).sum() > 20  # the RC override flew
    k = switches[1]
    assert u[k - 1] == pytest.approx(math.radians(-15), abs=lsb)
    assert abs(s["u_cmd"][k] - u[k - 1]) > 0.1
    for k in switches:  # every switch: no step in the rudder command
        assert abs(u[k] - u[k - 1]) <= 2 * lsb, (k, u[k - 3 : k + 3])
    # disarmed: exactly neutral; arming again starts from neutral
    assert (u[~armed] == 0.0).all() and (~armed).sum() >= 10
    k_arm = int(np.flatnonzero(armed[1:] & ~armed[:-1])[0]) + 1
    assert abs(u[k_arm]) <= 2 * lsb


def test_lockstep_lv_change_mid_flight_is_deterministic(tmp_path):
    """CLSAC_LV 20 -> 50 at t = 10 s of a lockstep flight: lower rudder energy afterwards than keeping 20;
    the same flight twice gives the same command sequence bit for bit."""
    a = _lockstep_flight(tmp_path / "a", change=True)
    b = _lockstep_flight(tmp_path / "b", change=True)
    c = _lockstep_flight(tmp_path / "c", change=False)
    assert np.array_equal(a["u"], b["u"])
    k = 1000
    # identical until the change, and the first step after it flies the very same command (no jump: the law keeps
    # its states, a new Lv acts through the reference model from the next step on); different from then on
    assert np.array_equal(a["u"][: k + 1], c["u"][: k + 1])
    assert not np.array_equal(a["u"][k + 1 :], c["u"][k + 1 :])
    energy = lambda s: float(np.sum(s["u"][k:] ** 2) * 0.01)  # noqa: E731
    assert energy(a) < 0.9 * energy(c), (energy(a), energy(c))


def _lockstep_flight(d, change: bool) -> dict:
    """Lockstep: the test is the ground station and schedules the setpoints (a +-10 deg square, period 4 s), so
    the autopilot waits at t = 10 s until the parameter is set: the change lands on frame 1000 every time."""
    d.mkdir()
    sitl_port, port = free_ports(2)
    sitl = Proc("sitl", ["--listen", f"127.0.0.1:{sitl_port}", "--lockstep", "--duration", "20"], d / "sitl.log")
    assert sitl.wait_for("sitl: listening", 30)
    gcs = Gcs(port)
    series = d / "series.npz"
    ap = _start_autopilot(
        d, "autopilot", port, "--lockstep", "--duration", "20", "--series", str(series), sitl_port=sitl_port
    )
    try:
        gcs.connect()

        def schedule(t0, t1):  # a point every 100 ms and one at t1 - 10 ms: the horizon reaches the last frame
            for ms in [*range(t0, t1, 100), t1 - 10]:
                deg = 10.0 if (ms // 2000) % 2 == 0 else -10.0
                q = [math.cos(math.radians(deg) / 2), math.sin(math.radians(deg) / 2), 0.0, 0.0]
                gcs.mav.set_attitude_target_send(ms, 1, 1, 71, q, 0, 0, 0, 0)

        gcs.wait("SYSTEM_TIME", timeout=30)  # the first frame waits for a schedule: sim time is known
        schedule(0, 10000)  # up to 9.99 s: frame 1000 (t = 10 s) waits for the schedule
        gcs.wait("SYSTEM_TIME", timeout=30, cond=lambda m: m.time_boot_ms == 10000)
        if change:
            gcs.mav.param_set_send(1, 1, b"CLSAC_LV", 50.0, A.MAV_PARAM_TYPE_REAL32)
            assert gcs.wait("PARAM_VALUE", cond=lambda m: m.param_id == "CLSAC_LV").param_value == 50.0
        schedule(10000, 20000)  # (at most 10 s ahead of sim time)
        assert ap.p.wait(60) == 0
    finally:
        gcs.close()
        ap.stop()
        sitl.stop()
    return dict(np.load(series))


def test_launcher_png_events_and_a_second_ground_station(tmp_path):
    """A launch (lockstep) with MAVProxy's set-up: unsigned, a ground station on a --gcs-peer port gets the
    stream and its answers; flight.png is drawn; the rrd summary lists the event log."""
    from tools.flight import Flight, FlightConfigError
    from tools.view import rrd_files as rrd

    with pytest.raises(FlightConfigError, match="gcs_peer"):
        Flight(gcs_peer=("nowhere",))
    port = free_ports(1)[0]
    gcs = Gcs(port)
    out = tmp_path / "flight"
    try:
        with Flight(lockstep=True, duration=20, out=out, signing=False, gcs_peer=(f"127.0.0.1:{port}",)) as flight:
            hb = gcs.wait("HEARTBEAT", timeout=30)
            assert hb.custom_mode == Mode.CLSAC and gcs.wait("ATTITUDE")
            gcs.mav.param_request_read_send(1, 1, b"CLSAC_LV", -1)
            assert gcs.wait("PARAM_VALUE", cond=lambda m: m.param_id == "CLSAC_LV").param_value == 20.0
            res = flight.wait(timeout=120)
    finally:
        gcs.close()
    assert res is not None and res.ok, res
    png = out / "flight.png"
    assert res.summary["files"]["png"] == str(png) and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = rrd.summary(out / "flight.rrd")
    assert "/autopilot/events" in text and "events:" in text
    # the autopilot's two links have their own component: the servo stream to the SITL (1:140) and its copy to the
    # ground stations (1:1) are told apart in the tlog
    streams = payload_streams(str(out / "flight.tlog"))
    servo = A.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW
    assert len(streams[(1, 140, servo)]) == 2000 and 0 < len(streams[(1, 1, servo)]) < 2000


# ------------------------------------------------------- a ground station that takes the loop away for long (issue 35)
def _hold(gcs: Gcs, seconds: float) -> None:
    """Wait ``seconds`` as a ground station does: a HEARTBEAT a second, reading what comes."""
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        gcs.mav.heartbeat_send(A.MAV_TYPE_GCS, A.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        gcs.drain()
        time.sleep(min(1.0, max(0.0, t_end - time.monotonic())))


def _station_flight(tmp_path, duration: float, script, attempts: int = 2) -> tuple:
    """A real-time launch (unsigned, a pymavlink station on a --gcs-peer port): ``script(gcs)`` runs once the
    station sees the vehicle; the flight's result and its series.  A flight the launcher itself finds starved of
    CPU (steps held or late: the machine's doing, which these tests do not judge) is flown again, up to
    ``attempts`` flights in all, and said on the test's output; what the test asserts holds of the last one."""
    from tools.flight import Flight

    for attempt in range(attempts):
        port = free_ports(1)[0]
        gcs = Gcs(port)
        out = tmp_path / f"flight{attempt}"
        try:
            with Flight(duration=duration, out=out, signing=False, quiet=True, gcs_peer=(f"127.0.0.1:{port}",)) as f:
                gcs.connect()
                script(gcs)
                res = f.wait(timeout=duration + 120)
        finally:
            gcs.close()
        assert res is not None, "the flight did not end"
        if res.ok or STARVED not in (res.reason or "") or attempt == attempts - 1:
            break
        print(f"flight {attempt + 1} starved of CPU, flown again: {res.reason}")
    return res, np.load(out / "autopilot_series.npz"), (out / "autopilot.log").read_text()


def test_manual_for_21_s_then_clsac_again_flies_to_the_end(tmp_path):
    """Must show: SET_MODE custom 0 (MANUAL), 21 s, COMMAND_INT DO_SET_MODE 101: the autopilot died 2 s later of a
    ZeroDivisionError (its 20 s tracking windows with no step of the law).  Now it flies to the end: the launcher
    exits 0 or 3, never 1, and the law flew again after the switch."""

    def script(gcs):
        _hold(gcs, 4.0)
        gcs.mav.set_mode_send(1, A.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, Mode.MANUAL)
        assert gcs.wait("HEARTBEAT", cond=lambda m: m.custom_mode == Mode.MANUAL)
        _hold(gcs, 21.0)
        gcs.drain()
        gcs.mav.command_int_send(1, 1, 0, A.MAV_CMD_DO_SET_MODE, 0, 0, 1, Mode.CLSAC, 0, 0, 0, 0, 0)
        ack = gcs.wait("COMMAND_ACK", cond=lambda m: m.command == A.MAV_CMD_DO_SET_MODE)
        assert ack.result == A.MAV_RESULT_ACCEPTED
        _hold(gcs, 3.0)

    res, s, log = _station_flight(tmp_path, 40.0, script)
    assert res.exit_code in (0, 3) and res.summary["exit_codes"]["autopilot"] == 0, (res.reason, log[-2000:])
    assert "error" not in log.lower() and res.summary["flown"]["complete"], res.reason
    mode = s["mode"].astype(int)
    manual = np.flatnonzero(mode == Mode.MANUAL)
    assert 20.5 <= len(manual) / 100.0 <= 22.0, len(manual)  # the station's 21 s, in control steps
    after = np.flatnonzero(mode[manual[-1] + 1 :] == Mode.CLSAC)
    assert len(after) >= 1000 and np.isfinite(s["u"][manual[-1] + 1 :]).all()  # the law flew again, to the end
    # manual_s is the MANUAL steps times the mean step period of the flight the envelope monitor judged
    # (autopilot.envelope.EnvelopeMonitor): from the first attitude on (the stand-by steps before it, at t < 0 in the
    # series, are not flight). Late steps on a busy machine stretch that period (CI: 10.07 ms; 10.01 ms, where the
    # period of every row of the series, stand-by included, made 20.978 s of 20.991)
    t = s["t"][s["t"] >= 0.0]
    period = (t[-1] - t[0]) / (len(t) - 1)
    assert res.summary["ground_station"]["manual_s"] == pytest.approx(len(manual) * period, abs=0.011)


def test_disarmed_for_26_s_then_armed_flies_to_the_end(tmp_path):
    """Must show: DISARM, 26 s, ARM (MAVProxy's `disarm`, `arm throttle`): the autopilot flies to the end."""

    def script(gcs):
        _hold(gcs, 4.0)
        assert gcs.command(A.MAV_CMD_COMPONENT_ARM_DISARM, 0).result == A.MAV_RESULT_ACCEPTED
        _hold(gcs, 26.0)
        assert gcs.command(A.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == A.MAV_RESULT_ACCEPTED
        _hold(gcs, 3.0)

    res, s, log = _station_flight(tmp_path, 40.0, script)
    assert res.exit_code in (0, 3) and res.summary["exit_codes"]["autopilot"] == 0, (res.reason, log[-2000:])
    assert "error" not in log.lower() and res.summary["flown"]["complete"], res.reason
    armed = s["armed"].astype(bool)
    disarmed = np.flatnonzero(~armed & (s["t"] >= 0.0))
    assert 25.5 <= len(disarmed) / 100.0 <= 27.0, len(disarmed)
    assert armed[disarmed[-1] + 1 :].sum() >= 500 and (s["u"][disarmed] == 0.0).all()


def test_a_flight_disarmed_5_s_in_and_never_armed_again_is_not_ok(tmp_path):
    """Must show: a DISARM about 5 s into a 30 s flight, never re-armed: the law flew about a sixth of it, so the
    flight is not OK (exit 3, OUT OF ENVELOPE, the reason says how much the law flew), however level it stayed."""

    def script(gcs):
        _hold(gcs, 5.0)
        assert gcs.command(A.MAV_CMD_COMPONENT_ARM_DISARM, 0).result == A.MAV_RESULT_ACCEPTED

    res, s, _log = _station_flight(tmp_path, 30.0, script)
    gs = res.summary["ground_station"]
    law = 1.0 - gs["disarmed_share"] - gs["manual_share"]
    assert res.exit_code == 3 and not res.ok and res.summary["outcome"] == "OUT OF ENVELOPE", res.reason
    assert 0.1 < law < 0.4 and gs["disarmed_s"] > 18.0, gs
    reason = res.summary["controlled"]["reason"]
    assert reason.startswith(f"the law flew only {100 * law:.1f} % of the flight (limit: more than 50 %"), reason


def test_current_mode_is_packed_as_pymavlink_packs_it():
    """CURRENT_MODE goes out through a fast packer on its wire layout (the autopilot does not load pymavlink's
    ``all`` dialect for it): the same bytes as that dialect's message, every mode and sequence number."""
    from autopilot.shared.fastmav import FastPacker
    from autopilot.vehicle import _CURRENT_MODE_MSG, CURRENT_MODE, MAV_STANDARD_MODE_NON_STANDARD

    assert CURRENT_MODE == mavall.MAVLINK_MSG_ID_CURRENT_MODE and MAV_STANDARD_MODE_NON_STANDARD == 0
    assert mavall.MAV_STANDARD_MODE_NON_STANDARD == 0
    packer = FastPacker(_CURRENT_MODE_MSG, 1, 1)
    ref = mavall.MAVLink(None, 1, 1)
    for seq, (mode, selected) in enumerate([(m, s) for m in Mode for s in (Mode.MANUAL, Mode.CLSAC, Mode.LAW)]):
        ref.seq = seq % 256
        want = mavall.MAVLink_current_mode_message(MAV_STANDARD_MODE_NON_STANDARD, int(mode), int(selected)).pack(ref)
        assert packer(seq % 256, int(mode), int(selected), MAV_STANDARD_MODE_NON_STANDARD) == want
