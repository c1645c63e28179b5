"""Several ground stations on a signed flight, each a pymavlink ``mavutil`` connection signing with pymavlink's own
``setup_signing`` (the code MAVProxy's ``signing setup`` runs), against the real processes of ``tools.flight``.

The autopilot's ground-station link admits every address whose packets carry a valid signature, up to
``AutopilotOptions.max_gcs`` (8) in all, the launcher's GCS script included: each admitted station receives the
telemetry stream and answers to its own requests; an unsigned station (``unsigned``), a station with the wrong key
(``bad_signature``) and signed stations beyond the bound (``not_peer``) are rejected, counted exactly in
``DIR/autopilot.json`` and receive nothing.  ``python -m tools.flight.keygen --passphrase`` makes the key MAVProxy's
``signing setup PASSPHRASE`` makes (SHA-256 of the passphrase), and a station keyed that way flies with it.
"""

from __future__ import annotations

import hashlib
import os
import re
import subprocess
import time
from collections import Counter
from pathlib import Path

import pytest

from autopilot.loop import AutopilotOptions
from autopilot.shared.signing import load_key
from tests._mavlink_procs import PY, load_json, mavlink
from tools.flight import Flight

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402  (MAVLink 2 chosen above, before mavutil picks its dialect)

from tools.flight.outcome import STARVED  # the launcher's own finding (realtime_advice)

pytestmark = pytest.mark.e2e  # real processes over loopback UDP

MAX_GCS = AutopilotOptions.max_gcs
AP_ID = (1, 1)  # the autopilot as ground stations see it
WRONG_KEY = bytes(range(32))
PASSPHRASE = "correct-horse-battery-staple"
_GCS_LINK = re.compile(r"GCS link [\d.]+:(\d+) -> ")


def _flight(out: Path, duration: float, **kw) -> Flight:
    """A real-time signed flight (SITL, GCS script, autopilot) in ``out``: nothing but the processes' JSON."""
    return Flight(duration=duration, out=out, quiet=True, rrd=False, series=False, png=False, **kw)


def _gcs_port(out: Path, timeout: float = 30.0) -> int:
    """The autopilot's ground-station port, once the launcher's GCS script has found the vehicle."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        try:
            m = _GCS_LINK.search((out / "autopilot.log").read_text())
            if m and "gcs: vehicle " in (out / "gcs.log").read_text():
                return int(m.group(1))
        except OSError:
            pass
        time.sleep(0.02)
    raise AssertionError(f"the flight in {out} did not start")


class Station:
    """A ground station on its own UDP port: pymavlink's mavutil, signing as MAVProxy does (``key``) or not."""

    def __init__(self, port: int, compid: int, key: bytes | None):
        self.conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", source_system=255, source_component=compid, dialect="common"
        )
        assert self.conn.mavlink20()
        if key is not None:
            self.conn.setup_signing(key, sign_outgoing=True)  # MAVProxy: SigningModule.setup_signing_link
        self.compid = compid
        self.port = None
        self.sent = 0  # datagrams sent (one message each)
        self.datagrams = 0  # datagrams received, whatever they hold
        self.got: Counter = Counter()  # messages received whose signature pymavlink accepted, by type
        self.param_indexes: set = set()
        self.acks: list = []  # COMMAND_ACKs addressed to this station

    def hello(self) -> None:
        """A HEARTBEAT, a PARAM_REQUEST_READ by index and a COMMAND_LONG (REQUEST_MESSAGE AUTOPILOT_VERSION)."""
        mav = self.conn.mav
        mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE)
        mav.param_request_read_send(*AP_ID, b"", self.compid % 8)
        mav.command_long_send(
            *AP_ID, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0
        )
        self.sent += 3
        self.port = self.conn.port.getsockname()[1]  # bound by the first send

    def pump(self) -> None:
        """Read every datagram waiting; decode them with pymavlink (which checks the autopilot's signatures)."""
        while data := self.conn.recv():
            self.datagrams += 1
            for msg in self.conn.mav.parse_buffer(data) or ():
                kind = msg.get_type()
                self.got[kind] += 1
                if kind == "PARAM_VALUE":
                    self.param_indexes.add(msg.param_index)
                elif kind == "COMMAND_ACK" and (msg.target_system, msg.target_component) == (255, self.compid):
                    self.acks.append(msg)

    def served(self) -> bool:
        got = self.got
        return bool(got["HEARTBEAT"] and got["ATTITUDE"] and self.acks and self.compid % 8 in self.param_indexes)

    def close(self) -> None:
        self.conn.close()


def _until(stations, done, timeout: float = 5.0, resend: float = 0.5) -> bool:
    """Pump every station until ``done()``; each one says hello every ``resend`` s (a first datagram may race
    the autopilot's start)."""
    t0 = time.monotonic()
    last = -1e9
    while time.monotonic() - t0 < timeout:
        if time.monotonic() - last >= resend:
            last = time.monotonic()
            for s in stations:
                s.hello()
        time.sleep(0.02)
        for s in stations:
            s.pump()
        if done():
            return True
    return False


def test_signed_stations_are_admitted_up_to_the_bound_the_others_rejected_and_counted(tmp_path):
    with _flight(tmp_path, duration=7.0) as flight:
        port = _gcs_port(tmp_path)
        key = load_key(tmp_path / "signing.key")  # the launcher's key of this flight
        # The launcher's GCS script is admitted from the start: MAX_GCS - 1 more stations fill the link.
        admitted = [Station(port, 191 + i, key) for i in range(MAX_GCS - 1)]
        assert _until(admitted, lambda: all(s.served() for s in admitted)), [
            (s.compid, dict(s.got), len(s.acks)) for s in admitted
        ]
        over = [Station(port, 210 + i, key) for i in range(2)]  # valid signatures, but the link is full
        unsigned = Station(port, 220, None)  # MAVProxy without "signing setup"
        wrong = Station(port, 221, WRONG_KEY)  # "signing setup" with another passphrase
        rejected = [*over, unsigned, wrong]
        _until([*admitted, *rejected], lambda: False, timeout=1.5)
        assert flight.wait(timeout=0) is None, "the flight ended before the stations were done (too slow a host?)"
        res = flight.wait(timeout=30)
    for s in [*admitted, *rejected]:
        s.close()
    assert res is not None, "the flight did not end"
    # A flight the launcher itself finds starved of CPU (a step held or late: the machine's doing, CI once held one
    # step of 700 at load 2.0) is not this test's to judge: it says so, and the admission is checked all the same.
    assert res.ok or STARVED in (res.reason or ""), res.reason
    if not res.ok:
        print(f"the flight was starved of CPU, its admission checked all the same: {res.reason}")

    for s in admitted:  # the telemetry stream, and the answers to its own requests (signed, checked by pymavlink)
        assert s.got["HEARTBEAT"] >= 1 and s.got["ATTITUDE"] >= 10, (s.compid, dict(s.got))
        assert s.got["BAD_DATA"] == 0 and {a.result for a in s.acks} == {mavlink.MAV_RESULT_ACCEPTED}, s.compid
    for s in rejected:  # not a single datagram came back to these
        assert s.sent >= 9 and s.datagrams == 0, (s.compid, s.datagrams)

    gcs = load_json(tmp_path / "autopilot.json")["links"]["gcs"]
    rej = gcs["rejected"]
    assert rej.get("unsigned") == unsigned.sent and rej.get("bad_signature") == wrong.sent, rej
    assert rej.get("not_peer") == sum(s.sent for s in over), rej
    assert "replay" not in rej, rej  # one timestamp stream per station (its component id): no collisions
    # The stations went quiet after 1.5 s: in the flight's remaining seconds their slots expired (no HEARTBEAT for
    # the expiry time, MAVLink's heartbeat protocol), so every one of them is either still admitted or listed expired.
    held = set(gcs["admitted"]) | {addr for addr, _ in gcs.get("expired", [])}
    assert len(held) == MAX_GCS, gcs
    assert {f"127.0.0.1:{s.port}" for s in admitted} < held
    assert not {f"127.0.0.1:{s.port}" for s in rejected} & held
    assert gcs["rx_datagrams"] == gcs["rx_accepted"] + sum(rej.values())
    asked = sum(s.sent for s in admitted) // 3  # every request of an admitted station was taken, none other
    assert gcs["rx_by_type"]["PARAM_REQUEST_READ"] == gcs["rx_by_type"]["COMMAND_LONG"] == asked, gcs["rx_by_type"]


def _keygen(path: Path, stdin: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [PY, "-m", "tools.flight.keygen", "--passphrase", str(path)],
        input=stdin,
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_keygen_passphrase_is_mavproxys_key(tmp_path):
    path = tmp_path / "pass.key"
    r = _keygen(path, PASSPHRASE + "\n")  # as `echo PASSPHRASE | python -m tools.flight.keygen --passphrase FILE`
    assert r.returncode == 0, r.stderr
    assert PASSPHRASE not in r.stdout + r.stderr and path.read_text().strip() not in r.stdout + r.stderr
    # MAVProxy's SigningModule.passphrase_to_key, computed here independently
    assert load_key(path) == hashlib.sha256(PASSPHRASE.encode("ascii")).digest()
    assert path.read_text() == hashlib.sha256(PASSPHRASE.encode()).hexdigest() + "\n"
    assert os.stat(path).st_mode & 0o777 == 0o600
    crlf = tmp_path / "crlf.key"
    assert _keygen(crlf, PASSPHRASE + "\r\n").returncode == 0 and load_key(crlf) == load_key(path)
    for bad, needle in (("", "empty passphrase"), ("\n", "empty passphrase"), ("short\n", "at least 8")):
        r = _keygen(tmp_path / "bad.key", bad)
        assert r.returncode == 2 and needle in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert not (tmp_path / "bad.key").exists()
    r = _keygen(tmp_path / "bad.key", "two words here\n")  # MAVProxy's command line would split it
    assert r.returncode == 2 and "without spaces" in r.stderr and not (tmp_path / "bad.key").exists()
    assert _keygen(path, PASSPHRASE + "\n").returncode == 2  # never overwrites a key
    # The passphrase is never an argument: given on the command line it is an unknown argument, nothing written.
    r = subprocess.run(
        [PY, "-m", "tools.flight.keygen", "--passphrase", PASSPHRASE, str(tmp_path / "argv.key")],
        capture_output=True,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
    )
    assert r.returncode == 2 and not (tmp_path / "argv.key").exists() and not Path(PASSPHRASE).exists()


def test_station_keyed_from_the_passphrase_flies_a_flight_keyed_by_keygen(tmp_path):
    key_file = tmp_path / "pass.key"
    assert _keygen(key_file, PASSPHRASE + "\n").returncode == 0
    out = tmp_path / "flight"
    with _flight(out, duration=3.0, signing_key=key_file) as flight:
        port = _gcs_port(out)
        # what MAVProxy does on "signing setup PASSPHRASE": SHA-256 of the passphrase, then setup_signing
        station = Station(port, 230, hashlib.sha256(PASSPHRASE.encode("ascii")).digest())
        assert _until([station], station.served), dict(station.got)
        res = flight.wait(timeout=30)
    station.close()
    assert res is not None and res.ok, res and res.reason
    assert station.got["BAD_DATA"] == 0
    gcs = load_json(out / "autopilot.json")["links"]["gcs"]
    assert f"127.0.0.1:{station.port}" in gcs["admitted"]
    assert not {"unsigned", "bad_signature", "replay", "not_peer"} & set(gcs["rejected"]), gcs["rejected"]
