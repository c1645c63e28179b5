"""Faults on a JSBSim aircraft (sitl.jsbsim_plant, sitl.jsbsim_damage): a real change of the aircraft, checked in
JSBSim's own properties against the coefficients of the installed model's XML, read here."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from sitl import damage
from sitl.jsbsim_damage import SLUG_LB, refusals
from sitl.jsbsim_plant import JsbsimPlant, _root, parse_spec

SPEC = parse_spec("jsbsim:c172x")
XML = _root() / "aircraft" / "c172x" / "c172x.xml"


def _coefficient(name: str) -> float:
    """The constant factor (``<value>``) of a coefficient function of the installed c172x."""
    for fn in ET.parse(XML).getroot().iter("function"):
        if fn.get("name") == f"aero/coefficient/{name}":
            return float(fn.find("product/value").text)
    raise KeyError(name)


def _effect(*specs):
    return damage.combine([damage.parse(s) for s in specs])


def _fly(plant, n_frames, u=lambda k: 0.02 * math.sin(0.05 * k)):
    out = []
    for k in range(n_frames):
        plant.advance(u(k), 10)
        out.append(np.array([*plant.truth, *plant.attitude()]))
    return np.array(out)


def test_the_model_copy_flies_bit_for_bit_like_the_installed_model_until_a_fault():
    a, b = JsbsimPlant(SPEC), JsbsimPlant(SPEC, damaged=True)
    b.set_effect(damage.NOMINAL)  # the multipliers at 1, the ballast at 0 lb
    assert np.array_equal(_fly(a, 300), _fly(b, 300))
    assert b.fdm["inertia/weight-lbs"] == a.fdm["inertia/weight-lbs"]


def test_effectiveness_scales_the_aircrafts_aileron_coefficients():
    p = JsbsimPlant(SPEC, damaged=True)
    p.set_effect(_effect("effectiveness=0.3@0"))
    _fly(p, 20, lambda k: 0.05)
    f = p.fdm
    qsb = f["aero/qbar-area"] * f["metrics/bw-ft"]
    da = f["fcs/effective-aileron-pos"]
    assert abs(da) > 1e-3
    assert f["aero/coefficient/Clda"] == pytest.approx(0.3 * qsb * da * _coefficient("Clda"), rel=1e-12)
    assert f["aero/coefficient/Cnda"] == pytest.approx(0.3 * qsb * da * _coefficient("Cnda"), rel=1e-12)
    assert f["aero/coefficient/CYda"] == pytest.approx(0.3 * f["aero/qbar-area"] * da * _coefficient("CYda"), rel=1e-12)
    assert f["aero/coefficient/Cldr"] == pytest.approx(qsb * f["fcs/rudder-pos-rad"] * _coefficient("Cldr"), abs=1e-9)


def test_damping_scales_the_roll_damping_coefficient():
    p = JsbsimPlant(SPEC, damaged=True)
    p.set_effect(_effect("damping=0.4@0"))
    _fly(p, 50, lambda k: 0.1)
    f = p.fdm
    want = f["aero/qbar-area"] * f["metrics/bw-ft"] * f["aero/bi2vel"] * f["velocities/p-aero-rad_sec"]
    assert abs(f["velocities/p-aero-rad_sec"]) > 1e-3
    assert f["aero/coefficient/Clp"] == pytest.approx(0.4 * want * _coefficient("Clp"), rel=1e-12)


def test_inertia_and_cg_move_jsbsims_mass_properties():
    p = JsbsimPlant(SPEC, damaged=True)
    f = p.fdm
    _fly(p, 5)
    ixx, izz, cg = f["inertia/ixx-slugs_ft2"], f["inertia/izz-slugs_ft2"], [f[f"inertia/cg-{a}-in"] for a in "xyz"]
    w0 = f["inertia/weight-lbs"]
    p.set_effect(_effect("inertia=1.58@0"))
    _fly(p, 1)
    assert f["inertia/ixx-slugs_ft2"] == pytest.approx(1.58 * ixx, rel=1e-6)
    assert f["inertia/izz-slugs_ft2"] - izz == pytest.approx(0.58 * ixx, rel=1e-5)  # tip masses: Izz grows as much
    assert [f[f"inertia/cg-{a}-in"] for a in "xyz"] == pytest.approx(cg, abs=1e-6)
    w = f["inertia/weight-lbs"]
    p.set_effect(_effect("inertia=1.58@0", "cg=0.05@0"))
    _fly(p, 1)
    assert f["inertia/cg-y-in"] - cg[1] == pytest.approx(0.05 / 0.0254, rel=1e-4)  # 5 cm to the right
    span_ft = f["metrics/bw-ft"]
    ballast = f["inertia/weight-lbs"] - w
    assert ballast == pytest.approx(w * 0.05 / (span_ft / 2 * 0.3048 - 0.05), rel=1e-4)
    assert (w - w0) / SLUG_LB * (span_ft / 2) ** 2 == pytest.approx(0.58 * ixx, rel=1e-6)  # 2 m (b/2)^2
    p.set_effect(damage.NOMINAL)
    _fly(p, 1)
    assert f["inertia/ixx-slugs_ft2"] == pytest.approx(ixx, rel=1e-6)


def test_airspeed_is_the_safety_pilots_new_target():
    p = JsbsimPlant(SPEC)
    v0 = p.fdm["velocities/vc-kts"]
    p.set_effect(_effect("airspeed=70@0"))
    assert p.pilot.v0 == pytest.approx(70 * 1852 / 3600, rel=1e-15)
    rows = _fly(p, 800, lambda k: -0.5 * p.truth[3] - 0.2 * p.truth[1])  # 8 s, wings held level by the test
    assert p.fdm["velocities/vc-kts"] < v0 - 10 and abs(np.degrees(rows[-1][3])) < 5


def test_stuck_and_rate_on_the_servo_path():
    p = JsbsimPlant(SPEC)
    _fly(p, 30, lambda k: 0.1)
    p.set_effect(_effect("stuck@0"))
    held = p.delta
    rows = _fly(p, 100, lambda k: -0.1)
    assert np.all(rows[:, 4] == held) and np.all(rows[:, 5] == 0.0)
    q = JsbsimPlant(SPEC)
    q.set_effect(_effect("rate=20@0"))
    rows = _fly(q, 100, lambda k: 0.15 * (-1) ** (k // 25))
    slope = np.abs(np.diff(np.concatenate([[0.0], rows[:, 4]]))) / 0.01
    assert slope.max() <= math.radians(20) * (1 + 1e-12) and slope.max() > 0.999 * math.radians(20)


def test_a_model_without_the_coefficients_cannot_take_those_faults(tmp_path):
    xml = tmp_path / "plain.xml"
    xml.write_text(
        '<fdm_config name="plain"><metrics><wingspan unit="FT">30</wingspan></metrics>'
        '<aerodynamics><axis name="ROLL"><function name="aero/coefficient/Clb"><product>'
        "<property>aero/qbar-area</property><property>aero/beta-rad</property><value>-0.1</value>"
        "</product></function></axis></aerodynamics></fdm_config>"
    )
    why = refusals(xml, "aileron")
    assert set(why) == {"effectiveness", "damping"} and "aileron's position" in why["effectiveness"]
    assert refusals(XML, "aileron") == {} and refusals(XML, "rudder") == {}


def test_a_mimo_plant_flies_its_other_surface_through_a_servo_fault_on_one():
    """A servo fault on one surface of the square MIMO plant leaves the other on its own servo (eq. (65)), which
    follows its command as in a fault-free flight: the aileron jammed, the rudder still flown, and the reverse."""
    spec = parse_spec("jsbsim:c172x:surface=aileron+rudder")
    free = JsbsimPlant(spec)
    jam1 = JsbsimPlant(spec)
    jam1.set_effect(damage.Effect(stuck=True, stuck_at=math.radians(5)))  # the aileron (a --fault's surface)
    jam2 = JsbsimPlant(spec)
    jam2.set_effect(damage.Effect(second=damage.Effect(stuck=True, stuck_at=math.radians(-3))))  # the rudder's
    for p in (free, jam1, jam2):
        p.u2 = math.radians(-8.0)
        for _ in range(30):
            p.advance(math.radians(4.0), 10)
    assert jam1.delta == math.radians(5) and jam2.delta2 == math.radians(-3)
    # the other surface: its servo's response to its own command, as without the fault (0.3 s: settled)
    assert jam1.delta2 == pytest.approx(free.delta2, abs=1e-12) and free.delta2 == pytest.approx(
        math.radians(-8), abs=1e-3
    )
    assert jam2.delta == pytest.approx(free.delta, abs=1e-12) and free.delta == pytest.approx(math.radians(4), abs=1e-3)
