"""Telemetry library in one process: layouts, time columns, writer behaviour, experiments (paper.rrd)."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from autopilot import telemetry as tm
from autopilot.clsac import TELEMETRY_FIELDS, ClSac
from autopilot.config import ClSacConfig
from autopilot.telemetry import layout as L
from sitl.model import STATE_NAMES
from tools import rrd
from tools.scenario import PAPER, PAPER_RUNS, run_inprocess


def test_layouts_cover_every_field_of_both_processes():
    assert L.AUTOPILOT_FIELDS[: len(TELEMETRY_FIELDS)] == TELEMETRY_FIELDS
    assert L.SITL_FIELDS[: len(STATE_NAMES)] == STATE_NAMES
    for table in (L.AUTOPILOT, L.SITL_TABLE, L.link_layout("gcs")):
        plotted = {f for p in table.plots for f in p.fields}
        assert plotted == set(table.fields), table.name
        paths = table.paths
        assert len(set(paths)) == len(paths)
    # the signals that overlay in the roll plot share one entity
    roll = next(p for p in L.AUTOPILOT.plots if p.path == L.AP_ROLL)
    assert roll.fields == ("um", "ym", "ym_ol", "y")
    with pytest.raises(ValueError):
        L.link_layout("a/b")
    with pytest.raises(ValueError):
        L.TableLayout("bad", ("a",), (L.Plot("/x", ("b",), ("b",), (L.GREY,)),))


def test_sim_time_is_rounded_not_truncated():
    # rerun's own float path computes (t * 1e9).astype(int): 0.0075 s -> 7499999 ns
    col = tm.writer.sim_time_column(np.array([0.0075, 1234 / 1000, 1234 * 0.001, 3 * 0.1]))
    ns = col.as_arrow_array().cast("int64").to_numpy()
    np.testing.assert_array_equal(ns, [7_500_000, 1_234_000_000, 1_234_000_000, 300_000_000])


def test_disabled_telemetry_costs_nothing_and_writes_nothing(tmp_path):
    tel = tm.Telemetry("autopilot", handle_signals=False)
    assert not tel.enabled
    ap = tel.table(tm.AUTOPILOT)
    assert isinstance(ap, tm.NullTable)
    ap.append(0.0, 0.0, (0.0,) * len(tm.AUTOPILOT_FIELDS))
    tel.close()
    assert list(tmp_path.iterdir()) == []


def test_rows_round_trip_exactly(tmp_path):
    path = tmp_path / "t.rrd"
    ctrl = ClSac(ClSacConfig(control_rate_hz=400.0))
    rows = []
    t_wall0 = time.time()
    with tm.Telemetry("autopilot", tm.new_recording_id(), path, handle_signals=False, send_blueprint=False) as tel:
        ap = tel.table(tm.AUTOPILOT)
        for k in range(1000):
            u = ctrl.step(math.sin(k / 100), 0.1)
            row = ctrl.telemetry() + (0.5 * k, 1500.0 + u, 0.0025, 1e-5 * k, -1e-6, k // 100)
            rows.append(row)
            if k % 2:
                ap.append(k / 400, t_wall0 + k / 400, row)
            else:
                ap.push((k / 400, t_wall0 + k / 400, row))  # the frame-free form
    assert tel.errors == 0
    assert tel.rows_sent["autopilot"] == 1000
    data = rrd.load(path)
    expect = np.array(rows, dtype=np.float64)
    for plot in tm.AUTOPILOT.plots:
        idx = [tm.AUTOPILOT_FIELDS.index(f) for f in plot.fields]
        np.testing.assert_array_equal(data[plot.path].values, expect[:, idx], err_msg=plot.path)
        assert data[plot.path].names == plot.labels
    wall = rrd.load(path, timeline=tm.WALL_TIME)[L.AP_ROLL]
    np.testing.assert_allclose(wall.t, t_wall0 + np.arange(1000) / 400, atol=1e-6)
    assert not rrd.has_blueprint(path)


def test_bad_rows_are_dropped_not_fatal(tmp_path):
    path = tmp_path / "t.rrd"
    with tm.Telemetry("sitl", None, path, handle_signals=False) as tel:
        st = tel.table(tm.SITL_TABLE)
        st.append(0.0, 0.0, (1.0, 2.0))  # wrong length: this batch is dropped, with a warning
        tel.flush()
        for k in range(10):
            st.append(k * 0.01, time.time(), (0.0,) * len(tm.SITL_FIELDS))
    assert tel.errors == 1 and "dropped 1 rows" in tel.last_error
    assert len(rrd.load(path)[L.SITL_ROLL].t) == 10


def test_state_channel_ignores_repeats_and_logs_text(tmp_path):
    path = tmp_path / "t.rrd"
    with tm.Telemetry("autopilot", None, path, handle_signals=False, send_blueprint=False) as tel:
        _, _, mode, failsafe = tel.autopilot_tables(links=())
        assert mode.set(0.0, 0.0, "WAITING")
        assert not mode.set(0.1, 0.0, "WAITING")
        assert mode.set(1.0, 0.0, "AUTO")
        assert failsafe.set(2.0, 0.0, "LINK_LOST", "no ATTITUDE for 0.5 s")
    states = rrd.load_states(path)
    assert states[L.AP_MODE] == [(0.0, "WAITING"), (1.0, "AUTO")]
    assert states[L.AP_FAILSAFE] == [(2.0, "LINK_LOST")]
    text = rrd.load_text(path, L.AP_EVENTS)
    assert text == [(0.0, "mode: - -> WAITING"), (1.0, "mode: WAITING -> AUTO"),
                    (2.0, "failsafe: - -> LINK_LOST (no ATTITUDE for 0.5 s)")]


def test_close_is_idempotent_and_fast(tmp_path):
    tel = tm.Telemetry("autopilot", None, tmp_path / "t.rrd", handle_signals=False)
    s = tel.series("/x", ("a", "b"))
    s.append(0.0, 0.0, (1.0, 2.0))
    t0 = time.perf_counter()
    tel.close()
    tel.close()
    assert time.perf_counter() - t0 < 2.0
    assert tel.closed
    ok, msg = tm.verify_rrd(tmp_path / "t.rrd", check_footers=False)
    assert ok, msg
    assert not tm.verify_rrd(tmp_path / "t.rrd")[0]  # no footer by default (flat memory)...


def test_finalize_writes_the_footer(tmp_path):
    with tm.Telemetry("sitl", None, tmp_path / "t.rrd", handle_signals=False, finalize=True) as tel:
        st = tel.table(tm.SITL_TABLE)
        for k in range(50):
            st.append(k * 0.01, time.time(), (0.0,) * len(tm.SITL_FIELDS))
    ok, msg = tm.verify_rrd(tmp_path / "t.rrd")  # ...but a process writing its final file can ask for one
    assert ok, msg
    assert len(rrd.load(tmp_path / "t.rrd")[L.SITL_ROLL].t) == 50


@pytest.fixture(scope="module")
def paper_results():
    return [run_inprocess(PAPER, run) for run in PAPER_RUNS]


def test_log_experiment_writes_every_run_side_by_side(tmp_path, paper_results):
    path = tm.log_experiment(paper_results, tmp_path / "paper.rrd")
    assert path == tmp_path / "paper.rrd"
    (app, _), = rrd.recordings(path)
    assert app == L.EXPERIMENT_APPLICATION_ID
    data = rrd.load(path)
    n = PAPER.steps
    first = paper_results[0].series
    np.testing.assert_array_equal(data[L.RUN_COMMAND].values[:, 0], first["um"])
    np.testing.assert_array_equal(data[L.RUN_REFERENCE_OL].values[:, 0], first["ym_ol"])
    for r in paper_results:
        s = r.series
        base = f"{L.RUNS}/{r.name}"
        for what, key in (("roll", "phi"), ("reference", "ym"), ("error", "e"), ("rudder", "u"),
                          ("gains/ke", "ke"), ("gains/kx", "kx"), ("gains/ku", "ku")):
            sig = data[f"{base}/{what}"]
            assert len(sig.t) == n, f"{base}/{what}"
            np.testing.assert_array_equal(sig.values[:, 0], s[key])
        np.testing.assert_array_equal(data[f"{base}/roll"].t_ns, np.rint(s["t"] * 1e9).astype(np.int64))
        assert data[f"{base}/gains/parts"].values.shape == (n, 6)
        assert data[f"{base}/state"].values.shape == (n, 4)
        assert f"Lv={r.lv:g}" in data[f"{base}/roll"].names[0]
    # SAC and CL-SAC really differ (otherwise an overlay proves nothing)
    assert not np.array_equal(data[f"{L.RUNS}/sac/roll"].values, data[f"{L.RUNS}/clsac/roll"].values)
    assert rrd.has_blueprint(path)
    views = rrd.blueprint_components(path, "ViewBlueprint:display_name")
    assert "Roll: command, open-loop reference and every run [rad]" in views
    assert {f"{r.name}: roll [rad]" for r in paper_results} <= set(views)  # one tab per run too
    queries = rrd.blueprint_components(path, "ViewContents:query")
    for r in paper_results:  # the overlay plot lists every run
        assert f"{L.RUNS}/{r.name}/roll" in queries
    assert f"{L.RUNS}/metrics" in rrd.entity_paths(path)
    ok, msg = tm.verify_rrd(path)
    assert ok, msg


def test_log_experiment_rejects_bad_names(tmp_path, paper_results):
    with pytest.raises(ValueError):
        tm.log_experiment([], tmp_path / "x.rrd")
    with pytest.raises(ValueError):
        tm.log_experiment([paper_results[0], paper_results[0]], tmp_path / "x.rrd")


def test_merge_without_parts_is_an_error(tmp_path):
    with pytest.raises(tm.RrdError):
        tm.merge_recordings([tmp_path / "missing.rrd"], tmp_path / "out.rrd")


def test_rrd_cli_summary_and_verify(tmp_path, capsys):
    path = tmp_path / "t.rrd"
    with tm.Telemetry("sitl", None, path, handle_signals=False, write_footer=True) as tel:
        st = tel.table(tm.SITL_TABLE)
        for k in range(5):
            st.append(k * 0.1, time.time(), (0.0,) * len(tm.SITL_FIELDS))
    assert rrd.main(["summary", str(path)]) == 0
    out = capsys.readouterr().out
    assert "/sitl/roll" in out and "5 rows" in out
    assert rrd.main(["verify", str(path)]) == 0
    assert rrd.main(["verify", str(tmp_path / "missing.rrd")]) == 1


def test_loop_hooks_turn_step_records_into_telemetry(tmp_path):
    """AutopilotHook / SitlHook read the loops' StepRecord / SitlRecord attributes (duck typing)."""
    from types import SimpleNamespace as NS

    from sitl.aircraft import Aircraft

    class FakeLink:
        def __init__(self):
            self.n = 0

        def counters(self):
            self.n += 1
            return {"rx_packets": 10 * self.n, "tx_packets": 5 * self.n, "rejected": {"crc": 1, "stale": self.n}}

    ap_obj = NS(timing=NS(missed=0), sitl=FakeLink(), gcs=FakeLink())
    ctrl = ClSac(ClSacConfig(control_rate_hz=400.0))
    ac = Aircraft()
    rid = tm.new_recording_id()
    with tm.Telemetry("autopilot", rid, tmp_path / "ap.rrd", handle_signals=False) as tel_ap, \
            tm.Telemetry("sitl", rid, tmp_path / "sitl.rrd", handle_signals=False) as tel_sitl:
        hook = tm.AutopilotHook(tel_ap, control_rate_hz=400.0)
        shook = tm.SitlHook(tel_sitl)
        for k in range(400):
            t = k / 400
            fs = "no attitude" if 100 <= k < 120 else None
            if fs:
                ctrl.hold(0.0)
            else:
                ctrl.step(float(np.float32(ac.phi)), 0.1)
            if k == 100:
                hook.event(2, "FAILSAFE no attitude 101.0 ms: rudder neutral")
            ap_obj.timing.missed = k // 100
            hook(NS(step=k + 1, t_sim=t, p=ac.p, pwm=1500 + k % 3, period=0.0025, compute=2e-5, lateness=1e-5,
                    missed=False, failsafe=fs, ctrl=ctrl, ap=ap_obj))
            shook(NS(t_sim=t, x=ac.x.copy(), u=ctrl.u, pwm=1500, frame=k, sitl=None))
            ac.advance(ctrl.u, 2)
    merged = tm.merge_recordings([tmp_path / "ap.rrd", tmp_path / "sitl.rrd"], tmp_path / "flight.rrd")
    data = rrd.load(merged)
    assert len(data[L.AP_ROLL].t) == 400 and len(data[L.SITL_ROLL].t) == 400
    assert len(data[f"{L.AP_LINK}/sitl"].t) == 10  # 10 Hz over 1 s of 400 Hz steps
    np.testing.assert_array_equal(data[f"{L.AP_LINK}/gcs"].values[0], [10.0, 5.0, 2.0])
    assert data[L.AP_TIMING_MISSED].values[-1, 0] == 3.0
    states = rrd.load_states(merged)
    assert [s for _, s in states[L.AP_FAILSAFE]] == ["OK", "NO_ATTITUDE", "OK"]
    assert [s for _, s in states[L.AP_MODE]] == ["ADAPTIVE", "HOLD", "ADAPTIVE"]
    text = [x for _, x in rrd.load_text(merged, L.AP_EVENTS)]
    assert "FAILSAFE no attitude 101.0 ms: rudder neutral" in text
    i = np.searchsorted(data[L.SITL_ROLL].t_ns, data[L.AP_ROLL].t_ns)
    stepped = np.r_[0:100, 120:400]  # while held (failsafe) the controller does not take a measurement
    np.testing.assert_array_equal(data[L.AP_ROLL].values[stepped, 3],
                                  data[L.SITL_ROLL].values[i[stepped], 0].astype(np.float32).astype(np.float64))


def test_cli_flags_build_the_writer(tmp_path):
    import argparse

    p = argparse.ArgumentParser()
    tm.add_arguments(p)
    args = p.parse_args(["--rrd", str(tmp_path / "x.rrd"), "--recording-id", "abc"])
    with tm.from_args(args, "sitl", handle_signals=False) as tel:
        assert tel.enabled and tel.recording_id == "abc" and tel.connect_url is None
    off = tm.from_args(p.parse_args([]), "sitl", handle_signals=False)
    assert not off.enabled
    off.close()
