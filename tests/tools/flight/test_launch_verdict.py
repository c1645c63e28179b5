"""The launcher never calls a failed flight OK (issue #11): a stalled SITL, a child that ends early with status 0,
impossible rates; and every process answers SIGINT within a period and still writes its stats."""

from __future__ import annotations

import json
import os
import signal
import time

import pytest

from tests._mavlink_procs import Proc, free_base_port, free_ports, mav, mavlink, pack, run_cli, udp
from tools.flight import Flight

pytestmark = pytest.mark.e2e  # real processes over loopback UDP


def _summary(res) -> dict:
    with open(res.out / "summary.json") as f:
        return json.load(f)


def _wait_for_steps(flight: Flight, name: str, text: str, timeout: float = 60.0) -> None:
    t0 = time.monotonic()
    while text not in (flight.out / f"{name}.log").read_text():
        assert time.monotonic() - t0 < timeout, f"no {text!r} in {name}.log"
        time.sleep(0.05)


# The autopilot's give-up on a silent SITL (lockstep) and the GCS script's on a silent vehicle, 5 s by default: shorter
# for the stalled flights below, which stop a process for good (still above the blame threshold, STALL_S = 2 s).
GIVE_UP_S = 3.0


def test_stalled_sitl_fails_the_flight_and_is_named(tmp_path):
    kw = dict(lockstep=True, duration=3000.0, out=tmp_path, quiet=True, rrd=False, series=False)
    with Flight(lockstep_idle_exit=GIVE_UP_S, **kw) as flight:
        _wait_for_steps(flight, "sitl", "lockstep from")
        time.sleep(1.0)
        os.kill(flight.pids["sitl"], signal.SIGSTOP)  # longer than the autopilot's lockstep idle timeout
        res = flight.wait(timeout=120)
    assert not res.ok and res.exit_code == 1
    assert res.summary["failed"] == "sitl" and res.reason.startswith("sitl stalled: sent nothing for "), res.reason
    s = _summary(res)
    assert s["ok"] is False and s["failed"] == "sitl"
    assert 0.0 < s["flown"]["fraction"] < 1.0 and f"{100 * s['flown']['fraction']:.3g} %" in s["error"]


def test_child_ending_early_with_status_0_fails_the_flight(tmp_path):
    kw = dict(duration=8.0, out=tmp_path, quiet=True, rrd=False, series=False)
    with Flight(**kw) as flight:
        _wait_for_steps(flight, "gcs", "gcs: vehicle ")
        time.sleep(1.5)
        os.kill(flight.pids["sitl"], signal.SIGINT)  # a clean, early exit with status 0
        res = flight.wait(timeout=120)
    assert res.summary["exit_codes"]["sitl"] == 0
    assert not res.ok and res.exit_code == 1
    assert res.summary["failed"] == "sitl" and "sitl exited early (exit code 0)" in res.reason, res.reason
    s = _summary(res)
    assert s["ok"] is False and 0.0 < s["flown"]["fraction"] < 0.9


def test_wall_clock_limit_is_the_launchers_verdict_not_a_childs(tmp_path):
    """A flight stopped by ``--timeout`` is failed by the launcher itself, not blamed on the child it stopped."""
    res = Flight(lockstep=True, duration=3000.0, timeout=3.0, out=tmp_path, quiet=True, rrd=False, png=False).run()
    s = _summary(res)
    assert not res.ok and res.exit_code == 1 and s["ok"] is False
    assert s["failed"] == "launch" and "did not finish within 3 s of wall clock (--timeout)" in s["error"], s["error"]
    assert 0.0 < s["flown"]["fraction"] < 1.0 and "flown " in s["error"]


def _kill_by_cmdline(needle: str) -> None:
    """SIGKILL every process whose command line contains ``needle`` (the orphans of a killed launcher)."""
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/cmdline", "rb") as f:
                    if needle.encode() in f.read():
                        os.kill(int(d), signal.SIGKILL)
            except OSError:
                continue


def test_a_killed_launcher_never_leaves_an_earlier_ok_verdict(tmp_path):
    """A folder reused by a second flight whose launcher is SIGKILLed: summary.json says not OK (still running or
    killed), never the first flight's "ok: true", and the first flight's stats, series and recording are gone."""
    import subprocess
    import sys

    out = tmp_path / "reused"
    r = run_cli("tools.launch", "--lockstep", "--duration", "2", "--quiet", "--no-png", "--out", str(out), timeout=120)
    assert r.returncode == 0 and json.loads((out / "summary.json").read_text())["ok"] is True
    argv = [sys.executable, "-m", "tools.launch", "--lockstep", "--duration", "3000", "--quiet", "--out", str(out)]
    launcher = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        t0 = time.monotonic()
        while True:  # this flight's SITL (its log starts with its own command line) is flying
            log = (out / "sitl.log").read_text() if (out / "sitl.log").exists() else ""
            if "3000" in log.split("\n", 1)[0] and "lockstep from" in log:
                break
            assert time.monotonic() - t0 < 60 and launcher.poll() is None
            time.sleep(0.05)
        launcher.kill()
        launcher.wait(10)
        s = json.loads((out / "summary.json").read_text())
        assert s["ok"] is False and s["running"] is True and s["exit_code"] is None
        assert f"pid {launcher.pid}" in s["error"]
        for stale in ("autopilot.json", "sitl.json", "gcs.json", "autopilot_series.npz", "flight.rrd"):
            assert not (out / stale).exists(), stale
    finally:
        _kill_by_cmdline(str(out))


def _raw_socket():
    """A raw IP socket (root or CAP_NET_RAW), or skip: forging a source address needs one."""
    import socket

    try:
        raw = socket.socket(socket.AF_INET, socket.SOCK_RAW, socket.IPPROTO_RAW)
    except PermissionError:
        pytest.skip("forging a source address needs root or CAP_NET_RAW")
    raw.setsockopt(socket.IPPROTO_IP, socket.IP_HDRINCL, 1)
    return raw


def _send_forged(raw, payload: bytes, sport: int, dport: int) -> None:
    """One UDP datagram from 127.0.0.1:``sport`` to 127.0.0.1:``dport`` (IPv4 header by hand; the kernel fills
    the checksum of a loopback IP header, and a UDP checksum of 0 means none)."""
    import socket
    import struct

    lo = socket.inet_aton("127.0.0.1")
    ip = struct.pack("!BBHHHBBH4s4s", 0x45, 0, 28 + len(payload), 0, 0, 64, socket.IPPROTO_UDP, 0, lo, lo)
    raw.sendto(ip + struct.pack("!HHHH", sport, dport, 8 + len(payload), 0) + payload, ("127.0.0.1", 0))


def test_ground_station_ended_by_a_forged_poweroff_fails_the_flight(tmp_path):
    """Unsigned, a HEARTBEAT POWEROFF forged with the autopilot's own address (what root can do: the README's
    "not protected") ends the GCS script mid-profile with "end of run (vehicle powered off)".  The autopilot flies
    on, wings level, every step on a fresh attitude: the verdict still says the flight failed, naming the GCS."""
    raw = _raw_socket()
    base = free_base_port()
    kw = dict(duration=8.0, out=tmp_path, quiet=True, rrd=False, series=False, png=False, signing=False)
    with Flight(base_port=base, **kw) as flight:
        _wait_for_steps(flight, "gcs", "gcs: vehicle ")
        time.sleep(1.5)
        hb = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_GENERIC, 0, 0, mavlink.MAV_STATE_POWEROFF, 3
        )
        _send_forged(raw, pack(mav(1, 1), hb), sport=base + 3, dport=base + 1)  # "from" the autopilot's GCS link
        res = flight.wait(timeout=120)
    raw.close()
    s = _summary(res)
    gcs = json.loads((tmp_path / "gcs.json").read_text())
    assert gcs["exit_reason"] == "end of run (vehicle powered off)"  # the forgery worked on the GCS script ...
    # ... and the autopilot flew every step to the end: those it counts as lost are the ones a stall of the machine
    # made late or held (CI: one 114 ms stall, 798 + 2 of 800), not steps it stopped flying with the GCS gone
    flown = res.summary["flown"]
    assert flown["steps"] + flown["lost"]["hold_steps"] + flown["lost"]["late_steps"] == flown["steps_asked"], flown
    assert not res.ok and res.exit_code == 1 and s["ok"] is False  # but the flight did not do what was asked
    assert s["failed"] == "gcs" and "gcs exited early (exit code 0)" in s["error"] and "of its profile" in s["error"]


def test_lowest_real_time_sensor_rate_is_flown(tmp_path):
    """Just above the bound (20 Hz: two ATTITUDE per 0.1 s attitude timeout) the real-time flight is flown whole."""
    res = Flight(duration=3.0, sensor_rate=20.0, out=tmp_path, quiet=True, rrd=False, series=False, png=False).run()
    assert res.ok, res.reason
    assert res.summary["flown"]["complete"] and res.summary["flown"]["fraction"] == 1.0


def test_lockstep_sitl_answers_sigint_while_waiting_and_writes_its_stats(tmp_path):
    port = free_ports(1)[0]
    stats = tmp_path / "sitl.json"
    sitl = Proc("sitl", ["--listen", f"127.0.0.1:{port}", "--lockstep", "--stats-json", str(stats)], tmp_path / "s")
    assert sitl.wait_for("listening on")
    s = udp()  # an autopilot that announces itself and then never answers a frame
    s.sendto(pack(mav(1, 1), mavlink.MAVLink_heartbeat_message(1, 0, 0, 0, 3, 3)), ("127.0.0.1", port))
    s.sendto(pack(mav(1, 140), mavlink.MAVLink_heartbeat_message(1, 0, 0, 0, 3, 3)), ("127.0.0.1", port))
    assert sitl.wait_for("lockstep from")
    time.sleep(0.5)
    t0 = time.monotonic()
    sitl.p.send_signal(signal.SIGINT)
    code = sitl.p.wait(10)
    assert code == 0 and time.monotonic() - t0 < 1.0
    sitl.stop()
    s.close()
    assert json.loads(stats.read_text())["exit_reason"] == "stopped by signal"


def test_stalled_autopilot_is_blamed_not_the_gcs_that_noticed(tmp_path):
    kw = dict(duration=20.0, out=tmp_path, quiet=True, rrd=False, series=False)
    with Flight(vehicle_timeout=GIVE_UP_S, **kw) as flight:
        _wait_for_steps(flight, "gcs", "gcs: vehicle ")
        time.sleep(1.0)
        os.kill(flight.pids["autopilot"], signal.SIGSTOP)  # longer than the GCS script's vehicle timeout
        res = flight.wait(timeout=60)  # the launcher then kills the stopped process
    assert not res.ok and res.exit_code == 1
    assert res.summary["failed"] == "autopilot", res.reason
    assert res.reason.startswith("autopilot stalled: sent nothing for "), res.reason
    assert "gcs reports: vehicle lost" in res.reason
