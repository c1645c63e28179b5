"""``python -m tools.pfc design`` of a square MIMO plant (issue 32, stage B): the c172x flown on the aileron (roll) and
the rudder (sideslip).  The written design is checked against independent computations: the transmission zeros by
python-control and by the polynomial det(sI - A) det F(s) fitted on a circle, C B as the limit s F(s), the K_e bands
and the baseline's margins by simulating the sampled closed loop (scipy's matrix exponential, the flying PID law)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import scipy.linalg

from autopilot.params import load_file
from sitl import linear_plant
from sitl import plant as plants

PLANT = "jsbsim:c172x:surface=aileron+rudder"
T = 0.01


@pytest.fixture(scope="module")
def design(tmp_path_factory):
    out = tmp_path_factory.mktemp("mimo") / "F.params"
    proc = subprocess.run(
        [sys.executable, "-m", "tools.pfc", "design", PLANT, "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    lp = linear_plant.load(out.with_suffix(".toml"))
    return proc.stdout, load_file(out), lp


def _f(values, lp):
    """(A_F, B_F, C_F) of F = T + diag(k_i/(s + a_i)), built here from the file's numbers."""
    pfcs = [(values["CLSAC_PFC_NUM"], values["CLSAC_PFC_DEN0"]), (values["CLSAC_PFC2_NUM"], values["CLSAC_PFC2_DEN0"])]
    n = lp.a_p.shape[0]
    a = scipy.linalg.block_diag(lp.a_p, -np.diag([p[1] for p in pfcs]))
    b = np.vstack([lp.b_p, np.eye(2)])
    c = np.hstack([lp.c_p, np.diag([p[0] for p in pfcs])])
    assert a.shape == (n + 2, n + 2)
    return a, b, c


def test_the_shipped_design_is_what_the_command_makes(design):
    """sitl/plants/jsbsim-c172x-aileron+rudder.params (what a MIMO flight of the c172x finds beside its plant, and
    what tests/tools/flight/test_e2e_mimo.py flies) holds the values this fresh `tools.pfc design` wrote, every one."""
    from pathlib import Path

    _text, values, _lp = design
    shipped = load_file(Path(plants.__file__).parent / "plants" / "jsbsim-c172x-aileron+rudder.params")
    assert sorted(values) == sorted(shipped) and "CLSAC_PFC2_NUM" in values and "PID2_KP" in values
    # Not to the last bit: the PFC gains are margin / g*, with g* the critical gain from polynomial roots and matrix
    # eigenvalues (LAPACK), whose last digits differ between numpy/scipy builds (CLSAC_PFC2_NUM 1.0582135411183893
    # against 1.058213541092955, 2.4e-11 relative, numpy 2.4.6/scipy 1.17.1).  1e-7 relative is 4000 times that, and
    # still far finer than any choice the design makes: a corner, a Gamma or a PID gain taken from the next grid
    # point is at least 47 % away (tools/design/tuning.py: CORNERS 10^(3/15), BASELINE_KPS 10^(1/6), GAMMAS 3x
    # apart), and the report prints 6 significant digits.
    for name, value in shipped.items():
        assert values[name] == pytest.approx(value, rel=1e-7, abs=0.0), name


def test_the_printout_says_how_each_item_was_chosen(design):
    text, values, lp = design
    for needle in (
        "PFC D_1(s)",
        "PFC D_2(s)",
        "transmission zeros",
        "minimum phase yes",
        "symmetric positive definite yes",
        "relative degree 1",
        "W-ASPR yes",
        "K_e = k I: continuous none",
        "adaptation weights Gamma",
        "baseline PID 1",
        "baseline PID 2",
        "disk margin",
        "multivariable disk margin",
        "closed loop stable",
    ):
        assert needle in text, needle
    assert lp.m == 2 and lp.output_names == ("phi", "beta")
    # the roll channel keeps the aileron-only design's numbers (sitl/plants/jsbsim-c172x.params)
    siso = load_file(plants.shipped("jsbsim-c172x.params"))
    for name in ("CLSAC_PFC_NUM", "CLSAC_PFC_DEN0", "PID_KP", "PID_KI", "PID_KD"):
        assert values[name] == pytest.approx(siso[name], rel=1e-6)


def test_f_is_minimum_phase_by_two_independent_computations(design):
    import control

    text, values, lp = design
    a, b, c = _f(values, lp)
    zeros = np.sort_complex(control.ss(a, b, c, np.zeros((2, 2))).zeros())
    assert zeros.size == a.shape[0] - 2 and np.max(zeros.real) < 0.0
    # det(sI - A) det(C (sI - A)^-1 B) is a polynomial of degree n - 2 whose roots are the zeros: fitted here on a
    # circle of radius 60 (in s / 60, well conditioned)
    n = a.shape[0]
    r = 60.0
    s = r * np.exp(2j * np.pi * (np.arange(64) + 0.5) / 64)
    vals = [np.linalg.det(si * np.eye(n) - a) * np.linalg.det(c @ np.linalg.solve(si * np.eye(n) - a, b)) for si in s]
    coeffs = np.polyfit(s / r, vals, n - 2)
    roots = np.sort_complex(np.roots(coeffs) * r)
    for z in zeros:
        assert np.min(np.abs(roots - z)) < 1e-5 * max(1.0, abs(z))
    # and they are what the printout says
    for z in zeros:
        assert f"{z.real:.4g}" in text


def test_cb_is_the_limit_of_s_f_and_symmetric_positive_definite(design):
    _text, values, lp = design
    a, b, c = _f(values, lp)
    s = 1e7j
    cb = (s * c @ np.linalg.solve(s * np.eye(a.shape[0]) - a, b)).real
    np.testing.assert_allclose(cb, np.diag([values["CLSAC_PFC_NUM"], values["CLSAC_PFC2_NUM"]]), atol=1e-5)
    assert np.min(np.linalg.eigvalsh(0.5 * (cb + cb.T))) > 0.0 and np.allclose(cb, cb.T, atol=1e-5)


def _grows(phi, gam, c, k, steps=3000) -> bool:
    x = np.zeros(phi.shape[0])
    x[0] = 1e-3
    x[-1] = 1e-3
    for _ in range(steps):
        x = phi @ x - k * gam @ (c @ x)
        if np.linalg.norm(x) > 1e6:  # diverged (and before it overflows)
            return True
    return bool(np.linalg.norm(x) > 1e-2)


def test_the_sampled_ke_band_starts_where_the_printout_says(design):
    """K_e = k I on the ZOH loop at 100 Hz: simulated (scipy's expm) just below and above the printed band edge."""
    text, values, lp = design
    edge = float(text.split("K_e = k I: continuous none, sampled [")[1].split(",")[0])
    a, b, c = _f(values, lp)
    n = a.shape[0]
    big = scipy.linalg.expm(np.block([[a, b], [np.zeros((2, n + 2))]]) * T)
    phi, gam = big[:n, :n], big[:n, n:]
    assert not _grows(phi, gam, c, 0.9 * edge)
    assert _grows(phi, gam, c, 1.1 * edge)
    assert not _grows(phi, gam, c, 1.0)


def _pid_loop_grows(lp, gains, steps=4000) -> bool:
    """The two flying PIDs (autopilot.baseline.Baseline) on the ZOH plant from a small initial condition."""
    from autopilot.baseline import Baseline, BaselineConfig

    n = lp.a_p.shape[0]
    big = scipy.linalg.expm(np.block([[lp.a_p, lp.b_p], [np.zeros((2, n + 2))]]) * T)
    phi, gam = big[:n, :n], big[:n, n:]
    laws = [Baseline(BaselineConfig(kp=g[0], ki=g[1], kd=g[2], u_limit_rad=10.0)) for g in gains]
    x = np.zeros(n)
    x[1] = 0.01  # a roll of 0.01 rad
    for _ in range(steps):
        y = lp.c_p @ x
        u = np.array([law(y[i], 0.0) for i, law in enumerate(laws)])
        x = phi @ x + gam @ u
    return bool(np.linalg.norm(x) > 1.0)


def test_the_baseline_loop_at_a_time_gain_margins_by_simulation(design):
    text, values, lp = design
    g1 = tuple(values[f"PID_{k}"] for k in ("KP", "KI", "KD"))
    g2 = tuple(values[f"PID2_{k}"] for k in ("KP", "KI", "KD"))
    assert not _pid_loop_grows(lp, [g1, g2])
    for i, tag in ((0, "baseline PID 1"), (1, "baseline PID 2")):
        gm_db = float(text.split(tag)[1].split("gain margin ")[1].split(" dB")[0])
        f = 10 ** (gm_db / 20)
        scaled = [g1, g2]
        scaled[i] = tuple(v * 0.85 * f for v in scaled[i])
        assert not _pid_loop_grows(lp, scaled), (tag, "0.85 x margin")
        scaled[i] = tuple(v * 1.15 * f / 0.85 for v in scaled[i])
        assert _pid_loop_grows(lp, scaled), (tag, "1.15 x margin")


def test_the_margins_match_python_control_with_the_other_loop_open(design):
    from autopilot.baseline import BaselineConfig
    from tools.design.margins import baseline_margins
    from tools.design.mimo import channel
    from tools.design.mimo_baseline import mimo_margins

    _text, values, lp = design
    g1 = tuple(values[f"PID_{k}"] for k in ("KP", "KI", "KD"))
    mats = (lp.a_p, lp.b_p, lp.c_p)
    ours = mimo_margins(mats, [g1, (0.0, 0.0, 0.0)], T)["loops"][0]
    ref = baseline_margins(BaselineConfig(kp=g1[0], ki=g1[1], kd=g1[2]), plant=channel(mats, 0))
    assert ours["gain_margin_db"] == pytest.approx(ref["gain_margin_db"], abs=0.05)
    assert ours["phase_margin_deg"] == pytest.approx(ref["phase_margin_deg"], abs=0.1)


def test_the_matrix_law_flies_a_pfc_per_channel():
    """ClSac's block-diagonal D(s) = diag(k_i/(s + a_i)): y_d of each channel against its exact ZOH, by hand."""
    import math

    from autopilot.clsac import ClSac
    from autopilot.config import ClSacConfig

    eye = ((1.0, 0.0), (0.0, 1.0))
    cfg = ClSacConfig(
        am=((-5.0, 0.0), (0.0, -5.0)),
        bm=((5.0, 0.0), (0.0, 5.0)),
        cm=eye,
        lv=((20.0, 0.0), (0.0, 20.0)),
        pfc_channels=(((1.2,), (1.0, 15.0)), ((1.05,), (1.0, 63.0))),
        u_limits_rad=(0.3, 0.28),
    )
    law = ClSac(cfg)
    xd = np.zeros(2)
    rng = np.random.default_rng(1)
    for _ in range(200):
        u = law(rng.normal(0, 0.1, 2), rng.normal(0, 0.2, 2))
        assert abs(u[0]) <= 0.3 and abs(u[1]) <= 0.28
        for i, (k, a) in enumerate(((1.2, 15.0), (1.05, 63.0))):
            assert law.y_pfc[i] == pytest.approx(k * xd[i], abs=1e-15)
            xd[i] = math.exp(-a * T) * xd[i] + (1 - math.exp(-a * T)) / a * u[i]
