"""Every plant a first-class aircraft (issue 30): its surface mapped from its own model, a safety pilot that holds it
or a clear refusal, its own design or a refusal naming the command that makes one, the plant and its surface named,
flags that would not fly refused, errors that name the fix.  The fast checks; the flights are
tests/tools/flight/test_e2e_every_plant.py."""

from __future__ import annotations

import math
import re
import subprocess
import sys

import numpy as np
import pytest

from sitl import plant as plants
from sitl.jsbsim_models import PILOT_HOLDS_M, PILOT_HOLDS_M_S, PILOTS, _root, surface_map

JSBSIM_DEG = 0.01745  # JSBSim's aerosurface_scale gain in the models' files: rad per deg


def _cli(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=timeout)


def _one_line_exit_2(r: subprocess.CompletedProcess) -> str:
    assert r.returncode == 2, r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    return lines[0]


# ------------------------------------------------------------------------------------------- the surface
def _scale_range(model: str, name: str) -> tuple[float, float]:
    """The (min, max) of the aerosurface_scale ``name`` in the model's file, read as text (independent of JSBSim)."""
    text = (_root() / "aircraft" / model / f"{model}.xml").read_text()
    block = re.search(r'<aerosurface_scale name="' + re.escape(name) + r'">(.*?)</aerosurface_scale>', text, re.S)
    rng = re.search(r"<range>\s*<min>\s*([-\d.]+)\s*</min>\s*<max>\s*([-\d.]+)\s*</max>", block.group(1))
    return float(rng.group(1)), float(rng.group(2))


def test_pa28s_aileron_mapping_is_its_own_not_the_c172x_one():
    """pa28's aerodynamics read its left aileron, scaled -30..15 deg per unit command (its file): 15 deg a unit up,
    30 down, not c172x's 17.5 on both sides."""
    lo, hi = _scale_range("pa28", "Left Aileron Control")
    m = surface_map("pa28", "aileron")
    assert m.prop == "fcs/left-aileron-pos-rad" and m.measured
    assert m.positive_rad == pytest.approx(hi * JSBSIM_DEG, rel=1e-9)
    assert m.negative_rad == pytest.approx(-lo * JSBSIM_DEG, rel=1e-9)
    assert m.limit_rad == m.positive_rad  # the smaller side is the stop on both
    assert plants.surface_limit_rad("jsbsim:pa28") == m.positive_rad


def test_c172x_keeps_its_documented_scale_and_its_actuator_is_measured():
    """c172x: (left - right)/2 of two ailerons scaled -20..15 deg (17.5 deg a unit, as documented); its actuators'
    1.57 rad/s rate limit acts per physics step as per 1/120 s (JSBSim sizes the step when the model loads), and
    their 0.005 rad hysteresis is measured (docs/jsbsim.md)."""
    text = (_root() / "aircraft" / "c172x" / "c172x.xml").read_text()
    rate = float(re.search(r"<rate_limit>\s*([\d.]+)", text).group(1))
    hyst = float(re.search(r'left-aileron-actuator">.*?<hysteresis_width>\s*([\d.]+)', text, re.S).group(1))
    lo, hi = _scale_range("c172x", "fcs/left-aileron-control")
    m = surface_map("c172x", "aileron")
    assert m.positive_rad == m.negative_rad == math.radians(17.5)  # KNOWN: the flights stay bit for bit
    from sitl.jsbsim_models import _measure  # the measurement KNOWN stands in for

    raw = _measure("c172x", "aileron", 90.0, 1000.0, 1000.0)
    assert raw.positive_rad == pytest.approx(0.5 * (hi - lo) * JSBSIM_DEG, rel=1e-9)  # 17.5 deg x 0.01745
    assert raw.positive_rad == pytest.approx(math.radians(17.5), rel=3e-4)  # what KNOWN stands for
    assert m.rate_limit_rad_s == pytest.approx(rate * (1 / 120.0) / 1e-3, rel=1e-9)  # 13.08 rad/s at 1 kHz
    assert m.hysteresis_rad == pytest.approx(hyst, rel=1e-9)


def test_a_model_without_a_deflection_in_rad_is_refused_naming_the_fix():
    with pytest.raises(plants.PlantError, match=r"T38's aerodynamics reads fcs/left-aileron-pos-norm.*surface_max_deg"):
        plants.check("jsbsim:T38")


def test_the_jsbsim_plant_flies_the_deflection_asked_on_each_side():
    """pa28 at trim, a steady +-0.05 rad command: JSBSim's own left aileron sits 0.05 rad from its trim position on
    either side of the kink (15 vs 30 deg per unit), as the law assumes."""
    from sitl.jsbsim_plant import JsbsimPlant, parse_spec

    for delta in (0.05, -0.05):
        ac = JsbsimPlant(parse_spec("jsbsim:pa28"), 1000.0)
        trim = ac.fdm["fcs/left-aileron-pos-rad"]
        ac.advance(delta, 500)  # the servo (eq. (65), 49 rad/s) settles in 0.5 s
        assert ac.fdm["fcs/left-aileron-pos-rad"] - trim == pytest.approx(delta, abs=1e-6), delta


# ------------------------------------------------------------------------------------------- the safety pilot
def test_the_safety_pilot_refuses_an_aircraft_it_does_not_hold():
    with pytest.raises(plants.PlantError) as err:
        plants.check("jsbsim:F4N:airspeed_kt=150")
    assert "safety pilot" in str(err.value) and "lost 301 m" in str(err.value) and "c172x" in str(err.value)


@pytest.mark.e2e
@pytest.mark.parametrize("model", sorted(PILOTS, key=str.lower))
def test_the_safety_pilot_holds_every_aircraft_it_flies(model):
    """The check behind ``PILOTS``: at its checked airspeed, +-10 deg roll steps for 30 s under a roll PD (on the
    aileron, in rad of deflection): the altitude within 5 m, the airspeed within 1.5 m/s."""
    from sitl.jsbsim_plant import JsbsimPlant, parse_spec

    ac = JsbsimPlant(parse_spec(f"jsbsim:{model}:airspeed_kt={PILOTS[model]:g}"), 1000.0)
    h0, v0 = ac.held()["altitude_m"], ac.held()["airspeed_m_s"]
    dh = dv = 0.0
    lim = ac.surface_map.limit_rad
    for k in range(3000):
        ref = math.radians(10.0) * (1 if (k / 100) % 10 < 5 else -1)
        u = max(-lim, min(lim, 1.5 * (ref - ac.truth[3]) - 0.4 * ac.truth[1]))
        ac.advance(u, 10)
        held = ac.held()
        dh, dv = max(dh, abs(held["altitude_m"] - h0)), max(dv, abs(held["airspeed_m_s"] - v0))
    assert dh < PILOT_HOLDS_M and dv < PILOT_HOLDS_M_S, (dh, dv)


# ------------------------------------------------------------------------------------------- trim
def test_an_airspeed_that_does_not_trim_names_one_that_does():
    """J3Cub at the default 90 kt: the refusal names where it trims and the spec to try, and that spec trims."""
    from sitl.jsbsim_plant import parse_spec, trimmed_fdm

    with pytest.raises(ValueError) as err:
        trimmed_fdm(parse_spec("jsbsim:J3Cub"), 1e-3)
    text = str(err.value)
    assert "does not trim in level flight at 90 kt" in text and "it trims at 40-80 kt there" in text, text
    try_spec = text.rsplit("try ", 1)[1]
    assert try_spec == "jsbsim:J3Cub:airspeed_kt=60"
    assert trimmed_fdm(parse_spec(try_spec), 1e-3)["velocities/vc-kts"] == pytest.approx(60.0, abs=0.5)


# ------------------------------------------------------------------------------------------- designs
def test_a_plant_without_a_design_is_refused_naming_the_command_that_makes_one():
    """Must show (M-every-plant): --plant jsbsim:pa28 without a design, exit 2, one line naming tools.pfc design and
    the file the launcher then finds."""
    line = _one_line_exit_2(_cli("tools.launch", "--lockstep", "--plant", "jsbsim:pa28", "--duration", "2"))
    assert "jsbsim:pa28 has no design" in line and "jsbsim-pa28.params" in line
    assert "`python -m tools.pfc design jsbsim:pa28 --out " in line and line.rstrip().endswith("(--params FILE)")
    from tools.flight import FlightConfig, FlightConfigError

    with pytest.raises(FlightConfigError) as err:  # Flight and FlightConfig the same
        FlightConfig(plant="jsbsim:pa28:airspeed_kt=80", controller="baseline")
    assert err.value.field == "plant" and "tools.pfc design jsbsim:pa28:airspeed_kt=80" in str(err.value)
    # the controller's values given explicitly: flown, not refused
    assert FlightConfig(plant="jsbsim:pa28", pfc="paper").params_file is None
    assert FlightConfig(plant="jsbsim:pa28", controller="baseline", baseline_gains="1,0.1,0.2").params_file is None


def test_the_kh2013a_file_flies_its_own_shipped_design_the_paper_s():
    from autopilot.params import load_file
    from tools.design.linearise import designed_baseline, designed_params

    kh = str(plants.shipped("kh2013a.toml"))
    path = designed_params(kh)
    assert path is not None and path.name == "kh2013a.params"
    v = load_file(path)
    assert (v["CLSAC_PFC_NUM"], v["CLSAC_PFC_DEN1"], v["CLSAC_PFC_DEN0"]) == (10.0, 4.0, 40.0)  # paper sec. 5.1
    assert designed_baseline(kh) == (0.1, 0.1, 0.02)  # autopilot.baseline's defaults


def test_a_design_flies_every_controller_its_values_split_by_law():
    """The design's file has the PFC and weights (SAC, CL-SAC) and the PID's gains (the baseline); each law takes
    its own and leaves the other's; a name of no law is still refused."""
    from autopilot import controllers
    from autopilot.params import ParamError, ParamTable, load_file

    values = load_file(plants.shipped("jsbsim-c172x.params"))
    opts = {"attitude_timeout_s": 0.1, "setpoint_timeout_s": 1.0, "max_roll_rad": 0.8}
    for name in ("sac", "clsac", "baseline"):
        table = ParamTable(controllers.get(name).config(control_rate_hz=100.0, u_limit_rad=0.3), opts)
        mine, others = table.split(values)
        table.update(mine)
        if name == "baseline":
            assert (table.config.kp, table.config.ki, table.config.kd) == (1.0, 0.1, 0.2)
            assert others and all(n.startswith(("CLSAC_PFC", "CLSAC_GAM")) for n in others)
        else:
            assert table.config.pfc_num == (values["CLSAC_PFC_NUM"],) and others == [f"PID_K{k}" for k in "PID"]
        with pytest.raises(ParamError, match="unknown parameter 'CLSAC_NOPE'"):
            table.update(table.split({"CLSAC_NOPE": 1.0})[0])


# ------------------------------------------------------------------------------------------- flags that do not fly
@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--controller", "sac", "--lv", "50"], "--lv 50: sac flies Lv = 0"),
        (["--controller", "baseline", "--lv", "5"], "--lv 5: for sac and clsac only"),
        (["--controller", "baseline", "--pfc", "robust"], "--pfc robust: for sac and clsac only"),
        (["--controller", "baseline", "--sigma-xu", "0.1"], "--sigma-xu 0.1: for sac and clsac only"),
        (["--controller", "clsac", "--baseline-gains", "1,0,0"], "--baseline-gains 1,0,0: clsac is adaptive"),
    ],
)
@pytest.mark.parametrize("module", ["tools.launch", "autopilot"])
def test_a_flag_the_controller_would_not_fly_is_refused(module, argv, needle):
    """Must show: --controller sac --lv 50 is refused (it flew L_v = 0 and was reported as 50); the baseline's
    --lv, --pfc and adaptation options too: one line, exit 2, from the launcher and the autopilot alike."""
    line = _one_line_exit_2(_cli(module, *argv))
    assert needle in line, line


def test_a_flag_the_design_would_override_is_refused():
    from tools.flight import FlightConfig, FlightConfigError

    with pytest.raises(FlightConfigError, match=r"pfc robust: jsbsim:c172x's design .* sets CLSAC_PFC_NUM"):
        FlightConfig(plant="jsbsim:c172x", pfc="robust")
    assert FlightConfig(controller="sac", lv=0.0).lv_value == 0.0  # the value that flies is no refusal


def test_a_misspelt_flag_is_named_not_its_value():
    """--turbulance moderate: argparse used to blame the profile ('invalid choice: moderate')."""
    line = _one_line_exit_2(_cli("tools.launch", "--turbulance", "moderate"))
    assert line == "python -m tools.launch: error: unrecognized argument --turbulance (did you mean --turbulence?)"


def test_tools_pfc_help_shows_design():
    r = _cli("tools.pfc", "--help")
    assert r.returncode == 0 and "python -m tools.pfc design PLANT" in r.stdout


# ------------------------------------------------------------------------------------------- names
def test_the_plant_and_its_surface_have_names():
    kh_file = str(plants.shipped("kh2013a.toml"))
    assert [plants.name_of(p) for p in ("kh2013a", "jsbsim:c172x", "jsbsim:c172x:surface=rudder", kh_file)] == [
        "KH2013A",
        "c172x",
        "c172x-rudder",
        "kh2013a",
    ]
    assert [plants.surface_of(p) for p in ("kh2013a", "jsbsim:pa28", "jsbsim:c172x:surface=rudder", kh_file)] == [
        "rudder",
        "aileron",
        "rudder",
        "rudder",
    ]


def test_the_verdict_names_the_surface():
    from autopilot.envelope import Envelope, judge

    out = judge(0.1, 0.5, Envelope(surface="aileron"), samples=100)
    assert out.reason == "aileron saturated 50.0 % of the flight (limit 20 %)"
    assert "rudder" in judge(0.1, 0.0, Envelope(), samples=100).reason  # the KH2013A's words as before


def test_the_recording_s_labels_name_the_surface():
    from autopilot.telemetry import layout as L

    labels = [s for p in L.AUTOPILOT.naming("rudder", "aileron").plots for s in p.labels]
    assert "aileron command u (limited)" in labels and not any("rudder" in s for s in labels)
    assert L.AUTOPILOT.naming("rudder", "rudder") is L.AUTOPILOT


# ------------------------------------------------------------------------------------------- real time
def test_a_real_time_flight_that_lost_steps_says_what_to_do_and_how_busy_the_machine_was():
    from tools.flight.outcome import realtime_advice

    lost = {"hold_steps": 1, "late_steps": 0, "servo_timeout_s": 0.0}
    busy = realtime_advice(lost, {"busy": 0.97, "load1": 5.3, "cpus": 2})
    assert "the machine's 2 CPUs were 97 % busy, load average 5.3" in busy
    assert "--lockstep" in busy and "--pin --busy-wait" in busy and "a quieter machine" in busy
    quiet = realtime_advice(lost, {"busy": 0.3, "load1": 0.5, "cpus": 2})
    assert "--lockstep" in quiet and "CPUs were" not in quiet  # the load only when it was high
    assert realtime_advice({"hold_steps": 0, "late_steps": 0, "servo_timeout_s": 0.0}, None) == ""


def test_the_machine_load_is_measured_from_proc_stat():
    from tools.flight.children import cpu_times, machine_load

    t0 = cpu_times()
    x = 0.0
    for i in range(2_000_000):  # busy for a moment
        x += i
    load = machine_load(t0)
    assert load is not None and 0.0 < load["busy"] <= 1.0 and load["cpus"] >= 1


# ------------------------------------------------------------------------------------------- turbulence
def test_turbulence_on_a_plant_file_is_scaled_to_its_aircraft_or_refused(tmp_path):
    """A plant file says which aircraft it is ([atmosphere] airspeed, span, altitude): the Dryden filters take them
    (MIL-HDBK-1797 low altitude, recomputed here from its formulas); without them --turbulence is refused."""
    from sitl import disturbances

    kh = plants.shipped("kh2013a.toml").read_text()
    bare = tmp_path / "bare.toml"
    bare.write_text(kh.split("[atmosphere]")[0])
    with pytest.raises(plants.PlantError, match=r"--turbulence cannot fly on --plant .*\[atmosphere\] airspeed"):
        plants.check_disturbances(str(bare), {"turbulence": "moderate"})
    plants.check_disturbances(str(bare), {"crosswind": 2.0})  # a steady side wind needs no scale
    navion = tmp_path / "navion.toml"
    navion.write_text(kh.split("[atmosphere]")[0] + "[atmosphere]\nairspeed = 53.6\nspan = 10.2\naltitude = 100.0\n")
    plants.check_disturbances(str(navion), {"turbulence": "moderate"})
    dist = disturbances.from_values({"turbulence": "moderate"})
    turb = plants.injected(str(navion), dist).atmosphere.turbulence
    h_ft = 100.0 / 0.3048
    k = 0.177 + 0.000823 * h_ft
    sigma_w = 0.1 * 30.0 * 1852.0 / 3600.0
    assert (turb.airspeed, turb.span, turb.length_w) == (53.6, 10.2, 100.0)
    assert turb.sigma_w == pytest.approx(sigma_w, rel=1e-4)
    assert turb.sigma_v == pytest.approx(sigma_w / k**0.4, rel=1e-4)
    assert turb.length_v == pytest.approx(h_ft / k**1.2 * 0.3048, rel=1e-9)
    # the KH2013A as a file keeps the built-in's turbulence exactly
    kh_file = str(plants.shipped("kh2013a.toml"))
    assert plants.injected(kh_file, dist) == dist
    high = tmp_path / "high.toml"
    high.write_text(kh.split("[atmosphere]")[0] + "[atmosphere]\nairspeed = 53.6\nspan = 10.2\naltitude = 1000.0\n")
    with pytest.raises(plants.PlantError, match="outside the low-altitude Dryden model"):
        plants.check_disturbances(str(high), {"turbulence": "light"})


def test_the_scaled_turbulence_has_the_dryden_spectrum_of_its_airspeed():
    """The side gust's PSD at the Navion's 53.6 m/s, checked against MIL-F-8785C's Phi_v(omega) written out here:
    sigma_v^2 L_v/(pi V) (1 + 3 (L_v omega/V)^2) / (1 + (L_v omega/V)^2)^2."""
    from sitl.atmosphere import DrydenConfig

    cfg = DrydenConfig(1.2, 1.0, 150.0, 100.0, airspeed=53.6, span=10.2)
    w = np.array([0.01, 0.3, 1.0, 5.0])
    a = 150.0 * w / 53.6
    expect = 1.2**2 * 150.0 / (math.pi * 53.6) * (1 + 3 * a**2) / (1 + a**2) ** 2
    assert np.allclose(cfg.psd(w)[0], expect, rtol=1e-12)
