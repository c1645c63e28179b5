"""The SITL's plants (sitl.plant): the KH2013A as a plant file, linear plants of your own, JSBSim, the linearisation."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sitl import model
from sitl import plant as plants
from sitl.aircraft import Aircraft, AircraftConfig
from sitl.disturbances import Injector, from_values
from tools.experiment.scenario import PAPER, PAPER_RUNS, run_inprocess

KH_FILE = str(plants.shipped("kh2013a.toml"))
SERVO = f"[servo]\nwn2 = {model.SERVO_WN2!r}\ntwo_zeta_wn = {model.SERVO_2ZETA_WN!r}\n"


def _sitl(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "sitl", "--duration", "0.01", *args], capture_output=True, text=True, timeout=60
    )


# ------------------------------------------------------------------------------------------- KH2013A as a file
def test_the_kh2013a_file_holds_the_printed_matrices():
    lp = plants.build(KH_FILE, 1000.0)
    ref = Aircraft(AircraftConfig())
    assert np.array_equal(lp._a, np.array(model.A_P_PRINTED)) and np.array_equal(lp._a, ref._a)
    assert np.array_equal(lp._b.ravel(), np.array(model.B_P_PRINTED, dtype=float))


@pytest.mark.parametrize("run", [PAPER_RUNS[0], PAPER_RUNS[1]], ids=lambda r: r.name)
def test_flying_the_kh2013a_file_equals_the_built_in_bit_for_bit(run):
    built_in = run_inprocess(PAPER, run)
    from_file = run_inprocess(replace(PAPER, plant=KH_FILE), run)
    assert from_file.metrics == built_in.metrics
    for key, series in built_in.series.items():
        assert np.array_equal(from_file.series[key], series), key


def test_the_kh2013a_file_in_turbulence_equals_the_built_in_bit_for_bit():
    dist = from_values({"turbulence": "moderate", "seed": 3})
    planes = [plants.build(p, 1000.0, None, dist) for p in (plants.KH2013A, KH_FILE)]
    injs = [Injector(dist, 1e-3, 100.0, True) for _ in planes]
    for k in range(300):
        u = 0.02 * math.sin(k / 10)
        xs = [inj.advance(ac, u, 10) for inj, ac in zip(injs, planes)]
        assert np.array_equal(xs[0], xs[1])


# ------------------------------------------------------------------------------------- a linear plant of your own
ROLL_MODE = """name = "first-order roll mode"
[input]
surface = "aileron"
[airframe]
states = ["p", "phi"]
A = [[-2.0, 0.0], [1.0, 0.0]]   # p' = -p / tau + L_delta delta, tau = 0.5 s; phi' = p
B = [[30.0], [0.0]]
C = [[0.0, 1.0]]
roll = "phi"
roll_rate = "p"
"""


def _residues(num: np.ndarray, den: np.ndarray) -> list[tuple[complex, complex]]:
    """(pole, residue) of num / (s den) (a step input), all poles simple: residue N(p) / D'(p)."""
    d = np.polymul(den, [1.0, 0.0])
    return [(p, np.polyval(num, p) / np.polyval(np.polyder(d), p)) for p in np.roots(d)]


def _step_by_residues(num, den, t, integrate: bool = False) -> np.ndarray:
    """The step response sum r e^{pt}, or (``integrate``) its integral from 0: sum r (e^{pt} - 1) / p (r t at p = 0)."""
    y = np.zeros_like(t, dtype=complex)
    for p, r in _residues(num, den):
        if not integrate:
            y += r * np.exp(p * t)
        elif abs(p) < 1e-12:
            y += r * t
        else:
            y += r * (np.exp(p * t) - 1.0) / p
    return np.real(y)


def test_a_first_order_roll_mode_file_flies_its_analytic_step_response(tmp_path):
    f = tmp_path / "roll.toml"
    f.write_text(ROLL_MODE + SERVO)
    ac = plants.build(str(f), 1000.0)
    u = math.radians(1.0)
    t = np.arange(1, 301) * 0.01
    phi, p = [], []
    for _ in t:
        x = ac.advance(u, 10)
        phi.append(ac.truth[model.PHI])
        p.append(ac.truth[model.P])
        assert x.shape == (4,)
    # p/delta_c = L wn2 / ((s + 1/tau) (s^2 + 2 zeta wn s + wn2)) by residues (no matrix exponential), phi = int p
    wn2, two_zwn = model.SERVO_WN2, model.SERVO_2ZETA_WN
    den_p = np.polymul([1.0, 2.0], [1.0, two_zwn, wn2])
    p_ref = _step_by_residues(np.array([30.0 * wn2 * u]), den_p, t)
    phi_ref = _step_by_residues(np.array([30.0 * wn2 * u]), den_p, t, integrate=True)
    np.testing.assert_allclose(phi, phi_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(p, p_ref, rtol=1e-9, atol=1e-12)
    # the textbook form once the servo has settled: p -> L tau delta (1 - e^{-t/tau})
    assert p[-1] == pytest.approx(30.0 * 0.5 * u * (1 - math.exp(-3.0 / 0.5)), rel=2e-3)


def test_a_transfer_function_file_flies_like_its_state_space_twin(tmp_path):
    ss, tf = tmp_path / "ss.toml", tmp_path / "tf.toml"
    ss.write_text(ROLL_MODE + SERVO)
    tf.write_text("[airframe]\nnum = [30.0]\nden = [1.0, 2.0, 0.0]\n" + SERVO)
    a, b = plants.build(str(ss), 1000.0), plants.build(str(tf), 1000.0)
    for _ in range(200):
        a.advance(0.01, 10)
        b.advance(0.01, 10)
    np.testing.assert_allclose(b.truth[[model.P, model.PHI]], a.truth[[model.P, model.PHI]], rtol=1e-9)


def test_the_surface_limit_of_a_file_is_a_mechanical_stop(tmp_path):
    f = tmp_path / "lim.toml"
    f.write_text(ROLL_MODE.replace('surface = "aileron"', 'surface = "aileron"\nlimit = 0.1') + SERVO)
    ac = plants.build(str(f), 1000.0)
    ac.advance(0.5, 500)
    assert ac.truth[model.DELTA_R] == 0.1


BAD = {
    "missing matrix": (ROLL_MODE.replace("B = [[30.0], [0.0]]\n", "") + SERVO, "[airframe] has no B matrix"),
    "wrong shape": (ROLL_MODE.replace("C = [[0.0, 1.0]]", "C = [[0.0, 1.0, 0.0]]") + SERVO, "C must be 1 x 2"),
    "NaN": (ROLL_MODE.replace("-2.0", "nan") + SERVO, "A has a NaN or infinite entry"),
    "unstable servo": (ROLL_MODE + SERVO.replace("72.22", "-5.0"), "two_zeta_wn must be a positive finite number"),
    "no servo": (ROLL_MODE, "no [servo] table"),
    "not TOML": ("A = [[1, 2\n", "not a TOML plant file"),
    "binary": (b"\x7fELF\x02\x01\x00\xff\xfe", "not a TOML plant file (not UTF-8 text)"),
    "unknown roll state": (ROLL_MODE.replace('roll = "phi"', 'roll = "bank"') + SERVO, "roll = 'bank' is not one"),
}


@pytest.mark.parametrize("case", BAD, ids=list(BAD))
def test_a_bad_plant_file_is_one_line_exit_2(tmp_path, case):
    text, needle = BAD[case]
    f = tmp_path / "bad.toml"
    f.write_bytes(text if isinstance(text, bytes) else text.encode())
    r = _sitl("--plant", str(f))
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr
    assert needle in lines[0] and str(f) in lines[0]


def test_scale_on_a_plant_file_is_refused_by_name(tmp_path):
    r = _sitl("--plant", KH_FILE, "--scale", "control=0.5")
    assert r.returncode == 2 and "--scale cannot fly on --plant" in r.stderr


def test_turbulence_on_a_plant_file_without_the_kh2013a_states_is_refused(tmp_path):
    f = tmp_path / "roll.toml"
    f.write_text(ROLL_MODE + SERVO)
    r = _sitl("--plant", str(f), "--turbulence", "light")
    assert r.returncode == 2 and "the atmosphere needs the airframe states [v, p, r, phi]" in r.stderr
    assert _sitl("--plant", KH_FILE, "--turbulence", "light", "--lockstep", "--connect-timeout", "0.2").returncode == 1


# ------------------------------------------------------------------------------------------------------- JSBSim
def test_an_unknown_jsbsim_model_lists_the_available_ones():
    r = _sitl("--plant", "jsbsim:c173")
    assert r.returncode == 2
    line = r.stderr.strip()
    assert len(line.splitlines()) == 1 and "no model 'c173'" in line
    from sitl.jsbsim_plant import available_models

    assert {"c172x", "J3Cub", "pa28"} <= set(available_models())
    assert all(name in line for name in available_models())


def test_jsbsim_trim_holds_level_flight_with_zero_roll_command_for_60_s(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    ac = plants.build("jsbsim:c172x", 1000.0)
    h0 = ac.held()["altitude_m"]
    rolls, heights = [], []
    for _ in range(6000):
        ac.advance(0.0, 10)
        rolls.append(ac.truth[model.PHI])
        heights.append(ac.held()["altitude_m"])
    assert ac.time == pytest.approx(60.0)
    assert max(abs(r) for r in rolls) < math.radians(1.0)
    assert max(abs(h - h0) for h in heights) < 2.0  # the safety pilot holds the trim altitude
    # the attitude is JSBSim's own: roll and the roll rate of the truth, a heading near the trim's 0
    phi, _theta, psi, p, _q, _r = ac.attitude()
    assert (phi, p) == (ac.truth[model.PHI], ac.truth[model.P]) and abs(psi) < math.radians(5.0)
    assert list(tmp_path.iterdir()) == []  # the model's own <output> file is not written


def test_the_servo_drives_the_aileron_on_top_of_the_trim():
    ac = plants.build("jsbsim:c172x", 1000.0)
    trim = ac.surface_trim
    ac.advance(math.radians(2.0), 500)
    assert ac.truth[model.DELTA_R] == pytest.approx(math.radians(2.0), rel=1e-3)
    assert ac.fdm["fcs/aileron-cmd-norm"] == pytest.approx(trim + math.radians(2.0) / math.radians(17.5), rel=1e-3)
    assert ac.truth[model.P] > 0  # a positive command rolls right: the sign the law assumes (positive hf gain)


def test_a_positive_rudder_command_rolls_right_too():
    ac = plants.build("jsbsim:c172x:surface=rudder", 1000.0)
    phi0 = ac.truth[model.PHI]
    ac.advance(math.radians(2.0), 2000)
    assert ac.truth[model.PHI] - phi0 > math.radians(1.0)  # JSBSim's positive rudder rolls left: mapped with -1
    assert ac.fdm["fcs/rudder-cmd-norm"] < ac.surface_trim


def test_jsbsim_turbulence_is_seeded():
    def roll_after(seed):
        ac = plants.build("jsbsim:c172x", 1000.0, None, from_values({"turbulence": "moderate", "seed": seed}))
        ac.advance(0.0, 3000)
        return ac.truth.copy()

    a, b, c = roll_after(1), roll_after(1), roll_after(2)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    still = plants.build("jsbsim:c172x", 1000.0)
    still.advance(0.0, 3000)
    assert abs(a[model.P] - still.truth[model.P]) > 1e-4  # the turbulence does move the aircraft


def test_the_linearisation_agrees_with_a_small_nonlinear_step(tmp_path):
    out = tmp_path / "c172x.toml"
    r = subprocess.run(
        [sys.executable, "-m", "tools.plant", "linearise", "jsbsim:c172x", "--airspeed", "100", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    lin = plants.build(str(out), 1000.0)
    nonlinear = plants.build("jsbsim:c172x:airspeed_kt=100", 1000.0)
    phi0 = nonlinear.truth[model.PHI]
    step = math.radians(2.0)
    d_lin, d_nl = [], []
    for _ in range(200):  # 2 s
        lin.advance(step, 10)
        nonlinear.advance(step, 10)
        d_lin.append(lin.truth[model.PHI])
        d_nl.append(nonlinear.truth[model.PHI] - phi0)
    d_lin, d_nl = np.array(d_lin), np.array(d_nl)
    assert d_nl[-1] > math.radians(10.0)  # a real roll, not a trivial comparison of zeros
    # within 8 % of the response all along (JSBSim's aileron actuator has a 0.005 rad hysteresis the linear
    # model does not)
    assert np.max(np.abs(d_lin - d_nl)) < 0.08 * np.max(np.abs(d_nl))


def test_a_bad_linearise_spec_is_one_line_exit_2(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "tools.plant", "linearise", "jsbsim:nope", "--out", str(tmp_path / "x.toml")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2 and "no model 'nope'" in r.stderr and "Traceback" not in r.stderr


def test_jsbsim_flies_the_paper_scenario_in_process():
    res = run_inprocess(replace(PAPER, plant="jsbsim:c172x", duration_s=10.0), PAPER_RUNS[1])
    phi = res.series["phi"]
    # the +10 deg step then the -10 deg one are followed (closely: with the PFC designed for it,
    # tests/tools/design/test_pfc_design.py)
    assert math.radians(5.0) < phi[400:500].mean() < math.radians(20.0)
    assert -math.radians(20.0) < phi[900:1000].mean() < -math.radians(5.0)
    assert Path(KH_FILE).is_file()


# ---------------------------------------------------------------------------------------- JSBSim over MAVLink
@pytest.mark.e2e
def test_two_lockstep_jsbsim_flights_in_turbulence_are_identical(tmp_path):
    from tools.flight import Flight

    def fly(name, seed):
        res = Flight(
            lockstep=True,
            duration=6,
            plant="jsbsim:c172x",
            turbulence="moderate",
            seed=seed,
            out=tmp_path / name,
            quiet=True,
            rrd=False,
            png=False,
        ).run()
        assert res.ok, res.reason
        return res

    a, b, c = fly("a", 4), fly("b", 4), fly("c", 5)
    assert a.metrics == b.metrics
    for key in a.series:
        assert np.array_equal(a.series[key], b.series[key]), key
    for name in ("sitl_series.npz",):
        sa, sb = np.load(tmp_path / "a" / name), np.load(tmp_path / "b" / name)
        assert all(np.array_equal(sa[k], sb[k]) for k in sa.files)
    assert not np.array_equal(a.series["phi"], c.series["phi"])  # the seed reaches JSBSim's turbulence
    # the +10 deg step is flown in the turbulence, with the PFC designed for the aircraft
    phi = a.series["phi"]
    assert math.radians(5.0) < phi[300:500].mean() < math.radians(15.0)


@pytest.mark.e2e
def test_the_launcher_flies_jsbsim_roll_steps_with_the_designed_pfc_and_records_the_held_axes(tmp_path):
    """python -m tools.launch --lockstep --plant jsbsim:c172x: OK, the designed PFC flown, the roll steps followed
    within the envelope, ATTITUDE carrying JSBSim's pitch and heading, the safety pilot's axes in flight.rrd."""
    from pymavlink import mavutil

    from tools.view import rrd_files as rrd

    out = tmp_path / "f"
    r = subprocess.run(
        [sys.executable, "-m", "tools.launch", "--lockstep", "--plant", "jsbsim:c172x", "--duration", "12"]
        + ["--out", str(out), "--quiet", "--no-png"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    assert "--params " + str(plants.shipped("jsbsim-c172x.params")) in (out / "autopilot.log").read_text()
    summary = __import__("json").loads((out / "summary.json").read_text())
    shipped = str(plants.shipped("jsbsim-c172x.params"))  # what flew is named: the plant, its parameter file
    assert (summary["plant"], summary["params"], summary["pfc"]) == ("jsbsim:c172x", shipped, f"from {shipped}")
    s = np.load(out / "autopilot_series.npz")
    phi, t = s["phi"], s["t"]
    assert np.max(np.abs(phi)) < math.radians(60.0)
    on = (t > 3.0) & (t < 5.0)
    assert np.all(np.abs(phi[on] - math.radians(10.0)) < math.radians(3.0))  # the +10 deg step, held
    # ATTITUDE is JSBSim's: a pitch near the trim's, a heading that turns right while banked right
    mlog = mavutil.mavlink_connection(str(out / "flight.tlog"))
    att = []
    while (m := mlog.recv_match(type="ATTITUDE")) is not None:
        att.append((m.time_boot_ms, m.pitch, m.yaw))
    att = np.array(att)
    assert np.all(np.abs(att[:, 1]) < math.radians(5.0)) and np.any(att[:, 1] != 0.0)
    at5 = att[np.argmin(np.abs(att[:, 0] - 5000)), 2]
    assert at5 > math.radians(2.0)
    held = rrd.load(out / "flight.rrd", prefix="/sitl/held")
    alt = held["/sitl/held/altitude"].values[:, 0]
    assert alt.size >= 1000 and np.max(np.abs(alt - 1000.0)) < 5.0  # the safety pilot held 1000 m
    v = held["/sitl/held/airspeed"].values[:, 0]
    assert np.max(np.abs(v - 90 * 1852 / 3600)) < 2.0  # the default 90 kt
    names = [str(n) for n in rrd.blueprint_components(out / "flight.rrd", "ViewBlueprint:display_name")]
    assert any("Altitude [m]" in n for n in names) and any("Safety pilot" in n for n in names)  # a tab shows them
    # The 3D aircraft flies JSBSim's roll and pitch (issue 20, "Seeing it"): each quaternion, rotated by scipy's
    # Euler ZYX (heading 0) from the recorded truth roll and pitch, is the same rotation (q and -q alike; the
    # recording keeps float32).
    from scipy.spatial.transform import Rotation

    t_q, quats = rrd.load_poses(out / "flight.rrd")["/sitl/attitude"]
    pitch_deg = held["/sitl/held/pitch"].values[:, 0]
    truth = rrd.load(out / "flight.rrd", prefix="/sitl/roll")["/sitl/roll"].values[:, 0]
    assert quats.shape[0] == pitch_deg.size == truth.size >= 1000 and np.ptp(pitch_deg) > 0.1
    expect = Rotation.from_euler("ZYX", np.column_stack([0 * truth, pitch_deg, truth]), degrees=True).as_quat()
    dots = np.abs(np.sum(expect * quats, axis=1))
    assert np.all(dots > 1.0 - 1e-7), dots.min()  # float32 quaternions: within 0.05 deg; R_x R_y instead is 5e-6 off


@pytest.mark.e2e
def test_the_kh2013a_file_over_mavlink_equals_the_built_in_bit_for_bit(tmp_path):
    from tools.flight import Flight

    def fly(name, plant):
        res = Flight(
            lockstep=True,
            duration=4,
            plant=plant,
            gust="1.5,10,1",
            out=tmp_path / name,
            quiet=True,
            rrd=False,
            png=False,
        ).run()
        assert res.ok, res.reason
        return res

    built_in, from_file = fly("built_in", "kh2013a"), fly("file", KH_FILE)
    assert from_file.metrics == built_in.metrics
    for key in built_in.series:
        assert np.array_equal(from_file.series[key], built_in.series[key]), key
    a, b = np.load(tmp_path / "built_in" / "sitl_series.npz"), np.load(tmp_path / "file" / "sitl_series.npz")
    assert all(np.array_equal(a[k], b[k]) for k in a.files)


@pytest.mark.parametrize(
    "kwargs, field, needle",
    [
        ({"plant": "jsbsim:c173"}, "plant", "no model 'c173'; available:"),
        ({"plant": "/no/such.toml"}, "plant", "cannot read"),
        ({"plant": "jsbsim:c172x", "gust": "1,10,2"}, "plant", "--gust cannot fly on --plant jsbsim:c172x"),
        ({"plant": "jsbsim:c172x:airspeed_kt=-5"}, "plant", "airspeed_kt must be positive"),
        ({"params": "/no/such.params"}, "params", "cannot read /no/such.params: No such file or directory"),
        ({"controller": "baseline", "baseline_gains": "1,2"}, "baseline_gains", "expected KP,KI,KD"),
        ({"baseline_gains": "1,2,3"}, "baseline_gains", "clsac is adaptive"),  # a value the law would not fly
    ],
)
def test_a_bad_plant_or_parameter_file_is_refused_by_flight(kwargs, field, needle):
    from tools.flight import Flight, FlightConfigError

    with pytest.raises(FlightConfigError) as err:
        Flight(**kwargs)
    assert err.value.field == field and needle in str(err.value)


@pytest.mark.e2e
@pytest.mark.parametrize(
    ("spec", "why"),
    [
        ("jsbsim:c172x:airspeed_kt=300", "does not trim"),
        ("jsbsim:ball", "aerodynamics reads no aileron position"),  # not an aircraft: nothing to roll it with
    ],
)
def test_a_jsbsim_plant_that_does_not_trim_is_refused_before_the_flight(tmp_path, spec, why):
    """Beyond the aircraft's envelope (or not an aircraft): one line, exit 2, nothing started (only the refusal's
    summary.json), JSBSim's own chatter kept out of the terminal; tools.pfc design says the same in one line."""
    import json

    out = tmp_path / "f"
    # as a user's shell has it: without PYTHONUNBUFFERED, JSBSim's messages waited in Python's stdout buffer and
    # came out after the launcher had put its stdout back
    user_env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    r = subprocess.run(
        [sys.executable, "-m", "tools.launch", "--lockstep", "--duration", "3", "--plant", spec, "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
        env=user_env,
    )
    assert r.returncode == 2 and r.stdout == "", r.stdout + r.stderr
    assert r.stderr.count("\n") == 1 and why in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["summary.json"]
    assert json.loads((out / "summary.json").read_text())["refused"] is True
    d = subprocess.run(
        [sys.executable, "-m", "tools.pfc", "design", spec, "--out", str(tmp_path / "x.params")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    last = d.stderr.strip().splitlines()[-1]
    assert d.returncode == 2 and why in last and "Traceback" not in d.stderr, d.stderr


@pytest.mark.e2e
def test_pfc_design_never_overwrites_another_plant_file(tmp_path):
    """The linearisation goes to OUT.toml beside --out: a different file already there is refused, unchanged."""
    mine = tmp_path / "mine.toml"
    mine.write_bytes(plants.shipped("kh2013a.toml").read_bytes())
    before = mine.read_bytes()
    d = subprocess.run(
        [sys.executable, "-m", "tools.pfc", "design", "jsbsim:c172x", "--out", str(tmp_path / "mine.params")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert d.returncode == 2 and "exists and is not this linearisation" in d.stderr, d.stderr
    assert mine.read_bytes() == before and not (tmp_path / "mine.params").exists()
