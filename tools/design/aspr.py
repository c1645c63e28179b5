"""The plant, its PFC and the augmented plant as transfer functions, and the W-ASPR conditions of the latter.

Paper sec. 5: T(s) = C_p (sI - A_p)^-1 B_p of the 6-state augmented lateral model, the PFC D(s) = 1/C(s)
with C(s) = (4s + 40)/10 and F(s) = T(s) + D(s), all printed as num/den.  Paper sec. 2: F is W-ASPR
(so SAC's gains stay bounded, eqs. (14)-(15)) if it is minimum phase, of relative degree 0 or 1 and its
high-frequency gain (the eigenvalues of C_p B_p) is positive.  Also the steady-state error the PFC adds.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Sequence

import numpy as np

from autopilot.config import PFC_PRESETS
from sitl import linear_plant, model
from tools.design._common import AnalysisError, CoefficientError, PfcError, ct, fmt_complex, poly

if TYPE_CHECKING:
    from control import TransferFunction

# The presets have one home, autopilot.config.PFC_PRESETS; these names are views of it.
# Paper sec. 5: C(s) = (4s + 40)/10, D(s) = 1/C(s) = 10/(4s + 40).  The default everywhere.
PAPER_PFC: tuple[tuple[float, ...], tuple[float, ...]] = PFC_PRESETS["paper"]

# The paper's compensator at a quarter of its gain: C(s) = (4s + 40)/40 = (s + 10)/10, D(s) = 10/(s + 10)
# (chosen with ``robust_pfc_search``, see docs/experiments.md).  The paper's C is within a factor 1.019 of the gain
# at which 1 + C T goes unstable, so F's zeros (= the closed-loop poles of 1 + C T) are almost undamped
# (-0.28 +- 58.9j) and 1 + K F is unstable for K in [0.62, 20.8] and [27.3, 1014].  With this D, F is
# W-ASPR with zeros damped at >= 0.27, 1 + K F is stable for every K > 0, the 100 Hz ZOH loop only for
# K > 20.0 (the sampling limit ~ 2/(hf_gain T)), and the steady-state offset is 0.069 deg at 10 deg.
ROBUST_PFC: tuple[tuple[float, ...], tuple[float, ...]] = PFC_PRESETS["robust"]


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


def validate_pfc(
    num: Sequence[float], den: Sequence[float], names: tuple[str, str] = ("pfc num", "pfc den")
) -> tuple[np.ndarray, np.ndarray]:
    """Check a PFC D(s) = num/den against what the controller needs (paper sec. 2: D = 1/C with C
    stabilising; strictly proper and stable, as ``ClSacConfig`` requires).  Returns the trimmed
    (num, den) arrays or raises ``PfcError`` naming the offending value."""
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
            f"the PFC {n.tolist()!r}/{d.tolist()!r} is not strictly proper "
            f"(deg num {n.size - 1} >= deg den {d.size - 1})"
        )
    poles = np.roots(d)
    if np.any(poles.real >= 0):
        worst = poles[np.argmax(poles.real)]
        raise PfcError(
            f"{names[1]} {d.tolist()!r} makes the PFC unstable: pole {fmt_complex(worst)} "
            "is not in the open left half plane"
        )
    return n, d


# --------------------------------------------------------------------------- transfer functions
def tf_coefficients(sys: TransferFunction) -> tuple[np.ndarray, np.ndarray]:
    """(num, den) of a SISO transfer function as 1-D arrays, leading zeros removed."""
    return poly(sys.num[0][0], "num"), poly(sys.den[0][0], "den")


def markov_relative_degree(a, b, c) -> int | None:
    """``sitl.linear_plant.markov_relative_degree`` (scale-free), its overflow an ``AnalysisError``."""
    try:
        return linear_plant.markov_relative_degree(a, b, c)
    except OverflowError as exc:
        raise AnalysisError(str(exc)) from None


def ss_to_tf(a, b, c, d=0.0, dt=0) -> TransferFunction:
    """SISO C (sI - A)^-1 B + D with the numerator's degree fixed by the Markov parameters.

    ss2tf leaves round-off of order 1e-13 on numerator coefficients that are exactly zero (for the
    paper's plant C_p B_p = C_p A_p B_p = C_p A_p^2 B_p = 0 structurally).  The relative degree r comes from the
    first Markov parameter C A^(r-1) B that is not negligible (``markov_relative_degree``); the coefficients above
    degree n - r are set to zero and the leading one to C A^(r-1) B exactly.
    """
    a = np.atleast_2d(np.asarray(a, dtype=float))
    b = np.asarray(b, dtype=float).reshape(-1, 1)
    c = np.asarray(c, dtype=float).reshape(1, -1)
    d = float(np.asarray(d, dtype=float).reshape(()))
    sys = ct().ss2tf(ct().ss(a, b, c, d, dt))
    num = np.atleast_1d(np.asarray(sys.num[0][0], dtype=float)).ravel()
    den = np.atleast_1d(np.asarray(sys.den[0][0], dtype=float)).ravel()
    n = a.shape[0]
    num = np.concatenate([np.zeros(n + 1 - num.size), num]) if num.size < n + 1 else num[-(n + 1) :]
    if d == 0.0:
        r = markov_relative_degree(a, b, c)
        if r is None:
            num[:] = 0.0
        else:
            ak_b = b.copy()
            for _ in range(r - 1):  # h_(r-1) = C A^(r-1) B, the powers applied to B one by one
                ak_b = a @ ak_b
            num[:r] = 0.0
            num[r] = (c @ ak_b).item() * den[0]
    return ct().tf(poly(num) if np.any(num) else [0.0], den, dt)


def plant_tf(plant=None) -> TransferFunction:
    """T(s) = C_p (sI - A_p)^-1 B_p of the 6-state augmented plant (paper sec. 5, num(s)/den(s)); ``plant``:
    another plant's (A_p, B_p, C_p) (``sitl.linear_plant``), by default the KH2013A's."""
    a, b, c = plant if plant is not None else (model.A_P, model.B_P, model.C_P)
    return ss_to_tf(a, b, c)


def pfc_tf(num: Sequence[float] = PAPER_PFC[0], den: Sequence[float] = PAPER_PFC[1]) -> TransferFunction:
    """D(s) = num/den, validated (paper secs. 2 and 5: D(s) = 1/C(s))."""
    n, d = validate_pfc(num, den)
    return ct().tf(n, d)


def augmented_tf(plant: TransferFunction, pfc: TransferFunction) -> TransferFunction:
    """F(s) = T(s) + D(s), the plant the adaptive law sees (paper sec. 5, num_F(s)/den_F(s)).

    Not normalised: with the paper's D = 10/(4s + 40), den_F leads with 4 and num_F with 10, as printed."""
    return plant + pfc


def augmented_realisation(pfc_num: Sequence[float] = PAPER_PFC[0], pfc_den: Sequence[float] = PAPER_PFC[1], plant=None):
    """State space (A, B, C) of F = T + D: the plant (A_p, B_p, C_p) in parallel with a realisation of
    D, which is what the controller computes (paper sec. 5, Fig. 5: y_a = y_p + D(s) u_p).  ``plant``: another
    plant's (A_p, B_p, C_p), by default the KH2013A's."""
    a_p, b_p, c_p = plant if plant is not None else (model.A_P, model.B_P, model.C_P)
    n, d = validate_pfc(pfc_num, pfc_den)
    dss = ct().tf2ss(ct().tf(n, d))
    nd = dss.nstates
    m = a_p.shape[0]
    a = np.zeros((m + nd, m + nd))
    a[:m, :m] = a_p
    a[m:, m:] = dss.A
    b = np.vstack([b_p, dss.B])
    c = np.hstack([c_p, dss.C])
    return a, b, c


# --------------------------------------------------------------------------- W-ASPR conditions
def relative_degree(num, den) -> int:
    """deg den - deg num (paper sec. 2: the augmented plant must have relative degree 0 or 1)."""
    return poly(den, "den").size - poly(num, "num").size


def hf_gain(num, den) -> float:
    """High-frequency gain lim s^r N(s)/D(s) = lead(num)/lead(den), r the relative degree (paper sec. 2:
    the eigenvalues of C_p B_p, which is this number for relative degree 1, must be positive)."""
    return float(poly(num, "num")[0] / poly(den, "den")[0])


def is_minimum_phase(num) -> bool:
    """All finite zeros in the open left half plane (paper sec. 2, W-ASPR condition)."""
    n = poly(num, "num")
    return bool(n.size == 1 or np.all(np.roots(n).real < 0))


def is_waspr(num, den) -> bool:
    """W-ASPR test for a SISO plant (paper sec. 2): minimum phase, relative degree <= 1, hf gain > 0."""
    return is_minimum_phase(num) and relative_degree(num, den) in (0, 1) and hf_gain(num, den) > 0


def damping_ratio(z: complex) -> float:
    """-Re z / |z|: how far a zero of F is from the imaginary axis (1 for the origin, by convention)."""
    mag = abs(z)
    return -z.real / mag if mag > 0 else 1.0


# --------------------------------------------------------------------------- steady state
def dc_gain(num, den) -> float:
    """N(0)/D(0)."""
    n, d = poly(num, "num"), poly(den, "den")
    if d[-1] == 0.0:
        return math.inf
    return float(n[-1] / d[-1])


def steady_state_offset(t_dc: float, d_dc: float, command: float) -> dict[str, float]:
    """Steady-state error the PFC adds (paper sec. 5, Fig. 5: y_a = y_p + D(s) u_p).

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
