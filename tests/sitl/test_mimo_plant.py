"""Square MIMO plants (issue 32, stage A): plant files with B of m columns and named outputs, the JSBSim spec
``surface=aileron+rudder`` and its 2x2 linearisation.  Checked against independent computations: the transfer matrix
evaluated from the airframe and the servo's own transfer function, JSBSim's nonlinear response to a rudder step."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from sitl import linear_plant, model
from sitl import plant as plants
from sitl.linear_plant import PlantFileError

A = [[-0.5, 0.0, 0.0], [0.0, -2.0, 0.0], [0.0, 1.0, 0.0]]  # beta, p, phi
B = [[0.1, 0.5], [20.0, 2.0], [0.0, 0.0]]
C = [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]
MIMO = f"""name = "two"
[input]
name = ["delta_a", "delta_r"]
surface = ["aileron", "rudder"]
limit = [0.3, 0.25]
[output]
name = ["phi", "beta"]
[airframe]
states = ["beta", "p", "phi"]
A = {A}
B = {B}
C = {C}
roll = "phi"
roll_rate = "p"
[servo]
wn2 = {model.SERVO_WN2!r}
two_zeta_wn = {model.SERVO_2ZETA_WN!r}
"""


def _write(tmp_path, text, name="two.toml"):
    f = tmp_path / name
    f.write_text(text)
    return f


def test_a_mimo_file_is_read_with_one_servo_per_input(tmp_path):
    lp = linear_plant.load(_write(tmp_path, MIMO))
    assert lp.m == 2 and lp.is_mimo
    assert lp.surfaces == ("aileron", "rudder") and lp.limits_rad == (0.3, 0.25)
    assert lp.input_names == ("delta_a", "delta_r") and lp.output_names == ("phi", "beta")
    assert lp.a_p.shape == (7, 7) and lp.b_p.shape == (7, 2) and lp.c_p.shape == (2, 7)
    # the transfer matrix of the augmented plant = the airframe's times each servo's wn2 / (s^2 + 2 zeta wn s + wn2),
    # evaluated independently at a few frequencies
    a, b, c = (np.array(x, dtype=float) for x in (A, B, C))
    for s in (0.3j, 2.0 + 1.0j, 15.0j):
        servo = model.SERVO_WN2 / (s * s + model.SERVO_2ZETA_WN * s + model.SERVO_WN2)
        want = c @ np.linalg.solve(s * np.eye(3) - a, b) * servo
        got = lp.c_p @ np.linalg.solve(s * np.eye(7) - lp.a_p, lp.b_p)
        np.testing.assert_allclose(got, want, rtol=1e-12)


@pytest.mark.parametrize(
    ("old", "new", "needle"),
    [
        ("C = [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]", "C = [[0.0, 0.0, 1.0]]", "a plant is square"),
        ('surface = ["aileron", "rudder"]', 'surface = ["aileron"]', "must be a list of 2 values"),
        ('surface = ["aileron", "rudder"]', 'surface = ["aileron", "aileron"]', "2 different surfaces"),
        ("limit = [0.3, 0.25]", "limit = [0.3, 2.0]", "limit[1] must be in (0, pi/2]"),
        ('name = ["phi", "beta"]', 'name = ["phi", "phi"]', "2 different names"),
        ("B = [[0.1, 0.5], [20.0, 2.0], [0.0, 0.0]]", "B = [[0.1, 0.0], [20.0, 0.0], [0.0, 0.0]]", "input 2"),
    ],
)
def test_a_bad_mimo_file_is_refused_in_one_line(tmp_path, old, new, needle):
    assert old in MIMO
    text = MIMO.replace(old, new)
    with pytest.raises(PlantFileError) as err:
        linear_plant.load(_write(tmp_path, text))
    assert needle in str(err.value) and "\n" not in str(err.value)


def test_a_mimo_file_is_not_flown_by_the_sitl(tmp_path):
    with pytest.raises(plants.PlantError, match="designed .* but not flown"):
        plants.build(str(_write(tmp_path, MIMO)), 1000.0)


def test_the_jsbsim_spec_names_its_surfaces_and_outputs():
    from sitl.jsbsim_plant import JsbsimPlantError, parse_spec

    spec = parse_spec("jsbsim:c172x:surface=aileron+rudder")
    assert spec.is_mimo and spec.surfaces == ("aileron", "rudder") and spec.outputs == ("phi", "beta")
    assert spec.text(short=True) == "jsbsim:c172x:surface=aileron+rudder"
    assert not parse_spec("jsbsim:c172x").is_mimo and parse_spec("jsbsim:c172x").surfaces == ("aileron",)
    with pytest.raises(JsbsimPlantError, match="aileron, rudder or aileron\\+rudder"):
        parse_spec("jsbsim:c172x:surface=elevator")


def test_the_c172x_linearises_into_a_2x2_plant_file(tmp_path):
    out = tmp_path / "mimo.toml"
    cmd = [sys.executable, "-m", "tools.plant", "linearise", "jsbsim:c172x:surface=aileron+rudder", "--out", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lp = linear_plant.load(out)
    siso = linear_plant.load(plants.shipped("jsbsim-c172x.toml"))  # the aileron alone, as shipped
    assert lp.m == 2 and lp.surfaces == ("aileron", "rudder") and lp.output_names == ("phi", "beta")
    n = 4
    # the aileron's column and the roll row are the SISO file's numbers
    np.testing.assert_allclose(lp.a_p[:n, :n], siso.a_p[:n, :n], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(lp.a_p[:n, n], siso.a_p[:n, n], rtol=1e-9, atol=1e-12)
    assert lp.limits_rad[0] == siso.limit_rad
    # the rudder's sign: JSBSim's own, a positive command raises the sideslip.  Independently, the nonlinear model:
    # a rudder step of +0.1 of its normalised travel, and beta 0.5 s later
    from sitl.jsbsim_plant import parse_spec, trimmed_fdm

    fdm = trimmed_fdm(parse_spec("jsbsim:c172x"), 0.001)
    beta0, trim = fdm["aero/beta-rad"], fdm["fcs/rudder-cmd-norm"]
    fdm["fcs/rudder-cmd-norm"] = trim + 0.1
    for _ in range(500):
        fdm.run()
    dbeta = fdm["aero/beta-rad"] - beta0
    # the linear file's prediction of the same step (the servo ignored: 0.1 of the unit travel in rad)
    a = lp.a_p[:n, :n]
    b = lp.a_p[:n, n + 2] * 0.1 * lp.limits_rad[1]
    from scipy.linalg import expm

    big = np.zeros((n + 1, n + 1))
    big[:n, :n], big[:n, n] = a, b
    x = expm(big * 0.5)[:n, n]
    assert dbeta > 0.0 and x[0] > 0.0
    assert x[0] == pytest.approx(dbeta, rel=0.3)
