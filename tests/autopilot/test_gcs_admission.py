"""Which ground stations the autopilot talks to by default, and how it says why it refuses one (docs/spec.md,
"Which ground stations are admitted"): real autopilot processes and pymavlink stations on real UDP sockets.

Systems 255 (QGroundControl, Mission Planner, MAVProxy) and 245 (MAVSDK) with any component are taken; any other
system is taken once it sent a MAV_TYPE_GCS HEARTBEAT; ``--gcs-id`` narrows to the listed ids.  A refused packet
whose ids look like a ground station's is counted per source and reported once, in the log and as a STATUSTEXT.
"""

from __future__ import annotations

import os
import time

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from autopilot.shared.events import StatusTextAssembler  # noqa: E402
from tests._mavlink_procs import Proc, free_ports, load_json  # noqa: E402

pytestmark = pytest.mark.e2e
M = mavutil.mavlink


class Station:
    """A ground station on the autopilot's --gcs port (udpin, as MAVProxy and QGroundControl listen)."""

    def __init__(self, port: int, sysid: int, compid: int):
        self.conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{port}", source_system=sysid, source_component=compid, dialect="common"
        )
        self.texts: list[str] = []
        self._assembler = StatusTextAssembler()

    @property
    def address(self) -> str:
        return "127.0.0.1:%d" % self.conn.port.getsockname()[1]

    def ids(self, sysid: int, compid: int) -> None:
        self.conn.mav.srcSystem, self.conn.mav.srcComponent = sysid, compid

    def recv(self, kind: str | None = None, timeout: float = 3.0, cond=None):
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            m = self.conn.recv_match(blocking=True, timeout=0.1)
            if m is None:
                continue
            if m.get_type() == "STATUSTEXT" and (text := self._assembler.add(m)) is not None:
                self.texts.append(text)
            if kind is not None and m.get_type() == kind and (cond is None or cond(m)):
                return m
        return None

    def heartbeat(self, mav_type: int = M.MAV_TYPE_GCS) -> None:
        self.conn.mav.heartbeat_send(mav_type, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)

    def read_lv(self, timeout: float = 2.0):
        self.conn.mav.param_request_read_send(1, 1, b"CLSAC_LV", -1)
        return self.recv("PARAM_VALUE", timeout, cond=lambda m: m.param_id == "CLSAC_LV")

    def close(self):
        self.conn.close()


@pytest.fixture
def start(tmp_path):
    procs = []

    def _start(*extra):
        port = free_ports(1)[0]
        station = Station(port, 255, 190)
        stats = tmp_path / f"autopilot{len(procs)}.json"
        args = ["--sitl", f"127.0.0.1:{free_ports(1)[0]}", "--gcs", f"127.0.0.1:{port}", "--stats-json", str(stats)]
        ap = Proc("autopilot", [*args, *extra], tmp_path / f"autopilot{len(procs)}.log")
        assert ap.wait_for("autopilot:", 30), ap.output()
        assert station.recv("HEARTBEAT", 10) is not None, ap.output()
        procs.append((ap, station))
        return ap, station, stats

    yield _start
    for ap, station in procs:
        station.close()
        ap.stop()


def _count(lines, needle: str) -> int:
    return sum(needle in line for line in lines)


def test_mavsdk_system_245_is_answered_by_default(start):
    ap, st, stats = start()
    st.ids(245, 190)  # MAVSDK's default ids: every packet of it was wrong_id before
    m = st.read_lv()
    assert m is not None and m.param_value == 20.0, ap.output()
    ap.stop()
    assert "wrong_id" not in load_json(stats)["links"]["gcs"]["rejected"]


def test_other_system_refused_and_reported_once_until_its_gcs_heartbeat(start):
    ap, st, stats = start()
    st.ids(42, 190)
    refused = 20
    for _ in range(refused):
        st.conn.mav.param_request_read_send(1, 1, b"CLSAC_LV", -1)
    assert st.recv("PARAM_VALUE", 1.5) is None  # no answer to an unknown system
    why = (
        f"GCS 42:190 at {st.address} refused: system 42 is not a ground station's (255, 245) and sent no "
        f"MAV_TYPE_GCS HEARTBEAT first"
    )
    assert _count(st.texts, why) == 1, st.texts  # one STATUSTEXT (chunked: longer than 50 bytes), not twenty
    assert _count(ap.output().splitlines(), why) == 1, ap.output()
    # A companion computer (not a ground station's ids, not a GCS heartbeat): refused, counted, not reported
    st.ids(43, 191)
    st.heartbeat(M.MAV_TYPE_ONBOARD_CONTROLLER)
    assert st.read_lv(1.0) is None
    # The GCS heartbeat makes system 42 a ground station: now it is answered
    st.ids(42, 190)
    st.heartbeat()
    m = st.read_lv()
    assert m is not None and m.param_value == 20.0, ap.output()
    ap.stop()
    gcs = load_json(stats)["links"]["gcs"]
    assert gcs["learned_gcs_systems"] == [42]
    assert gcs["refused_gcs"] == {"wrong_id 42:190": refused}
    assert gcs["rejected"]["wrong_id"] == refused + 2  # and 43:191's heartbeat and request, counted, never reported
    assert "43:191" not in ap.output()


def test_gcs_id_narrows_and_turns_learning_off(start):
    ap, st, stats = start("--gcs-id", "255:190")
    assert st.read_lv() is not None
    st.ids(245, 190)
    st.heartbeat()  # a GCS heartbeat does not widen a list given with --gcs-id
    assert st.read_lv(1.0) is None
    why = f"GCS 245:190 at {st.address} refused: not one of the accepted --gcs-id 255:190"
    st.recv(timeout=0.5)
    assert _count(st.texts, why) == 1, st.texts
    ap.stop()
    gcs = load_json(stats)["links"]["gcs"]
    assert "learned_gcs_systems" not in gcs and gcs["refused_gcs"] == {"wrong_id 245:190": 2}


def test_unsigned_ground_station_told_why_by_a_signed_vehicle(start, tmp_path):
    key = tmp_path / "k.key"
    key.write_text("ab" * 32)
    key.chmod(0o600)
    ap, st, stats = start("--signing-key", str(key))  # pymavlink without a key reads the signed HEARTBEAT
    for _ in range(5):
        st.heartbeat()
    assert st.read_lv(1.0) is None
    why = f"GCS 255:190 at {st.address} refused: unsigned; this vehicle takes only packets signed with its key"
    st.recv(timeout=0.5)
    assert _count(st.texts, why) == 1, st.texts
    assert _count(ap.output().splitlines(), why) == 1
    ap.stop()
    assert load_json(stats)["links"]["gcs"]["refused_gcs"] == {"unsigned 255:190": 6}


def _setpoint_far_ahead(st: Station) -> None:
    # MAVSDK's stamp: its host's uptime in ms, here ~11.6 days, far ahead of any sim time the vehicle has
    st.conn.mav.set_attitude_target_send(1_000_000_000, 1, 1, 71, [1.0, 0.0, 0.0, 0.0], 0, 0, 0, 0)


def test_a_setpoint_stamped_with_the_senders_clock_is_refused_and_said_once(start):
    ap, st, stats = start()
    for _ in range(10):
        _setpoint_far_ahead(st)
    st.recv(timeout=1.0)
    why = "a ground station stamping its own clock (MAVSDK) needs --setpoint-time now"
    assert sum(why in t for t in st.texts) == 1, st.texts
    assert sum(why in line for line in ap.output().splitlines()) == 1
    ap.stop()
    s = load_json(stats)
    assert s["links"]["gcs"]["rejected"]["future_setpoint"] == 10 and s["events"].get("setpoints", 0) == 0


def test_setpoint_time_now_flies_a_setpoint_whatever_its_stamp(start):
    ap, st, stats = start("--setpoint-time", "now")
    for _ in range(10):
        _setpoint_far_ahead(st)
    st.recv(timeout=1.0)
    ap.stop()
    s = load_json(stats)
    assert "future_setpoint" not in s["links"]["gcs"]["rejected"]
    assert s["events"]["setpoints"] == 10 and s["events"]["setpoints_now"] == 10
