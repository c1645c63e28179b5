"""End to end, real time: the launcher's default mode, the attitude-loss failsafe (SITL killed and
restarted) and the SITL's servo timeout (autopilot killed and restarted).  Timing bounds are loose
(a loaded 2-core machine); the strict targets are in ``python -m tools.bench mavlink``."""

from __future__ import annotations

import os
import re
import time

import pytest

from autopilot.shared.process import rt_throttling
from autopilot.shared.tlog import read_tlog
from tests._mavlink_procs import Proc, free_ports, load_json, mav, mavlink, run_cli, udp

pytestmark = pytest.mark.e2e  # real processes over loopback UDP


def test_launch_realtime(tmp_path):
    out = tmp_path / "rt"
    r = run_cli("tools.launch", "--duration", "3", "--rate", "100", "--out", str(out), timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    s = load_json(out / "summary.json")
    assert s["ok"] and s["mode"] == "realtime" and s["scenario"] == "custom"
    (run,) = s["runs"]
    assert run["steps"] == 300
    assert run["metrics"]["max_abs_u"] > 0.0  # it flew the square wave
    timing = s["timing"]
    assert timing["period_jitter_ms"]["n"] == 299
    assert timing["missed_deadlines"] <= 30  # loose: a loaded 2-core machine
    # real time: the figure includes the wait for the deadline, so it is reported as an age, not a latency
    assert "attitude age" in r.stdout and "in-to-out latency" not in r.stdout
    assert len(list(read_tlog(str(out / "flight.tlog")))) > 600
    # the GCS live line is shown on the console and in its log
    assert "[gcs] gcs: t=" in r.stdout and "setpoint=" in (out / "gcs.log").read_text()
    assert "flight.tlog" in r.stdout and "summary.json" in r.stdout


def test_launch_realtime_busy_wait_pinned_serves_both_links(tmp_path):
    """--pin --busy-wait: the loop never sleeps, yet every attitude and setpoint is taken while it spins and
    the helper threads are moved off the control CPU."""
    out = tmp_path / "busy"
    r = run_cli(
        "tools.launch", "--duration", "3", "--rate", "100", "--pin", "--busy-wait", "--out", str(out), timeout=120
    )
    assert r.returncode == 0, r.stdout + r.stderr
    s = load_json(out / "summary.json")
    assert s["ok"] and s["runs"][0]["steps"] == 300
    assert s["timing"]["missed_deadlines"] <= 30  # loose: a loaded 2-core machine
    ap, gcs = s["counters"]["autopilot"], s["counters"]["gcs"]
    # ATTITUDE at about the 200 Hz sensor rate for 3 s (loose: the SITL shares CPU 0 with the GCS script), every
    # one of them read between steps; every setpoint sent was taken.
    sitl_sent = s["counters"]["sitl"]["tx_by_type"]["ATTITUDE"]
    assert sitl_sent >= 0.75 * 200 * 3
    # (the SITL goes on sending for a moment after the autopilot's last step, until the launcher stops it: 0.25 s)
    assert ap["sitl"]["rx_by_type"]["ATTITUDE"] >= sitl_sent - 0.25 * 200
    assert ap["sitl"]["tx_by_type"]["SERVO_OUTPUT_RAW"] == 300
    sent = gcs["tx_by_type"]["SET_ATTITUDE_TARGET"]
    assert sent > 50 and ap["gcs"]["rx_by_type"]["SET_ATTITUDE_TARGET"] >= sent - 2
    assert not ap["sitl"]["rejected"] and not ap["gcs"]["rejected"]
    start = (out / "autopilot.log").read_text()
    assert "busy-wait (never sleeps)" in start
    if (os.cpu_count() or 1) >= 2:
        assert re.search(r"[1-9]\d* helper thread\(s\) moved off CPU 1", start), start


def test_busy_wait_refuses_lockstep_and_throttled_fifo():
    r = run_cli("tools.launch", "--lockstep", "--busy-wait", timeout=60)
    assert r.returncode == 2 and "--busy-wait is for real time" in r.stderr
    r = run_cli("autopilot", "--lockstep", "--busy-wait", timeout=60)
    assert r.returncode == 2 and "--busy-wait is for real time" in r.stderr
    if rt_throttling():
        for module in ("tools.launch", "autopilot"):
            r = run_cli(module, "--busy-wait", "--rt-priority", "10", timeout=60)
            assert r.returncode == 2 and "throttling" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def _gcs_messages(sock) -> list:
    """Every common-dialect message received (a datagram may carry several; messages of other dialects, such as
    CURRENT_MODE, are skipped)."""
    sock.setblocking(False)
    parser = mav(255, 190)
    parser.robust_parsing = True
    out = []
    while True:
        try:
            data = sock.recv(4096)
        except BlockingIOError:
            return out
        out += [m for m in parser.parse_buffer(bytearray(data)) or () if m.get_type() != "BAD_DATA"]


def test_sitl_killed_puts_autopilot_in_failsafe_and_restart_recovers(tmp_path):
    (sitl_port,) = free_ports(1)
    gcs = udp()  # the test is the ground station
    rate = 100.0
    sitl_args = ["--listen", f"127.0.0.1:{sitl_port}", "--quiet"]
    sitl = Proc("sitl", sitl_args, tmp_path / "sitl1.log")
    ap = Proc(
        "autopilot",
        [
            "--sitl",
            f"127.0.0.1:{sitl_port}",
            "--gcs",
            f"127.0.0.1:{gcs.getsockname()[1]}",
            "--rate",
            str(rate),
            "--telemetry-rate",
            "0",
            "--stats-json",
            str(tmp_path / "ap.json"),
        ],
        tmp_path / "ap.log",
    )
    try:
        assert sitl.wait_for("listening on") and ap.wait_for("autopilot: clsac")
        time.sleep(1.5)
        sitl.kill()  # SIGKILL: the SITL vanishes mid-flight
        assert ap.wait_for("failsafe entered", timeout=10)
        time.sleep(0.5)
        sitl = Proc("sitl", sitl_args, tmp_path / "sitl2.log")
        assert ap.wait_for("attitude back", timeout=15)
        time.sleep(0.5)
    finally:
        code = ap.stop()
        sitl.stop()
    assert code == 0, ap.output()
    stats = load_json(tmp_path / "ap.json")
    ev = stats["events"]
    assert ev["failsafes"] == 1 and ev["recoveries"] == 1
    (age_ms,) = ev["failsafe_entries_ms"]
    period_ms = 1000.0 / rate
    assert 100.0 < age_ms <= 100.0 + 3 * period_ms, f"failsafe {age_ms:.1f} ms after the last attitude"
    msgs = _gcs_messages(gcs)
    statuses = [m.system_status for m in msgs if m.get_msgId() == mavlink.MAVLINK_MSG_ID_HEARTBEAT]
    texts = [m.text for m in msgs if m.get_msgId() == mavlink.MAVLINK_MSG_ID_STATUSTEXT]
    assert mavlink.MAV_STATE_CRITICAL in statuses
    assert statuses[-2] == mavlink.MAV_STATE_ACTIVE and statuses[-1] == mavlink.MAV_STATE_POWEROFF
    assert any("FAILSAFE" in t for t in texts) and any("attitude back" in t for t in texts)
    gcs.close()


def test_autopilot_killed_sitl_goes_neutral_and_recovers(tmp_path):
    sitl_port, ap_port = free_ports(2)
    # the SITL is pinned to the autopilot's address: the restarted autopilot comes back on the same one
    ap_args = ["--sitl", f"127.0.0.1:{sitl_port}", "--sitl-bind", f"127.0.0.1:{ap_port}", "--gcs", "127.0.0.1:9"]
    ap_args += ["--telemetry-rate", "0"]
    sitl = Proc(
        "sitl",
        ["--listen", f"127.0.0.1:{sitl_port}", "--servo-timeout", "0.3", "--stats-json", str(tmp_path / "sitl.json")],
        tmp_path / "sitl.log",
    )
    ap = Proc("autopilot", ap_args, tmp_path / "ap1.log")
    try:
        assert sitl.wait_for("listening on") and ap.wait_for("autopilot: clsac")
        time.sleep(1.0)
        ap.kill()
        assert sitl.wait_for("rudder neutral", timeout=10)
        ap = Proc("autopilot", ap_args, tmp_path / "ap2.log")
        assert sitl.wait_for("autopilot back", timeout=15)
    finally:
        ap.stop()
        code = sitl.stop()
    assert code == 0
    ev = load_json(tmp_path / "sitl.json")["events"]
    assert ev["servo_timeouts"] == 1 and ev["servo_applied"] > 50


def test_launch_ctrl_c_stops_everything_cleanly(tmp_path):
    """Started as a script's background job would be (SIGINT inherited *ignored*, which Python keeps), the launcher
    still takes SIGINT, and so do its processes: each ends by its own stop handler (exit 0) with its files, none is
    killed after the grace (-9)."""
    import signal
    import subprocess

    from tests._mavlink_procs import PY

    out = tmp_path / "int"
    p = subprocess.Popen(
        [PY, "-m", "tools.launch", "--duration", "60", "--out", str(out), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),  # as a background job inherits it
    )
    t0 = time.monotonic()
    while not (out / "flight.tlog").exists() or (out / "flight.tlog").stat().st_size < 20000:
        assert time.monotonic() - t0 < 60 and p.poll() is None
        time.sleep(0.1)
    p.send_signal(signal.SIGINT)
    stdout, stderr = p.communicate(timeout=60)
    assert p.returncode == 130, stdout + stderr
    assert "interrupted" in stderr
    s = load_json(out / "summary.json")
    assert not s["ok"] and s["exit_code"] == 130
    assert s["exit_codes"] == {"sitl": 0, "gcs": 0, "autopilot": 0}, s["exit_codes"]  # stopped, not killed
    assert s["runs"] and s["runs"][0]["steps"] > 50  # the autopilot still wrote what flew
    recs = list(read_tlog(str(out / "flight.tlog")))
    assert len(recs) > 100 and (out / "flight.tlog").stat().st_size == sum(8 + len(r) for _t, r in recs)


def test_launch_failing_child_is_named(tmp_path):
    blocker = udp()  # the SITL's port is taken: the SITL cannot start
    port = blocker.getsockname()[1]
    r = run_cli(
        "tools.launch",
        "--lockstep",
        "--duration",
        "5",
        "--base-port",
        str(port),
        "--out",
        str(tmp_path / "f"),
        "--quiet",
        timeout=120,
    )
    blocker.close()
    assert r.returncode == 1
    assert "sitl failed" in r.stderr and "exit code 98" in r.stderr
    s = load_json(tmp_path / "f" / "summary.json")
    assert s["failed"] == "sitl" and not s["ok"]
