"""The fixed-gain baseline: its stated margins (python-control, checked by an independent frequency sweep), that it
flies wherever ClSac flies (ControlStep, experiments, the autopilot process), and an asymmetric end-to-end flight
that catches a flipped sign anywhere between the GCS and the rudder."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm

from autopilot.baseline import Baseline, BaselineConfig
from autopilot.clsac import TELEMETRY_FIELDS
from autopilot.config import ConfigError
from autopilot.shared.pwm import PwmMap
from autopilot.step import ControlStep, ProfileSetpoints
from sitl import model
from tools.design.margins import baseline_margins
from tools.experiment.scenario import BASELINE_RUN, PAPER, Scenario, run_inprocess
from tools.flight.profiles import Profile


def _independent_margins(cfg: BaselineConfig) -> tuple[float, float]:
    """Phase margin (deg) and gain margin (dB) of the sampled loop from a dense frequency sweep of
    L(z) = C(z) C_p (zI - Phi)^-1 Gamma with numpy alone (ZOH by the matrix exponential)."""
    T = cfg.dt
    n = model.A_P.shape[0]
    blk = np.zeros((n + 1, n + 1))
    blk[:n, :n] = model.A_P * T
    blk[:n, n:] = model.B_P * T
    e = expm(blk)
    phi, gam = e[:n, :n], e[:n, n:]
    w = np.linspace(0.05, math.pi / T * 0.999, 200_000)
    z = np.exp(1j * w * T)
    c = cfg.kp + cfg.ki * T * z / (z - 1) + cfg.kd * (z - 1) / (T * z)
    p = np.array([(model.C_P @ np.linalg.solve(zz * np.eye(n) - phi, gam))[0, 0] for zz in z[::50]])
    loop = c[::50] * p
    mag, ang = np.abs(loop), np.unwrap(np.angle(loop))
    i = np.flatnonzero((mag[:-1] >= 1) & (mag[1:] < 1))[0]
    pm = 180.0 + math.degrees(ang[i])
    j = np.flatnonzero(np.diff(np.sign(ang + math.pi)))[0]
    gm = -20 * math.log10(mag[j])
    return pm, gm


def test_stated_margins_and_an_independent_sweep():
    m = baseline_margins()
    assert m["closed_loop_stable"]
    assert m["gain_margin_db"] == pytest.approx(23.94, abs=0.05)
    assert m["phase_margin_deg"] == pytest.approx(59.28, abs=0.05)
    assert m["gain_crossover_rad_s"] == pytest.approx(4.73, abs=0.02)
    pm, gm = _independent_margins(BaselineConfig())
    assert pm == pytest.approx(m["phase_margin_deg"], abs=0.3)
    assert gm == pytest.approx(m["gain_margin_db"], abs=0.3)


def test_the_pfc_inverse_is_stabilising_but_has_almost_no_margin():
    m = baseline_margins(pfc_inverse=True)
    assert m["closed_loop_stable"]
    assert 0 < m["gain_margin_db"] < 0.5 and 0 < m["phase_margin_deg"] < 2.0


def test_flies_the_paper_scenario_through_controlstep():
    res = run_inprocess(PAPER, BASELINE_RUN)
    assert res.metrics["ise_ref"] < 0.05 and res.metrics["max_abs_u"] < math.radians(5)
    phi, ym = res.series["phi"], res.series["ym_ol"]
    assert np.max(np.abs(phi[-200:] - ym[-200:])) < math.radians(1.0)  # tracks the reference model
    # ise_crm is ise_ref: the baseline's e is y_m,ol - y
    assert res.metrics["ise_crm"] == res.metrics["ise_ref"]


def test_quacks_like_clsac():
    step = ControlStep(BaselineConfig(), PwmMap(), ProfileSetpoints(lambda t: 0.1))
    r = step(0.0, 0.0)
    assert r.u_cmd == step.law.u and len(step.law.telemetry()) == len(TELEMETRY_FIELDS)
    step.hold(0.01)
    assert step.law.frozen
    law = Baseline()
    first = [law(0.01 * k, 0.2) for k in range(50)]
    law.reset()
    assert [law(0.01 * k, 0.2) for k in range(50)] == first
    assert ControlStep(law=law).law is law
    with pytest.raises(ConfigError, match="kp"):
        BaselineConfig(kp=-1.0)


def test_integrator_anti_windup():
    on = Baseline(BaselineConfig(u_limit_rad=1e-3))
    off = Baseline(BaselineConfig(u_limit_rad=1e-3, anti_windup=False))
    for law in (on, off):
        for _ in range(500):
            law(0.0, 0.5)  # a far command the limited rudder never reaches
        assert law.saturated
    assert on.xi < 0.01 < off.xi


@pytest.mark.e2e
def test_asymmetric_profile_over_mavlink_catches_a_flipped_sign(tmp_path):
    """Positive steps only: a flipped sign between the GCS setpoint and the rudder (quaternion, PWM map, servo
    channel, the law) would roll the aircraft the wrong way, or diverge; a square wave could hide it."""
    from tools.flight import Flight

    for controller in ("clsac", "baseline"):
        out = tmp_path / controller
        result = Flight(
            lockstep=True, duration=4.0, controller=controller, profile="step", amplitude=10.0, out=out, rrd=False
        ).run()
        assert result.ok, result.reason
        truth = np.load(out / "sitl_series.npz")
        t, phi, rudder = truth["t"], truth["phi"], truth["delta_r"]
        assert np.all(np.abs(phi[t < 0.99]) < 1e-9)  # before the step: wings level
        assert phi[-1] == pytest.approx(math.radians(10.0), abs=math.radians(2.0))  # right wing down, +10 deg
        assert rudder[(t > 1.0) & (t < 1.3)].max() > 0  # a positive rudder started the positive roll
        run = BASELINE_RUN if controller == "baseline" else None
        if run is not None:
            ref = run_inprocess(
                Scenario(profile=Profile.of("step", amplitude_deg=10.0), duration_s=4.0), run, wire=PwmMap()
            )
            assert result.metrics == ref.metrics  # the wire model, to the last bit
