"""W-ASPR analysis (tools/design/) against the paper's printed numbers, hand-computable cases and
independent root computations (numpy.roots / numpy.linalg.eigvals, never the module's own band finder)."""

from __future__ import annotations

import math
from decimal import Decimal

import numpy as np
import pytest
from scipy.signal import cont2discrete, ss2tf

from sitl.model import A_P, B_P, C_P
from tools import design as analysis

# Paper section 5, printed coefficients (highest power first), kept as strings to know the last digit.
PRINTED_NUM = ["6.444e05", "1.119e07", "9.185e08"]
PRINTED_DEN = ["1", "104.8", "6728", "2.28e05", "5.18e06", "1.4e07", "6.351e06"]
PRINTED_NUM_F = ["10", "1048", "6.7e04", "4.8e06", "1.2e08", "4.2e09", "3.68e10"]
PRINTED_DEN_F = ["4", "459.1", "3.11e04", "1.1e06", "2.9e07", "2.6e08", "5.8e08", "2.5e08"]


def ulp(printed: str) -> float:
    """One unit in the last printed digit: '6.444e05' -> 100, '104.8' -> 0.1, '6728' -> 1."""
    return float(Decimal(1).scaleb(Decimal(printed).as_tuple().exponent))


def independent_f(pfc_num, pfc_den):
    """num_F, den_F of F = T + D via scipy.signal.ss2tf, not via tools.design (paper sec. 5)."""
    num_t, den_t = ss2tf(A_P, B_P, C_P, np.zeros((1, 1)))
    num_t = np.trim_zeros(np.where(np.abs(num_t[0]) < 1e-6, 0.0, num_t[0]), "f")  # ss2tf round-off at s^5..s^3
    num_f = np.polyadd(np.polymul(num_t, pfc_den), np.polymul(pfc_num, den_t))
    den_f = np.polymul(den_t, pfc_den)
    return num_f, den_f


def max_re(num, den, k) -> float:
    """Spectral abscissa of den + k num by numpy.roots."""
    return float(np.max(np.roots(np.polyadd(den, k * np.asarray(num))).real))


@pytest.fixture(scope="module")
def paper():
    return analysis.analyse(*analysis.PAPER_PFC, pfc_name="paper")


@pytest.fixture(scope="module")
def robust():
    return analysis.analyse(*analysis.ROBUST_PFC, pfc_name="robust")


# ------------------------------------------------------------------ transfer functions vs the paper
def test_plant_tf_matches_printed_coefficients():
    num, den = analysis.tf_coefficients(analysis.plant_tf())
    assert num.size == 3 and den.size == 7  # relative degree 4: C B = C A B = C A^2 B = 0 exactly
    # The plant's printed coefficients are ROUNDED to the printed digits: |computed - printed| <= half a unit
    # in the last printed digit (e.g. 6.4435e5 -> 6.444e05, 104.78 -> 104.8; truncation would give 6.443e05).
    for computed, printed in zip(np.concatenate([num, den]), PRINTED_NUM + PRINTED_DEN):
        assert abs(computed - float(printed)) <= 0.5 * ulp(printed) * (1 + 1e-9), (computed, printed)


def test_augmented_tf_matches_printed_coefficients(paper):
    # num_F/den_F as printed (leading 10 and 4, not normalised).  The paper mostly TRUNCATES these
    # (4.858e6 -> 4.8e06, 4.262e9 -> 4.2e09, 1.181e6 -> 1.1e06, 2.984e7 -> 2.9e07) but rounds 1047.8 -> 1048,
    # so the check is |computed - printed| < one unit in the last printed digit.
    assert paper.f_num.size == len(PRINTED_NUM_F) and paper.f_den.size == len(PRINTED_DEN_F)
    for computed, printed in zip(np.concatenate([paper.f_num, paper.f_den]), PRINTED_NUM_F + PRINTED_DEN_F):
        assert abs(computed - float(printed)) < ulp(printed), (computed, printed)
    num_f, den_f = independent_f([10.0], [4.0, 40.0])
    np.testing.assert_allclose(paper.f_num, num_f, rtol=1e-12)
    np.testing.assert_allclose(paper.f_den, den_f, rtol=1e-12)


def test_paper_pfc_waspr_properties(paper):
    assert paper.minimum_phase is True
    assert paper.relative_degree == 1
    assert paper.hf_gain == pytest.approx(2.5, rel=1e-12)  # 10/4
    assert paper.waspr is True
    # barely minimum phase: a pair of zeros at -0.28 +- 58.87j (damping 0.005)
    top = paper.zeros[0]
    assert top.real == pytest.approx(-0.282304, abs=1e-5) and abs(top.imag) == pytest.approx(58.867507, abs=1e-5)
    np.testing.assert_allclose(
        sorted(paper.zeros.real), sorted([-81.4256, -10.7033, -6.04322, -6.04322, -0.282304, -0.282304]), rtol=1e-5
    )
    # C(s) = (4s + 40)/10 is within 2 % of the largest gain that keeps 1 + C T stable (paper: "as high as possible")
    assert paper.compensator_gain_margin == pytest.approx(1.01933, rel=1e-4)


# ------------------------------------------------------------------ the unstable band(s)
def test_paper_band_values(paper):
    lows_highs = [(b.low, b.high) for b in paper.bands]
    assert len(lows_highs) == 2  # a stable window between the two bands: [20.80, 27.29]
    np.testing.assert_allclose(np.ravel(lows_highs), [0.6215458, 20.803930, 27.288749, 1014.0569], rtol=1e-6)
    assert paper.to_dict()["unstable_gain_bands_hull"] == pytest.approx([paper.bands[0].low, paper.bands[1].high])


EDGES = [(0, "low"), (0, "high"), (1, "low"), (1, "high")]


@pytest.mark.parametrize("band_index,edge", EDGES)
def test_paper_band_edges_are_stability_boundaries(paper, band_index, edge):
    """Independent check by numpy.roots of den_F + K num_F (F from scipy.signal.ss2tf)."""
    num_f, den_f = independent_f([10.0], [4.0, 40.0])
    k = getattr(paper.bands[band_index], edge)
    below, above = max_re(num_f, den_f, k * (1 - 1e-6)), max_re(num_f, den_f, k * (1 + 1e-6))
    if edge == "low":
        assert below < 0 <= above
    else:
        assert below >= 0 > above


def test_paper_band_edges_agree_with_crossing_frequency(paper):
    """At an edge K, den_F(jw) + K num_F(jw) = 0 at the reported w (paper sec. 2 crossing condition)."""
    for b in paper.bands:
        for k, w in ((b.low, b.omega_low), (b.high, b.omega_high)):
            val = np.polyval(paper.f_den, 1j * w) + k * np.polyval(paper.f_num, 1j * w)
            scale = abs(np.polyval(paper.f_den, 1j * w)) + k * abs(np.polyval(paper.f_num, 1j * w))
            assert abs(val) / scale < 1e-9


def test_band_finder_routh_hurwitz_cubic():
    """D + K N = s^3 + (1 + K) s^2 + (1 + K) s + (0.5 + 5K): Routh-Hurwitz says unstable iff
    (1 + K)^2 < 0.5 + 5K, i.e. K^2 - 3K + 0.5 < 0, K in ((3 - sqrt 7)/2, (3 + sqrt 7)/2), crossing at
    w = sqrt(1 + K)."""
    num, den = [1.0, 1.0, 5.0], [1.0, 1.0, 1.0, 0.5]
    bands = analysis.unstable_gain_bands(num, den)
    lo, hi = (3 - math.sqrt(7)) / 2, (3 + math.sqrt(7)) / 2
    assert len(bands) == 1
    assert bands[0].low == pytest.approx(lo, rel=1e-12) and bands[0].high == pytest.approx(hi, rel=1e-12)
    assert bands[0].omega_low == pytest.approx(math.sqrt(1 + lo), rel=1e-9)
    assert bands[0].omega_high == pytest.approx(math.sqrt(1 + hi), rel=1e-9)


@pytest.mark.parametrize(
    "num,den,expected",
    [
        ([1.0], [1.0, 3.0, 3.0, 1.0], [(8.0, math.inf)]),  # 1 + K/(s+1)^3: unstable for K > 8 (w = sqrt 3)
        ([1.0], [1.0, -1.0], [(0.0, 1.0)]),  # 1 + K/(s-1): unstable for K < 1
        ([1.0], [1.0, 1.0], []),  # 1 + K/(s+1): never unstable
        ([1.0, 2.0], [1.0, 3.0], []),  # relative degree 0, root stays at -(3 + 2K)/(1 + K)
        # (1 - s)/(1 + s): root (K + 1)/(K - 1) -> through infinity at K = 1
        ([-1.0, 1.0], [1.0, 1.0], [(1.0, math.inf)]),
    ],
)
def test_band_finder_hand_cases(num, den, expected):
    got = [(b.low, b.high) for b in analysis.unstable_gain_bands(num, den)]
    assert len(got) == len(expected)
    for (glo, ghi), (elo, ehi) in zip(got, expected):
        assert glo == pytest.approx(elo, abs=1e-12, rel=1e-12)
        assert ghi == pytest.approx(ehi, rel=1e-12) if math.isfinite(ehi) else math.isinf(ghi)


def test_discrete_band_finder_hand_case():
    """1 + K/(z - 0.5): root z = 0.5 - K leaves the unit circle at z = -1, K = 1.5 (w = pi/T)."""
    bands = analysis.unstable_gain_bands_discrete([[0.5]], [[1.0]], [[1.0]], 0.01)
    assert len(bands) == 1 and bands[0].low == pytest.approx(1.5, rel=1e-12) and math.isinf(bands[0].high)
    assert bands[0].omega_low == pytest.approx(math.pi / 0.01, rel=1e-9)


def test_paper_discrete_band_is_a_boundary(paper):
    """100 Hz ZOH loop: unstable from ~0.514 up; checked with scipy's ZOH and numpy eigenvalues."""
    (band,) = paper.bands_discrete
    assert band.low == pytest.approx(0.51387, rel=1e-4) and math.isinf(band.high)
    a, b, c = analysis.augmented_realisation(*analysis.PAPER_PFC)
    ad, bd, cd, _, _ = cont2discrete((a, b, c, np.zeros((1, 1))), 0.01, method="zoh")
    rho = lambda k: np.max(np.abs(np.linalg.eigvals(ad - k * bd @ cd)))  # noqa: E731
    assert rho(band.low * (1 - 1e-6)) < 1 <= rho(band.low * (1 + 1e-6))
    assert rho(1e4) > 1


def test_robust_pfc_has_no_band(robust):
    assert robust.waspr and robust.minimum_phase and robust.relative_degree == 1 and robust.hf_gain == 10.0
    assert robust.bands == [] and robust.to_dict()["unstable_gain_bands_hull"] is None
    num_f, den_f = independent_f(*analysis.ROBUST_PFC)
    assert all(max_re(num_f, den_f, k) < 0 for k in np.logspace(-4, 7, 400))
    assert min(-z.real / abs(z) for z in robust.zeros) > 0.27  # well-damped zeros of F
    # sampled at 100 Hz only the sampling limit ~ 2/(hf_gain T) = 20 remains
    (band,) = robust.bands_discrete
    assert band.low == pytest.approx(20.026, rel=1e-4) and math.isinf(band.high)


# ------------------------------------------------------------------ steady state, CL-SAC Kx loop
def test_steady_state_offset_matches_the_closed_loop(paper, robust):
    """D(0) u_ss from the analysis = y_a - y_p in the in-process paper scenario at rest (t = 4.99 s)."""
    from autopilot.config import ClSacConfig
    from tools.experiment.scenario import PAPER, PAPER_RUNS, run_inprocess

    assert math.degrees(paper.steady_state["offset"]) == pytest.approx(0.017257, rel=1e-4)
    assert math.degrees(robust.steady_state["offset"]) == pytest.approx(0.068673, rel=1e-4)
    base = ClSacConfig(pfc_num=analysis.ROBUST_PFC[0], pfc_den=analysis.ROBUST_PFC[1])
    res = run_inprocess(PAPER, PAPER_RUNS[1], base=base)
    s = res.series
    assert s["ya"][499] - s["phi"][499] == pytest.approx(robust.steady_state["offset"], rel=1e-2)


def test_clsac_kx_band_is_a_boundary(paper):
    (band,) = paper.kx_bands["minus_kx"]
    num = np.polymul(paper.f_num, [20.0])
    den = np.polymul(paper.f_den, [1.0, 25.0])
    assert max_re(num, den, band.low * (1 - 1e-6)) < 0 <= max_re(num, den, band.low * (1 + 1e-6))
    assert analysis.clsac_kx_bands(paper.f_num, paper.f_den, 0.0) == {"minus_kx": [], "kx": []}


# ------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    "text,word",
    [("1,a", "'a'"), ("", "empty"), ("1,,2", "''"), ("nan", "'nan'"), ("1,inf", "'inf'")],
)
def test_parse_coefficients_rejects(text, word):
    with pytest.raises(analysis.CoefficientError, match=word):
        analysis.parse_coefficients(text, "--pfc-num")


@pytest.mark.parametrize(
    "num,den,word",
    [
        ([1.0, 2.0], [1.0, 3.0], "not strictly proper"),
        ([1.0], [3.0], "degree 0"),
        ([1.0], [1.0, -2.0], "unstable"),
        ([1.0], [1.0, 0.0], "unstable"),
        ([float("nan")], [1.0, 2.0], "nan"),
        ([], [1.0, 2.0], "empty"),
        ([0.0], [1.0, 2.0], "all zeros"),
    ],
)
def test_validate_pfc_rejects(num, den, word):
    with pytest.raises(analysis.PfcError, match=word):
        analysis.validate_pfc(num, den)


# ------------------------------------------------------------------ exact rational arithmetic
def _exact_plant():
    """num(s), den(s) of C_p (sI - A_p)^-1 B_p in exact rationals from the printed matrices (paper sec. 5),
    by Faddeev-LeVerrier: adj(sI - A) = sum_k M_k s^(n-k), M_k = A M_(k-1) + c_(n-k+1) I."""
    from fractions import Fraction

    from sitl.model import A_P_PRINTED, B_P_PRINTED, C_P_PRINTED

    q = lambda x: Fraction(Decimal(repr(float(x))))  # noqa: E731  (the printed decimal, exactly)
    a = [[q(x) for x in row] for row in A_P_PRINTED]
    b, c, n = [q(x) for x in B_P_PRINTED], [q(x) for x in C_P_PRINTED], len(A_P_PRINTED)
    mul = lambda x, y: [[sum(x[i][k] * y[k][j] for k in range(n)) for j in range(n)] for i in range(n)]  # noqa: E731
    coef = [Fraction(0)] * (n + 1)
    coef[n] = Fraction(1)  # coef[k]: coefficient of s^k of det(sI - A)
    m = [[Fraction(0)] * n for _ in range(n)]
    ms = []
    for k in range(1, n + 1):
        am = mul(a, m)
        m = [[am[i][j] + (coef[n - k + 1] if i == j else 0) for j in range(n)] for i in range(n)]
        ms.append(m)
        coef[n - k] = -sum(mul(a, m)[i][i] for i in range(n)) / k
    num = [sum(c[i] * mk[i][j] * b[j] for i in range(n) for j in range(n)) for mk in ms]
    return num, coef[::-1]


def test_plant_tf_and_band_edges_against_exact_arithmetic(paper):
    """T(s) to 1e-12 and every band edge to 1e-9 relative (bisection on the exact crossing polynomial
    Im(den_F(jw) conj num_F(jw)), paper sec. 2), all in fractions.Fraction."""
    from fractions import Fraction

    num_t, den_t = _exact_plant()
    assert num_t[:3] == [0, 0, 0]  # relative degree 4, exactly
    t_num, t_den = analysis.tf_coefficients(analysis.plant_tf())
    np.testing.assert_allclose(t_num, [float(x) for x in num_t[3:]], rtol=1e-12)
    np.testing.assert_allclose(t_den, [float(x) for x in den_t], rtol=1e-12)

    def mul(p, r):
        out = [Fraction(0)] * (len(p) + len(r) - 1)
        for i, x in enumerate(p):
            for j, y in enumerate(r):
                out[i + j] += x * y
        return out

    # num_F = 10 den_T + (4s + 40) num_T (degree 6 and 3), den_F = (4s + 40) den_T
    f_num = [a + b for a, b in zip(mul([10], den_t), [0] * 3 + mul(num_t[3:], [4, 40]))]
    f_den = mul(den_t, [4, 40])

    def at_jw(p, w):
        re = im = Fraction(0)
        for i, x in enumerate(p):
            k = len(p) - 1 - i
            v = x * w**k * (1 if k % 4 < 2 else -1)
            re, im = (re + v, im) if k % 2 == 0 else (re, im + v)
        return re, im

    def h(w):
        dr, di = at_jw(f_den, w)
        nr, ni = at_jw(f_num, w)
        return di * nr - dr * ni

    for band in paper.bands:
        for k, w in ((band.low, band.omega_low), (band.high, band.omega_high)):
            lo, hi = Fraction(w) * Fraction(999999, 10**6), Fraction(w) * Fraction(1000001, 10**6)
            sign_lo = h(lo) > 0
            assert (h(hi) > 0) != sign_lo
            for _ in range(60):
                mid = (lo + hi) / 2
                lo, hi = (mid, hi) if (h(mid) > 0) == sign_lo else (lo, mid)
            dr, di = at_jw(f_den, lo)
            nr, ni = at_jw(f_num, lo)
            k_exact = -(dr * nr + di * ni) / (nr * nr + ni * ni)
            assert k == pytest.approx(float(k_exact), rel=1e-9)
