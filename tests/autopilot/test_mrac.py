"""autopilot.mrac (MRAC with integral action, Lavretsky & Wise 2013 ch. 9-10; CRM-MRAC, Gibson, Annaswamy &
Lavretsky 2013) against the test's own closed loop: the law written here from the textbook's equations (numpy, not
the law's module), the continuous KH2013A integrated by solve_ivp per control period (tests/_law_loop.py),
compared with the class flying the exact ZOH plant and with the product's own lockstep flight of the shipped design
(in process).

Both fly the same samples (the law holds its signals over a period, as the module documents), so they differ only by
solve_ivp's tolerance (rtol 1e-11) against the exact ZOH: 1e-7 rad bounds it with room.  No number printed in the
textbook or in Gibson et al. for their own examples is reproduced here (their examples' models are not ours)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import solve_continuous_lyapunov

from autopilot.config import ConfigError, NonFiniteInputError
from autopilot.lawkit import proj
from autopilot.mrac import CRM_PARAMETERS, PARAMETERS, TELEMETRY_FIELDS, Mrac, MracConfig, crm_config
from tests import _law_loop as loop


def _textbook(cfg: MracConfig):
    """The textbook's sampled law as (law_sample, state0) for ``loop.ivp_flight``; state [x_I, x_ref (3), dK (3)]."""
    a = np.array([[0, 1, 0], [0, cfg.a11, cfg.a12], [0, cfg.a21, cfg.a22]], dtype=float)
    b = np.array([0.0, cfg.b1, cfg.b2])
    b_ref = np.array([-1.0, 0.0, 0.0])
    k = np.array([cfg.k_i, cfg.k_phi, cfg.k_p])
    a_ref = a - np.outer(b, k)
    a_c = a_ref - cfg.crm_l * np.eye(3)
    pb = solve_continuous_lyapunov(a_c.T, -np.eye(3)) @ b  # A_c^T P + P A_c = -I

    def sample(_k, phi, p, _r, cmd, s):
        xi, x_ref, dk = s[0], s[1:4], s[4:7]
        z = np.array([xi, phi, p])
        e = z - x_ref
        u = float((dk - k) @ z)
        assert abs(u) < cfg.u_limit_rad  # the scenario never saturates: no anti-windup to mirror
        assert np.linalg.norm(dk) < cfg.k_max / math.sqrt(1 + cfg.proj_eps)  # Proj idle: the plain gradient law
        lo, hi = k * (1 - cfg.g_max), k * (1 - cfg.g_min)  # ... on the ball and on the box (each dK_j in [lo, hi])
        assert np.all(np.abs(dk - (lo + hi) / 2) < (hi - lo) / 2 / math.sqrt(1 + cfg.proj_eps))

        def ode(y, z=z, e=e, cmd=cmd):
            return np.concatenate([
                [phi - cmd],  # x_I' = phi - r (the held sample)
                a_ref @ y[1:4] + b_ref * cmd + cfg.crm_l * (z - y[1:4]),  # x_ref' (CRM: + l (z - x_ref))
                -cfg.gamma * z * float(e @ pb),  # dK' = -gamma z e^T P B
            ])  # fmt: skip

        return u, ode, s

    return sample, np.zeros(7)


@pytest.fixture(scope="module", params=["mrac", "crm-mrac"])
def flown(request):
    """15 s (two edges of the square wave, the effectiveness at 0.3 from 10 s): the product's lockstep flight of the
    law with its shipped design, and the textbook's loop with that design integrated by solve_ivp."""
    cfg, independent, product = loop.flown_against(request.param, _textbook)
    assert cfg.crm_l > 0 if request.param == "crm-mrac" else cfg.crm_l == 0
    return cfg, independent, product


def test_matches_the_textbook_loop_integrated_by_solve_ivp(flown):
    cfg, independent, _ = flown
    phi, u = loop.lockstep(Mrac(cfg), n=loop.CHECK_N, effectiveness=loop.CHECK_FAULT)
    loop.assert_agree((phi, u), independent)
    assert np.max(np.abs(phi)) > math.radians(9)  # it flew the command


def test_the_products_lockstep_flight_matches_the_textbook_loop(flown):
    """The product's flight (ControlStep, the SITL's aircraft, the fault as --fault flies it) against the textbook's
    loop: both sample the roll at the same instants and hold the surface over the period, and the SITL advances the
    linear plant exactly (ten exact 1 ms steps), so the sampling leaves no difference to explain; what remains is
    solve_ivp's tolerance (rtol 1e-11; measured 2e-13 rad), which 1e-7 rad bounds with room."""
    _, independent, product = flown
    loop.assert_agree(product, independent)
    assert np.max(np.abs(product[1][1000:])) > np.max(np.abs(product[1][:1000]))  # the fault flew: more surface


@pytest.mark.parametrize("crm", [False, True], ids=["mrac", "crm-mrac"])
def test_tracks_the_paper_scenario_and_reports_the_effectiveness_drop(crm):
    cfg = crm_config() if crm else MracConfig()
    ref = loop.reference()
    phi, u = loop.lockstep(Mrac(cfg))
    late = loop.late_error_deg(phi, ref)
    phi_f, u_f = loop.lockstep(Mrac(cfg), effectiveness=(1000, 0.3))
    late_f = loop.late_error_deg(phi_f, ref)
    print(f"\n{'crm-mrac' if crm else 'mrac'}: late |phi - ref| {late:.3g} deg nominal, {late_f:.3g} deg with the "
          f"effectiveness at 0.3 from 10 s; max |u| {math.degrees(np.max(np.abs(u))):.3g} / "
          f"{math.degrees(np.max(np.abs(u_f))):.3g} deg")  # fmt: skip
    assert late < 1.0
    assert np.all(np.isfinite(phi_f)) and late_f < 5.0


def test_projection_keeps_the_gains_in_their_ball():
    """Proj's two properties (Lavretsky & Wise ch. 11): the bound, and (theta - theta*)^T (Proj(theta, y) - y) <= 0
    for any theta* inside the ball (what the Lyapunov proof needs)."""
    rng = np.random.default_rng(1)
    t_max, eps = 2.0, 0.1
    for _ in range(2000):
        theta = rng.normal(size=3) * rng.uniform(0, 1.2) * t_max / math.sqrt(3)
        y = rng.normal(size=3) * 10
        star = rng.normal(size=3)
        star *= rng.uniform(0, 1) * t_max / math.sqrt(1 + eps) / np.linalg.norm(star)
        py = proj(theta, y, t_max, eps)
        assert (theta - star) @ (py - y) <= 1e-9
        if np.linalg.norm(theta) >= t_max:
            grad = theta  # the outward normal
            assert py @ grad <= 1e-9 * np.linalg.norm(y) * np.linalg.norm(theta)
    # A law adapting hard on a plant it cannot match stays in the ball.
    cfg = MracConfig(gamma=1e4, k_max=0.5)
    law = Mrac(cfg)
    loop.lockstep(law, n=600, effectiveness=(0, 0.3))
    assert np.linalg.norm(law.dk) <= cfg.k_max * (1 + 1e-12)


def test_projection_box_keeps_each_gain_within_its_range():
    """The design's box: every gain of K - dK within [g_min, g_max] x its baseline gain, whatever the adaptation
    asks (a law adapting hard on a plant it cannot match), at every step."""
    cfg = MracConfig(gamma=1e4)
    k = np.array([cfg.k_i, cfg.k_phi, cfg.k_p])
    law = Mrac(cfg)
    step, hits = law.step, []

    def checked(*args):
        u = step(*args)
        g = (k - law.dk) / k  # each gain's multiple of its baseline
        hits.append(law.projecting)
        assert np.all(g >= cfg.g_min - 1e-12) and np.all(g <= cfg.g_max + 1e-12), g
        return u

    law.step = checked
    loop.lockstep(law, n=600, effectiveness=(0, 0.3))
    assert any(hits)  # the box was reached
    with pytest.raises(ConfigError):
        MracConfig(g_min=1.2)  # dK = 0 outside the box
    fixed = Mrac(MracConfig(g_min=1.0, g_max=1.0, gamma=1e4))  # an empty box: no adaptation
    loop.lockstep(fixed, n=100)
    assert not np.any(fixed.dk)


@pytest.mark.parametrize("name", ["mrac", "crm-mrac"])
def test_light_turbulence_without_a_fault_stays_controlled(name):
    """The damage study's light turbulence (seed 1), no fault, 10 s, the shipped design, in process (the SITL's own
    Dryden injector on the KH2013A): the roll rate's gusts (about 20 deg/s rms) drive dK_p towards more damping
    (dK_p' = -gamma p e^T P B, e_p ~ p); the box stops it at 1.4 k_p, where the aircraft is stable.  Under the
    former ball ||dK|| <= 4 ||K|| the rate gain reached 54 k_p within 0.5 s (the KH2013A is unstable from 2 k_p) and
    the rudder sat on its stops 95 % of the time."""
    from tools.experiment.scenario import Scenario, run_inprocess, run_of

    sc = Scenario(duration_s=10.0, disturbances=(("seed", 1), ("turbulence", "light")))
    s = run_inprocess(sc, run_of(name), atmosphere=True).series
    assert np.degrees(np.max(np.abs(s["p"]))) > 20.0  # the turbulence flew
    assert np.max(np.abs(s["u"])) < math.radians(29.0)  # never on the stops
    assert np.degrees(np.max(np.abs(s["phi"]))) < 20.0  # +-10 deg commanded


def test_interface_hold_reset_telemetry_and_bad_input():
    law = Mrac(crm_config())
    u = law.step(0.01, 0.02, 0.0, 0.1)
    assert abs(u) <= law.config.u_limit_rad
    assert set(law.telemetry()) == set(TELEMETRY_FIELDS)
    assert all(isinstance(v, float) for v in law.telemetry().values())
    for _ in range(50):
        law.step(0.0, 0.0, 0.0, 0.2)
    dk, xi, xr = law.dk.copy(), law.xi, law.x_ref.copy()
    law.hold(0.05)
    assert np.array_equal(law.dk, dk) and law.xi == xi  # adaptation and integral frozen
    assert not np.array_equal(law.x_ref, xr)  # the reference model moves on
    assert law.telemetry()["u"] == 0.05
    law.reset()
    assert law.xi == 0.0 and not np.any(law.dk) and not np.any(law.x_ref)
    for bad in (math.nan, math.inf):
        with pytest.raises(NonFiniteInputError):
            law.step(bad, 0.0, 0.0, 0.0)
        with pytest.raises(NonFiniteInputError):
            law.step(0.0, 0.0, bad, 0.0)
    for field in ("gamma", "k_max", "b2", "control_rate_hz"):
        with pytest.raises(ConfigError):
            MracConfig(**{field: math.nan})
    with pytest.raises(ConfigError):
        MracConfig(k_max=-1.0)
    with pytest.raises(ConfigError):
        MracConfig(crm_l=-1.0)
    names = [row[0] for row in PARAMETERS + CRM_PARAMETERS]
    assert len(set(names)) == len(names) and all(len(n) <= 16 for n in names)  # MAVLink param_id
    assert all(n.startswith("MRAC_") for n in names[: len(PARAMETERS)])
    assert all(n.startswith("CRM_") for n in names[len(PARAMETERS) :])


def test_reconfigure_keeps_the_adaptation():
    law = Mrac()
    for _ in range(200):
        law.step(0.0, 0.0, 0.0, 0.2)
    dk, xi = law.dk.copy(), law.xi
    law.reconfigure(crm_config(gamma=0.0))
    assert np.array_equal(law.dk, dk) and law.xi == xi and law.config.crm_l > 0
    law.step(0.0, 0.0, 0.0, 0.2)
    assert np.array_equal(law.dk, dk)  # gamma = 0 from now on
