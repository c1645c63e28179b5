"""The PID bound of the damage study (``tools.design.tuning.design_pid_bound``): the design rule's objective over
continuous gains, checked against a brute-force search, python-control's margins, and the fault's delay."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.baseline import BaselineConfig
from tools.design.linearise import linear_model
from tools.design.margins import baseline_margins
from tools.design.tuning import TD_MAX, _Loop, design_baseline, design_pid_bound, faulted_plant, meets
from tools.experiment.damage.grid import effect_of


@pytest.fixture(scope="module")
def c172x_damping():
    a, b, c, rr = linear_model("jsbsim:c172x")
    return faulted_plant((a, b, c), rr, effect_of("damping", 0.3))


@pytest.fixture(scope="module")
def bound(c172x_damping):
    return design_pid_bound(c172x_damping)


def test_the_fast_margins_are_python_control_s(c172x_damping):
    loop = _Loop(c172x_damping, 100.0, 3)
    for kp, td in ((0.464, 0.43), (1.0, 0.2), (0.1, 0.3), (3.0, 0.1), (0.3, 1.0)):
        mine = loop.margins(kp, td)
        ref = baseline_margins(BaselineConfig(kp=kp, ki=kp / 10, kd=kp * td), plant=c172x_damping, delay_steps=3)
        assert mine["closed_loop_stable"] == ref["closed_loop_stable"]
        assert mine["gain_crossover_rad_s"] == pytest.approx(ref["gain_crossover_rad_s"], rel=1e-4)
        assert mine["phase_margin_deg"] == pytest.approx(ref["phase_margin_deg"], abs=0.01)
        assert mine["gain_margin_db"] == pytest.approx(ref["gain_margin_db"], abs=0.01)


def test_the_bound_meets_the_rule_and_beats_the_grid_and_the_issue_s_point(c172x_damping, bound):
    m = baseline_margins(BaselineConfig(kp=bound.kp, ki=bound.ki, kd=bound.kd), plant=c172x_damping)
    assert meets(m) and bound.ki == pytest.approx(bound.kp / 10)
    grid = design_baseline(c172x_damping)  # K_d/K_p <= 0.3: crossover 2.2 rad/s
    assert grid.margins["gain_crossover_rad_s"] < 2.5
    # the off-grid PID of issue 36 meets every margin at 4.2 rad/s: the bound reaches the 5 rad/s cap
    off = baseline_margins(BaselineConfig(kp=0.464, ki=0.0464, kd=0.2), plant=c172x_damping)
    assert meets(off) and off["gain_crossover_rad_s"] == pytest.approx(4.22, abs=0.01)
    assert m["gain_crossover_rad_s"] == pytest.approx(5.0, abs=1e-3)


def test_no_point_of_a_brute_force_search_beats_the_bound(c172x_damping, bound):
    """Random (K_p log-uniform over 0.01-10, T_d = K_d/K_p uniform over 0-1 s) and a dense line along T_d at the
    bound's K_p's neighbourhood: no point meeting the rule has a higher crossover, nor the 5 rad/s cap with less
    derivative time."""
    loop = _Loop(c172x_damping, 100.0, 0)
    td_bound = bound.kd / bound.kp
    w_bound = bound.margins["gain_crossover_rad_s"]
    rng = np.random.default_rng(36)
    pts = list(zip(10 ** rng.uniform(-2, 1, 300), rng.uniform(0, TD_MAX, 300)))
    pts += [(kp, td) for kp in np.linspace(0.5, 1.0, 11) for td in np.linspace(0.25, td_bound, 8)]
    # and along the cap: for each T_d the K_p whose |L| is 1 at 5 rad/s (the crossover is checked below)
    pts += [(loop.kp_at(5.0 * (1 - 1e-7), td), td) for td in np.linspace(0.0, TD_MAX, 41)]
    feasible = 0
    for kp, td in pts:
        m = loop.margins(kp, td)
        if not meets(m):
            continue
        feasible += 1
        w = m["gain_crossover_rad_s"]
        assert w <= w_bound + 1e-3, (kp, td, m)
        if w >= w_bound - 1e-3:
            assert td >= td_bound - 3e-3, (kp, td, m)  # at the cap, none with less derivative action
    assert feasible > 20  # the search did look at the feasible set


def test_the_retuned_pid_is_designed_with_the_fault_s_delay():
    """A 50 ms delay on the KH2013A (5 control steps): the study's design meets the rule on the loop WITH z^-5
    (python-control, independently of the design's own numbers); the design made without the delay does not."""
    from tools.experiment.damage.flight import design
    from tools.experiment.damage.grid import Design

    a, b, c, rr = linear_model("kh2013a")
    plant = faulted_plant((a, b, c), rr, effect_of("none", None))
    d = design(Design("kh2013a", "delay", 0.05))
    kp, ki, kd = d["gains"]
    delayed = baseline_margins(BaselineConfig(kp=kp, ki=ki, kd=kd), plant=plant, delay_steps=5)
    assert meets(delayed) and d["delay_steps"] == 5
    blind = design_pid_bound(plant)  # designed as if there were no delay
    cfg = BaselineConfig(kp=blind.kp, ki=blind.ki, kd=blind.kd)
    # z^-5 takes w_c 5 T of phase at the crossover: 5 rad/s x 0.05 s = 14 deg, below the 60 deg floor
    assert baseline_margins(cfg, plant=plant, delay_steps=5)["phase_margin_deg"] < 60.0 - math.degrees(0.2)
    assert (kp, kd) != pytest.approx((blind.kp, blind.kd), rel=1e-3)


# ----------------------------------------------------------------------------------- the PFC corner chosen
def test_the_design_picks_the_corner_of_least_offset_by_a_routh_table():
    """T(s) = 1/((s+1)(s+2)(s+3)), C = g (s + a): 1 + C T has the characteristic polynomial
    s^3 + 6 s^2 + (11 + g) s + (6 + g a), stable (Routh) while 6 (11 + g) > 6 + g a, so the critical gain is
    g* = 60/(a - 6) for a > 6: 60 at a = 7, 10 at a = 12.  With the margin 3, k = 3/g* and D(0) = k/a: the offset at
    10 deg, 10 D(0)/(T(0) + D(0)) with T(0) = 1/6, is 0.41096 deg at a = 7 and 1.30435 deg at a = 12.  The design
    must take a = 7, in either order of the grid (mutation: the comparison reversed, which takes the worst)."""
    from tools.design.tuning import design_pfc

    a_mat = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-6.0, -11.0, -6.0]])
    b_mat, c_mat = np.array([[0.0], [0.0], [1.0]]), np.array([[1.0, 0.0, 0.0]])

    def offset(a):
        d0 = (3.0 / (60.0 / (a - 6.0))) / a
        return 10.0 * d0 / (1.0 / 6.0 + d0)

    assert offset(7.0) == pytest.approx(0.410958904, rel=1e-8) and offset(12.0) == pytest.approx(1.304347826, rel=1e-8)
    for grid in ((7.0, 12.0), (12.0, 7.0)):
        d = design_pfc((a_mat, b_mat, c_mat), corners=grid)
        assert d.accepted == 2 and d.a == 7.0, grid
        assert d.critical_gain == pytest.approx(60.0, rel=1e-9) and d.k == pytest.approx(0.05, rel=1e-9)
        assert d.offset_deg == pytest.approx(offset(7.0), rel=1e-9)
