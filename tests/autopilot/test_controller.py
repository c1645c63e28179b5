"""The CL-SAC controller against hand computation, an independent plain-SAC implementation, and its limits."""

import math

import numpy as np
import pytest
from scipy.linalg import expm

from autopilot.clsac import TELEMETRY_FIELDS, ClSac
from autopilot.config import ClSacConfig, ConfigError, NonFiniteInputError

T = 0.01  # 100 Hz


def test_two_steps_equal_hand_computation():
    """Paper values (Am=-5, Bm=5, Lv=20, Gammas=10, sigma=5, D(s)=10/(4s+40)), from rest, by hand."""
    ctrl = ClSac(ClSacConfig())
    y0, um0 = 0.02, 0.17
    u0 = ctrl(y0, um0)
    # Step 0: x_m = 0, PFC = 0, K_I = 0, so y_a = y0, e = -y0, K_pe = 10 e^2, K_px = 0, K_pu = 10 e um.
    e0 = -y0
    assert ctrl.e == e0 and ctrl.ya == y0 and ctrl.ym == 0.0
    assert ctrl.kpe == pytest.approx(10 * e0**2, rel=1e-15)
    assert ctrl.kpu == pytest.approx(10 * e0 * um0, rel=1e-15)
    assert u0 == pytest.approx(10 * e0**3 + 10 * e0 * um0**2, rel=1e-14)

    # Integral gains after step 0 (used by step 1): K_Ie = (1-e^{-5T})/5 * 10 e0^2, K_Ix = T*10*e0*x_m(0) = 0,
    # K_Iu = T*10*e0*um0.
    kie1 = (1 - math.exp(-5 * T)) / 5 * 10 * e0**2
    kiu1 = T * 10 * e0 * um0
    assert ctrl.kie == ctrl.kix == ctrl.kiu == 0.0  # step 0 used K_I(0) = 0 ...
    assert ctrl.ki_e == pytest.approx(kie1, rel=1e-12)  # ... and carries these to step 1
    assert ctrl.ki_x == 0.0
    assert ctrl.ki_u == pytest.approx(kiu1, rel=1e-12)

    y1, um1 = 0.03, 0.17
    ctrl(y1, um1)
    # PFC after one held step: D(s) = 2.5/(s+10) so y_d(T) = 0.25 (1 - e^{-10T}) u0 for any realisation.
    y_pfc1 = 0.25 * (1 - math.exp(-10 * T)) * u0
    assert ctrl.y_pfc == pytest.approx(y_pfc1, rel=1e-12)
    # Closed-loop model x_m' = -25 x_m + 5 um + 20 ya with inputs held: exact solution from 0.
    xm1 = (1 - math.exp(-25 * T)) / 25 * (5 * um0 + 20 * y0)
    assert ctrl.ym == pytest.approx(xm1, rel=1e-12)
    # Open-loop model x' = -5 x + 5 um.
    assert ctrl.ym_ol == pytest.approx((1 - math.exp(-5 * T)) * um0, rel=1e-12)
    # Step 1 output.
    ya1 = y1 + y_pfc1
    e1 = xm1 - ya1
    ke = 10 * e1 * e1 + kie1
    kx = 10 * e1 * xm1
    ku = 10 * e1 * um1 + kiu1
    assert ctrl.e == pytest.approx(e1, rel=1e-12)
    assert ctrl.u == pytest.approx(ke * e1 + kx * xm1 + ku * um1, rel=1e-11)
    assert (ctrl.ke, ctrl.kx, ctrl.ku) == pytest.approx((ke, kx, ku), rel=1e-11)
    assert (ctrl.kie, ctrl.kiu) == pytest.approx((kie1, kiu1), rel=1e-12)  # the integral parts step 1 used


def _plain_sac_run(ys, ums, gamma=10.0, sigma=5.0, umax=math.radians(30)):
    """Paper section 2 SAC written procedurally, with no L_v term anywhere (independent of ClSac)."""
    blk = np.zeros((2, 2))
    blk[0, 0] = -5.0
    blk[0, 1] = 5.0
    E = expm(blk * T)
    phi_m, g_m = E[0, 0], E[0, 1]
    blk = np.zeros((2, 2))
    blk[0, 0] = -10.0
    blk[0, 1] = 1.0  # D(s) = 2.5/(s+10) = 10/(4s+40)
    E = expm(blk * T)
    phi_d, g_d = E[0, 0], E[0, 1]
    decay = math.exp(-sigma * T)
    gain_ie = (1.0 - decay) / sigma
    xm = xd = kie = kix = kiu = 0.0
    out = []
    for y, um in zip(ys, ums):
        ya = y + 2.5 * xd
        e = xm - ya
        ke = e * e * gamma + kie
        kx = e * xm * gamma + kix
        ku = e * um * gamma + kiu
        u_raw = ke * e + kx * xm + ku * um
        u = min(max(u_raw, -umax), umax)
        kie = decay * kie + gain_ie * (e * e * gamma)
        kix = kix + T * (e * xm * gamma)
        kiu = kiu + T * (e * um * gamma)
        xm = phi_m * xm + g_m * um
        xd = phi_d * xd + g_d * u
        out.append((u, e, xm))
    return np.array(out)


def test_lv_zero_is_plain_sac():
    """CL-SAC with L_v = 0 reproduces an independent plain-SAC implementation (no saturation reached)."""
    rng = np.random.default_rng(3)
    ys = rng.normal(0, 0.05, 400)
    ums = np.where((np.arange(400) // 100) % 2 == 0, 0.17, -0.17)
    ref = _plain_sac_run(ys, ums)
    ctrl = ClSac(ClSacConfig.sac())
    got = np.array([(ctrl(y, um), ctrl.e, ctrl.xm) for y, um in zip(ys, ums)])
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-15)


def test_lv_zero_reference_model_is_bit_identical_to_open_loop():
    # SAC is CL-SAC with L_v = 0 exactly: the closed-loop model collapses bit for bit onto the open-loop one,
    # whatever the plant does (here a random measured roll, saturating the command at times).
    rng = np.random.default_rng(5)
    a = ClSac(ClSacConfig(lv=0.0))
    b = ClSac(ClSacConfig.sac())
    for k in range(3000):
        y, um = float(rng.normal(0, 0.3)), (0.17 if (k // 500) % 2 == 0 else -0.17)
        ua, ub = a(y, um), b(y, um)
        assert ua == ub
        assert a.ym == a.ym_ol
        assert a.telemetry() == b.telemetry()


def test_fast_path_equals_matrix_path():
    # The scalar SISO path and the general m x m numpy path are two codings of the same law.
    rng = np.random.default_rng(11)
    fast, mat = ClSac(ClSacConfig()), ClSac(ClSacConfig(), fast=False)
    assert fast._fast and not mat._fast
    for k in range(2000):
        y, um = float(rng.normal(0, 0.2)), (0.17 if (k // 300) % 2 == 0 else -0.17)
        uf = fast(y, um)
        um_ = mat(y, um)
        assert uf == pytest.approx(float(um_[0]), rel=1e-12, abs=1e-15)
    for name in ("ki_e", "ki_x", "ki_u", "xm"):
        assert float(np.ravel(getattr(mat, name))[0]) == pytest.approx(getattr(fast, name), rel=1e-12)


def test_mimo_two_channels_run_and_shapes():
    cfg = ClSacConfig(
        am=((-5.0, 0.0), (0.0, -4.0)),
        bm=((5.0, 0.0), (0.0, 4.0)),
        cm=((1.0, 0.0), (0.0, 1.0)),
        lv=((20.0, 0.0), (0.0, 10.0)),
    )
    assert cfg.dims() == (2, 2, 2) and not cfg.is_siso
    ctrl = ClSac(cfg)
    u = ctrl([0.01, -0.02], [0.1, 0.05])
    assert u.shape == (2,) and ctrl.ke.shape == (2, 2) and ctrl.kx.shape == (2, 2)
    # Channel 2 of the reference model uses its own Am, Bm, Lv: hand-check x_m2 after one step.
    ya2 = -0.02
    a2 = -4.0 - 10.0
    assert ctrl.xm[1] == pytest.approx((math.exp(a2 * T) - 1) / a2 * (4.0 * 0.05 + 10.0 * ya2), rel=1e-12)


def test_saturation_clips_and_pfc_sees_the_applied_command():
    cfg = ClSacConfig(gamma_pe=1e6, gamma_px=1e6, gamma_pu=1e6)
    ctrl = ClSac(cfg)
    applied = []
    pfc = []
    for k in range(200):
        u = ctrl(0.0 if k < 50 else -0.3, 0.17)
        applied.append(u)
        pfc.append(ctrl.y_pfc)
        assert abs(u) <= cfg.u_limit_rad
    assert any(abs(a) == cfg.u_limit_rad for a in applied)
    # Independent PFC: y_d[k] from the applied sequence through D(s) = 2.5/(s+10) discretised with ZOH.
    ad, bd = math.exp(-10 * T), (1 - math.exp(-10 * T)) / 10
    xd, expect = 0.0, []
    for u in applied:
        expect.append(2.5 * xd)
        xd = ad * xd + bd * u
    np.testing.assert_allclose(pfc, expect, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("anti_windup", [True, False])
def test_integral_gains_do_not_wind_up_while_saturated(anti_windup):
    # Plant output stuck far below the command: e > 0 stays, u_raw >> limit.  With anti-windup the
    # x and u integral gains stop growing while saturated; without it they keep integrating.
    ctrl = ClSac(ClSacConfig(lv=0.0, u_limit_rad=1e-4, anti_windup=anti_windup))
    for _ in range(50):
        ctrl(0.0, 0.17)
    assert ctrl.saturated
    kiu_before = ctrl.kiu
    for _ in range(100):
        ctrl(0.0, 0.17)
    if anti_windup:
        assert ctrl.kiu == kiu_before
    else:
        assert ctrl.kiu > kiu_before * 1.5


def test_hold_freezes_adaptation_and_drives_pfc():
    ctrl = ClSac()
    for _ in range(20):
        ctrl(0.01, 0.17)
    gains = (ctrl.ki_e, ctrl.ki_x, ctrl.ki_u, ctrl.xm)
    y_before = ctrl.y_pfc
    for _ in range(100):
        ctrl.hold(0.0)
    assert ctrl.frozen
    assert (ctrl.ki_e, ctrl.ki_x, ctrl.ki_u, ctrl.xm) == gains
    ctrl(0.01, 0.17)
    assert abs(ctrl.y_pfc) < abs(y_before) * math.exp(-10 * 0.9)  # decayed with the D(s) pole at -10
    assert not ctrl.frozen


def test_reset_restarts_identically():
    ctrl = ClSac()
    seq = [(0.01 * k, 0.17) for k in range(50)]
    first = [ctrl(y, um) for y, um in seq]
    ctrl.reset()
    assert ctrl.ki_e == ctrl.ki_x == ctrl.ki_u == 0.0 and ctrl.u == 0.0
    assert [ctrl(y, um) for y, um in seq] == first


def test_telemetry_tuple_matches_fields():
    ctrl = ClSac()
    ctrl(0.01, 0.1)
    values = ctrl.telemetry()
    assert len(values) == len(TELEMETRY_FIELDS)
    for name, value in zip(TELEMETRY_FIELDS, values):
        assert value == getattr(ctrl, name), name
    for _ in range(3):
        ctrl(0.02, 0.1)
    assert ctrl.kie > 0 and ctrl.ke == ctrl.kpe + ctrl.kie  # each gain = its P part + the I part of the same step
    assert ctrl.kx == ctrl.kpx + ctrl.kix and ctrl.ku == ctrl.kpu + ctrl.kiu


@pytest.mark.parametrize("field", ["gamma_pe", "gamma_ie", "gamma_px", "gamma_ix", "gamma_pu", "gamma_iu"])
@pytest.mark.parametrize("value,ok", [(0.0, True), (1e-12, True), (-1e-12, False), (-10.0, False)])
def test_gamma_sign_boundary(field, value, ok):
    if ok:
        ClSacConfig(**{field: value})
    else:
        with pytest.raises(ConfigError, match=rf"{field}.*{value!r}".replace("(", r"\(").replace(")", r"\)")):
            ClSacConfig(**{field: value})


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"control_rate_hz": 0.0}, "control_rate_hz.*0.0"),
        ({"control_rate_hz": -100.0}, "control_rate_hz.*-100.0"),
        ({"control_rate_hz": float("inf")}, "control_rate_hz"),
        ({"sigma": -1.0}, "sigma.*-1.0"),
        ({"lv": -5.0}, "lv.*-5.0"),
        ({"am": 0.5}, "am must be Hurwitz.*0.5"),
        ({"lv": 5.0, "am": 1.0}, "am must be Hurwitz"),
        ({"u_limit_rad": 0.0}, "u_limit_rad.*0.0"),
        ({"pfc_num": (1.0, 2.0), "pfc_den": (1.0, 3.0)}, "strictly proper"),
        ({"pfc_den": (4.0, -40.0)}, "stable"),
        ({"pfc_num": ("a",)}, "pfc_num"),
        ({"pfc_num": (float("nan"),)}, "finite"),
    ],
)
def test_bad_config_names_the_offending_value(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        ClSacConfig(**kwargs)


@pytest.mark.parametrize("y,um", [(float("nan"), 0.1), (0.0, float("inf")), (-float("inf"), 0.0)])
def test_non_finite_inputs_are_rejected_without_changing_state(y, um):
    ctrl = ClSac()
    ctrl(0.01, 0.1)
    before = ctrl.telemetry(), ctrl.xm, ctrl.ki_e
    with pytest.raises(NonFiniteInputError, match="finite"):
        ctrl(y, um)
    assert (ctrl.telemetry(), ctrl.xm, ctrl.ki_e) == before


@pytest.mark.parametrize(
    "num,den", [((10.0,), (4.0, 40.0)), ((1.0, 2.0), (1.0, 3.0, 5.0)), ((3.0,), (2.0, 1.0, 4.0, 7.0))]
)
def test_pfc_realisation_has_the_given_transfer_function(num, den):
    from scipy.signal import ss2tf

    from autopilot.clsac import pfc_state_space

    a, b, c = pfc_state_space(num, den)
    n2, d2 = ss2tf(a, b, c, np.zeros((1, 1)))
    np.testing.assert_allclose(d2, np.asarray(den) / den[0], rtol=1e-12)
    k = len(num)
    np.testing.assert_allclose(n2[0][-k:], np.asarray(num) / den[0], rtol=1e-12)
    np.testing.assert_allclose(n2[0][:-k], 0.0, atol=1e-12)  # leading terms vanish: strictly proper


def test_higher_order_pfc_runs_on_the_general_path():
    # A second-order PFC: the SISO loop falls back to the matrix path, and its y_pfc is D(s) = 10/(s^2+12s+20)
    # driven by the applied commands, checked against scipy's own ZOH discretisation of that transfer function.
    from scipy.signal import cont2discrete, dlsim, tf2ss

    ctrl = ClSac(ClSacConfig(pfc_num=(10.0,), pfc_den=(1.0, 12.0, 20.0)))
    assert not ctrl._fast
    applied, pfc = [], []
    for k in range(200):
        u = ctrl(0.01 * math.sin(0.1 * k), 0.17)
        applied.append(float(u[0]))
        pfc.append(float(ctrl.y_pfc[0]))
    ad, bd, cd, dd, _ = cont2discrete(tf2ss((10.0,), (1.0, 12.0, 20.0)), T, method="zoh")
    _, y, _ = dlsim((ad, bd, cd, dd, T), np.array(applied))
    # y_pfc[k] is D's output before u[k] acts (strictly proper, dd = 0): the ZOH response to u[0..k-1].
    np.testing.assert_allclose(pfc, y.ravel(), rtol=1e-9, atol=1e-12)
    assert max(abs(v) for v in pfc) > 1e-4  # the PFC was really driven
