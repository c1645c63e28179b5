"""The one control step (autopilot.step) against a procedural loop written from its definition."""

from __future__ import annotations

import math

import pytest

from autopilot import ClSac, ClSacConfig, ControlStep, Failsafe, PwmMap, SetpointQueue
from autopilot.step import TRANSFER_TAU_S, ProfileSetpoints
from sitl import Aircraft


def _square(t: float) -> float:
    return math.radians(10.0) if (t % 10.0) < 5.0 else -math.radians(10.0)


@pytest.mark.parametrize("pwm", [None, PwmMap()])
def test_step_equals_a_procedural_loop(pwm):
    """Law, limit, PWM map and the five metrics (docs/spec.md, "Metrics") recomputed by hand."""
    cfg = ClSacConfig()
    step = ControlStep(cfg, pwm, ProfileSetpoints(_square))
    law = ClSac(cfg)
    ac1, ac2 = Aircraft(), Aircraft()
    dt = cfg.dt
    ise_ref = ise_crm = energy = tv = umax = 0.0
    u_prev = None
    for k in range(1500):
        t = k * dt
        r = step(t, ac1.phi)
        u_cmd = law(ac2.phi, _square(t))
        u = u_cmd if pwm is None else pwm.to_rad(pwm.to_pwm(u_cmd))
        assert (r.k, r.t, r.um, r.u_cmd, r.u, r.failsafe) == (k + 1, t, _square(t), u_cmd, u, Failsafe.NONE)
        assert r.pwm == (None if pwm is None else pwm.to_pwm(u_cmd))
        ise_ref += (ac2.phi - law.ym_ol) ** 2 * dt
        ise_crm += law.e**2 * dt
        energy += u * u * dt
        tv += 0.0 if u_prev is None else abs(u - u_prev)
        umax = max(umax, abs(u))
        u_prev = u
        ac1.advance(r.u, 10)
        ac2.advance(u, 10)
    got = step.metrics.result()
    for name, want in (("ise_ref", ise_ref), ("ise_crm", ise_crm), ("energy", energy), ("tv", tv), ("max_abs_u", umax)):
        assert got[name] == pytest.approx(want, rel=1e-12, abs=1e-15), name
    if pwm is not None:  # the law's own command, before quantisation, is scored apart
        assert step.metrics_commanded.result()["energy"] != got["energy"]


def test_setpoint_queue_makes_the_last_due_point_the_command():
    q = SetpointQueue(limit=4)
    assert q.at(0.0) == 0.0  # nothing scheduled: 0 (wings level)
    assert q.push(20_000.0, 0.2) and q.push(10_000.0, 0.1) and q.push(30_000.0, 0.3)  # out of order
    assert q.at(0.005) == 0.0
    assert q.at(0.01) == 0.1  # due exactly at its time
    assert q.at(0.025) == 0.2
    assert q.at(0.02) == 0.2  # time going back does not bring points back
    assert q.push(40_000.0, 0.4) and q.push(50_000.0, 0.5) and q.push(60_000.0, 0.6)
    assert not q.push(70_000.0, 0.7)  # limit of 4 waiting points reached: refused, nothing queued
    assert len(q) == 4 and q.at(1.0) == 0.6


def test_wings_level_flies_a_zero_command():
    step = ControlStep(ClSacConfig(), PwmMap(), ProfileSetpoints(lambda t: 0.3))
    r = step(0.0, 0.0, wings_level=True)
    assert r.um == 0.0 and step.setpoints.current == 0.0 and r.failsafe is Failsafe.NO_SETPOINT
    assert step(0.01, 0.0).um == 0.3


@pytest.mark.parametrize(
    ("phi", "cmd", "failsafe"),
    [
        (math.nan, 0.1, Failsafe.NO_ATTITUDE),
        (math.inf, 0.1, Failsafe.NO_ATTITUDE),
        (0.0, math.nan, Failsafe.NO_SETPOINT),
    ],
)
def test_a_nonfinite_input_is_flown_as_a_hold_and_never_scored(phi, cmd, failsafe):
    step = ControlStep(ClSacConfig(), PwmMap(), ProfileSetpoints(lambda t: cmd))
    r = step(0.0, phi)
    assert (r.u, r.pwm, r.failsafe) == (0.0, 1500, failsafe)
    assert step.nonfinite_inputs == 1 and step.metrics.n == 0 and step.law.frozen
    assert all(math.isfinite(v) for v in step.metrics.result().values())


def test_hold_is_neutral_and_unscored():
    step = ControlStep(ClSacConfig(), PwmMap(pwm_trim=1520, pwm_min=1020, pwm_max=2020))
    step(0.0, 0.01)
    r = step.hold(0.01, 0.02)
    assert (r.k, r.u, r.pwm, r.failsafe, step.metrics.n) == (2, 0.0, 1520, Failsafe.NO_ATTITUDE, 1)
    step.reset()
    assert step.k == 0 and step.metrics.n == 0 and not step.law.frozen


# ------------------------------------------------------------------------------------- bumpless transfer clamp
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_bumpless_transfer_is_clamped_at_the_rudder_limit(sign):
    """MANUAL at full rudder, then the law: the command starts at the limit and joins the law's own command
    exponentially (offset * exp(-dt / TRANSFER_TAU_S) per step), never beyond +-u_limit, while the law's command
    plus the offset would pass the limit (the clamp is exercised, not only allowed)."""
    step = ControlStep(ClSacConfig(), setpoints=ProfileSetpoints(lambda t: sign * 0.4))
    lim = step.config.u_limit_rad
    step.manual = sign * lim
    for k in range(20):  # the ground station's full rudder
        assert step(k * 0.01, 0.0).u == sign * lim
    step.manual = None
    step.transfer()
    decay = math.exp(-0.01 / TRANSFER_TAU_S)
    offset = None
    clamped = 0
    for j in range(60):
        r = step((20 + j) * 0.01, 0.0)
        law_u = step.law.u  # the law's own command this step (what flew is r.u)
        if offset is None:
            offset = sign * lim - law_u  # the first command is the last one flown
        unclamped = law_u + offset * decay**j
        clamped += abs(unclamped) > lim
        assert r.u == pytest.approx(max(-lim, min(lim, unclamped)), abs=1e-12), j
        assert abs(r.u) <= lim
    assert clamped >= 1  # the law's command plus the offset went past the limit at least once
    assert abs(r.u - step.law.u) < 0.1 * lim  # and the transfer has nearly joined the law
