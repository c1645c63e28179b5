"""The KH2013A model and its exact discretisation, against independent facts."""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from sitl import model
from sitl.aircraft import Aircraft, AircraftConfig, AircraftConfigError, NonFiniteCommandError


def test_augmented_plant_is_the_printed_one():
    # A_p, B_p, C_p built from A_lp, B_lp and the servo equal the matrices printed in section 5.
    np.testing.assert_array_equal(model.A_P, np.array(model.A_P_PRINTED, dtype=float))
    np.testing.assert_array_equal(model.B_P.ravel(), np.array(model.B_P_PRINTED, dtype=float))
    np.testing.assert_array_equal(model.C_P.ravel(), np.array(model.C_P_PRINTED, dtype=float))


def test_servo_step_response_is_the_analytic_second_order_one():
    # Servo wn^2 = 2367, 2 zeta wn = 72.22, unity DC gain: underdamped step response in closed form.
    wn = math.sqrt(model.SERVO_WN2)
    zeta = model.SERVO_2ZETA_WN / (2 * wn)
    wd = wn * math.sqrt(1 - zeta**2)
    ac = Aircraft()
    u = 0.1
    for k in range(1, 301):
        x = ac.step(u)
        t = k * ac.config.dt
        analytic = u * (
            1 - math.exp(-zeta * wn * t) * (math.cos(wd * t) + zeta / math.sqrt(1 - zeta**2) * math.sin(wd * t))
        )
        assert x[model.DELTA_R] == pytest.approx(analytic, abs=1e-12)


def test_dc_gain_matches_printed_transfer_function():
    # T(0) = 9.185e08 / 6.351e06 from the printed num(s), den(s); printed to 4 significant figures.
    ac = Aircraft()
    u = 0.002
    ac.advance(u, 40_000)  # 40 s: slowest pole -0.572 rad/s has decayed by e^-22
    printed = 9.185e08 / 6.351e06
    assert ac.phi / u == pytest.approx(printed, rel=2e-3)


@pytest.mark.parametrize("rate", [1000.0, 250.0])
def test_discrete_model_matches_continuous_solution(rate):
    # ZOH discretisation is exact: a held command sequence integrated by solve_ivp (tight tolerances)
    # gives the same states; the remaining difference is the solver's, ~1e-9 relative.
    rng = np.random.default_rng(7)
    ac = Aircraft(AircraftConfig(physics_rate_hz=rate))
    dt = ac.config.dt
    x = np.zeros(6)
    for k in range(int(0.5 * rate)):
        u = float(rng.uniform(-0.05, 0.05))
        sol = solve_ivp(model.plant_rhs, (0.0, dt), x, args=(u,), method="DOP853", rtol=1e-12, atol=1e-14)
        x = sol.y[:, -1]
        xd = ac.step(u)
        scale = np.maximum(np.abs(x), 1e-6)
        assert np.all(np.abs(xd - x) / scale < 1e-7), (k, xd, x)


def test_advance_equals_repeated_steps():
    a, b = Aircraft(), Aircraft()
    for u in (0.01, -0.02, 0.005):
        a.advance(u, 10)
        for _ in range(10):
            b.step(u)
        np.testing.assert_allclose(a.x, b.x, rtol=1e-12, atol=1e-15)
    assert a.steps == b.steps == 30
    assert a.time == pytest.approx(0.03)


def test_rudder_limits_hold():
    ac = Aircraft(AircraftConfig(rudder_limit_rad=0.1, rudder_rate_limit_rad_s=2.0))
    for _ in range(500):
        x = ac.step(0.5)
        assert abs(x[model.DELTA_R]) <= 0.1 + 1e-15
        assert abs(x[model.DELTA_R_DOT]) <= 2.0 + 1e-15
    assert x[model.DELTA_R] == pytest.approx(0.1)


@pytest.mark.parametrize(
    "field,value",
    [
        ("physics_rate_hz", 0.0),
        ("physics_rate_hz", -1000.0),
        ("physics_rate_hz", float("nan")),
        ("rudder_limit_rad", -0.1),
        ("rudder_rate_limit_rad_s", 0.0),
    ],
)
def test_bad_aircraft_config_names_the_value(field, value):
    with pytest.raises(AircraftConfigError, match=field):
        AircraftConfig(**{field: value})


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_command_is_rejected(bad):
    ac = Aircraft()
    with pytest.raises(NonFiniteCommandError, match="finite"):
        ac.step(bad)
    with pytest.raises(NonFiniteCommandError):
        ac.advance(bad, 10)
    assert ac.steps == 0 and np.all(ac.x == 0)
