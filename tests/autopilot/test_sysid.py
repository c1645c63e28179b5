"""The vehicle's system id (``--sysid N``): two real launches with ids 1 and 2 streaming to one ground-station port
are two vehicles, each with its own HEARTBEAT and ATTITUDE; the id reaches every process (autopilot N:1 and N:140,
SITL N:200: the flight's tlog), and a bad id is one line and exit 2 on every command."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from collections import Counter, defaultdict

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

from autopilot.shared.tlog import packet_ids, read_tlog  # noqa: E402
from tests._mavlink_procs import free_ports, load_json  # noqa: E402

pytestmark = pytest.mark.e2e


class Listener:
    """One UDP port, as a ground station listens: every packet decoded (signed ones too: no key, no check) and
    counted by (source system, component, message)."""

    def __init__(self, port: int):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.2)
        self.seen: Counter = Counter()
        self.times: dict = defaultdict(list)  # source system -> ATTITUDE.time_boot_ms, in arrival order
        self.stop = False
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        mav = mavlink.MAVLink(None, 255, 190)
        while not self.stop:
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                continue
            for m in mav.parse_buffer(data) or []:
                key = (m.get_srcSystem(), m.get_srcComponent(), m.get_type())
                self.seen[key] += 1
                if m.get_type() == "ATTITUDE":
                    self.times[m.get_srcSystem()].append(m.time_boot_ms)

    def close(self):
        self.stop = True
        self.thread.join(5)
        self.sock.close()


def _launch(out, sysid: int, port: int) -> subprocess.Popen:
    args = ["--lockstep", "--duration", "5", "--sysid", str(sysid), "--gcs-peer", f"127.0.0.1:{port}"]
    return subprocess.Popen(
        [sys.executable, "-m", "tools.launch", *args, "--out", str(out), "--no-rrd", "--no-png", "--quiet"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        stdin=subprocess.DEVNULL,
    )


def test_two_launches_with_sysid_1_and_2_are_two_vehicles_on_one_port(tmp_path):
    port = free_ports(1)[0]
    gs = Listener(port)
    try:
        flights = {n: _launch(tmp_path / f"v{n}", n, port) for n in (1, 2)}  # at the same time, one port
        codes = {n: p.wait(120) for n, p in flights.items()}
        time.sleep(0.3)
    finally:
        gs.close()
    assert codes == {1: 0, 2: 0}, {n: (tmp_path / f"v{n}" / "autopilot.log").read_text()[-1500:] for n in codes}
    systems = {s for s, c, _ in gs.seen if c == 1}
    assert systems == {1, 2}, gs.seen
    for n in (1, 2):
        assert gs.seen[(n, 1, "HEARTBEAT")] >= 1 and gs.seen[(n, 1, "ATTITUDE")] >= 40, gs.seen  # 10 Hz x 5 s
        summary = load_json(tmp_path / f"v{n}" / "summary.json")
        assert summary["ok"] is True
        srcs = {packet_ids(raw)[:2] for _, raw in read_tlog(str(tmp_path / f"v{n}" / "flight.tlog"))}
        # what the autopilot sent and accepted: its GCS link N:1, its SITL link N:140, the SITL N:200, the GCS 255
        assert {(n, 1), (n, 140), (n, 200)} <= srcs and not any(s == 3 - n for s, _ in srcs), srcs
        assert f"gcs: vehicle {n}:1 at" in (tmp_path / f"v{n}" / "gcs.log").read_text()  # its script flew N:1
        # one vehicle's stream is one clock: the two flights' ATTITUDE (both from sim time 0) are never merged
        times = gs.times[n]
        assert len(times) >= 40 and times == sorted(times), times


@pytest.mark.parametrize("module", ["tools.launch", "autopilot", "sitl", "tools.gcs"])
@pytest.mark.parametrize(
    "value, why", [("0", "must be 1..254"), ("255", "must be 1..254"), ("x", "expected an integer")]
)
def test_bad_sysid_is_one_line_and_exit_2(module, value, why):
    r = subprocess.run(
        [sys.executable, "-m", module, "--sysid", value],
        capture_output=True,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
    )
    assert r.returncode == 2 and r.stdout == "", (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "--sysid" in lines[0] and why in lines[0], r.stderr
