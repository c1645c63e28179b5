"""Telemetry in one process: the shared writer, both processes' layouts and hooks, experiments (paper.rrd).

Also the dependency rule as far as telemetry goes: the shared primitives import nothing of the project outside
``autopilot.shared``, the SITL's telemetry never loads the control law, and nothing loads rerun unless asked to.
"""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from types import SimpleNamespace as NS

import numpy as np
import pytest

from autopilot.clsac import TELEMETRY_FIELDS, ClSac
from autopilot.config import ClSacConfig
from autopilot.shared import telemetry as tm
from autopilot.shared.telemetry.columns import sim_time_column
from autopilot.step import Failsafe
from autopilot.telemetry import layout as L
from autopilot.telemetry.hooks import AutopilotHook, autopilot_tables
from autopilot.vehicle import Mode
from sitl import telemetry as S
from sitl.model import STATE_NAMES
from tools import rrd as rrd_cli
from tools.experiment.scenario import PAPER
from tools.view import recording, views
from tools.view import rrd_files as rrd

ROOT = Path(__file__).resolve().parents[2]


def test_layouts_cover_every_field_of_both_processes():
    assert L.AUTOPILOT_FIELDS[: len(TELEMETRY_FIELDS)] == TELEMETRY_FIELDS
    assert S.SITL_FIELDS[: len(STATE_NAMES)] == STATE_NAMES
    for table in (L.AUTOPILOT, S.SITL_TABLE, L.link_layout("gcs")):
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
        tm.TableLayout("bad", ("a",), (tm.Plot("/x", ("b",), ("b",), (tm.layout.GREY,)),))


def test_state_colours_are_exactly_the_states_emitted():
    """Mode: the vehicle's own modes (autopilot.vehicle.Mode); failsafe: OK for Failsafe.NONE, else the member's name
    (NO_ATTITUDE included)."""
    assert set(L.FAILSAFE_COLORS) == {"OK", *(f.name for f in Failsafe if f is not Failsafe.NONE)}
    assert set(L.FAILSAFE_COLORS) == {L.failsafe_state(f) for f in Failsafe}
    assert L.failsafe_state(Failsafe.NONE) == "OK" and L.failsafe_state(Failsafe.NO_ATTITUDE) == "NO_ATTITUDE"
    modes = {"MANUAL", "SAC", "CLSAC", "BASELINE", "MRAC", "CRM_MRAC", "L1", "INDI", "LAW", "FAILSAFE"}
    assert set(L.MODE_COLORS) == modes == {m.name for m in Mode}
    assert L.MODE_WARN == {"FAILSAFE"}
    assert L.FAILSAFE_WARN == {"NO_ATTITUDE", "NO_SETPOINT", "LAW_ERROR"}


def test_roll_quaternions_put_the_right_wing_down_for_positive_roll():
    """q = (sin(phi/2), 0, 0, cos(phi/2)): its rotation matrix (Hamilton, x y z w) takes the body's right wing
    (0, 1, 0) to (0, cos phi, sin phi), i.e. down (+z in FRD) for phi > 0, and the nose stays on x."""
    from autopilot.shared.telemetry.columns import roll_quaternions

    phi = np.radians([-30.0, 0.0, 10.0, 45.0])
    for (x, y, z, w), p in zip(roll_quaternions(phi), phi):
        rot = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
        np.testing.assert_allclose(rot @ [0, 1, 0], [0, math.cos(p), math.sin(p)], atol=1e-15)
        np.testing.assert_allclose(rot @ [1, 0, 0], [1, 0, 0], atol=1e-15)
    with pytest.raises(ValueError, match="unknown field"):
        tm.TableLayout("t", ("a",), (), poses=(tm.layout.Pose("/p", "phi", "x", (0, 0, 0, 255)),))
    with pytest.raises(ValueError, match="scale"):
        tm.Plot("/x", ("a",), ("a",), (tm.layout.GREY,), scale=0.0)


def test_sim_time_is_rounded_not_truncated():
    # rerun's own float path computes (t * 1e9).astype(int): 0.0075 s -> 7499999 ns
    col = sim_time_column(np.array([0.0075, 1234 / 1000, 1234 * 0.001, 3 * 0.1]))
    ns = col.as_arrow_array().cast("int64").to_numpy()
    np.testing.assert_array_equal(ns, [7_500_000, 1_234_000_000, 1_234_000_000, 300_000_000])


def test_disabled_telemetry_costs_nothing_and_writes_nothing(tmp_path):
    tel = tm.Telemetry("autopilot")
    assert not tel.enabled
    ap = tel.table(L.AUTOPILOT)
    assert isinstance(ap, tm.NullTable)
    ap.append(0.0, 0.0, (0.0,) * len(L.AUTOPILOT_FIELDS))
    tel.close()
    assert list(tmp_path.iterdir()) == []


def test_rows_round_trip_exactly(tmp_path):
    path = tmp_path / "t.rrd"
    ctrl = ClSac(ClSacConfig(control_rate_hz=400.0))
    rows = []
    t_wall0 = time.time()
    with tm.Telemetry("autopilot", tm.new_recording_id(), path) as tel:
        ap = tel.table(L.AUTOPILOT)
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
    # angles (rad rows) are shown in degrees, the roll rate in deg/s; everything else exactly as appended
    in_degrees = {L.AP_ROLL, L.AP_ROLL_RATE, L.AP_ERROR, L.AP_AUGMENTED, L.AP_RUDDER}
    for plot in L.AUTOPILOT.plots:
        idx = [L.AUTOPILOT_FIELDS.index(f) for f in plot.fields]
        if plot.path in in_degrees:
            np.testing.assert_allclose(data[plot.path].values, np.degrees(expect[:, idx]), rtol=1e-15, atol=0)
        else:
            np.testing.assert_array_equal(data[plot.path].values, expect[:, idx], err_msg=plot.path)
        assert data[plot.path].names == plot.labels
    wall = rrd.load(path, timeline=tm.WALL_TIME)[L.AP_ROLL]
    np.testing.assert_allclose(wall.t, t_wall0 + np.arange(1000) / 400, atol=1e-6)
    assert not rrd.has_blueprint(path)  # a process never sends a layout: the launcher adds one


def test_bad_rows_are_dropped_not_fatal(tmp_path):
    path = tmp_path / "t.rrd"
    with tm.Telemetry("sitl", None, path) as tel:
        st = tel.table(S.SITL_TABLE)
        st.append(0.0, 0.0, (1.0, 2.0))  # wrong length: this batch is dropped, with a warning
        tel.flush()
        for k in range(10):
            st.append(k * 0.01, time.time(), (0.0,) * len(S.SITL_FIELDS))
    assert tel.errors == 1 and "dropped 1 rows" in tel.last_error
    assert len(rrd.load(path)[S.SITL_ROLL].t) == 10


def test_the_true_roll_is_shown_wrapped_as_the_measured_roll_is(tmp_path):
    """After a full roll the SITL's true roll (the plant's state, unwrapped: 368 to 500 deg) was drawn beside the
    measured roll, which ATTITUDE reports wrapped to (-180, 180] deg.  The viewer now gets the true roll wrapped the
    same way: each value is ``autopilot.shared.numerics.wrap_pi`` of the row's (the SITL's ATTITUDE encoding), in
    degrees; the row itself (the series files, the 3D pose) keeps the unwrapped state.  The spooled layout keeps the
    flag."""
    from autopilot.shared.numerics import wrap_pi
    from autopilot.shared.telemetry.spool import layout_from_data, layout_to_data

    phi = [0.0, 3.0, 3.3, 2 * math.pi + 0.1, 8.7, -3.3, math.pi, -math.pi, -7 * math.pi, float("nan")]
    path = tmp_path / "t.rrd"
    with tm.Telemetry("sitl", None, path) as tel:
        st = tel.table(S.SITL_TABLE)
        for k, v in enumerate(phi):
            st.append(k * 0.01, time.time(), tuple(v if f == "phi" else 0.0 for f in S.SITL_FIELDS))
    got = rrd.load(path)[S.SITL_ROLL].values[:, 0]
    expect = [math.degrees(wrap_pi(v)) if math.isfinite(v) else math.nan for v in phi]
    np.testing.assert_allclose(got, expect, rtol=1e-12, atol=1e-12)
    assert np.nanmax(np.abs(got)) <= 180.0 and got[6] == got[7] == 180.0  # -pi and pi: both +180, as ATTITUDE
    assert layout_from_data(layout_to_data(S.SITL_TABLE)) == S.SITL_TABLE
    assert [p.wrap for p in S.SITL_TABLE.plots if p.path == S.SITL_ROLL] == [True]


def test_state_channel_ignores_repeats_and_logs_text(tmp_path):
    path = tmp_path / "t.rrd"
    with tm.Telemetry("autopilot", None, path) as tel:
        _, _, mode, failsafe = autopilot_tables(tel, links=())
        assert mode.set(0.0, 0.0, "CLSAC")
        assert not mode.set(0.1, 0.0, "CLSAC")
        assert mode.set(1.0, 0.0, "FAILSAFE")
        assert failsafe.set(2.0, 0.0, "NO_ATTITUDE", "no ATTITUDE for 0.5 s")
    states = rrd.load_states(path)
    assert states[L.AP_MODE] == [(0.0, "CLSAC"), (1.0, "FAILSAFE")]
    assert states[L.AP_FAILSAFE] == [(2.0, "NO_ATTITUDE")]
    text = rrd.load_text(path, L.AP_EVENTS)
    assert text == [
        (0.0, "mode: - -> CLSAC"),
        (1.0, "mode: CLSAC -> FAILSAFE"),
        (2.0, "failsafe: - -> NO_ATTITUDE (no ATTITUDE for 0.5 s)"),
    ]


def test_close_is_idempotent_and_fast(tmp_path):
    tel = tm.Telemetry("autopilot", None, tmp_path / "t.rrd")
    s = tel.series("/x", ("a", "b"))
    s.append(0.0, 0.0, (1.0, 2.0))
    t0 = time.perf_counter()
    tel.close()
    tel.close()
    assert time.perf_counter() - t0 < 60.0  # a hang (nothing waits for a viewer); no speed asserted here
    assert tel.closed
    ok, msg = tm.verify_rrd(tmp_path / "t.rrd", check_footers=False)
    assert ok, msg
    assert not tm.verify_rrd(tmp_path / "t.rrd")[0]  # no footer by default (flat memory)...


def test_finalize_writes_the_footer(tmp_path):
    with tm.Telemetry("sitl", None, tmp_path / "t.rrd", finalize=True) as tel:
        st = tel.table(S.SITL_TABLE)
        for k in range(50):
            st.append(k * 0.01, time.time(), (0.0,) * len(S.SITL_FIELDS))
    ok, msg = tm.verify_rrd(tmp_path / "t.rrd")  # ...but a process writing its final file can ask for one
    assert ok, msg
    assert len(rrd.load(tmp_path / "t.rrd")[S.SITL_ROLL].t) == 50


@pytest.fixture(scope="module")
def paper_results(paper_runs):
    return list(paper_runs.values())


def test_log_experiment_writes_every_run_side_by_side(tmp_path, paper_results):
    path = recording.log_experiment(paper_results, tmp_path / "paper.rrd")
    assert path == tmp_path / "paper.rrd"
    ((app, _),) = rrd.recordings(path)
    assert app == recording.EXPERIMENT_APPLICATION_ID
    data = rrd.load(path)
    n = PAPER.steps
    first = paper_results[0].series
    # angles are shown in degrees (the series in rad times 180/pi); gains as they are
    deg = dict(rtol=1e-15, atol=0)
    np.testing.assert_allclose(data[views.RUN_COMMAND].values[:, 0], np.degrees(first["um"]), **deg)
    np.testing.assert_allclose(data[views.RUN_REFERENCE_OL].values[:, 0], np.degrees(first["ym_ol"]), **deg)
    for r in paper_results:
        s = r.series
        base = f"{views.RUNS}/{r.name}"
        for what, key in (
            ("roll", "phi"),
            ("reference", "ym"),
            ("error", "e"),
            ("rudder", "u"),
            ("gains/ke", "ke"),
            ("gains/kx", "kx"),
            ("gains/ku", "ku"),
        ):
            sig = data[f"{base}/{what}"]
            assert len(sig.t) == n, f"{base}/{what}"
            if key in ("phi", "ym", "e", "u"):
                np.testing.assert_allclose(sig.values[:, 0], np.degrees(s[key]), **deg)
            else:
                np.testing.assert_array_equal(sig.values[:, 0], s[key])
        np.testing.assert_array_equal(data[f"{base}/roll"].t_ns, np.rint(s["t"] * 1e9).astype(np.int64))
        assert data[f"{base}/gains/parts"].values.shape == (n, 6)
        assert data[f"{base}/state"].values.shape == (n, 4)
        assert f"Lv={r.lv:g}" in data[f"{base}/roll"].names[0]
    # SAC and CL-SAC really differ (otherwise an overlay proves nothing)
    assert not np.array_equal(data[views.run_path("sac", "roll")].values, data[views.run_path("clsac", "roll")].values)
    assert rrd.has_blueprint(path)
    names = rrd.blueprint_components(path, "ViewBlueprint:display_name")
    assert "Roll: command, open-loop reference and every run [deg]" in names
    assert {f"{r.name}: roll [deg]" for r in paper_results} <= set(names)  # one tab per run too
    queries = rrd.blueprint_components(path, "ViewContents:query")
    for r in paper_results:  # the overlay plot lists every run
        assert views.run_path(r.name, "roll") in queries
    assert views.RUN_METRICS in rrd.entity_paths(path)
    ok, msg = tm.verify_rrd(path)
    assert ok, msg


def test_log_experiment_rejects_bad_names(tmp_path, paper_results):
    with pytest.raises(ValueError):
        recording.log_experiment([], tmp_path / "x.rrd")
    with pytest.raises(ValueError):
        recording.log_experiment([paper_results[0], paper_results[0]], tmp_path / "x.rrd")


def test_merge_without_parts_is_an_error(tmp_path):
    with pytest.raises(tm.RrdError):
        tm.merge_recordings([tmp_path / "missing.rrd"], tmp_path / "out.rrd")


def test_rrd_cli_summary_and_verify(tmp_path, capsys):
    path = tmp_path / "t.rrd"
    with tm.Telemetry("sitl", None, path, write_footer=True) as tel:
        st = tel.table(S.SITL_TABLE)
        for k in range(5):
            st.append(k * 0.1, time.time(), (0.0,) * len(S.SITL_FIELDS))
    assert rrd_cli.main(["summary", str(path)]) == 0
    out = capsys.readouterr().out
    assert "/sitl/roll" in out and "5 rows" in out
    assert rrd_cli.main(["verify", str(path)]) == 0
    assert rrd_cli.main(["verify", str(tmp_path / "missing.rrd")]) == 1
    # merge adds the flight layout, once: not again over a file that carries one, never with --no-blueprint
    assert rrd_cli.main(["merge", str(tmp_path / "m.rrd"), str(path)]) == 0
    assert rrd_cli.main(["merge", str(tmp_path / "m2.rrd"), str(tmp_path / "m.rrd")]) == 0
    assert len(rrd.blueprint_components(tmp_path / "m2.rrd", "ViewportBlueprint:root_container")) == 1
    assert rrd_cli.main(["merge", "--no-blueprint", str(tmp_path / "bare.rrd"), str(path)]) == 0
    assert not rrd.has_blueprint(tmp_path / "bare.rrd")
    # --concatenate (long flights): the same rows and one layout, no footer (the input's footer is not copied)
    cat = tmp_path / "cat.rrd"
    assert rrd_cli.main(["merge", "--concatenate", str(cat), str(path)]) == 0
    assert len(rrd.load(cat)["/sitl/roll"].t) == 5
    assert len(rrd.blueprint_components(cat, "ViewportBlueprint:root_container")) == 1
    assert rrd_cli.main(["verify", "--no-footer-check", str(cat)]) == 0 and rrd_cli.main(["verify", str(cat)]) == 1


def test_loop_hooks_turn_step_records_into_telemetry(tmp_path):
    """AutopilotHook / SitlHook turn the loops' StepRecord / SitlRecord into rows and state changes."""
    from collections import Counter

    from autopilot.loop import StepRecord
    from autopilot.shared.pwm import PwmMap
    from autopilot.step import ControlStep, ProfileSetpoints
    from sitl.aircraft import Aircraft

    links = {name: NS(rx_packets=0, tx_packets=0, rejected=Counter()) for name in L.LINKS}
    ap_obj = NS(timing=NS(missed=0), vehicle=NS(mode=Mode.CLSAC), **links)
    step = ControlStep(ClSacConfig(control_rate_hz=400.0), PwmMap(), ProfileSetpoints(lambda _t: 0.1))
    ac = Aircraft()
    rid = tm.new_recording_id()
    with (
        tm.Telemetry("autopilot", rid, tmp_path / "ap.rrd") as tel_ap,
        tm.Telemetry("sitl", rid, tmp_path / "sitl.rrd") as tel_sitl,
    ):
        hook = AutopilotHook(tel_ap, control_rate_hz=400.0)
        shook = S.SitlHook(tel_sitl)
        for k in range(400):
            t = k / 400
            phi = float(np.float32(ac.phi))
            # the vehicle's mode as Vehicle.housekeeping sets it: FAILSAFE while the attitude is lost
            ap_obj.vehicle.mode = Mode.FAILSAFE if 100 <= k < 120 else Mode.CLSAC
            if 100 <= k < 120:
                res = step.hold(t, phi)  # no attitude: rudder neutral, adaptation frozen
            else:
                res = step(t, phi, wings_level=200 <= k < 220)  # no setpoint: wings level, still adapting
            if k == 100:
                hook.event(2, "FAILSAFE no attitude 101.0 ms: rudder neutral")
            ap_obj.timing.missed = k // 100
            for j, link in enumerate(links.values()):
                link.rx_packets, link.tx_packets = 10 * k + j, 5 * k
                link.rejected["crc"] = k // 50
            hook(
                StepRecord(
                    result=res,
                    frame=k,
                    wall=time.perf_counter(),
                    p=ac.p,
                    r=ac.r,
                    period=0.0025,
                    lateness=1e-5,
                    compute=2e-5,
                    latency=None,
                    missed=False,
                    ctrl=step.law,
                    ap=ap_obj,
                )
            )
            shook(NS(t_sim=t, x=ac.x.copy(), u=res.u, pwm=res.pwm, frame=k, sitl=None))
            if k == 300:
                shook.event(4, "servo timeout: rudder neutral")
            ac.advance(res.u, 2)
    merged = tm.merge_recordings(
        [tmp_path / "ap.rrd", tmp_path / "sitl.rrd"], tmp_path / "flight.rrd", blueprint=views.flight_blueprint()
    )
    data = rrd.load(merged)
    assert len(data[L.AP_ROLL].t) == 400 and len(data[S.SITL_ROLL].t) == 400
    assert len(data[f"{L.AP_LINK}/sitl"].t) == 10  # 10 Hz over 1 s of 400 Hz steps
    np.testing.assert_array_equal(data[f"{L.AP_LINK}/gcs"].values[0], [391.0, 195.0, 0.0])  # step 40 (k = 39)
    np.testing.assert_array_equal(data[f"{L.AP_LINK}/sitl"].values[-1], [3990.0, 1995.0, 7.0])
    assert data[L.AP_TIMING_MISSED].values[-1, 0] == 3.0
    np.testing.assert_array_equal(data[L.AP_RUDDER_PWM].values[:, 0], data[S.SITL_SERVO_PWM].values[:, 0])
    assert np.all(data[L.AP_RUDDER_PWM].values[100:120, 0] == 1500)  # neutral while the attitude is lost
    states = rrd.load_states(merged)
    assert [s for _, s in states[L.AP_FAILSAFE]] == ["OK", "NO_ATTITUDE", "OK", "NO_SETPOINT", "OK"]
    assert [t for t, _ in states[L.AP_FAILSAFE]] == pytest.approx([0.0, 0.25, 0.3, 0.5, 0.55])
    assert [s for _, s in states[L.AP_MODE]] == ["CLSAC", "FAILSAFE", "CLSAC"]
    text = [x for _, x in rrd.load_text(merged, L.AP_EVENTS)]
    assert "FAILSAFE no attitude 101.0 ms: rudder neutral" in text
    assert "failsafe: OK -> NO_ATTITUDE" in text
    assert [x for _, x in rrd.load_text(merged, S.SITL_EVENTS)] == ["servo timeout: rudder neutral"]
    i = np.searchsorted(data[S.SITL_ROLL].t_ns, data[L.AP_ROLL].t_ns)
    stepped = np.r_[0:100, 120:400]  # while held (failsafe) the controller does not take a measurement
    # Both are shown in degrees (rad rows times 180/pi): the measured roll is the float32 of the true one.
    phi_truth = data[S.SITL_ROLL].values[i[stepped], 0] * (math.pi / 180.0)
    np.testing.assert_allclose(
        data[L.AP_ROLL].values[stepped, 3],
        np.degrees(phi_truth.astype(np.float32).astype(np.float64)),
        rtol=1e-14,
        atol=0,
    )
    assert rrd.has_blueprint(merged)


def test_cli_flags_build_the_writer(tmp_path):
    import argparse

    p = argparse.ArgumentParser()
    tm.add_arguments(p)
    args = p.parse_args(["--rrd", str(tmp_path / "x.rrd"), "--recording-id", "abc"])
    assert tm.requested(args)
    with tm.from_args(args, "sitl") as tel:
        assert tel.enabled and tel.recording_id == "abc" and tel.connect_url is None
    off = tm.from_args(p.parse_args([]), "sitl")
    assert not off.enabled
    off.close()


def test_attach_registers_the_hooks_only_when_asked(tmp_path):
    import argparse

    from autopilot import telemetry as autopilot_telemetry

    p = argparse.ArgumentParser()
    tm.add_arguments(p)
    target = NS(hooks=[], event_hooks=[])
    assert autopilot_telemetry.attach(p.parse_args([]), target, control_rate_hz=100.0) is None
    assert S.attach(p.parse_args([]), target) is None
    assert target.hooks == [] and target.event_hooks == []
    tel = S.attach(p.parse_args(["--rrd", str(tmp_path / "sitl.rrd")]), target)
    try:
        assert isinstance(target.hooks[0], S.SitlHook) and target.event_hooks == [target.hooks[0].event]
    finally:
        tel.close()
    target = NS(hooks=[], event_hooks=[])
    tel = autopilot_telemetry.attach(p.parse_args(["--rrd", str(tmp_path / "ap.rrd")]), target, control_rate_hz=100.0)
    try:
        assert isinstance(target.hooks[0], AutopilotHook) and target.event_hooks == [target.hooks[0].event]
    finally:
        tel.close()


def _loaded_after(code: str) -> list[str]:
    """The project modules (and rerun) loaded in a fresh interpreter after running ``code``."""
    probe = textwrap.dedent(code) + textwrap.dedent("""
        import sys
        print(sorted(m for m in sys.modules if m.split('.')[0] in ('autopilot', 'sitl', 'tools', 'rerun')))
    """)
    out = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, check=True)
    return eval(out.stdout.strip().splitlines()[-1])  # noqa: S307 - our own list literal


def test_shared_telemetry_imports_nothing_of_the_project_outside_shared():
    loaded = _loaded_after("""
        import autopilot.shared.telemetry as t
        import importlib
        for m in t._MODULES:
            importlib.import_module(f"autopilot.shared.telemetry.{m}")
    """)
    project = [m for m in loaded if m.split(".")[0] in ("autopilot", "sitl", "tools")]
    assert [m for m in project if m != "autopilot" and not m.startswith("autopilot.shared")] == []
    assert "autopilot.shared.telemetry.writer" in project  # the probe did import every module


def test_sitl_telemetry_does_not_load_the_control_law():
    loaded = _loaded_after("import sitl.telemetry")
    for m in ("autopilot.clsac", "autopilot.loop", "autopilot.step", "autopilot.telemetry"):
        assert m not in loaded
    assert [
        m for m in loaded if m.startswith("autopilot") and m != "autopilot" and not m.startswith("autopilot.shared")
    ] == []


def test_nothing_imports_rerun_without_telemetry_flags():
    """``--help`` and runs without telemetry flags stay fast: attaching nothing never loads rerun."""
    loaded = _loaded_after("""
        import argparse
        from types import SimpleNamespace
        import autopilot.__main__, sitl.__main__
        from autopilot import telemetry
        from autopilot.shared.telemetry import add_arguments
        import sitl.telemetry
        p = argparse.ArgumentParser()
        add_arguments(p)
        target = SimpleNamespace(hooks=[], event_hooks=[])
        assert telemetry.attach(p.parse_args([]), target) is None
        assert sitl.telemetry.attach(p.parse_args([]), target) is None
    """)
    assert not any(m.split(".")[0] == "rerun" for m in loaded)


def test_attitude_quaternions_are_euler_zyx_without_the_heading():
    """The 3D aircraft's quaternion of roll and pitch against scipy's Euler ZYX rotation with heading 0, and the nose
    (body x) of a pitched-up aircraft pointing up in FRD (negative z)."""
    from scipy.spatial.transform import Rotation

    from autopilot.shared.telemetry.columns import attitude_quaternions, roll_quaternions

    rng = np.random.default_rng(3)
    phi, theta = rng.uniform(-3.0, 3.0, 50), rng.uniform(-1.5, 1.5, 50)
    q = attitude_quaternions(phi, theta)
    ref = Rotation.from_euler("ZYX", np.column_stack([0 * phi, theta, phi])).as_quat()
    assert np.allclose(np.abs(np.sum(q * ref, axis=1)), 1.0, atol=1e-12)
    assert np.allclose(attitude_quaternions(phi, 0 * phi), roll_quaternions(phi), atol=1e-15)
    nose = Rotation.from_quat(attitude_quaternions(np.array([0.0]), np.array([0.3]))).apply([1.0, 0.0, 0.0])[0]
    assert nose[2] == pytest.approx(-np.sin(0.3)) and nose[0] == pytest.approx(np.cos(0.3))
