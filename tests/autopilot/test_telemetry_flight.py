"""Telemetry across real processes: one recording from two writers, signals, SIGKILL, no viewer by default.

The writers are this file run as a script (``python tests/autopilot/test_telemetry_flight.py ROLE ...``): each
flies the same deterministic closed loop (ClSac + Aircraft at 400 Hz, roll measured through float32
as over MAVLink) paced on the wall clock, and logs its side of it, as the autopilot and the SITL will:
the autopilot its controller row, link counters, mode and failsafe; the SITL the truth state.  Like the real
processes, a writer stops on SIGINT/SIGTERM through ``autopilot.shared.process.install_stop_handlers`` and
closes its telemetry on the way out; the viewer layout comes from the merge (``tools.view.views``), not the writers.
"""

from __future__ import annotations

import math
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from autopilot.shared import telemetry as tm
from autopilot.telemetry import layout as L
from autopilot.telemetry.hooks import autopilot_tables
from sitl import telemetry as S
from tools.view import rrd_files as rrd
from tools.view import views
from tools.view.views import flight_blueprint

pytestmark = pytest.mark.e2e  # real processes over loopback UDP

HERE = Path(__file__).resolve()
RATE = 400.0
PWM_PER_RAD = 500.0 / math.radians(30.0)


# ------------------------------------------------------------------------------------------ the writer
def _writer(role: str, recording_id: str, path: str, duration_s: float, connect: str | None) -> int:
    from autopilot.clsac import ClSac
    from autopilot.config import ClSacConfig
    from autopilot.shared.process import EXIT_INTERRUPTED, install_stop_handlers
    from sitl.aircraft import Aircraft, AircraftConfig
    from tools.flight import profiles

    ctrl = ClSac(ClSacConfig(control_rate_hz=RATE))
    ac = Aircraft(AircraftConfig(physics_rate_hz=2000.0))
    tel = tm.Telemetry(role, recording_id, path, connect_url=connect)
    stop = []
    install_stop_handlers(lambda: stop.append(True))
    print(f"pid={os.getpid()} tables", flush=True)
    n = 0
    try:
        with tel:
            if role == "autopilot":
                ap, links, mode, failsafe = autopilot_tables(tel)
                mode.set(0.0, time.time(), "CLSAC")
                failsafe.set(0.0, time.time(), "OK")
            else:
                st = tel.table(S.SITL_TABLE)
            steps = int(round(duration_s * RATE)) if duration_s > 0 else 10**9
            t0 = time.perf_counter()
            for k in range(steps):
                if stop:
                    return EXIT_INTERRUPTED
                deadline = t0 + k / RATE
                now = time.perf_counter()
                if deadline > now:
                    time.sleep(deadline - now)
                t = k / RATE
                w = time.time()
                x = ac.x
                phi_meas = float(np.float32(x[3]))  # MAVLink ATTITUDE carries float32
                p_meas = float(np.float32(x[1]))
                u = ctrl.step(phi_meas, profiles.square(t, math.radians(10.0), 2.0))
                pwm = float(round(1500.0 + PWM_PER_RAD * u))
                if role == "autopilot":
                    ap.append(t, w, ctrl.telemetry() + (p_meas, pwm, 1.0 / RATE, 2e-5, 1e-5, 0))
                    if k % 40 == 0:
                        links["sitl"].append(t, w, (k, k, 0))
                        links["gcs"].append(t, w, (k // 40, k // 4, 1))
                    if k == int(RATE * 0.5):
                        failsafe.set(t, w, "NO_ATTITUDE", "no ATTITUDE for 0.2 s")
                    if k == int(RATE * 0.75):
                        failsafe.set(t, w, "OK")
                else:
                    st.append(t, w, tuple(x.tolist()) + (u, pwm))
                n += 1
                ac.advance(u, 5)
                if n % 40 == 0:
                    print(f"appended={n}", flush=True)
    finally:
        print(f"done appended={n} sent={dict(tel.rows_sent)} errors={tel.errors}", flush=True)
    return 0


# ------------------------------------------------------------------------------------------ helpers
def _start(role: str, rid: str, path: Path, duration_s: float, connect: str | None = None, env=None):
    cmd = [sys.executable, str(HERE), role, rid, str(path), str(duration_s)]
    if connect:
        cmd.append(connect)
    e = dict(os.environ)
    e.pop("DISPLAY", None)
    e.pop("WAYLAND_DISPLAY", None)
    e.update(env or {})
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=e)


def _wait_appended(proc, at_least: int, timeout_s: float = 20.0) -> int:
    """Read the writer's progress lines until it reports ``at_least`` appended rows; returns the last count."""
    deadline = time.time() + timeout_s
    last = 0
    while time.time() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        if line.startswith("appended="):
            last = int(line.split("=")[1])
            if last >= at_least:
                return last
    raise AssertionError(f"writer did not reach {at_least} rows (last {last}); stderr: {proc.stderr.read()[-2000:]}")


def _finish(proc, timeout_s: float = 30.0) -> tuple[int, str, str]:
    out, err = proc.communicate(timeout=timeout_s)
    return proc.returncode, out, err


def _sent(out: str) -> dict:
    line = [ln for ln in out.splitlines() if ln.startswith("done")][-1]
    return eval(line.split("sent=")[1].split(" errors=")[0])  # noqa: S307 - our own dict literal


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """Two real writer processes, one recording id, merged as the launcher will do."""
    d = tmp_path_factory.mktemp("flight")
    rid = tm.new_recording_id()
    parts = tm.part_paths(d)
    duration = 2.0
    t0 = time.perf_counter()
    procs = {role: _start(role, rid, parts[role], duration) for role in ("autopilot", "sitl")}
    results = {role: _finish(p) for role, p in procs.items()}
    elapsed = time.perf_counter() - t0
    for role, (rc, _, err) in results.items():
        assert rc == 0, f"{role} writer failed: {err[-2000:]}"
    merged = tm.merge_recordings(list(parts.values()), d / "flight.rrd", blueprint=flight_blueprint())
    return {
        "dir": d,
        "rid": rid,
        "parts": parts,
        "path": merged,
        "duration": duration,
        "elapsed": elapsed,
        "sent": {role: _sent(out) for role, (_, out, _) in results.items()},
    }


# ------------------------------------------------------------------------------------------ tests
def test_two_processes_write_one_recording(flight):
    recs = rrd.recordings(flight["path"])
    assert recs == [(tm.APPLICATION_ID, flight["rid"])]
    paths = set(rrd.entity_paths(flight["path"]))
    for p in (
        *L.AUTOPILOT.paths,
        *S.SITL_TABLE.paths,
        f"{L.AP_LINK}/sitl",
        f"{L.AP_LINK}/gcs",
        L.AP_MODE,
        L.AP_FAILSAFE,
        L.AP_EVENTS,
    ):
        assert p in paths, f"{p} missing from the merged recording"
    # Both processes ran at the same time: the flight did not take two flights' time.
    assert flight["elapsed"] < 2 * flight["duration"] + 8


def test_sample_counts_match_duration_and_rates(flight):
    n = int(round(flight["duration"] * RATE))
    data = rrd.load(flight["path"])
    assert flight["sent"]["autopilot"]["autopilot"] == n
    assert flight["sent"]["sitl"]["sitl"] == n
    for p in (*L.AUTOPILOT.paths, *S.SITL_TABLE.paths):
        assert len(data[p].t) == n, p
    for link in ("sitl", "gcs"):
        assert len(data[f"{L.AP_LINK}/{link}"].t) == n // 40
    # sim_time is exactly k / rate, to the nanosecond, on both sides
    expected = np.rint(np.arange(n) / RATE * 1e9).astype(np.int64)
    np.testing.assert_array_equal(data[L.AP_ROLL].t_ns, expected)
    np.testing.assert_array_equal(data[S.SITL_ROLL].t_ns, expected)
    # wall time: monotonic, spanning about the flight's duration (paced on the clock)
    rd = rrd.load(flight["path"], timeline=tm.WALL_TIME)[L.AP_ROLL]
    assert np.all(np.diff(rd.t_ns) >= 0)
    assert flight["duration"] * 0.9 < (rd.t[-1] - rd.t[0]) < flight["duration"] + 2.0
    # series shapes and names as in the layout
    assert data[L.AP_ROLL].values.shape == (n, 4)
    assert data[L.AP_ROLL].names[3] == "roll phi (measured)"
    assert data[L.AP_GAIN_KE].values.shape == (n, 3)


def test_truth_and_autopilot_roll_agree_to_float32(flight):
    data = rrd.load(flight["path"])
    truth, seen = data[S.SITL_ROLL], data[L.AP_ROLL]
    common, i_truth, i_seen = np.intersect1d(truth.t_ns, seen.t_ns, return_indices=True)
    assert len(common) == len(truth.t_ns)
    # The recording shows degrees: the rows (rad) times 180/pi.  Back in rad, the measured roll is the float32 of
    # the true one (to the last bits of the two conversions).
    phi_truth = np.radians(truth.values[i_truth, 0])
    phi_meas = np.radians(seen.values[i_seen, 3])  # "y": the roll the controller used
    assert np.max(np.abs(phi_truth)) > math.radians(5)  # the aircraft did roll
    np.testing.assert_allclose(phi_meas, phi_truth.astype(np.float32).astype(np.float64), rtol=1e-14, atol=0)
    assert np.max(np.abs(phi_meas - phi_truth)) <= np.max(np.abs(phi_truth)) * 2.0**-23
    # rudder: what the autopilot commanded is what the SITL applied
    u_ap = data[L.AP_RUDDER].values[i_seen, 0]
    u_sitl = data[S.SITL_RUDDER].values[i_truth, 1]
    np.testing.assert_array_equal(u_ap, u_sitl)


def test_gains_are_sum_of_parts(flight):
    """Each logged gain is its proportional part plus its integral part of the same step: K = K_p + K_I."""
    data = rrd.load(flight["path"])
    for p in (L.AP_GAIN_KE, L.AP_GAIN_KX, L.AP_GAIN_KU):
        v = data[p].values
        np.testing.assert_allclose(v[:, 0] + v[:, 1], v[:, 2], rtol=1e-12, atol=1e-15)
    assert np.any(data[L.AP_GAIN_KE].values[:, 1] != 0)  # adaptation happened


def test_mode_and_failsafe_are_state_changes(flight):
    states = rrd.load_states(flight["path"])
    assert [s for _, s in states[L.AP_MODE]] == ["CLSAC"]
    assert [s for _, s in states[L.AP_FAILSAFE]] == ["OK", "NO_ATTITUDE", "OK"]
    assert states[L.AP_FAILSAFE][1][0] == pytest.approx(0.5)
    lines = [txt for _, txt in rrd.load_text(flight["path"], L.AP_EVENTS)]
    assert "failsafe: OK -> NO_ATTITUDE (no ATTITUDE for 0.2 s)" in lines


def test_blueprint_present_once_and_verified(flight):
    path = flight["path"]
    assert rrd.has_blueprint(path)
    assert len(rrd.blueprint_components(path, "ViewportBlueprint:root_container")) == 1  # one layout, not two
    names = rrd.blueprint_components(path, "ViewBlueprint:display_name")
    for expected in (
        "Roll tracking [deg]",
        "Attitude: aircraft (true roll) and reference ym (ghost)",
        "Error e = ym - ya [deg]",
        views.RUDDER_PLOT,
        "Gain Ke (error), PARAM_SET marks",
        "Loop timing [s]",
        "Link counters",
        "Mode and failsafe",
    ):
        assert expected in names
    # the side panels start collapsed (the Flight tab then fits 1600x1000); the time bar stays
    collapsed = 2  # rerun.blueprint.PanelState.Collapsed
    assert rrd.blueprint_components(path, "PanelBlueprint:state") == [collapsed, collapsed]  # blueprint, selection
    assert rrd.blueprint_components(path, "TimePanelBlueprint:state") == [collapsed]
    assert rrd.blueprint_components(path, "TimePanelBlueprint:timeline") == ["sim_time"]
    links = rrd.blueprint_components(path, "TimeAxis:link")
    assert links and all(v == 2 for v in links)  # LinkToGlobal on every plot
    ok, msg = tm.verify_rrd(path)  # footers required: the merged flight.rrd has one
    assert ok, msg
    for part in flight["parts"].values():  # parts are complete streams, written without footer
        ok, msg = tm.verify_rrd(part, check_footers=False)
        assert ok, msg


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_leaves_a_valid_file(tmp_path, sig):
    path = tmp_path / "ap.rrd"
    proc = _start("autopilot", tm.new_recording_id(), path, 0)
    _wait_appended(proc, 400)  # ~1 s of flight
    t_sig = time.perf_counter()
    proc.send_signal(sig)
    rc, out, err = _finish(proc)
    assert time.perf_counter() - t_sig < 5.0
    assert rc != 0  # interrupted, not a normal end
    sent = _sent(out)["autopilot"]
    assert sent >= 400
    ok, msg = tm.verify_rrd(path, check_footers=False)  # a complete, valid stream (parts have no footer)
    assert ok, msg
    data = rrd.load(path)
    assert len(data[L.AP_ROLL].t) == sent  # every appended row made it to the file
    merged = tm.merge_recordings([path], tmp_path / "flight.rrd")  # what the launcher then does
    ok, msg = tm.verify_rrd(merged)
    assert ok, msg


def test_sigkill_loses_at_most_one_second(tmp_path):
    rid = tm.new_recording_id()
    killed, clean = tmp_path / "autopilot.rrd", tmp_path / "sitl.rrd"
    other = _start("sitl", rid, clean, 1.0)
    proc = _start("autopilot", rid, killed, 0)
    last = _wait_appended(proc, 800)  # ~2 s of flight
    proc.kill()
    proc.wait(10)
    proc.stdout.close()
    proc.stderr.close()
    assert _finish(other)[0] == 0
    data = rrd.load(killed)  # no footer, still readable
    got = len(data[L.AP_ROLL].t)
    # `last` rows had been appended when we read the progress line, so at the kill at least that many
    assert last - got <= int(RATE * 1.0), f"lost {last - got} rows (> 1 s at {RATE:g} Hz)"
    assert got > 0
    print(f"SIGKILL after {last}+ rows appended: {got} in the file (loss <= {max(0, last - got)} rows)")
    np.testing.assert_array_equal(data[L.AP_ROLL].t_ns, np.rint(np.arange(got) / RATE * 1e9).astype(np.int64))
    # the launcher can still merge it with the other process's part into one valid recording
    merged = tm.merge_recordings([killed, clean], tmp_path / "flight.rrd")
    assert rrd.recordings(merged) == [(tm.APPLICATION_ID, rid)]
    m = rrd.load(merged)
    assert len(m[L.AP_ROLL].t) == got and len(m[S.SITL_ROLL].t) == int(RATE)
    ok, msg = tm.verify_rrd(merged)
    assert ok, msg


def test_concatenation_is_the_merged_recording_without_index(flight, tmp_path):
    """Long flights are concatenated (constant memory) instead of merged: the same recording, row for row."""
    parts = list(flight["parts"].values())
    joined = tm.concatenate_recordings(
        parts, tmp_path / "flight.rrd", blueprint=flight_blueprint(), recording_id=flight["rid"]
    )
    assert rrd.recordings(joined) == [(tm.APPLICATION_ID, flight["rid"])]
    a, b = rrd.load(joined), rrd.load(flight["path"])
    assert sorted(a) == sorted(b) and len(a) >= len(L.AUTOPILOT.paths) + len(S.SITL_TABLE.paths)
    for k in a:
        np.testing.assert_array_equal(a[k].t_ns, b[k].t_ns, err_msg=k)
        np.testing.assert_array_equal(a[k].values, b[k].values, err_msg=k)
    assert len(rrd.blueprint_components(joined, "ViewportBlueprint:root_container")) == 1
    assert tm.verify_rrd(joined, check_footers=False)[0]
    assert not tm.verify_rrd(joined)[0]  # no footer: said, not hidden (summary.json rrd_indexed: false)
    # each input's stream header was written once: the size is the parts' messages plus one header and the layout
    assert joined.stat().st_size < sum(p.stat().st_size for p in flight["parts"].values()) + 200_000


def test_concatenation_drops_a_torn_tail_and_refuses_foreign_files(flight, tmp_path):
    part = flight["parts"]["autopilot"]
    torn = tmp_path / "torn.rrd"
    torn.write_bytes(part.read_bytes()[:-100])  # a SIGKILL in the middle of the last message
    joined = tm.concatenate_recordings([torn, flight["parts"]["sitl"]], tmp_path / "joined.rrd")
    data, whole = rrd.load(joined), rrd.load(part)
    n = len(data[L.AP_ROLL].t)
    assert 0 < n <= len(whole[L.AP_ROLL].t)  # every complete message kept, the torn one dropped
    np.testing.assert_array_equal(data[L.AP_ROLL].t_ns, whole[L.AP_ROLL].t_ns[:n])
    assert len(data[S.SITL_ROLL].t) == len(rrd.load(flight["parts"]["sitl"])[S.SITL_ROLL].t)
    text = tmp_path / "notes.rrd"
    text.write_text("not a recording at all\n")
    with pytest.raises(tm.RrdError, match="not an RRD stream"):
        tm.concatenate_recordings([part, text], tmp_path / "x.rrd")
    odd = tmp_path / "odd.rrd"
    raw = bytearray(part.read_bytes())
    raw[4] ^= 0xFF  # another rerun version in the stream header
    odd.write_bytes(bytes(raw))
    with pytest.raises(tm.RrdError, match="stream header"):
        tm.concatenate_recordings([part, odd], tmp_path / "y.rrd")
    with pytest.raises(tm.RrdError, match="no recording to join"):
        tm.concatenate_recordings([tmp_path / "missing.rrd"], tmp_path / "z.rrd")
    assert not (tmp_path / "x.rrd").exists() and not (tmp_path / "y.rrd").exists()  # nothing half-written


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_live_stream_from_two_processes_is_one_recording(tmp_path):
    """--connect: both processes stream to one gRPC server (a viewer, or here `rerun --save`, its
    headless stand-in) and it sees ONE recording holding both, plus the blueprint the launcher sends."""
    port = _free_port()
    live = tmp_path / "live.rrd"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    server = subprocess.Popen(
        [tm.rerun_cli_path(), "--port", str(port), "--save", str(live)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
    )
    try:
        url = tm.viewer_url(port)
        deadline = time.time() + 15
        while not tm.viewer_reachable(url) and time.time() < deadline:
            time.sleep(0.05)
        assert tm.viewer_reachable(url), "rerun --save did not start listening"
        rid = tm.new_recording_id()
        assert tm.send_blueprint(url, flight_blueprint(), rid)  # what the launcher does for --viewer/--connect
        procs = [_start(role, rid, tmp_path / f"{role}.rrd", 1.0, connect=url) for role in ("autopilot", "sitl")]
        for p in procs:
            rc, _, err = _finish(p)
            assert rc == 0, err[-2000:]
    finally:
        server.send_signal(signal.SIGINT)
        try:
            server.wait(10)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait(5)
    assert rrd.recordings(live) == [(tm.APPLICATION_ID, rid)]
    data = rrd.load(live)
    assert len(data[L.AP_ROLL].t) == int(RATE) and len(data[S.SITL_ROLL].t) == int(RATE)
    assert rrd.has_blueprint(live)
    assert "Roll tracking [deg]" in rrd.blueprint_components(live, "ViewBlueprint:display_name")


def _port_free(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
            return True
        except OSError:
            return False


def test_no_viewer_is_contacted_without_flags(tmp_path):
    """No DISPLAY, no flags: a writer never connects to the default viewer port nor spawns a viewer."""
    import psutil

    port = tm.DEFAULT_VIEWER_PORT
    if not _port_free(port):
        pytest.skip(f"port {port} is in use (a viewer is running?)")
    listener = socket.socket()
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    listener.bind(("127.0.0.1", port))
    listener.listen(8)
    listener.settimeout(0.05)
    try:
        t0 = time.perf_counter()
        proc = _start("autopilot", tm.new_recording_id(), tmp_path / "ap.rrd", 0.5)
        children = set()
        connections = 0
        while proc.poll() is None:
            try:
                conn, _ = listener.accept()
                conn.close()
                connections += 1
            except (TimeoutError, socket.timeout):
                pass
            try:
                children |= {c.name() for c in psutil.Process(proc.pid).children(recursive=True)}
            except psutil.Error:
                pass
        rc, _, err = _finish(proc)
        elapsed = time.perf_counter() - t0
    finally:
        listener.close()
    assert rc == 0, err[-2000:]
    assert connections == 0
    assert not any("rerun" in c for c in children)
    assert elapsed < 15.0  # ~0.5 s flight + interpreter start; nothing waits for a viewer
    ok, msg = tm.verify_rrd(tmp_path / "ap.rrd", check_footers=False)
    assert ok, msg


def test_connect_url_without_viewer_does_not_hang(tmp_path):
    """--connect to a port where nothing listens: a warning, the file is still written, no 5 s gRPC waits."""
    port = 9  # discard: nothing listens there on a test machine
    with socket.socket() as s:
        if s.connect_ex(("127.0.0.1", port)) == 0:
            pytest.skip("something listens on port 9")
    t0 = time.perf_counter()
    with tm.Telemetry("autopilot", None, tmp_path / "ap.rrd", connect_url=tm.viewer_url(port)) as tel:
        ap = tel.series("/test/x", ("x",))
        for k in range(100):
            ap.append(k / 100, time.time(), (float(k),))
    assert time.perf_counter() - t0 < 3.0
    assert tel.connect_url is None  # dropped after the probe
    assert len(rrd.load(tmp_path / "ap.rrd")["/test/x"].t) == 100
    # --connect alone, nobody there: the writer turns itself off instead of buffering in memory
    only_viewer = tm.Telemetry("sitl", None, None, connect_url=tm.viewer_url(port))
    assert not only_viewer.enabled
    assert isinstance(only_viewer.table(S.SITL_TABLE), tm.NullTable)
    only_viewer.close()


def test_spawn_viewer_on_headless_machine_returns_at_once(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_SOCKET", raising=False)
    if not sys.platform.startswith("linux"):
        pytest.skip("display detection is Linux-specific")
    port = 9  # nothing listens: would spawn if there were a display
    t0 = time.perf_counter()
    assert tm.spawn_viewer(port) is None
    assert time.perf_counter() - t0 < 2.0


if __name__ == "__main__":
    role, rid, path, duration = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4])
    sys.exit(_writer(role, rid, path, duration, sys.argv[5] if len(sys.argv) > 5 else None))
