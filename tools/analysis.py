"""W-ASPR analysis of the KH2013A roll plant with a parallel feedforward compensator (PFC).  No I/O.

Jana & Bhat 2017, section 2 (W-ASPR conditions, PFC D(s) = 1/C(s)) and section 5 (the plant T(s), the
PFC D(s) = 10/(4s + 40) and the augmented plant F(s) = T(s) + D(s)).  DESIGN.md section 3 asks for:

* the transfer functions T(s) = C_p (sI - A_p)^-1 B_p and F(s) = T(s) + D(s);
* the W-ASPR conditions of F: minimum phase, relative degree <= 1, positive high-frequency gain;
* the constant output-feedback gains K_e > 0 for which 1 + K_e F(s) is unstable.

Why the last item matters: SAC's error gain K_e(t) = e^2 Gamma_pe + K_Ie(t) is non-negative and grows
while the error is large.  W-ASPR theory (paper eq. wasprc1-wasprc2) only promises that *some* constant
K_e stabilises F; if 1 + K_e F is unstable for an intermediate range of K_e, an adaptive law that drives
K_e into that range makes the loop oscillate until the gains leave it.

The band finder works on polynomials: 1 + K N(s)/D(s) = 0  <=>  D(s) + K N(s) = 0.  A closed-loop root
crosses the imaginary axis at s = jw only where K = -D(jw)/N(jw) is real, i.e. where the polynomial
Im(D(jw) conj N(jw)) in w vanishes (w = 0 included); a root can also pass through infinity where the
leading coefficient of D + K N vanishes.  Between consecutive such gains the number of unstable roots is
constant, so one root evaluation per interval classifies it; every edge is polished and then checked by
root evaluation just inside and just outside.  The same is done for the exact zero-order-hold
discretisation of F at the control rate (the loop the 100 Hz controller really closes), with the unit
circle mapped onto the imaginary axis by the bilinear transform so the crossing polynomial stays well
conditioned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, NamedTuple, Sequence

import numpy as np

from autopilot.config import PFC_PRESETS
from sitl import model

if TYPE_CHECKING:
    from control import TransferFunction


def _ct():
    """python-control, imported on first use: importing it costs ~2.5 s (scipy.signal, matplotlib) and
    ``python -m tools.pfc`` should answer --help and bad input at once."""
    import control

    return control


def brentq(*args, **kwargs):
    """scipy.optimize.brentq, imported on first use (~0.7 s) for the same reason as ``_ct``."""
    from scipy.optimize import brentq as _brentq

    return _brentq(*args, **kwargs)

# The presets have one home, autopilot.config.PFC_PRESETS; these names are views of it.
# Paper section 5: C(s) = (4s + 40)/10, D(s) = 1/C(s) = 10/(4s + 40).  The default everywhere.
PAPER_PFC: tuple[tuple[float, ...], tuple[float, ...]] = PFC_PRESETS["paper"]

# The paper's compensator at a quarter of its gain: C(s) = (4s + 40)/40 = (s + 10)/10, D(s) = 10/(s + 10)
# (chosen with ``robust_pfc_search``, see the README).  The paper's C is within a factor 1.019 of the gain
# at which 1 + C T goes unstable, so F's zeros (= the closed-loop poles of 1 + C T) are almost undamped
# (-0.28 +- 58.9j) and 1 + K F is unstable for K in [0.62, 20.8] and [27.3, 1014].  With this D, F is
# W-ASPR with zeros damped at >= 0.27, 1 + K F is stable for every K > 0, the 100 Hz ZOH loop only for
# K > 20.0 (the sampling limit ~ 2/(hf_gain T)), and the steady-state offset is 0.069 deg at 10 deg.
ROBUST_PFC: tuple[tuple[float, ...], tuple[float, ...]] = PFC_PRESETS["robust"]

_STEP_REL = 1e-6  # the relative step used to confirm that an edge is a stability boundary


class AnalysisError(ValueError):
    """The analysis could not be carried out (e.g. a numerically inconsistent stability boundary)."""


class PfcError(AnalysisError):
    """The PFC is unusable (empty, not finite, not strictly proper, unstable); the message names the value."""


class CoefficientError(PfcError):
    """A coefficient list could not be parsed; the message names the offending text."""


class GainBand(NamedTuple):
    """Gains low < K < high for which the loop is unstable (high may be inf), and the crossing frequencies
    (rad/s) where a closed-loop root sits on the stability boundary at each edge (None at 0 or inf)."""

    low: float
    high: float
    omega_low: float | None
    omega_high: float | None


# --------------------------------------------------------------------------- input
def parse_coefficients(text: str, name: str) -> tuple[float, ...]:
    """Parse a comma-separated coefficient list, highest power first ("4,40" -> 4 s + 40)."""
    if text is None or not str(text).strip():
        raise CoefficientError(f"{name} is empty, expected comma-separated numbers such as '4,40'")
    out = []
    for item in str(text).split(","):
        item_s = item.strip()
        try:
            value = float(item_s)
        except ValueError:
            raise CoefficientError(f"{name}: {item_s!r} is not a number (in {text!r})") from None
        if not math.isfinite(value):
            raise CoefficientError(f"{name}: {item_s!r} is not a finite number (in {text!r})")
        out.append(value)
    return tuple(out)


def _poly(coeffs, name: str = "polynomial") -> np.ndarray:
    """A 1-D float array of coefficients with leading zeros removed."""
    try:
        arr = np.atleast_1d(np.asarray(coeffs, dtype=float)).ravel()
    except (TypeError, ValueError):
        raise AnalysisError(f"{name} must be a sequence of numbers, got {coeffs!r}") from None
    if not np.all(np.isfinite(arr)):
        raise AnalysisError(f"{name} must be finite, got {list(arr)!r}")
    arr = np.trim_zeros(arr, "f")
    if arr.size == 0:
        raise AnalysisError(f"{name} is zero")
    return arr


def validate_pfc(
    num: Sequence[float], den: Sequence[float], names: tuple[str, str] = ("pfc num", "pfc den")
) -> tuple[np.ndarray, np.ndarray]:
    """Check a PFC D(s) = num/den against what the controller needs (paper sec. 2: D = 1/C with C
    stabilising; DESIGN.md sec. 3: strictly proper and stable, as in ``ClSacConfig``).  Returns the
    trimmed (num, den) arrays or raises ``PfcError`` naming the offending value."""
    arrs = []
    for name, coeffs in zip(names, (num, den)):
        try:
            arr = np.atleast_1d(np.asarray(coeffs, dtype=float)).ravel()
        except (TypeError, ValueError):
            raise PfcError(f"{name} must be numbers, got {coeffs!r}") from None
        if arr.size == 0:
            raise PfcError(f"{name} is empty")
        bad = [float(v) for v in arr if not math.isfinite(v)]
        if bad:
            raise PfcError(f"{name} has a non-finite coefficient {bad[0]!r} in {arr.tolist()!r}")
        trimmed = np.trim_zeros(arr, "f")
        if trimmed.size == 0:
            raise PfcError(f"{name} is all zeros: {arr.tolist()!r}")
        arrs.append(trimmed)
    n, d = arrs
    if d.size < 2:
        raise PfcError(f"{names[1]} {d.tolist()!r} has degree 0: the PFC must be strictly proper (deg num < deg den)")
    if n.size >= d.size:
        raise PfcError(
            f"the PFC {n.tolist()!r}/{d.tolist()!r} is not strictly proper (deg num {n.size - 1} >= deg den {d.size - 1})"
        )
    poles = np.roots(d)
    if np.any(poles.real >= 0):
        worst = poles[np.argmax(poles.real)]
        raise PfcError(
            f"{names[1]} {d.tolist()!r} makes the PFC unstable: pole {_fmt_complex(worst)} is not in the open left half plane"
        )
    return n, d


def _fmt_complex(z: complex) -> str:
    z = complex(z)
    if abs(z.imag) < 1e-12 * max(1.0, abs(z.real)):
        return f"{z.real:.6g}"
    return f"{z.real:.6g}{z.imag:+.6g}j"


# --------------------------------------------------------------------------- transfer functions
def tf_coefficients(sys: TransferFunction) -> tuple[np.ndarray, np.ndarray]:
    """(num, den) of a SISO transfer function as 1-D arrays, leading zeros removed."""
    return _poly(sys.num[0][0], "num"), _poly(sys.den[0][0], "den")


def ss_to_tf(a, b, c, d=0.0, dt=0) -> TransferFunction:
    """SISO C (sI - A)^-1 B + D with the numerator's degree fixed by the Markov parameters.

    ss2tf leaves round-off of order 1e-13 on numerator coefficients that are exactly zero (for the
    paper's plant C_p B_p = C_p A_p B_p = C_p A_p^2 B_p = 0 structurally).  The relative degree r is the
    index of the first Markov parameter C A^(r-1) B that is not negligible against |C| |A|^(r-1) |B|;
    the coefficients above degree n - r are set to zero and the leading one to C A^(r-1) B exactly.
    """
    a = np.atleast_2d(np.asarray(a, dtype=float))
    b = np.asarray(b, dtype=float).reshape(-1, 1)
    c = np.asarray(c, dtype=float).reshape(1, -1)
    d = float(np.asarray(d, dtype=float).reshape(()))
    sys = _ct().ss2tf(_ct().ss(a, b, c, d, dt))
    num = np.atleast_1d(np.asarray(sys.num[0][0], dtype=float)).ravel()
    den = np.atleast_1d(np.asarray(sys.den[0][0], dtype=float)).ravel()
    n = a.shape[0]
    num = np.concatenate([np.zeros(n + 1 - num.size), num]) if num.size < n + 1 else num[-(n + 1):]
    if d == 0.0:
        num[0] = 0.0
        na, nb, nc = np.linalg.norm(a, 2), np.linalg.norm(b), np.linalg.norm(c)
        ak_b = b.copy()
        for k in range(n):  # Markov parameters h_k = C A^k B
            h = (c @ ak_b).item()
            if abs(h) > 1e-10 * nc * nb * max(na, 1.0) ** k:
                num[: k + 1] = 0.0
                num[k + 1] = h * den[0]
                break
            ak_b = a @ ak_b
        else:
            num[:] = 0.0
    return _ct().tf(_poly(num) if np.any(num) else [0.0], den, dt)


def plant_tf() -> TransferFunction:
    """T(s) = C_p (sI - A_p)^-1 B_p of the 6-state augmented plant (paper section 5, num(s)/den(s))."""
    return ss_to_tf(model.A_P, model.B_P, model.C_P)


def pfc_tf(num: Sequence[float] = PAPER_PFC[0], den: Sequence[float] = PAPER_PFC[1]) -> TransferFunction:
    """D(s) = num/den, validated (paper sections 2 and 5: D(s) = 1/C(s))."""
    n, d = validate_pfc(num, den)
    return _ct().tf(n, d)


def augmented_tf(plant: TransferFunction, pfc: TransferFunction) -> TransferFunction:
    """F(s) = T(s) + D(s), the plant the adaptive law sees (paper section 5, num_F(s)/den_F(s)).

    Not normalised: with the paper's D = 10/(4s + 40), den_F leads with 4 and num_F with 10, as printed."""
    return plant + pfc


# --------------------------------------------------------------------------- W-ASPR conditions
def relative_degree(num, den) -> int:
    """deg den - deg num (paper sec. 2: the augmented plant must have relative degree 0 or 1)."""
    return _poly(den, "den").size - _poly(num, "num").size


def hf_gain(num, den) -> float:
    """High-frequency gain lim s^r N(s)/D(s) = lead(num)/lead(den), r the relative degree (paper sec. 2:
    the eigenvalues of C_p B_p, which is this number for relative degree 1, must be positive)."""
    return float(_poly(num, "num")[0] / _poly(den, "den")[0])


def is_minimum_phase(num) -> bool:
    """All finite zeros in the open left half plane (paper sec. 2, W-ASPR condition)."""
    n = _poly(num, "num")
    return bool(n.size == 1 or np.all(np.roots(n).real < 0))


def is_waspr(num, den) -> bool:
    """W-ASPR test for a SISO plant (paper sec. 2): minimum phase, relative degree <= 1, hf gain > 0."""
    return is_minimum_phase(num) and relative_degree(num, den) in (0, 1) and hf_gain(num, den) > 0


# --------------------------------------------------------------------------- unstable gain bands
def _closed_loop_poly(num: np.ndarray, den: np.ndarray, k: float) -> np.ndarray:
    """D(s) + K N(s): the characteristic polynomial of 1 + K N/D (paper sec. 2, eq. wasprc1 with K_e = K)."""
    m = max(num.size, den.size)
    p = np.zeros(m)
    p[m - den.size:] += den
    p[m - num.size:] += k * num
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
    omegas = [0.0]
    for w in ws:
        if abs(w.imag) <= 1e-3 * max(1.0, abs(w.real)) and w.real > 0:
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
            probes += [lo * r ** 0.25, lo * r ** 0.5, lo * r ** 0.75]
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
    Re >= 0).  Paper sec. 2, eq. wasprc1: K plays the role of the output-feedback gain K_e.

    ``realisation``: optional state space (A, B, C[, d]) of N/D used for the root evaluations.  Returns
    the bands in increasing order, each with the crossing frequency (rad/s) at its finite edges; an
    empty list if 1 + K N/D is stable for every K > 0.  Each edge is checked by root evaluation at
    K (1 -+ 1e-6); an inconsistency raises ``AnalysisError``.
    """
    num, den = _poly(num, "num"), _poly(den, "den")
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


def augmented_realisation(pfc_num: Sequence[float] = PAPER_PFC[0], pfc_den: Sequence[float] = PAPER_PFC[1]):
    """State space (A, B, C) of F = T + D: the plant (A_p, B_p, C_p) in parallel with a realisation of
    D, which is what the controller computes (paper sec. 5, Fig. "Details": y_a = y_p + D(s) u_p)."""
    n, d = validate_pfc(pfc_num, pfc_den)
    dss = _ct().tf2ss(_ct().tf(n, d))
    nd = dss.nstates
    a = np.zeros((6 + nd, 6 + nd))
    a[:6, :6] = model.A_P
    a[6:, 6:] = dss.A
    b = np.vstack([model.B_P, dss.B])
    c = np.hstack([model.C_P, dss.C])
    return a, b, c


def discretise(realisation, rate_hz: float):
    """Exact zero-order-hold discretisation (Ad, Bd, Cd) of a strictly proper (A, B, C) at ``rate_hz``:
    the controller samples y and holds u over each control period (autopilot/clsac.py), and the
    simulator holds u exactly, so the loop it closes is 1 + K_e ZOH(T + D)(z) (ZOH(T) + ZOH(D) = ZOH(F))."""
    if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and rate_hz > 0):
        raise AnalysisError(f"rate must be positive and finite, got {rate_hz!r}")
    a, b, c = realisation
    dsys = _ct().c2d(_ct().ss(a, b, c, 0.0), 1.0 / rate_hz, method="zoh")
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
    tn, td = _poly(plant_num, "plant num"), _poly(plant_den, "plant den")
    dn, dd = _poly(pfc_num, "pfc num"), _poly(pfc_den, "pfc den")
    # 1 + g C T = 0  <=>  td dn + g tn dd = 0
    bands = unstable_gain_bands(np.polymul(tn, dd), np.polymul(td, dn))
    for b in bands:
        if b.low < 1.0 < b.high or b.low == 1.0:
            return None
    above = [b.low for b in bands if b.low > 1.0]
    return min(above) if above else math.inf


def clsac_kx_bands(f_num, f_den, lv: float, am: float = -5.0, cm: float = 1.0) -> dict[str, list[GainBand]]:
    """Frozen-gain loop of CL-SAC through its reference model (paper eq. clrm1 and eq. saccontrol, SISO).

    With L_v > 0 the reference model is driven by y_a: x_m = (B_m u_m + L_v y_a)/(s - A_m + L_v C_m), so
    the "feedforward" term K_x x_m of u = K_e e + K_x x_m + K_u u_m feeds y_a back.  With K_e = 0 and
    u_m = 0 the loop is 1 + (-K_x) L_v F(s)/(s - A_m + L_v C_m) (for SAC, L_v = 0, there is no such loop).
    Returns the unstable bands of -K_x > 0 ("minus_kx") and of K_x > 0 ("kx")."""
    fn, fd = _poly(f_num, "F num"), _poly(f_den, "F den")
    if not (math.isfinite(lv) and lv >= 0):
        raise AnalysisError(f"lv must be finite and >= 0, got {lv!r}")
    if lv == 0.0:
        return {"minus_kx": [], "kx": []}
    num = np.polymul(fn, [lv])
    den = np.polymul(fd, [1.0, -am + lv * cm])
    return {"minus_kx": unstable_gain_bands(num, den), "kx": unstable_gain_bands(-num, den)}


# --------------------------------------------------------------------------- steady state
def dc_gain(num, den) -> float:
    """N(0)/D(0)."""
    n, d = _poly(num, "num"), _poly(den, "den")
    if d[-1] == 0.0:
        return math.inf
    return float(n[-1] / d[-1])


def steady_state_offset(t_dc: float, d_dc: float, command: float) -> dict[str, float]:
    """Steady-state error the PFC adds (paper sec. 5, Fig. "Details": y_a = y_p + D(s) u_p).

    At rest with perfect tracking y_a = y_m = u_m (C_m (-A_m)^-1 B_m = 1, e = 0 also holds for CL-SAC),
    so u = u_m / (T(0) + D(0)), y_p = T(0) u and the offset u_m - y_p = D(0) u.  Also returned: the
    first-order estimate D(0) u_m / T(0) (the plant's own steady command times D(0))."""
    u = command / (t_dc + d_dc)
    return {
        "command": command,
        "u_ss": u,
        "y_p_ss": t_dc * u,
        "offset": d_dc * u,
        "offset_estimate": d_dc * command / t_dc,
    }


# --------------------------------------------------------------------------- the report
@dataclass
class WasprReport:
    """Everything ``python -m tools.pfc`` prints.  Gains are dimensionless (rad of rudder per rad of roll)."""

    pfc_name: str
    plant_num: np.ndarray
    plant_den: np.ndarray
    pfc_num: np.ndarray
    pfc_den: np.ndarray
    f_num: np.ndarray
    f_den: np.ndarray
    zeros: np.ndarray
    poles: np.ndarray
    plant_zeros: np.ndarray
    plant_poles: np.ndarray
    minimum_phase: bool
    relative_degree: int
    hf_gain: float
    waspr: bool
    bands: list[GainBand]
    rate_hz: float | None
    bands_discrete: list[GainBand] | None
    plant_dc_gain: float
    pfc_dc_gain: float
    steady_state: dict[str, float]
    compensator_gain_margin: float | None
    lv: float = 20.0
    kx_bands: dict[str, list[GainBand]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def band_span(self) -> tuple[float, float] | None:
        """[lowest low, highest high] over all bands, or None."""
        return (self.bands[0].low, self.bands[-1].high) if self.bands else None

    def to_dict(self) -> dict:
        """JSON-ready dict (DESIGN.md section 7 keys first).  An unbounded edge (K -> inf) is null."""

        def inf_none(x: float):
            return None if math.isinf(x) else float(x)

        def bands_list(bands):
            return [
                {"low": inf_none(b.low), "high": inf_none(b.high), "omega_low": b.omega_low, "omega_high": b.omega_high}
                for b in bands
            ]

        def cplx(zs):
            return [[float(z.real), float(z.imag)] for z in zs]

        span = self.band_span
        d = {
            "minimum_phase": self.minimum_phase,
            "relative_degree": self.relative_degree,
            "hf_gain": self.hf_gain,
            "unstable_gain_band": None if span is None else [inf_none(span[0]), inf_none(span[1])],
            "unstable_gain_bands": bands_list(self.bands),
            "waspr": self.waspr,
            "pfc": self.pfc_name,
            "pfc_num": self.pfc_num.tolist(),
            "pfc_den": self.pfc_den.tolist(),
            "plant_num": self.plant_num.tolist(),
            "plant_den": self.plant_den.tolist(),
            "f_num": self.f_num.tolist(),
            "f_den": self.f_den.tolist(),
            "zeros": cplx(self.zeros),
            "poles": cplx(self.poles),
            "plant_zeros": cplx(self.plant_zeros),
            "plant_poles": cplx(self.plant_poles),
            "plant_dc_gain": self.plant_dc_gain,
            "pfc_dc_gain": self.pfc_dc_gain,
            "steady_state": {k: float(v) for k, v in self.steady_state.items()},
            "steady_state_error_deg": math.degrees(self.steady_state["offset"]),
            "compensator_gain_margin": (
                None if self.compensator_gain_margin is None else inf_none(self.compensator_gain_margin)
            ),
            "clsac_kx": {
                "lv": self.lv,
                "unstable_minus_kx_bands": bands_list(self.kx_bands.get("minus_kx", [])),
                "unstable_kx_bands": bands_list(self.kx_bands.get("kx", [])),
            },
            "notes": list(self.notes),
        }
        if self.rate_hz is not None:
            span_d = (self.bands_discrete[0].low, self.bands_discrete[-1].high) if self.bands_discrete else None
            d["discrete"] = {
                "rate_hz": self.rate_hz,
                "unstable_gain_band": None if span_d is None else [inf_none(span_d[0]), inf_none(span_d[1])],
                "unstable_gain_bands": bands_list(self.bands_discrete),
            }
        return d


def analyse(
    pfc_num: Sequence[float] = PAPER_PFC[0],
    pfc_den: Sequence[float] = PAPER_PFC[1],
    *,
    command_rad: float = math.radians(10.0),
    rate_hz: float | None = 100.0,
    lv: float = 20.0,
    pfc_name: str = "custom",
) -> WasprReport:
    """The W-ASPR analysis of F = T + D for a PFC D = pfc_num/pfc_den (paper sections 2 and 5).

    ``command_rad``: the steady roll command for the steady-state offset (paper scenario: 10 deg).
    ``rate_hz``: also analyse the ZOH-discretised loop at this control rate (None to skip).
    ``lv``: the CL-SAC L_v for ``clsac_kx_bands`` (paper: 20).
    Raises ``PfcError`` for an unusable PFC, ``AnalysisError`` for other bad input.
    """
    if not math.isfinite(command_rad):
        raise AnalysisError(f"command must be finite, got {command_rad!r}")
    t = plant_tf()
    d = pfc_tf(pfc_num, pfc_den)
    f = augmented_tf(t, d)
    tn, td = tf_coefficients(t)
    dn, dd = tf_coefficients(d)
    fn, fd = tf_coefficients(f)
    zeros = np.roots(fn) if fn.size > 1 else np.array([], dtype=complex)
    poles = np.roots(fd)
    real = augmented_realisation(pfc_num, pfc_den)
    bands = unstable_gain_bands(fn, fd, realisation=real)
    bands_d = None if rate_hz is None else discrete_bands(real, rate_hz)
    t_dc, d_dc = dc_gain(tn, td), dc_gain(dn, dd)
    rep = WasprReport(
        pfc_name=pfc_name,
        plant_num=tn, plant_den=td, pfc_num=dn, pfc_den=dd, f_num=fn, f_den=fd,
        zeros=_sort_roots(zeros), poles=_sort_roots(poles),
        plant_zeros=_sort_roots(np.roots(tn) if tn.size > 1 else np.array([], dtype=complex)),
        plant_poles=_sort_roots(np.roots(td)),
        minimum_phase=is_minimum_phase(fn),
        relative_degree=relative_degree(fn, fd),
        hf_gain=hf_gain(fn, fd),
        waspr=is_waspr(fn, fd),
        bands=bands, rate_hz=rate_hz, bands_discrete=bands_d,
        plant_dc_gain=t_dc, pfc_dc_gain=d_dc,
        steady_state=steady_state_offset(t_dc, d_dc, command_rad),
        compensator_gain_margin=compensator_gain_margin(tn, td, dn, dd),
        lv=float(lv),
        kx_bands=clsac_kx_bands(fn, fd, lv),
    )
    rep.notes = _notes(rep)
    return rep


def _sort_roots(r: np.ndarray) -> np.ndarray:
    return np.array(sorted(np.asarray(r, dtype=complex), key=lambda z: (-z.real, z.imag)))


def _notes(rep: WasprReport) -> list[str]:
    notes = []
    g = rep.compensator_gain_margin
    if g is None:
        notes.append("C = 1/D does not stabilise T in feedback (1 + C T unstable): F is not minimum phase")
    elif math.isfinite(g):
        notes.append(
            f"C = 1/D stabilises T with gain margin {g:.4g} ({20 * math.log10(g):.2f} dB): "
            "F loses minimum phase if the gain of C rises by that factor"
        )
    if rep.zeros.size:
        z = min(rep.zeros, key=_damping)
        notes.append(
            f"least damped zero of F at {_fmt_complex(z)} (damping ratio {_damping(z):.4f}): "
            "the closed-loop roots of 1 + K F tend to the zeros of F as K -> inf"
        )
    if rep.bands:
        spans = ", ".join(f"[{b.low:.6g}, {b.high:.6g}]" for b in rep.bands)
        notes.append(
            f"1 + Ke F(s) is unstable for constant Ke in {spans} although F is "
            f"{'W-ASPR' if rep.waspr else 'not W-ASPR'}; SAC's Ke(t) >= 0 grows with e^2 and can enter this band"
        )
    else:
        notes.append("1 + Ke F(s) is stable for every constant Ke > 0 (continuous time)")
    mk = rep.kx_bands.get("minus_kx", [])
    if mk:
        notes.append(
            f"CL-SAC (Lv = {rep.lv:g}) feeds y_a back through its reference model: with Ke = 0 the loop is "
            f"unstable for -Kx in " + ", ".join(f"[{b.low:.6g}, {b.high:.6g}]" for b in mk)
        )
    if rep.bands_discrete is not None:
        if rep.bands_discrete:
            spans = ", ".join(f"[{b.low:.6g}, {'inf' if math.isinf(b.high) else f'{b.high:.6g}'}]" for b in rep.bands_discrete)
            notes.append(
                f"sampled at {rep.rate_hz:g} Hz with a zero-order hold (the controller's own loop), "
                f"1 + Ke F_zoh(z) is unstable for Ke in {spans}"
            )
        else:
            notes.append(f"sampled at {rep.rate_hz:g} Hz (ZOH), 1 + Ke F_zoh(z) is stable for every Ke > 0")
    return notes


def _damping(z: complex) -> float:
    mag = abs(z)
    return -z.real / mag if mag > 0 else 1.0


# --------------------------------------------------------------------------- PFC design
def first_order_pfc(k: float, a: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """D(s) = k/(s + a), i.e. C(s) = (s + a)/k (paper sec. 2: D = 1/C, C stabilising T)."""
    return (float(k),), (1.0, float(a))


def robust_pfc_search(
    ks: Sequence[float], as_: Sequence[float], *, rate_hz: float | None = 100.0, command_rad: float = math.radians(10.0)
) -> list[dict]:
    """Evaluate D = k/(s + a) over a grid (the family of the paper's D = 2.5/(s + 10)): W-ASPR, the
    continuous and discrete unstable bands, the least zero damping of F and the steady-state offset.
    Pure computation; the README's choice of ``ROBUST_PFC`` came from this table."""
    t = plant_tf()
    tn, td = tf_coefficients(t)
    t_dc = dc_gain(tn, td)
    rows = []
    for k in ks:
        for a in as_:
            num, den = first_order_pfc(k, a)
            f = augmented_tf(t, _ct().tf(num, den))
            fn, fd = tf_coefficients(f)
            real = augmented_realisation(num, den)
            zeros = np.roots(fn)
            row = {
                "k": float(k), "a": float(a),
                "waspr": is_waspr(fn, fd),
                "min_zero_damping": float(min(_damping(z) for z in zeros)),
                "bands": [(b.low, b.high) for b in unstable_gain_bands(fn, fd, realisation=real)],
                "offset_deg": math.degrees(steady_state_offset(t_dc, k / a, command_rad)["offset"]),
            }
            if rate_hz is not None:
                row["bands_discrete"] = [(b.low, b.high) for b in discrete_bands(real, rate_hz)]
            rows.append(row)
    return rows
