"""autopilot.indi (adaptive INDI, Smeur, Chu & de Croon 2016, as Paparazzi's stabilization_indi.c flies it) against the
test's own closed loop: the paper's equations written here (each continuous filter integrated by solve_ivp, not the
law's module), the continuous KH2013A integrated by solve_ivp per control period (tests/_law_loop.py), compared with
the class flying the exact ZOH plant and with the product's own lockstep flight of the shipped design (in process).

Both fly the same samples, so they differ by solve_ivp's tolerance only: 1e-7 rad bounds it with room.  The paper's
flight results (its Bebop's effectiveness estimates) are not reproducible on this plant: no number of it is."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from autopilot.config import ConfigError, NonFiniteInputError
from autopilot.indi import PARAMETERS, TELEMETRY_FIELDS, Indi, IndiConfig
from tests import _law_loop as loop


def _paper(cfg: IndiConfig):
    """The paper's sampled law as (law_sample, state0); state [p_f, p_f', u_f, u_f', u_act, phi_m, G]."""
    w, z = cfg.omega_f, cfg.zeta_f

    def second_order(y0, inp):
        """The synchronising filter w^2 / (s^2 + 2 z w s + w^2) over one period, its newest input held."""
        f = lambda _t, y: [y[1], w * w * (inp - y[0]) - 2 * z * w * y[1]]  # noqa: E731
        return solve_ivp(f, (0, loop.T), y0, method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]

    def sample(_k, phi, p, _r, cmd, s):
        s = s.copy()
        s[0:2] = second_order(s[0:2], p)  # filtered roll rate and its derivative (the filtered acceleration)
        s[2:4] = second_order(s[2:4], s[4])  # the modelled actuator position, filtered the same way
        p_dd = w * w * (p - s[0]) - 2 * z * w * s[1]
        nu = cfg.k_att * (s[5] - phi) - cfg.k_rate * p  # desired roll acceleration
        g = s[6]
        u = float(np.clip(s[2] + (nu - s[1]) / g, -cfg.u_limit_rad, cfg.u_limit_rad))  # u_f + G^-1 (nu - Omega'_f)
        s[6] = max(cfg.g_min, g - cfg.mu * loop.T * (g * s[3] - p_dd) * s[3])  # LMS on the filtered derivatives

        def ode(y, u=u, cmd=cmd):
            return np.array([0, 0, 0, 0, (u - y[4]) / cfg.tau_act, cfg.omega_r * (cmd - y[5]), 0.0])

        return u, ode, s

    return sample, np.array([0, 0, 0, 0, 0, 0, cfg.g0], dtype=float)


@pytest.fixture(scope="module")
def flown():
    """15 s, the effectiveness at 0.3 from 10 s: the product's lockstep flight of ``indi`` with its shipped design,
    and the paper's loop with that design integrated by solve_ivp."""
    return loop.flown_against("indi", _paper)


def test_the_products_lockstep_flight_matches_the_paper_loop(flown):
    """The product's flight (ControlStep, the SITL's aircraft, the fault as --fault flies it) against the paper's
    loop: the same sampling instants and held surface, the plant advanced exactly by both, so only solve_ivp's
    tolerance remains (measured 6e-14 rad); 1e-7 rad bounds it with room."""
    _, independent, product = flown
    loop.assert_agree(product, independent)
    assert np.max(np.abs(product[1][1000:])) > np.max(np.abs(product[1][:1000]))  # the fault flew: more surface


@pytest.mark.parametrize("mu", [None, 10.0], ids=["designed", "fast-lms"])
def test_matches_the_paper_loop_integrated_by_solve_ivp(mu, flown):
    if mu is None:
        cfg, independent, _ = flown
    else:
        cfg = IndiConfig(mu=mu)
        independent = loop.ivp_flight(*_paper(cfg), n=loop.CHECK_N, effectiveness=loop.CHECK_FAULT)
    law = Indi(cfg)
    phi, u = loop.lockstep(law, n=loop.CHECK_N, effectiveness=loop.CHECK_FAULT)
    loop.assert_agree((phi, u), independent)
    assert np.max(np.abs(phi)) > math.radians(9)
    if mu is not None:
        assert law.g < 0.9 * cfg.g0  # the LMS estimate moved toward the lower effectiveness


def test_tracks_the_paper_scenario_and_reports_the_effectiveness_drop():
    ref = loop.reference()
    law_f = Indi()
    phi, u = loop.lockstep(Indi())
    phi_f, u_f = loop.lockstep(law_f, effectiveness=(1000, 0.3))
    late, late_f = loop.late_error_deg(phi, ref), loop.late_error_deg(phi_f, ref)
    print(f"\nindi: late |phi - ref| {late:.3g} deg nominal, {late_f:.3g} deg with the effectiveness at 0.3 from 10 s "
          f"(G {law_f.g:.4g} at 30 s, G0 {law_f.config.g0:.4g}); max |u| {math.degrees(np.max(np.abs(u))):.3g} / "
          f"{math.degrees(np.max(np.abs(u_f))):.3g} deg")  # fmt: skip
    assert late < 1.0
    assert np.all(np.isfinite(phi_f)) and np.max(np.abs(phi_f)) < math.radians(30)


def test_interface_hold_reset_telemetry_and_bad_input():
    law = Indi()
    assert abs(law.step(0.01, 0.02, 0.0, 0.1)) <= law.config.u_limit_rad
    assert set(law.telemetry()) == set(TELEMETRY_FIELDS)
    for _ in range(20):
        law.step(0.02, 0.1, 0.0, 0.2)
    g, xp = law.g, law.xp.copy()
    law.hold(0.1)
    assert law.g == g and np.array_equal(law.xp, xp) and law.telemetry()["u"] == 0.1
    assert law.u_act != 0.0
    law.reset()
    assert law.g == law.config.g0 and law.u_act == 0.0 and not np.any(law.xp)
    with pytest.raises(NonFiniteInputError):
        law.step(0.0, math.nan, 0.0, 0.0)
    for field in ("g0", "omega_f", "mu"):
        with pytest.raises(ConfigError):
            IndiConfig(**{field: math.nan})
    with pytest.raises(ConfigError):
        IndiConfig(tau_act=-0.1)
    assert Indi(IndiConfig(tau_act=0.0)).step(0.0, 0.0, 0.0, 0.1) == 0.0  # no actuator lag: a = 0
    names = [r[0] for r in PARAMETERS]
    assert all(n.startswith("INDI_") and len(n) <= 16 for n in names) and len(set(names)) == len(names)


def test_reconfigure_keeps_the_effectiveness_estimate():
    law = Indi(IndiConfig(mu=10.0))
    for k in range(100):
        law.step(0.0, 0.1 * math.sin(k / 5), 0.0, 0.2)
    g = law.g
    law.reconfigure(IndiConfig(mu=0.0, k_att=50.0))
    assert law.g == g and law.config.k_att == 50.0
