"""What the viewer gets (issue 30, "The viewer"): both processes' data together, the plots on the flight, and a live
stream thin enough for a software-rendered viewer while the recording keeps every row.

Checked on real recordings:

* a real lockstep flight's spools (the three processes started as the launcher starts them, each spooling its rows)
  recorded into a ``.rrd``: in file order the autopilot's and the SITL's chunks run side by side in sim time (neither
  more than ``2 x INTERLEAVE_S`` ahead of the other), where the order before sent the whole autopilot first; read back,
  both files hold the same recording (every entity, row and value on both timelines, states, texts, poses);
* the flight layout in a launched flight's ``flight.rrd`` and the experiment's in ``paper.rrd``, read back from the
  file: every time-series and state view's visible time range is the flight's (absolute, ns-exact);
* a live stream to a real endpoint (``rerun --save``, what a viewer receives) next to the flight's recording: the
  endpoint got the first row of each ``1 / live_rate`` s of sim time of each table of lines (counted independently from
  the recorded rows) and every marker, state and event line, while ``flight.rrd`` kept every row.
"""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from autopilot.shared import telemetry as tm
from autopilot.shared.telemetry.rerun_sink import INTERLEAVE_S
from autopilot.shared.telemetry.thinning import thinned
from autopilot.telemetry import layout as L
from sitl import telemetry as S
from tests._mavlink_procs import free_ports
from tools.view import rrd_files as rrd
from tools.view import views

ROOT = Path(__file__).resolve().parents[3]


def _source(entity: str) -> str:
    return entity.split("/")[1]


def lead_s(order: list[tuple[str, float, float]]) -> float:
    """How far one process's data runs ahead of the other's in file order: at each chunk, the latest sim time
    received of one process minus the other's (the flight's first instant before the other's first chunk)."""
    start = min(t0 for _, t0, _ in order)
    latest = {"autopilot": start, "sitl": start}
    lead = 0.0
    for entity, _, t1 in order:
        src = _source(entity)
        if src in latest:
            latest[src] = max(latest[src], t1)
            lead = max(lead, abs(latest["autopilot"] - latest["sitl"]))
    return lead


def _same_recording(a: Path, b: Path) -> None:
    """Both files hold the same recording: entities, rows and values on both timelines, states, texts, poses."""
    assert rrd.recordings(a) == rrd.recordings(b)
    assert rrd.entity_paths(a) == rrd.entity_paths(b)
    for timeline in ("sim_time", "wall_time"):
        la, lb = rrd.load(a, timeline=timeline), rrd.load(b, timeline=timeline)
        assert sorted(la) == sorted(lb) and la
        for ep in la:
            assert la[ep].names == lb[ep].names, ep
            assert np.array_equal(la[ep].t_ns, lb[ep].t_ns), (ep, timeline)
            assert np.array_equal(la[ep].values, lb[ep].values, equal_nan=True), (ep, timeline)
    assert rrd.load_states(a) == rrd.load_states(b)
    assert rrd.load_texts(a) == rrd.load_texts(b)
    pa, pb = rrd.load_poses(a), rrd.load_poses(b)
    assert sorted(pa) == sorted(pb) and pa
    for ep in pa:
        assert np.array_equal(pa[ep][0], pb[ep][0]) and np.array_equal(pa[ep][1], pb[ep][1]), ep


@pytest.fixture(scope="module")
def spooled_flight(tmp_path_factory) -> dict:
    """A real 20 s lockstep flight whose autopilot and SITL spool their rows (the launcher's command lines)."""
    from tools.flight.command_lines import child_argvs
    from tools.flight.config import FlightConfig

    out = tmp_path_factory.mktemp("spooled")
    cfg = FlightConfig(lockstep=True, duration=20.0, out=out, quiet=True, png=False, signing=False)
    rid = tm.new_recording_id()
    spools = tm.spool_paths(out)
    spools["autopilot"].parent.mkdir(parents=True, exist_ok=True)
    telemetry = {n: ["--recording-id", rid, "--telemetry-spool", str(spools[n])] for n in ("autopilot", "sitl")}
    sitl_port, gcs_port, *ap_ports = free_ports(4)
    argvs = child_argvs(cfg, out, sitl_port, gcs_port, telemetry, None, tuple(ap_ports))
    logs = {n: open(out / f"{n}.log", "w") for n in argvs}  # noqa: SIM115 - closed below
    procs = {n: subprocess.Popen(a, cwd=ROOT, stdout=logs[n], stderr=subprocess.STDOUT) for n, a in argvs.items()}
    try:
        codes = {n: procs[n].wait(180) for n in ("autopilot", "sitl", "gcs")}
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
        for f in logs.values():
            f.close()
    assert codes == {"autopilot": 0, "sitl": 0, "gcs": 0}, [(out / f"{n}.log").read_text()[-500:] for n in codes]
    return {"out": out, "rid": rid, "spools": [spools["autopilot"], spools["sitl"]]}


def test_a_recorded_flight_holds_both_processes_side_by_side_in_sim_time(spooled_flight):
    out, spools = spooled_flight["out"], spooled_flight["spools"]
    before = tm.record_spools(spools, out / "before.rrd", interleave_s=None)  # each spool whole, in turn
    after = tm.record_spools(spools, out / "after.rrd")
    assert after["recording_id"] == before["recording_id"] == spooled_flight["rid"]
    order_before, order_after = rrd.chunk_order(out / "before.rrd"), rrd.chunk_order(out / "after.rrd")
    # before: every autopilot chunk first, the SITL's truth after all of them (the whole flight ahead)
    assert [_source(e) for e, _, _ in order_before] == sorted(_source(e) for e, _, _ in order_before)
    assert lead_s(order_before) > 19.0
    # after: the two interleave, neither more than two slices ahead of the other; a slice spans one INTERLEAVE_S
    assert lead_s(order_after) <= 2 * INTERLEAVE_S
    assert max(t1 - t0 for _, t0, t1 in order_after) < INTERLEAVE_S
    assert {_source(e) for e, _, _ in order_after[:40]} == {"autopilot", "sitl"}
    _same_recording(out / "before.rrd", out / "after.rrd")
    assert after["span"] == before["span"]
    t0, t1 = after["span"]
    data = rrd.load(out / "after.rrd")
    assert t0 == min(s.t[0] for s in data.values()) and t1 == max(s.t[-1] for s in data.values())
    assert len(data[L.AP_ROLL].t) == 2000 and t1 == pytest.approx(20.0, abs=0.02)  # 100 Hz for 20 s


def test_the_merged_flight_keeps_the_recorded_order(spooled_flight):
    """``rerun rrd merge`` (the launcher's join, with the layout) orders chunks by their ids, which are minted in
    the order they are sent: the interleaving survives it."""
    out = spooled_flight["out"]
    tm.record_spools(spooled_flight["spools"], out / "part.rrd")
    merged = rrd.merge(out / "merged.rrd", [out / "part.rrd"])
    assert rrd.has_blueprint(merged)
    assert lead_s(rrd.chunk_order(merged)) <= 2 * INTERLEAVE_S
    _same_recording(out / "part.rrd", merged)


def test_a_launched_flight_is_interleaved_and_its_plots_show_the_flight(tmp_path):
    """``python -m tools.launch --lockstep --start-time 5 --duration 12``: flight.rrd's chunks interleave, and every
    time-series and state view shows 5..17 s of sim time (read back from the file's blueprint)."""
    r = subprocess.run(
        [sys.executable, "-m", "tools.launch", "--lockstep", "--start-time", "5", "--duration", "12"]
        + ["--out", str(tmp_path), "--quiet", "--no-png"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    path = tmp_path / "flight.rrd"
    assert lead_s(rrd.chunk_order(path)) <= 2 * INTERLEAVE_S
    ranges = rrd.visible_time_ranges(path)
    plots = set(rrd.blueprint_components(path, "ViewBlueprint:display_name")) - {"Events"}
    plots -= {name for name in plots if name.startswith("Attitude")}  # the 3D view shows the cursor's instant
    assert plots and set(ranges) == plots  # every time series and the state lanes
    for window in ranges.values():
        assert window == [
            {"timeline": "sim_time", "start": ("Absolute", 5_000_000_000), "end": ("Absolute", 17 * 10**9)}
        ]
    data = rrd.load(path)
    assert min(s.t[0] for s in data.values()) >= 5.0 and max(s.t[-1] for s in data.values()) <= 17.0 + 1e-9
    assert rrd.y_ranges(path) == {views.RUDDER_PLOT: [-37.5, 37.5]}  # the KH2013A's 30 deg rudder, 25 % margin


@pytest.mark.parametrize(("limit_deg", "half"), [(17.5, 21.875), (30.0, 37.5), (None, 37.5), (float("nan"), 37.5)])
def test_the_rudder_plot_has_a_fixed_range_and_u_raw_its_own_plot(tmp_path, monkeypatch, limit_deg, half):
    """A diverging law's unlimited command u_raw reaches -100,000 deg: autoscaled, the Rudder plot drew the real
    rudder as a flat line.  Its y range is now fixed at 1.25 times the surface's limit (17.5 deg on the c172x: +-21.875;
    none given, or not a number: the KH2013A's 30 deg), read back from the layout's file, the only fixed range; u_raw
    is also in the Details tab's plot of the command, autoscaled.  The cached layout is one per limit."""
    from tools.view import layout_cache

    views.flight_blueprint((0.0, 30.0), rudder_limit_deg=limit_deg).save(tm.APPLICATION_ID, str(tmp_path / "f.rbl"))
    assert rrd.y_ranges(tmp_path / "f.rbl") == {views.RUDDER_PLOT: [-half, half]}
    assert views.RUDDER_RAW_PLOT in rrd.blueprint_components(tmp_path / "f.rbl", "ViewBlueprint:display_name")
    monkeypatch.setenv("CLSAC_CACHE_DIR", str(tmp_path / "cache"))
    cached = layout_cache.flight_blueprint_file(span=(0.0, 30.0), rudder_limit_deg=limit_deg)
    other = layout_cache.flight_blueprint_file(span=(0.0, 30.0), rudder_limit_deg=45.0)
    assert cached != other and rrd.y_ranges(other) == {views.RUDDER_PLOT: [-56.25, 56.25]}
    assert rrd.y_ranges(cached) == {views.RUDDER_PLOT: [-half, half]}


def test_the_experiment_plots_show_its_runs(tmp_path):
    from tools.experiment.scenario import PAPER, run_inprocess, run_of
    from tools.view.recording import log_experiment

    scenario = dataclasses.replace(PAPER, duration_s=4.0)
    results = [run_inprocess(scenario, run_of(name)) for name in ("sac", "clsac")]
    path = log_experiment(results, tmp_path / "paper.rrd")
    t = results[0].series["t"]
    ranges = rrd.visible_time_ranges(path)
    assert len(ranges) == 7 + 4 * 2  # the overlays (roll, reference, error, rudder, Ke, Kx, Ku) and 4 per run
    start, end = round(float(t[0]) * 1e9), round(float(t[-1]) * 1e9)
    assert end > start
    for window in ranges.values():
        assert window == [{"timeline": "sim_time", "start": ("Absolute", start), "end": ("Absolute", end)}]


# ---------------------------------------------------------------------------------------- the live stream
def test_thinning_keeps_the_first_row_of_each_bucket():
    sim = np.arange(0, 250) * 0.01  # 100 Hz for 2.5 s
    keep, last = thinned(sim[:120], 25.0, -math.inf)
    keep2, _ = thinned(sim[120:], 25.0, last)
    kept = sim[np.concatenate([keep, keep2])]
    # 25 Hz: buckets of 40 ms; the first row of each is the 100 Hz row at a multiple of 40 ms
    assert np.allclose(kept, np.arange(0, 2.5, 0.04))
    slow = np.arange(0, 30) * 0.1  # a 10 Hz table (the link counters): every row
    assert thinned(slow, 25.0, -math.inf)[0].all()


def _default_sigint() -> None:
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


class _Endpoint:
    """``rerun --save FILE`` on a free port: a gRPC endpoint that writes what a viewer would receive."""

    def __init__(self, path: Path):
        import socket

        from autopilot.shared.telemetry.viewer import rerun_cli_path

        with socket.socket() as s:  # a free TCP port (free_ports hands out UDP ones)
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        self.path = path
        self.proc = subprocess.Popen(
            [rerun_cli_path(), "--bind", "127.0.0.1", "--port", str(self.port), "--save", str(path)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            # close() stops it with SIGINT, which it would inherit ignored from a suite run as a script's background
            # job (CI): it then waited out close()'s 30 s and was killed (33 s of the parallel phase's last module)
            preexec_fn=_default_sigint,
        )
        self.url = tm.viewer_url(self.port)
        deadline = time.monotonic() + 30
        while not tm.viewer_reachable(self.url):
            assert time.monotonic() < deadline and self.proc.poll() is None, "rerun --save did not listen"
            time.sleep(0.1)

    def close(self) -> None:
        import signal

        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def test_a_live_viewer_gets_a_thinned_stream_and_the_recording_every_row(tmp_path):
    """A lockstep flight streamed to a live endpoint at ``--live-rate 25``: the endpoint holds, of each table of
    lines, the first row of each 40 ms of sim time of the recorded rows (100 Hz autopilot: every fourth; the 10 Hz
    link counters: all), and every state and event; flight.rrd holds every row."""
    endpoint = _Endpoint(tmp_path / "live.rrd")
    try:
        r = subprocess.run(
            [sys.executable, "-m", "tools.launch", "--lockstep", "--duration", "6", "--out", str(tmp_path / "f")]
            + ["--quiet", "--no-png", "--connect", endpoint.url, "--live-rate", "25"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=180,
        )
        time.sleep(1.0)  # what the endpoint received is in its file
    finally:
        endpoint.close()
    assert r.returncode == 0, r.stderr[-2000:]
    full, live = rrd.load(tmp_path / "f" / "flight.rrd"), rrd.load(tmp_path / "live.rrd")
    assert len(full[L.AP_ROLL].t) == 600 and len(full[S.SITL_ROLL].t) == 600  # every row: 100 Hz for 6 s
    assert sorted(live) == sorted(full)
    for ep, sig in full.items():
        bucket = np.floor(sig.t_ns / 40_000_000)  # 25 Hz: the first row of each 40 ms
        first = np.concatenate([[True], bucket[1:] != bucket[:-1]])
        if ep.startswith(("/autopilot/param_set", "/autopilot/fault_marks", "/sitl/fault_marks")):
            first[:] = True  # markers: every one
        assert np.array_equal(live[ep].t_ns, sig.t_ns[first]), ep
        assert np.array_equal(live[ep].values, sig.values[first], equal_nan=True), ep
    assert len(live[L.AP_ROLL].t) == 150
    assert rrd.load_states(tmp_path / "live.rrd") == rrd.load_states(tmp_path / "f" / "flight.rrd")
    assert rrd.load_texts(tmp_path / "live.rrd") == rrd.load_texts(tmp_path / "f" / "flight.rrd")
    # the live layout: plots over the last 20 s before the cursor (--live-window), the lanes over the flight
    ranges = rrd.visible_time_ranges(tmp_path / "live.rrd")
    assert ranges["Roll tracking [deg]"][0]["start"] == ("CursorRelative", -20 * 10**9)
    assert ranges["Mode and failsafe"][0]["end"] == ("Absolute", 6 * 10**9)
