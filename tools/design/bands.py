"""Constant output-feedback gains K_e > 0 for which 1 + K_e F is unstable, in continuous time and sampled.

Why it matters: SAC's error gain K_e(t) = e^2 Gamma_pe + K_Ie(t) is non-negative and grows while the error
is large.  W-ASPR theory (paper sec. 2, eqs. (14)-(15)) only promises that *some* constant K_e stabilises
F; if 1 + K_e F is unstable for an intermediate range of K_e, an adaptive law that drives K_e into that
range makes the loop oscillate until the gains leave it.

The band finder works on polynomials: 1 + K N(s)/D(s) = 0  <=>  D(s) + K N(s) = 0.  A closed-loop root
crosses the imaginary axis at s = jw only where K = -D(jw)/N(jw) is real, i.e. where the polynomial
Im(D(jw) conj N(jw)) in w vanishes (w = 0 included); a root can also pass through infinity where the
leading coefficient of D + K N vanishes.  Between consecutive such gains the number of unstable roots is
constant, so one root evaluation per interval classifies it; every edge is polished and then checked by
root evaluation just inside and just outside.  The same is done for the exact zero-order-hold
discretisation of F at the control rate (the loop the 100 Hz controller really closes), with the unit
circle mapped onto the imaginary axis by the bilinear transform so the crossing polynomial stays well
conditioned.  Also here: how far the PFC's own compensator C = 1/D is from destabilising T, and the loop
CL-SAC closes through its reference model and K_x.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from tools.design._common import AnalysisError, brentq, ct, poly
from tools.design.aspr import ss_to_tf, tf_coefficients

_STEP_REL = 1e-6  # the relative step used to confirm that an edge is a stability boundary
W_ZERO_RTOL = 1e-9  # a crossing frequency below this fraction of the fastest open-loop pole is w = 0


class GainBand(NamedTuple):
    """Gains low < K < high for which the loop is unstable (high may be inf), and the crossing frequencies
    (rad/s) where a closed-loop root sits on the stability boundary at each edge (None at 0 or inf)."""

    low: float
    high: float
    omega_low: float | None
    omega_high: float | None


def _closed_loop_poly(num: np.ndarray, den: np.ndarray, k: float) -> np.ndarray:
    """D(s) + K N(s): the characteristic polynomial of 1 + K N/D (paper sec. 2, eq. (14) with K_e = K)."""
    m = max(num.size, den.size)
    p = np.zeros(m)
    p[m - den.size :] += den
    p[m - num.size :] += k * num
    return np.trim_zeros(p, "f")


def _jw_coeffs(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Real and imaginary parts of p(jw) as real polynomials in w."""
    deg = p.size - 1
    c = p * (1j ** np.arange(deg, -1, -1))
    return c.real.copy(), c.imag.copy()


def _crossing_candidates(num: np.ndarray, den: np.ndarray) -> list[float]:
    """Gains K > 0 at which a root of D(s) + K N(s) can sit on the imaginary axis (paper sec. 2).

    s = jw is a root for real K only where K = -D(jw)/N(jw) is real, i.e. at the real roots w >= 0 of
    Im(D(jw) conj N(jw)) = D_i(w) N_r(w) - D_r(w) N_i(w) (w = 0 always is one), polished by Newton
    steps on that polynomial.  Also the gain at which deg(D + K N) drops (a root through infinity).
    Near-real roots are accepted generously: a spurious candidate only adds an interval to classify.
    """
    dr, di = _jw_coeffs(den)
    nr, ni = _jw_coeffs(num)
    h = np.trim_zeros(np.polysub(np.polymul(di, nr), np.polymul(dr, ni)), "f")
    dh = np.polyder(h) if h.size > 1 else np.array([0.0])
    ws = np.roots(h) if h.size > 1 else np.array([])
    # w = 0 is a root of h (it is odd) and is taken exactly: a root this close to it is that one, computed with
    # round-off.  With an open-loop pole at s = 0 (a roll integrator; z = 1 sampled, w = 0 after the bilinear map),
    # computed as a pole within W_ZERO_RTOL of the fastest, K = -D(0)/N(0) ~ 1e-17 is round-off too, where no
    # closed-loop root's side of the axis can be resolved: not a candidate (the band finder probes from K > 0 on).
    poles = np.abs(np.roots(den)) if den.size > 1 else np.zeros(0)
    w_zero = W_ZERO_RTOL * max(1.0, float(np.max(poles))) if poles.size else 0.0
    omegas = [0.0] if not (poles.size and float(np.min(poles)) <= w_zero) else []
    for w in ws:
        if abs(w.imag) <= 1e-3 * max(1.0, abs(w.real)) and w.real > w_zero:
            wr = float(w.real)
            for _ in range(4):  # Newton polish on the crossing polynomial
                d = np.polyval(dh, wr)
                if d == 0.0:
                    break
                step = np.polyval(h, wr) / d
                if not math.isfinite(step) or abs(step) > 1e-3 * max(1.0, wr):
                    break
                wr = abs(wr - step)
            omegas.append(wr)
    out = []
    for w in omegas:
        nj = np.polyval(num, 1j * w)
        if abs(nj) > 0.0:
            out.append(float((-np.polyval(den, 1j * w) / nj).real))
    if num.size == den.size:  # the leading coefficient of D + K N vanishes: a root through infinity
        out.append(float(-den[0] / num[0]))
    return sorted(k for k in out if math.isfinite(k) and k > 0)


def _roots_fn(num: np.ndarray, den: np.ndarray, realisation=None):
    """K -> closed-loop roots of 1 + K F: eigenvalues of A - K B (1 + K d)^-1 C when a realisation
    (A, B, C[, d]) of F is given (well conditioned even when poles cluster, e.g. a fast-sampled plant
    with all its poles near z = 1), otherwise the roots of D + K N."""
    if realisation is not None:
        a, b, c = (np.atleast_2d(np.asarray(m, dtype=float)) for m in realisation[:3])
        d = float(realisation[3]) if len(realisation) > 3 else 0.0
        bc = b.reshape(-1, 1) @ c.reshape(1, -1)

        def roots(k: float) -> np.ndarray:
            den_k = 1.0 + k * d
            if den_k == 0.0:
                return np.array([complex(math.inf, 0.0)])
            return np.linalg.eigvals(a - (k / den_k) * bc)

        return roots

    def roots(k: float) -> np.ndarray:
        p = _closed_loop_poly(num, den, k)
        return np.roots(p) if p.size > 1 else np.array([complex(-math.inf, 0.0)])

    return roots


def _refine_edge(f, k0: float | None, lo: float, hi: float) -> float:
    """The gain in (lo, hi) where the stability margin f changes sign (f(lo), f(hi) of opposite sign).

    k0, the analytic candidate from the crossing polynomial, is kept if f changes sign within
    k0 (1 -+ 1e-6) and the root finder cannot do better; otherwise brentq on f, starting from a
    bracket around k0 that widens tenfold up to (lo, hi)."""
    tol = dict(xtol=1e-14 * (k0 or lo), rtol=4 * np.finfo(float).eps)
    if k0 is not None:
        rel = _STEP_REL
        while rel < 1.0:
            a, b = max(k0 * (1 - rel), lo), min(k0 * (1 + rel), hi)
            if (f(a) >= 0) != (f(b) >= 0):
                return float(brentq(f, a, b, **tol))
            rel *= 10.0
    return float(brentq(f, lo, hi, **tol))


def _bands(cands: list[float], f, omega_of) -> list[GainBand]:
    """Unstable bands from candidate boundary gains and the stability margin f (>= 0: unstable).

    Each open interval between consecutive candidates is classified by root evaluation at three
    interior points (one would do if the candidates are complete; the extra two are a safety net
    that catches a crossing the polynomial missed, whose gain is then found by brentq).  A band
    edge is the candidate between two differently classified probes, polished by ``_refine_edge``.
    """
    ks: list[float] = []
    for k in cands:  # merge candidates closer than 1e-12 relative (the same crossing found twice)
        if not ks or k - ks[-1] > 1e-12 * k:
            ks.append(k)
    bounds = [0.0] + ks + [math.inf]
    probes = []
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        if lo == 0.0 and math.isinf(hi):
            probes += [1e-3, 1.0, 1e3]
        elif lo == 0.0:
            probes += [hi * 1e-3, hi * 0.1, hi * 0.5]
        elif math.isinf(hi):
            probes += [lo * 1.5, lo * 10.0, lo * 1e3]
        else:
            r = hi / lo
            probes += [lo * r**0.25, lo * r**0.5, lo * r**0.75]
    flags = [f(p) >= 0.0 for p in probes]
    edges = []  # (gain, becomes_unstable)
    for p0, p1, u0, u1 in zip(probes[:-1], probes[1:], flags[:-1], flags[1:]):
        if u0 == u1:
            continue
        inside = [k for k in ks if p0 < k < p1]
        edges.append((_refine_edge(f, inside[0] if len(inside) == 1 else None, p0, p1), u1))
    bands = []
    low = 0.0 if flags[0] else None
    for k, up in edges:
        if up:
            low = k
        else:
            bands.append((low, k))
            low = None
    if low is not None:
        bands.append((low, math.inf))
    out = [GainBand(lo, hi, omega_of(lo), omega_of(hi)) for lo, hi in bands]
    _confirm(f, out)
    return out


def _confirm(f, bands: list[GainBand]) -> None:
    """Each edge must be a boundary: stable just outside, unstable just inside (root evaluation)."""
    for b in bands:
        checks = []
        if b.low > 0:
            checks += [(b.low * (1 - _STEP_REL), False), (b.low * (1 + _STEP_REL), True)]
        if math.isfinite(b.high):
            checks += [(b.high * (1 - _STEP_REL), True), (b.high * (1 + _STEP_REL), False)]
        for k, want in checks:
            if (f(k) >= 0.0) != want:
                raise AnalysisError(
                    f"band [{b.low!r}, {b.high!r}] failed its root check at K={k!r} (expected "
                    f"{'unstable' if want else 'stable'}): the problem is numerically too ill-conditioned"
                )


def unstable_gain_bands(num, den, *, realisation=None) -> list[GainBand]:
    """All bands of constant gains K > 0 for which 1 + K N(s)/D(s) is unstable (a closed-loop root with
    Re >= 0).  Paper sec. 2, eq. (14): K plays the role of the output-feedback gain K_e.

    ``realisation``: optional state space (A, B, C[, d]) of N/D used for the root evaluations.  Returns
    the bands in increasing order, each with the crossing frequency (rad/s) at its finite edges; an
    empty list if 1 + K N/D is stable for every K > 0.  Each edge is checked by root evaluation at
    K (1 -+ 1e-6); an inconsistency raises ``AnalysisError``.
    """
    num, den = poly(num, "num"), poly(den, "den")
    roots = _roots_fn(num, den, realisation)

    def f(k: float) -> float:
        return float(np.max(roots(k).real))

    def omega_of(k: float):
        if k == 0.0 or math.isinf(k):
            return None
        r = roots(k)
        return float(abs(r[np.argmax(r.real)].imag))

    return _bands(_crossing_candidates(num, den), f, omega_of)


def bilinear_realisation(ad, bd, cd, dt: float):
    """(A_w, B_w, C_w, d_w) of G(w) = G_z(z) with z = (1 + w dt/2)/(1 - w dt/2).

    The map takes the unit circle to the imaginary axis and the open unit disk to the open left half
    plane, so 1 + K G_z(z) is stable iff 1 + K G(w) is; and G(w) is well conditioned where the
    z-domain polynomials are not (all poles near z = 1).  With P = I + A_d:
    A_w = (2/dt) P^-1 (A_d - I), B_w = (2/dt) P^-1 B_d, C_w = 2 C_d P^-1, d_w = -C_d P^-1 B_d.
    """
    ad, bd, cd = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (ad, bd, cd))
    n = ad.shape[0]
    p = np.eye(n) + ad
    if np.linalg.cond(p) > 1e12:
        raise AnalysisError("the sampled plant has a pole at z = -1; the bilinear map is undefined")
    pinv_b = np.linalg.solve(p, bd.reshape(n, 1))
    aw = (2.0 / dt) * np.linalg.solve(p, ad - np.eye(n))
    bw = (2.0 / dt) * pinv_b
    cw = 2.0 * np.linalg.solve(p.T, cd.reshape(n, 1)).T
    dw = -(cd.reshape(1, n) @ pinv_b).item()
    return aw, bw, cw, dw


def unstable_gain_bands_discrete(ad, bd, cd, dt: float) -> list[GainBand]:
    """Bands of constant K > 0 for which the sampled loop 1 + K C_d (zI - A_d)^-1 B_d is unstable (a root
    with |z| >= 1).  Candidates come from the bilinear (w-plane) image, where the continuous-time
    crossing polynomial is well conditioned; roots are evaluated as eigenvalues of A_d - K B_d C_d.
    Omegas are physical frequencies in rad/s (angle of the boundary root / dt)."""
    ad, bd, cd = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (ad, bd, cd))
    aw, bw, cw, dw = bilinear_realisation(ad, bd, cd, dt)
    g = ss_to_tf(aw, bw, cw, dw)
    wn, wd = tf_coefficients(g)
    bc = bd.reshape(-1, 1) @ cd.reshape(1, -1)

    def roots(k: float) -> np.ndarray:
        return np.linalg.eigvals(ad - k * bc)

    def f(k: float) -> float:
        return float(np.max(np.abs(roots(k)))) - 1.0

    def omega_of(k: float):
        if k == 0.0 or math.isinf(k):
            return None
        r = roots(k)
        z = r[np.argmax(np.abs(r))]
        return abs(math.atan2(z.imag, z.real)) / dt

    return _bands(_crossing_candidates(wn, wd), f, omega_of)


def discretise(realisation, rate_hz: float):
    """Exact zero-order-hold discretisation (Ad, Bd, Cd) of a strictly proper (A, B, C) at ``rate_hz``:
    the controller samples y and holds u over each control period (autopilot/clsac.py), and the
    simulator holds u exactly, so the loop it closes is 1 + K_e ZOH(T + D)(z) (ZOH(T) + ZOH(D) = ZOH(F))."""
    if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and rate_hz > 0):
        raise AnalysisError(f"rate must be positive and finite, got {rate_hz!r}")
    a, b, c = realisation
    dsys = ct().c2d(ct().ss(a, b, c, 0.0), 1.0 / rate_hz, method="zoh")
    return np.asarray(dsys.A), np.asarray(dsys.B), np.asarray(dsys.C)


def discrete_bands(realisation, rate_hz: float) -> list[GainBand]:
    """Unstable K_e bands of the loop the controller really closes: 1 + K_e F_zoh(z) at ``rate_hz``."""
    ad, bd, cd = discretise(realisation, rate_hz)
    return unstable_gain_bands_discrete(ad, bd, cd, 1.0 / rate_hz)


def compensator_gain_margin(plant_num, plant_den, pfc_num, pfc_den) -> float | None:
    """Factor g >= 1 by which the gain of C = 1/D can be raised before 1 + g C T goes unstable (paper
    sec. 5: "C(s) ... stabilises the plant T(s) ... its gain is selected as high as possible while
    ensuring the stability").  The zeros of F = T + D are the closed-loop poles of 1 + C T, so this is
    also how far C is from making F non-minimum-phase.  inf if no gain destabilises; None if 1 + C T is
    already unstable (F not minimum phase)."""
    tn, td = poly(plant_num, "plant num"), poly(plant_den, "plant den")
    dn, dd = poly(pfc_num, "pfc num"), poly(pfc_den, "pfc den")
    # 1 + g C T = 0  <=>  td dn + g tn dd = 0
    bands = unstable_gain_bands(np.polymul(tn, dd), np.polymul(td, dn))
    for b in bands:
        if b.low < 1.0 < b.high or b.low == 1.0:
            return None
    above = [b.low for b in bands if b.low > 1.0]
    return min(above) if above else math.inf


def clsac_kx_bands(f_num, f_den, lv: float, am: float = -5.0, cm: float = 1.0) -> dict[str, list[GainBand]]:
    """Frozen-gain loop of CL-SAC through its reference model (paper sec. 3, eqs. (18) and (21), SISO).

    With L_v > 0 the reference model is driven by y_a: x_m = (B_m u_m + L_v y_a)/(s - A_m + L_v C_m), so
    the "feedforward" term K_x x_m of u = K_e e + K_x x_m + K_u u_m feeds y_a back.  With K_e = 0 and
    u_m = 0 the loop is 1 + (-K_x) L_v F(s)/(s - A_m + L_v C_m) (for SAC, L_v = 0, there is no such loop).
    Defaults A_m = -5, C_m = 1 are the paper's reference model (sec. 5).  Returns the unstable bands of
    -K_x > 0 ("minus_kx") and of K_x > 0 ("kx")."""
    fn, fd = poly(f_num, "F num"), poly(f_den, "F den")
    if not (math.isfinite(lv) and lv >= 0):
        raise AnalysisError(f"lv must be finite and >= 0, got {lv!r}")
    if lv == 0.0:
        return {"minus_kx": [], "kx": []}
    num = np.polymul(fn, [lv])
    den = np.polymul(fd, [1.0, -am + lv * cm])
    return {"minus_kx": unstable_gain_bands(num, den), "kx": unstable_gain_bands(-num, den)}
