"""Dryden turbulence, 1-cosine gust, crosswind and the aircraft's disturbance input (sitl.atmosphere, sitl.aircraft).

Statistical tolerances: the runs are seeded (so the tests are deterministic), and each bound is set at four
standard errors of the estimate, the standard error computed from the process's own autocorrelation, so a
correct filter fails with probability < 1e-4 over seeds and a filter whose variance is off by the tolerance
cannot pass.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm, solve_continuous_lyapunov
from scipy.signal import welch

from sitl import model
from sitl.aircraft import Aircraft, AircraftConfig
from sitl.atmosphere import (
    AIRSPEED,
    Atmosphere,
    AtmosphereConfig,
    AtmosphereConfigError,
    DrydenConfig,
    Gust,
    disturbance_matrix,
    noise_zoh,
)

MODERATE = DrydenConfig.intensity("moderate")
N = 2**18


def _run(cfg: DrydenConfig, dt: float, seed: int = 7) -> np.ndarray:
    return Atmosphere(AtmosphereConfig(cfg), dt, np.random.default_rng(seed)).sample(N)


FINE, COARSE = 2e-3, 0.5


@pytest.fixture(scope="module")
def fine():  # 2 ms: the roll and yaw gusts (time constants 25 ms and 18 ms) resolved, 524 s
    return _run(MODERATE, FINE)


@pytest.fixture(scope="module")
def coarse():  # 0.5 s: the side gust's 8.6 s correlation time over 1.3e5 s (15,000 correlation times)
    return _run(MODERATE, COARSE)


def _variance_tolerance(cfg: DrydenConfig, i: int, dt: float) -> float:
    """Four standard errors of the sample variance of output i: var(s^2) = 2 sum_k R(k dt)^2 / N for a Gaussian
    process, R from the continuous model (R(tau) = C e^{A tau} P C^T)."""
    a, b, c = cfg.state_space()
    p = solve_continuous_lyapunov(a, -b @ b.T)
    step = expm(a * dt)
    x = p.copy()
    r = []
    for _ in range(200000):
        r.append((c @ x @ c.T)[i, i])
        if abs(r[-1]) < 1e-6 * r[0] and len(r) > 10:
            break
        x = step @ x
    r = np.array(r)
    return 4 * math.sqrt(2 * (r[0] ** 2 + 2 * np.sum(r[1:] ** 2)) / N)


def test_intensity_tables():
    # MIL-HDBK-1797 low altitude at h = 10 m = 32.8 ft: W20 = 30 kt, sigma_w = 0.1 W20, L_w = h.
    h = 10 / 0.3048
    assert MODERATE.sigma_w == pytest.approx(0.1 * 30 * 0.514444)
    assert MODERATE.length_w == pytest.approx(10.0)
    assert MODERATE.length_v == pytest.approx(h / (0.177 + 0.000823 * h) ** 1.2 * 0.3048)
    assert MODERATE.sigma_v == pytest.approx(MODERATE.sigma_w / (0.177 + 0.000823 * h) ** 0.4)
    assert DrydenConfig.intensity("severe").sigma_v == pytest.approx(1.5 * MODERATE.sigma_v)
    assert AIRSPEED == pytest.approx(math.hypot(7.55, 1.93))
    with pytest.raises(AtmosphereConfigError, match="intensity"):
        DrydenConfig.intensity("storm")
    with pytest.raises(AtmosphereConfigError, match="altitude"):
        DrydenConfig.intensity("light", altitude=1.0)


def test_psd_integrates_to_sigma_squared():
    """The analytic spectra are the MIL-F-8785C ones: Phi_v integrates to sigma_v^2, Phi_p to sigma_p^2."""
    w = np.logspace(-5, 6, 400001)
    phi = MODERATE.psd(w)
    assert np.trapezoid(phi[0], w) == pytest.approx(MODERATE.sigma_v**2, rel=1e-3)
    assert np.trapezoid(phi[1], w) == pytest.approx(MODERATE.sigma_p**2, rel=1e-3)
    # Phi_v in MIL-F-8785C form, written out independently.
    a = MODERATE.length_v / MODERATE.airspeed
    ref = MODERATE.sigma_v**2 * a / math.pi * (1 + 3 * (a * w[:10]) ** 2) / (1 + (a * w[:10]) ** 2) ** 2
    np.testing.assert_allclose(phi[0, :10], ref)


@pytest.mark.parametrize("i", [0, 1, 2])
def test_variance_matches_definition_at_any_step(fine, coarse, i):
    a, b, c = MODERATE.state_space()
    p = solve_continuous_lyapunov(a, -b @ b.T)
    target = (c @ p @ c.T)[i, i]
    expected = [MODERATE.sigma_v**2, MODERATE.sigma_p**2, None][i]
    if expected is not None:
        assert target == pytest.approx(expected, rel=1e-9)
    runs = [(coarse, COARSE)] if i == 0 else [(fine, FINE), (coarse, COARSE)]
    for d, dt in runs:
        tol = _variance_tolerance(MODERATE, i, dt)
        assert tol < 0.05 * target  # the run is long enough for a 5 % check
        assert np.var(d[:, i]) == pytest.approx(target, abs=tol), f"output {i} at dt={dt}"


def _sampled_psd(cfg: DrydenConfig, i: int, f: np.ndarray, fs: float) -> np.ndarray:
    """One-sided PSD per Hz of the exact samples at rate fs: the continuous 2 pi Phi(2 pi f), aliased."""
    total = np.zeros_like(f)
    for m in range(-200, 201):
        total += 2 * math.pi * cfg.psd(2 * math.pi * np.abs(f + m * fs))[i]
    return total  # one-sided at f in (0, fs/2): the two-sided aliases at f + m fs, m in Z, each S_1(|.|)/2, twice


@pytest.mark.parametrize(
    ("i", "band", "which"), [(0, (0.005, 0.9), "coarse"), (1, (1.0, 100.0), "fine"), (2, (1.0, 100.0), "fine")]
)
def test_welch_psd_matches_analytic(fine, coarse, i, band, which):
    d, dt = (coarse, COARSE) if which == "coarse" else (fine, FINE)
    nperseg = 2**13
    f, s = welch(d[:, i], fs=1 / dt, nperseg=nperseg)
    ref = _sampled_psd(MODERATE, i, f, 1 / dt)
    k = 2 * N // nperseg - 1  # half-overlapping Hann segments
    edges = np.logspace(math.log10(band[0]), math.log10(band[1]), 9)
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (f >= lo) & (f < hi)
        m = int(sel.sum())
        assert m >= 4
        # Welch bin: relative variance 1.06/K (Hann, 50 % overlap); neighbouring bins correlated, so m/2 independent.
        tol = 4 * math.sqrt(1.06 / k / (m / 2)) + 0.02  # + 2 %: leakage of the Hann window on the slopes
        ratio = s[sel].mean() / ref[sel].mean()
        assert ratio == pytest.approx(1.0, abs=tol), f"output {i}, band {lo:.3g}-{hi:.3g} Hz"


def test_seeded():
    a = Atmosphere(AtmosphereConfig(MODERATE), 1e-3, np.random.default_rng(3)).sample(1000)
    b = Atmosphere(AtmosphereConfig(MODERATE), 1e-3, np.random.default_rng(3)).sample(1000)
    c = Atmosphere(AtmosphereConfig(MODERATE), 1e-3, np.random.default_rng(4)).sample(1000)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    # Sampling in blocks gives the same sequence as one long block (to rounding: the block products differ).
    atm = Atmosphere(AtmosphereConfig(MODERATE), 1e-3, np.random.default_rng(3))
    np.testing.assert_allclose(np.vstack([atm.sample(10) for _ in range(100)]), a, rtol=0, atol=1e-12)
    # And it is the filter's recursion x[k+1] = A_d x[k] + L_d z[k], d[k] = C x[k], stepped one by one.
    rng = np.random.default_rng(3)
    f = Atmosphere(AtmosphereConfig(MODERATE), 1e-3, np.random.default_rng(0)).filter
    x = f.initial(rng)
    z = rng.standard_normal((1000, 4))
    ref = []
    for zk in z:
        ref.append(f.c @ x)
        x = f.ad @ x + f.ld @ zk
    np.testing.assert_allclose(a, ref, rtol=0, atol=1e-12)


def test_one_cosine_gust_peak_and_length():
    g = Gust(amplitude=2.5, length=15.0, start=1.0)
    dt = 1e-4
    atm = Atmosphere(AtmosphereConfig(gusts=(g,)), dt, np.random.default_rng(0))
    d = atm.sample(int(6 / dt))
    t = np.arange(len(d)) * dt
    v = d[:, 0]
    nonzero = t[v > 0]
    assert v.max() == pytest.approx(2.5, rel=1e-6)
    assert t[np.argmax(v)] == pytest.approx(1.0 + 15.0 / AIRSPEED / 2, abs=dt)
    assert nonzero[0] == pytest.approx(1.0, abs=dt)
    assert nonzero[-1] - nonzero[0] == pytest.approx(15.0 / AIRSPEED, abs=2 * dt)
    assert not d[:, 1:].any()


def test_crosswind_is_a_constant_side_gust():
    d = Atmosphere(AtmosphereConfig(crosswind=-3.0), 0.01, np.random.default_rng(0)).sample(50)
    assert np.all(d[:, 0] == -3.0) and not d[:, 1:].any()


def test_disturbance_matrix_aerodynamic_columns():
    e = disturbance_matrix(model.A_P)
    # v_g: all of the v column (Y_v, L_v, N_v), sign flipped; p_g, r_g: L and N rows only; phi and servo rows 0.
    np.testing.assert_array_equal(e[:, 0], [3.34, 40.5, -234.0, 0, 0, 0])
    np.testing.assert_array_equal(e[:, 1], [0, 2.22, 2.84, 0, 0, 0])
    np.testing.assert_array_equal(e[:, 2], [0, -2.48, 27.0, 0, 0, 0])


def test_aircraft_disturbance_is_air_relative():
    """Moving the aircraft and the air together changes nothing aerodynamic: with v = v_g the v derivatives
    keep only the kinematic terms (zero here), i.e. x' = A (x - x_g) on the aero part."""
    ac = Aircraft(AircraftConfig(physics_rate_hz=1000.0), x0=np.array([2.0, 0, 0, 0, 0, 0]))
    ac.advance(0.0, 1, np.array([[2.0, 0.0, 0.0]]))
    np.testing.assert_allclose(ac.x, [2.0, 0, 0, 0, 0, 0], atol=1e-12)


def test_aircraft_disturbance_exact_zoh():
    rng = np.random.default_rng(1)
    d = rng.standard_normal((10, 3))
    a, b = Aircraft(), Aircraft()
    a.advance(0.02, 10, d)
    for row in d:
        b.step(0.02, row)
    np.testing.assert_allclose(a.x, b.x, rtol=1e-12, atol=1e-15)
    # The exact ZOH of x' = A x + B u + E d with u, d held: the block exponential, computed independently.
    blk = np.zeros((10, 10))
    blk[:6, :6] = model.A_P
    blk[:6, 6:7] = model.B_P
    blk[:6, 7:] = disturbance_matrix(model.A_P)
    phi = expm(blk * 1e-3)
    x = np.zeros(6)
    for row in d:
        x = phi[:6, :6] @ x + phi[:6, 6:] @ np.concatenate([[0.02], row])
    np.testing.assert_allclose(a.x, x, rtol=1e-9, atol=1e-13)


def test_noise_discretisation_matches_van_loan_at_a_short_step():
    """Q_d = P - A_d P A_d^T against Van Loan's block exponential (accurate when dt is short)."""
    a, b, _c = MODERATE.state_space()
    dt = 1e-3
    ad, qd, _p = noise_zoh(a, b, dt)
    n = a.shape[0]
    blk = np.zeros((2 * n, 2 * n))
    blk[:n, :n], blk[:n, n:], blk[n:, n:] = -a, b @ b.T, a.T
    f = expm(blk * dt)
    np.testing.assert_allclose(ad, f[n:, n:].T, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(qd, f[n:, n:].T @ f[:n, n:], rtol=1e-6, atol=1e-12)
