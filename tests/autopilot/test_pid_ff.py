"""pid-ff (``autopilot.baseline`` with ``kff`` and ``derivative="measurement"``, ``--controller pid-ff``): the PID
with the reference model's roll rate fed forward and the derivative on the measurement, against an independent
discrete PID written here (simple-pid's differential_on_measurement and the reference model's exact solution);
the registry, the flags, the gain schedule, and a lockstep flight equal to the in-process one."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot import controllers
from autopilot.baseline import KFF_KH2013A, Baseline, BaselineConfig
from autopilot.config import ConfigError
from sitl import model

T = 0.01
LIMIT = math.radians(30.0)


def independent_pid_ff(ys, ums, kp, ki, kd, kff, am=-5.0, bm=5.0, umax=LIMIT):
    """A discrete PID from scratch: the reference model x' = am x + bm um solved exactly over each period
    (x[k+1] = e^{am T} x + (e^{am T} - 1)/am bm um), the error to it, P + I (the integral before this step's
    increment, not integrated while saturated and pushing further), D on the measurement -kd (y - y_prev)/T (none
    on the first step, as simple-pid's _last_input), and kff times the model's rate am x + bm um."""
    a = math.exp(am * T)
    g = (a - 1.0) / am * bm
    x = integral = 0.0
    last = None
    out = []
    for y, um in zip(ys, ums):
        e = x - y
        d = 0.0 if last is None else -kd * (y - last) / T
        raw = kff * (am * x + bm * um) + kp * e + integral + d
        u = max(-umax, min(umax, raw))
        if not (u != raw and ki * T * e * raw > 0):
            integral += ki * T * e
        x = a * x + g * um
        last = y
        out.append(u)
    return np.array(out)


def test_pid_ff_is_an_independent_discrete_pid_with_feed_forward():
    rng = np.random.default_rng(7)
    n = 400
    ys = np.cumsum(rng.normal(0, 0.01, n))
    ums = np.where((np.arange(n) // 100) % 2 == 0, 0.17, -0.17)
    cfg = BaselineConfig(kp=1.0, ki=0.5, kd=0.2, kff=0.23, derivative="measurement")
    law = Baseline(cfg)
    got = np.array([law.step(y, um) for y, um in zip(ys, ums)])
    want = independent_pid_ff(ys, ums, 1.0, 0.5, 0.2, 0.23)
    assert np.max(np.abs(got - want)) < 1e-12
    assert np.any(np.abs(got) >= LIMIT)  # the limit and the anti-windup were exercised


def test_a_command_step_does_not_kick_the_surface_with_the_derivative_on_the_measurement():
    # on the error the derivative jumps with the reference model's first move; on the measurement it does not
    on_e = Baseline(BaselineConfig(kp=0.0, ki=0.0, kd=0.2))
    on_y = Baseline(BaselineConfig(kp=0.0, ki=0.0, kd=0.2, derivative="measurement"))
    for law in (on_e, on_y):
        law.step(0.0, 0.17)
    assert on_e.step(0.0, 0.17) != 0.0 and on_y.step(0.0, 0.17) == 0.0


def test_the_baseline_is_unchanged_and_the_feed_forward_is_the_kh2013a_roll_mode():
    assert KFF_KH2013A == -model.A_LP[1, 1] / model.B_LP[1, 0]  # -L_p / L_delta, paper sec. 5.1
    from tools.design.linearise import feedforward_gain, linear_model

    a, b, c, rr = linear_model("kh2013a")
    assert feedforward_gain((a, b, c), rr) == KFF_KH2013A
    a, b, c, rr = linear_model("jsbsim:c172x")  # states [beta, phi, p, r]: L_p = -4.3655, L_da = 18.6099
    assert feedforward_gain((a, b, c), rr) == pytest.approx(4.365483361450203 / 18.609913599571907, rel=1e-15)
    base = controllers.get("baseline").config(control_rate_hz=100.0, u_limit_rad=LIMIT)
    assert base == BaselineConfig() and base.kff == 0.0 and base.derivative == "error"
    ff = controllers.get("pid-ff").config(control_rate_hz=100.0, u_limit_rad=LIMIT)
    assert (ff.kp, ff.ki, ff.kd, ff.kff, ff.derivative) == (0.1, 0.1, 0.02, KFF_KH2013A, "measurement")


def test_set_gains_retunes_from_the_next_step_and_keeps_the_integrator():
    ys, ums = np.linspace(0, 0.1, 50), np.full(50, 0.17)
    a = Baseline(BaselineConfig())
    for y, um in zip(ys[:30], ums[:30]):
        a.step(y, um)
    xi, e_prev = a.xi, a.e
    a.set_gains(0.3, 0.2, 0.01)
    assert a.xi == xi
    u = a.step(ys[30], ums[30])
    assert u == pytest.approx(0.3 * a.e + xi + 0.01 / T * (a.e - e_prev), rel=1e-12)
    assert a.xi == pytest.approx(xi + 0.2 * T * a.e, rel=1e-12)
    with pytest.raises(ConfigError, match="finite and >= 0"):
        a.set_gains(-1.0, 0.0, 0.0)


def test_bad_gains_for_the_baseline_and_pid_ff_are_one_line():
    from autopilot.flags import baseline_gains
    from tools.flight import Flight, FlightConfigError

    assert baseline_gains("1,0.1,0.2,0.23") == (1.0, 0.1, 0.2, 0.23)
    with pytest.raises(ConfigError, match="fourth gain"):
        controllers.get("baseline").config(control_rate_hz=100.0, u_limit_rad=LIMIT, gains=(1, 0, 0, 0.2))
    with pytest.raises(FlightConfigError, match="fourth gain"):
        Flight(lockstep=True, controller="baseline", baseline_gains="1,0.1,0.2,0.23")
    with pytest.raises(ConfigError, match="derivative"):
        BaselineConfig(derivative="setpoint")
    with pytest.raises(ConfigError, match="kff"):
        BaselineConfig(kff=-0.1)


def test_pid_ff_flies_the_plants_feed_forward():
    from tools.flight.config import FlightConfig

    assert FlightConfig(lockstep=True, controller="pid-ff", plant="jsbsim:c172x").baseline_gains_flown == (
        1.0,
        0.1,
        0.2,
        pytest.approx(4.365483361450203 / 18.609913599571907, rel=1e-15),
    )
    # the plain baseline takes its designed gains from the design's parameter file (PID_KP/KI/KD, --params)
    assert FlightConfig(lockstep=True, controller="baseline", plant="jsbsim:c172x").baseline_gains_flown is None
    assert FlightConfig(lockstep=True, controller="pid-ff", baseline_gains="1,2,3,4").baseline_gains_flown == (
        1.0,
        2.0,
        3.0,
        4.0,
    )


@pytest.mark.e2e
def test_a_lockstep_pid_ff_flight_is_the_in_process_one(tmp_path):
    from dataclasses import replace

    from autopilot.shared.pwm import PwmMap
    from tools.experiment.scenario import PAPER, run_inprocess, run_of
    from tools.flight import Flight

    res = Flight(lockstep=True, duration=10.0, quiet=True, out=tmp_path, controller="pid-ff").run()
    assert res.completed and res.summary["controller"] == "pid-ff"
    ref = run_inprocess(replace(PAPER, duration_s=10.0), run_of("pid-ff"), wire=PwmMap())
    assert res.summary["runs"][0]["metrics"] == ref.metrics
