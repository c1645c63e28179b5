"""Mid-flight faults (sitl.damage) on the linear plants, against independent numbers: a continuous-time solver
(scipy's DOP853 on the matrices written out here), the servo's analytic step response (paper eq. (65)), the
eigenvalues of a hand-built A_lp; the spec, the schedule and the ground station's table against their rules."""

from __future__ import annotations

import math
import socket
import time

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from autopilot.shared import servo_failures as sf
from autopilot.shared.mavlink import mavlink as M
from autopilot.shared.pwm import PwmMap
from sitl import damage, model
from sitl import plant as plants
from sitl.aircraft import Aircraft
from sitl.damage import Effect, FaultSpecError

DT = 1e-3
WN2, TZW = model.SERVO_WN2, model.SERVO_2ZETA_WN
A_LP = np.array([[-3.34, 1.93, -7.55, 7.82], [-40.5, -2.22, 2.48, 0.0], [234.0, -2.84, -27.0, 0.0], [0, 1, 0.268, 0]])
B_LP = np.array([-8.41, 59.7, 793.0, 0.0])  # paper section 5, written out again here


def _augmented(a_lp, b_lp):
    a = np.zeros((6, 6))
    a[:4, :4] = a_lp
    a[:4, 4] = b_lp
    a[4, 5] = 1.0
    a[5, 4], a[5, 5] = -WN2, -TZW
    b = np.zeros(6)
    b[5] = WN2
    return a, b


def _servo_step(t):
    """The servo's unit step response (eq. (65): delta'' + 2 zeta wn delta' + wn^2 delta = wn^2 u), analytic."""
    wn = math.sqrt(WN2)
    zeta = TZW / (2 * wn)
    wd = wn * math.sqrt(1 - zeta**2)
    t = np.asarray(t, dtype=float)
    out = 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta * wn / wd * np.sin(wd * t))
    return np.where(t > 0, out, 0.0)


def _fly(ac, u, n):
    """n physics steps one frame (10 steps) at a time, the truth after each step group."""
    out = []
    for _ in range(n // 10):
        ac.advance(u, 10)
        out.append(ac.truth.copy())
    return np.array(out)


# ---------------------------------------------------------------------------------------------- the spec
@pytest.mark.parametrize(
    "spec,kind,value,start,end",
    [
        ("effectiveness=0.3@10", "effectiveness", 0.3, 10.0, None),
        ("stuck@2.5:7", "stuck", None, 2.5, 7.0),
        ("stuck=-5@0", "stuck", math.radians(-5), 0.0, None),
        ("off@1", "off", None, 1.0, None),
        ("rate=20@10", "rate", math.radians(20), 10.0, None),
        ("delay=0.06@3", "delay", 0.06, 3.0, None),
        ("delay=0@3", "delay", 0.0, 3.0, None),
        ("damping=2@0:1e3", "damping", 2.0, 0.0, 1000.0),
        ("inertia=1.58@5", "inertia", 1.58, 5.0, None),
        ("cg=-0.1@5", "cg", -0.1, 5.0, None),
        ("airspeed=63@5", "airspeed", 63 * 1852 / 3600, 5.0, None),
    ],
)
def test_a_spec_gives_its_kind_si_value_and_times(spec, kind, value, start, end):
    f = damage.parse(spec)
    assert (f.kind, f.start, f.end, f.source) == (kind, start, end, "command line")
    assert f.value == pytest.approx(value, rel=1e-15) if value is not None else f.value is None
    assert damage.parse(f.spec) == f  # the spec back parses to the same fault


@pytest.mark.parametrize(
    "spec,needle",
    [
        ("effectiveness=-1@10", "effectiveness must be > 0 and at most 10, got -1"),
        ("effectiveness=0@10", "effectiveness must be > 0"),
        ("effectiveness=10.5@10", "effectiveness must be > 0 and at most 10, got 10.5"),
        ("effectiveness=1e308@10", "at most 10"),
        ("damping=11@1", "damping must be > 0 and at most 10"),
        ("inertia=10.01@1", "inertia must be at most 10"),
        ("stuck=1000@1", "stuck must be within +-90 deg, got 1000"),
        ("stuck=-90.5@1", "stuck must be within +-90 deg"),
        ("rate=1000.5@1", "rate must be > 0 and at most 1000 deg/s"),
        ("airspeed=1e6@1", "airspeed must be > 0 and at most 5000 kt"),
        ("delay=10.001@1", "delay must be in [0, 10] s"),
        ("stuck@1e308", "START must be at most 1e+06 s, got 1e308"),
        ("stuck@1:1e308", "END must be at most 1e+06 s"),
        ("stuck=1e309@1", "must be finite"),
        ("effectiveness=0.3@\uff11\uff10", "START must be a number in ASCII digits"),  # fullwidth 10
        ("effectiveness=0.3@\u0661\u0660", "START must be a number in ASCII digits"),  # Arabic-Indic 10
        ("effectiveness=0.3@1_0", "START must be a number in ASCII digits"),
        ("effectiveness=0.\uff13@1", "value must be a number in ASCII digits"),
        ("stuck@1:\uff12", "END must be a number in ASCII digits"),
        ("effectiveness=inf@10", "must be finite"),
        ("effectiveness=nan@10", "must be finite"),
        ("bogus@1", "unknown kind 'bogus'"),
        ("effectiveness=0.3@nan", "START must be finite"),
        ("stuck@-5", "START must be >= 0 s, got -5"),
        ("rate=0@1", "rate must be > 0 and at most 1000 deg/s, got 0"),
        ("effectiveness=0.3", "missing @START"),
        ("rate@1", "rate needs a value"),
        ("off=3@1", "off takes no value"),
        ("stuck@10:10", "END must be after START"),
        ("stuck@10:nan", "END must be finite"),
        ("delay=-0.1@1", "delay must be in [0, 10] s"),
        ("inertia=0.5@1", "must be >= 1"),
        ("damping=x@1", "must be a number"),
    ],
)
def test_a_bad_spec_is_refused_with_its_reason(spec, needle):
    with pytest.raises(FaultSpecError, match=None) as exc:
        damage.parse(spec)
    assert needle in str(exc.value) and spec in str(exc.value)


@pytest.mark.parametrize(
    "plant,spec,needle",
    [
        ("kh2013a", "inertia=1.5@1", "inertia=1.5@1 cannot fly on --plant kh2013a"),
        ("kh2013a", "airspeed=60@1", "cannot fly on --plant kh2013a"),
        ("jsbsim:c172x", "cg=3@1", "half the half span"),
    ],
)
def test_a_kind_the_plant_cannot_fly_is_refused_before_anything_starts(plant, spec, needle):
    with pytest.raises(plants.PlantError) as exc:
        plants.check_faults(plant, [damage.parse(spec)])
    assert needle in str(exc.value)


def test_damping_needs_a_roll_rate_state(tmp_path):
    tf = tmp_path / "tf.toml"
    tf.write_text("[airframe]\nnum = [50.0]\nden = [1.0, 5.0, 0.0]\n[servo]\nwn2 = 2367.0\ntwo_zeta_wn = 72.22\n")
    with pytest.raises(plants.PlantError, match="not one of its states"):
        plants.check_faults(str(tf), [damage.parse("damping=0.5@1")])
    plants.check_faults(str(tf), [damage.parse("effectiveness=0.5@1"), damage.parse("stuck@1")])
    plants.check_faults(str(plants.shipped("kh2013a.toml")), [damage.parse("damping=0.5@1")])


# ---------------------------------------------------------------------------------------------- the schedule
def test_the_schedule_cuts_at_starts_and_ends_on_the_physics_grid():
    s = damage.Schedule([damage.parse("rate=20@0.0125:0.02"), damage.parse("effectiveness=0.5@0.015")], 0.0, DT)
    assert [(f.kind, s0, e0) for f, s0, e0 in s.entries] == [("rate", 13, 20), ("effectiveness", 15, None)]
    segs = s.segments(10, 20)
    assert [m for m, _ in segs] == [3, 2, 5, 10] and sum(m for m, _ in segs) == 20
    assert [[(f.kind, st) for f, st in ch] for _m, ch in segs] == [[], [("rate", True)], [("effectiveness", True)],
                                                                     [("rate", False)]]  # fmt: skip
    assert s.effect(14) == Effect(rate=math.radians(20))
    assert s.effect(19) == Effect(rate=math.radians(20), effectiveness=0.5)
    assert s.effect(20) == Effect(effectiveness=0.5)
    # A flight whose clock starts at 4290 s: a fault at 4290.5 s is 500 steps in, one before the start at step 0.
    late = damage.Schedule([damage.parse("off@4290.5"), damage.parse("stuck@1")], 4290.0, DT)
    assert [e[1] for e in late.entries] == [500, 0]
    # A ground station's faults end together when it clears them, the command line's stay.
    g = damage.Schedule([damage.parse("damping=2@0")], 0.0, DT)
    g.add(damage.Fault("off", None, 0.1, None, damage.GROUND_STATION), 100)
    assert g.clear(damage.GROUND_STATION, 250) == 1
    assert g.effect(249) == Effect(damping=2.0, off=True) and g.effect(250) == Effect(damping=2.0)
    assert g.records(300)[1] | {} == {
        "kind": "off", "surface": None, "value": None, "unit": None, "start": 0.1, "end": 0.25,
        "source": "ground station", "spec": "off@0.1:0.25", "started": True,
    }  # fmt: skip


def test_a_clear_ends_a_fault_whose_end_is_ahead_and_one_not_yet_started():
    g = damage.Schedule([], 0.0, DT)
    g.add(damage.Fault("stuck", math.radians(3), 0.1, 2.0, damage.GROUND_STATION), 100)  # ends at 2 s
    g.add(damage.Fault("rate", math.radians(20), 0.5, None, damage.GROUND_STATION), 500)  # starts at 0.5 s
    g.add(damage.Fault("off", None, 0.05, 0.12, damage.GROUND_STATION), 50)  # already over
    assert g.clear(damage.GROUND_STATION, 300) == 2
    assert g.effect(299) == Effect(stuck=True, stuck_at=math.radians(3))
    assert g.effect(300) == damage.NOMINAL and g.effect(600) == damage.NOMINAL  # neither is active after it
    assert [(r["start"], r["end"], r["started"]) for r in g.records(400)] == [
        (0.1, 0.3, True), (0.5, 0.5, False), (0.05, 0.12, True)
    ]  # fmt: skip


def test_a_rejam_at_a_new_angle_takes_the_new_angle():
    s = damage.Schedule([damage.parse("stuck=3@0.1"), damage.parse("stuck=7@0.2:0.3")], 0.0, DT)
    assert s.effect(150).stuck_at == math.radians(3) and s.effect(250).stuck_at == math.radians(7)
    assert s.effect(300).stuck_at == math.radians(3)  # the second ends: the first's angle is the newest active
    assert damage.jammed(s.effect(150), s.effect(250), math.radians(3)) == math.radians(7)
    # the plant flown through the schedule: the surface at each angle from the step each jam starts
    ac = Aircraft()
    fly = damage.ScheduledEffects(ac, s)
    for k, want in ((100, None), (100, 3.0), (100, 7.0), (100, 3.0)):
        fly.advance(math.radians(-10), k)
        if want is not None:
            assert ac.truth[4] == pytest.approx(math.radians(want), abs=1e-12)


@pytest.mark.parametrize(
    "delay,dt,steps", [(0.03, 0.01, 3), (0.29, 0.01, 29), (0.043, 0.001, 43), (0.059, 0.001, 59), (0.0006, 0.001, 1)]
)
def test_a_delay_is_rounded_to_the_nearest_whole_step(delay, dt, steps):
    # 0.29 / 0.01 is 28.999999999999996 in floating point, 0.043 / 0.001 42.99999999999999: floored, one step short
    act = damage.Actuator(Effect(delay=delay), dt, u_last=-1.0)
    assert act.delay_steps == steps
    out = [act.command(float(k)) for k in range(steps + 2)]
    assert out == [-1.0] * steps + [0.0, 1.0]  # the command of `steps` steps before, the held one first


def test_the_study_rounds_a_delay_to_whole_control_periods():
    from tools.experiment.study import faults as study_faults

    for spec, steps in (("delay=0.03@0.5", 3), ("delay=0.29@0.5", 29), ("delay=0.57@0.5", 57)):  # 0.57/0.01: 56.99..
        plan = study_faults.plan([damage.parse(spec)], 100, 0.01)
        assert [(p.start, p.delay) for p in plan.phases] == [(50, steps)]


def test_the_faults_of_two_surfaces_by_name():
    names = ("aileron", "rudder")
    gs = damage.GROUND_STATION
    s = damage.Schedule([damage.parse("effectiveness=0.5@0"), damage.parse("delay=0.02@0")], 0.0, DT, names)
    s.add(damage.Fault("stuck", math.radians(5), 0.1, None, gs, "rudder"), 100)
    s.add(damage.Fault("off", None, 0.2, None, gs, damage.ALL), 200)
    e = s.effect(150)
    assert (e.effectiveness, e.delay, e.stuck) == (0.5, 0.02, False)  # the command line's: the first surface's
    assert e.second == Effect(stuck=True, stuck_at=math.radians(5))
    e = s.effect(250)
    assert e.off and e.second == Effect(stuck=True, stuck_at=math.radians(5), off=True)
    assert [r["surface"] for r in s.records(300)] == ["aileron", "aileron", "rudder", "aileron+rudder"]
    assert s.clear(gs, 300, 0) == 1  # the aileron's (the one on all): the rudder's own stays
    assert s.effect(300).second == Effect(stuck=True, stuck_at=math.radians(5)) and not s.effect(300).off
    assert damage.Schedule([damage.parse("damping=2@0")], 0.0, DT, names).records(1)[0]["surface"] is None
    text = damage.status_text(damage.Fault("stuck", math.radians(5), 0.1, None, gs, "rudder"), True, 0.1, "rudder")
    assert text == "fault start t=0.100: stuck=5 on the rudder (ground station)"


def test_faults_active_together_combine():
    fs = [damage.parse(s) for s in ("effectiveness=0.5@0", "effectiveness=0.5@0", "rate=30@0", "rate=20@0")]
    fs += [damage.parse(s) for s in ("delay=0.02@0", "delay=0.03@0", "stuck@0", "stuck=3@0", "cg=0.1@0", "cg=0.05@0")]
    e = damage.combine(fs)
    assert e.effectiveness == 0.25 and e.rate == math.radians(20) and e.delay == pytest.approx(0.05)
    assert e.stuck and e.stuck_at == math.radians(3) and e.cg == pytest.approx(0.15) and not e.nominal
    assert damage.combine([]).nominal


# ---------------------------------------------------------------------------------------------- the KH2013A
def test_effectiveness_is_flying_the_plant_with_b_scaled():
    """A 5 deg rudder command from t = 0, effectiveness 0.3 from t = 1 s: the plant as a continuous-time system
    whose B_lp column is scaled by 0.3 from t = 1 s (DOP853, tolerance 1e-12)."""
    u, f, t1, t2 = math.radians(5), 0.3, 1.0, 2.0
    ac = Aircraft()
    sched = damage.Schedule([damage.parse(f"effectiveness={f}@{t1}")], 0.0, DT)
    rows = []
    for _ in range(int(t2 / 0.01)):
        for m, ch in sched.segments(ac.steps, 10):
            if ch:
                ac.set_effect(sched.effect(ac.steps))
            ac.advance(u, m)
        rows.append(ac.truth.copy())
    a0, b = _augmented(A_LP, B_LP)
    a1, _ = _augmented(A_LP, f * B_LP)
    opts = dict(method="DOP853", rtol=1e-12, atol=1e-14)
    first = solve_ivp(lambda t, x: a0 @ x + b * u, (0, t1), np.zeros(6), dense_output=True, **opts)
    second = solve_ivp(lambda t, x: a1 @ x + b * u, (t1, t2), first.y[:, -1], dense_output=True, **opts)
    t = np.arange(1, len(rows) + 1) * 0.01
    want = np.array([first.sol(tk) if tk <= t1 else second.sol(tk) for tk in t])
    assert np.max(np.abs(np.array(rows)[:, 3] - want[:, 3])) < 1e-9  # roll, rad
    # the effect is real: 0.3 of the control power rolls the aircraft another way than the whole of it
    nominal = Aircraft()
    nominal.advance(u, int(t2 / DT))
    assert abs(nominal.phi - rows[-1][3]) > 1e-3


def test_a_rate_limit_makes_the_surface_ramp_at_that_rate_and_the_airframe_sees_the_ramp():
    r = math.radians(20)
    ac = Aircraft()
    ac.set_effect(damage.combine([damage.parse("rate=20@0")]))
    deltas, states = [0.0], [ac.truth.copy()]
    for _ in range(1200):  # 1.2 s of a 10 deg command, one step at a time
        ac.advance(math.radians(10), 1)
        deltas.append(float(ac.truth[4]))
        states.append(ac.truth.copy())
    slope = np.diff(deltas) / DT
    assert np.max(np.abs(slope)) <= r * (1 + 1e-12)  # never faster than the limit
    ramp = np.flatnonzero(np.abs(slope - r) < 1e-9 * r)
    assert ramp.size > 300  # a long stretch at exactly the limit (10 deg takes 0.5 s at 20 deg/s)
    assert abs(deltas[-1] - math.radians(10)) < 1e-4  # and it gets there
    # On the ramp the airframe (A_lp, B_lp) is driven by delta = delta0 + r t: the continuous-time solution.
    k0, k1 = ramp[20], ramp[20] + 200
    assert np.all(np.abs(slope[k0:k1] - r) < 1e-9 * r)
    x0, d0 = states[k0][:4], states[k0][4]
    sol = solve_ivp(
        lambda t, x: A_LP @ x + B_LP * (d0 + r * t), (0, (k1 - k0) * DT), x0, method="DOP853", rtol=1e-12, atol=1e-14
    )
    assert np.max(np.abs(sol.y[:, -1] - states[k1][:4])) < 1e-9


def test_a_delay_shifts_the_servo_response_by_that_delay():
    d, u = 0.05, math.radians(4)
    ac = Aircraft()
    ac.advance(0.0, 100)
    ac.set_effect(damage.combine([damage.parse(f"delay={d}@0")]))
    deltas = []
    for _ in range(400):
        ac.advance(u, 1)
        deltas.append(float(ac.truth[4]))
    t = np.arange(1, 401) * DT  # the command held from t = 0 (after the fault started)
    assert np.max(np.abs(np.array(deltas) - u * _servo_step(t - d))) < 1e-12
    assert max(abs(v) for v in deltas[: int(d / DT)]) == 0.0  # nothing moves for the whole delay


def test_stuck_holds_the_surface_and_off_lets_it_float_to_neutral():
    u = math.radians(6)
    ac = Aircraft()
    ac.advance(u, 3000)  # settled: delta = u, delta_dot = 0 to 1e-30
    ac.set_effect(damage.combine([damage.parse("stuck@0")]))
    x0 = ac.truth.copy()
    rows = _fly(ac, -u, 500)
    assert np.all(rows[:, 4] == x0[4]) and np.all(rows[:, 5] == 0.0)
    sol = solve_ivp(lambda t, x: A_LP @ x + B_LP * x0[4], (0, 0.5), x0[:4], method="DOP853", rtol=1e-12, atol=1e-14)
    assert np.max(np.abs(sol.y[:, -1] - rows[-1][:4])) < 1e-9  # the airframe sees the jammed deflection
    jam = Aircraft()
    jam.set_effect(damage.combine([damage.parse("stuck=-3@0")]))
    jam.advance(u, 100)
    assert jam.truth[4] == math.radians(-3) and jam.truth[5] == 0.0
    off = Aircraft()
    off.advance(u, 3000)
    d0 = float(off.truth[4])
    off.set_effect(damage.combine([damage.parse("off@0")]))
    deltas = [float(_fly(off, u, 10)[-1][4]) for _ in range(30)]
    t = np.arange(1, 31) * 0.01
    assert np.max(np.abs(np.array(deltas) - d0 * (1 - _servo_step(t)))) < 1e-12  # floats to 0 whatever u is


def test_damping_moves_the_roll_subsidence_pole():
    """L_p times 2: the KH2013A's roll subsidence pole moves from -2.445 to -4.997, the real eigenvalue of the
    hand-built A_lp with L_p = -4.44; a free motion started on that eigenvector decays exactly as e^(lambda t)."""
    f = 2.0
    a = A_LP.copy()
    a[1, 1] *= f
    lam, vec = np.linalg.eig(a)
    nominal = np.linalg.eigvals(A_LP)
    real = [i for i in range(4) if abs(lam[i].imag) < 1e-12]
    k = min(real, key=lambda i: abs(lam[i].real + 5))  # the roll subsidence mode (the other real one is spiral)
    k0 = min((i for i in range(4) if abs(nominal[i].imag) < 1e-12), key=lambda i: abs(nominal[i].real + 2.4))
    assert lam[k].real == pytest.approx(-4.997, abs=1e-3) and nominal[k0].real == pytest.approx(-2.445, abs=1e-3)
    v = np.real(vec[:, k]) / np.max(np.abs(np.real(vec[:, k])))
    ac = Aircraft(x0=np.concatenate([v, [0.0, 0.0]]))
    ac.set_effect(damage.combine([damage.parse(f"damping={f}@0")]))
    ac.advance(0.0, 500)
    assert np.max(np.abs(ac.truth[:4] - v * math.exp(lam[k].real * 0.5))) < 1e-12
    plain = Aircraft(x0=np.concatenate([v, [0.0, 0.0]]))
    plain.advance(0.0, 500)
    assert np.max(np.abs(plain.truth[:4] - v * math.exp(lam[k].real * 0.5))) > 1e-3


def test_damping_on_a_plant_file_is_its_roll_rate_term(tmp_path):
    """A one-axis plant p' = L_p p + L_d delta, phi' = p: with damping F the free roll rate decays as e^(F L_p t)."""
    lp, f, p0 = -3.0, 0.25, 0.4
    path = tmp_path / "roll.toml"
    path.write_text(
        '[airframe]\nstates = ["p", "phi"]\nA = [[-3.0, 0.0], [1.0, 0.0]]\nB = [[20.0], [0.0]]\nC = [[0.0, 1.0]]\n'
        'roll = "phi"\nroll_rate = "p"\n[servo]\nwn2 = 2367.0\ntwo_zeta_wn = 72.22\n'
    )
    ac = plants.build(str(path), 1000.0)
    ac.reset(np.array([p0, 0.0, 0.0, 0.0]))
    ac.set_effect(damage.combine([damage.parse(f"damping={f}@0")]))
    ac.advance(0.0, 800)
    t = 0.8
    assert ac.p == pytest.approx(p0 * math.exp(f * lp * t), rel=1e-12)
    assert ac.phi == pytest.approx(p0 / (-f * lp) * (1 - math.exp(f * lp * t)), rel=1e-11)


def test_the_plant_flies_as_built_again_once_the_faults_end():
    ac, ref = Aircraft(), Aircraft()
    ac.set_effect(damage.combine([damage.parse("effectiveness=0.2@0"), damage.parse("rate=5@0")]))
    ac.set_effect(damage.NOMINAL)
    for a in (ac, ref):
        a.advance(0.05, 300)
    assert np.array_equal(ac.truth, ref.truth)


# ---------------------------------------------------------------------------------------------- ground stations
@pytest.mark.parametrize(
    "params,spec",
    [
        ((102, 1, 0, 0.0), "off"),
        ((102, 2, 4, 0.0), "stuck"),
        ((102, 2, 0, math.nan), "stuck"),
        ((102, 2, 0, -7.5), "stuck=-7.5"),
        ((102, 5, 0, 0.0), "rate=20.0"),
        ((102, 5, 0, 45.0), "rate=45.0"),
        ((102, 6, 0, math.nan), "delay=0.1"),
        ((102, 6, 4, 0.25), "delay=0.25"),
        ((102, 0, 0, 0.0), None),
    ],
)
def test_the_servo_failure_table(params, spec):
    assert sf.servo_failure(*params) == spec
    if spec is not None:
        damage.parse_kind(spec, spec)  # what the table gives, the SITL's parser takes


def test_a_nan_param5_is_unset_only_when_every_unused_param_is():
    """MAVLink's NaN is "optional/default": MAVSDK's Failure plugin leaves params 4 to 7 all NaN, and a STUCK from it
    jams the surface where it is; a NaN param5 beside a number in param 4, 6 or 7 is a value, and no angle: DENIED."""
    nan = math.nan
    assert sf.servo_failure(102, 2, 4, nan, others=(nan, nan, nan)) == "stuck"
    assert sf.servo_failure(102, 6, 4, nan, others=(nan, nan, nan)) == "delay=0.1"
    for others in ((nan, 0.0, 0.0), (0.0, nan, nan), (nan, nan, 0.0)):
        for kind in (2, 5, 6):
            with pytest.raises(sf.FailureDenied, match="param5 is NaN"):
                sf.servo_failure(102, kind, 4, nan, others=others)
    assert sf.servo_failure(102, 2, 4, -3.0, others=(0.0, 0.0, 0.0)) == "stuck=-3.0"  # a number is a number
    assert sf.servo_failure(102, 0, 4, nan, others=(0.0, 0.0, 0.0)) is None  # a clear needs no value
    assert sf.servo_failure(102, 1, 4, nan, others=(0.0, 0.0, 0.0)) == "off"


@pytest.mark.parametrize(
    "params,error",
    [
        ((101, 1, 0, 0.0), sf.FailureUnsupported),  # another unit (motor)
        ((102, 3, 0, 0.0), sf.FailureUnsupported),  # GARBAGE
        ((102, 7, 0, 0.0), sf.FailureUnsupported),  # INTERMITTENT
        ((102, 1, 3, 0.0), sf.FailureUnsupported),  # another servo
        ((102, 5, 0, -5.0), sf.FailureDenied),
        ((102, 6, 0, math.inf), sf.FailureDenied),
        ((102, 6, 0, 11.0), sf.FailureDenied),
    ],
)
def test_the_servo_failure_table_refuses(params, error):
    with pytest.raises(error):
        sf.servo_failure(*params)
    assert error.result == (M.MAV_RESULT_UNSUPPORTED if error is sf.FailureUnsupported else M.MAV_RESULT_DENIED)


def _inject(sock, m, target, failure_type, param5=0.0, instance=0.0, unit=102.0, src=None):
    msg = M.MAVLink_command_long_message(1, 200, 420, 0, unit, failure_type, instance, 0, param5, 0, 0)
    sock.sendto(msg.pack(m), target)
    m.seq = (m.seq + 1) % 256


def _acks(sock, sitl, wait=0.3):
    """Poll the SITL (its link, as its loop does) and read what it sent back: (ACK results, STATUSTEXTs)."""
    parser = M.MAVLink(None)
    parser.robust_parsing = True
    acks, texts = [], []
    t_end = time.monotonic() + wait
    while time.monotonic() < t_end:
        sitl.link.poll(sitl._on_msg)
        try:
            data = sock.recv(65536)
        except BlockingIOError:
            time.sleep(0.005)
            continue
        for msg in parser.parse_buffer(data) or []:
            if msg.get_type() == "COMMAND_ACK":
                acks.append((msg.command, msg.result))
            elif msg.get_type() == "STATUSTEXT":  # a text longer than 50 characters comes in chunks of one id
                if getattr(msg, "chunk_seq", 0) > 0 and texts:
                    texts[-1] += msg.text
                else:
                    texts.append(msg.text)
    return acks, texts


def test_a_ground_station_failure_is_applied_once_acknowledged_and_recorded():
    """A real Sitl on a real UDP socket; the autopilot's SITL link (1:140) sends MAV_CMD_INJECT_FAILURE."""
    from sitl.endpoint import Sitl, SitlOptions

    sitl = Sitl(SitlOptions(listen=("127.0.0.1", 0), lockstep=True, verbose=False), PwmMap())
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    ap = M.MAVLink(None, 1, 140)
    target = sitl.link.local
    try:
        sitl._advance(math.radians(5), 1000)  # 1 s flown
        _inject(sock, ap, target, 2.0)  # stuck, where it is
        _inject(sock, ap, target, 2.0)  # the same again (its ACK lost): not applied twice
        acks, _ = _acks(sock, sitl)
        assert acks == [(420, M.MAV_RESULT_ACCEPTED)] * 2
        held = float(sitl.aircraft.truth[4])
        sitl._advance(math.radians(-5), 500)
        _a, texts = _acks(sock, sitl, 0.1)
        assert float(sitl.aircraft.truth[4]) == held
        assert texts == ["fault start t=1.000: stuck on the rudder (ground station)"]
        for unit, ftype, inst in ((101, 1, 0), (102, 3, 0), (102, 1, 9)):
            _inject(sock, ap, target, ftype, unit=unit, instance=inst)
        _inject(sock, ap, target, 5.0, param5=-3.0)
        other = M.MAVLink(None, 1, 141)  # not the autopilot's SITL link: refused by the link, no answer
        _inject(sock, other, target, 1.0)
        acks, _ = _acks(sock, sitl)
        assert acks == [(420, M.MAV_RESULT_UNSUPPORTED)] * 3 + [(420, M.MAV_RESULT_DENIED)]
        assert sitl.link.rejected["wrong_id"] == 1
        _inject(sock, ap, target, 0.0)  # OK: clear
        acks, _ = _acks(sock, sitl)
        sitl._advance(math.radians(-5), 500)
        _a, texts = _acks(sock, sitl, 0.1)
        assert acks == [(420, M.MAV_RESULT_ACCEPTED)] and texts == ["fault end t=1.500: stuck on the rudder"]
        assert float(sitl.aircraft.truth[4]) < held - 0.05  # the servo drives it again
        faults = sitl.stats()["faults"]
        assert [(f["kind"], f["start"], f["end"], f["source"], f["started"]) for f in faults] == [
            ("stuck", 1.0, 1.5, "ground station", True)
        ]
    finally:
        sock.close()
        sitl.close()
