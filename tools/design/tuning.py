"""A PFC and a fixed-gain baseline designed for any linear plant (``python -m tools.pfc design PLANT``).  No I/O.

PFC (Barkana's rule, paper sec. 2: D(s) = 1/C(s), C a stabilising controller of T): C(s) = g (s + a), the
family of the paper's C(s) = (4s + 40)/10.  For each corner a of a grid, the critical gain g* at which
1 + g (s + a) T(s) first goes unstable (``unstable_gain_bands``); C takes g = g*/margin (a gain margin of
``margin``), so D(s) = k/(s + a) with k = margin/g*.  The zeros of F = T + D are the closed-loop poles of
1 + C T (F = (1 + C T)/C), so F is minimum phase by construction; its relative degree is 1 (T's is >= 2, D's
is 1) and its high-frequency gain is k > 0: W-ASPR.  Among the corners whose F has no unstable K_e band in
continuous time nor in the loop sampled at the control rate below ``ke_floor``, the one with the least
steady-state offset (the PFC's D(0) = k/a) is chosen; ties go to the best-damped zeros.

Adaptation weights: the paper's Gamma = 10 (all six) were tuned on the KH2013A; for another plant the designer
flies the reference scenario in-process on the linear plant for Gamma in GAMMAS and keeps the smallest whose
CL-SAC ise_ref is within 1.5x of the best of the grid without saturating the surface.

Baseline: the PID of ``autopilot.baseline`` (C(z) = K_p + K_i T z/(z - 1) + K_d (z - 1)/(T z) on the ZOH plant),
on a grid of K_p and K_d/K_p with K_i = K_p/10 s^-1, keeping the largest gain crossover up to the reference
model's bandwidth (|A_m| = 5 rad/s: it follows the open-loop reference model, no need to be faster) with a phase
margin >= 60 deg and a gain margin >= 10 dB (``tools.design.margins.baseline_margins``, python-control).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tools.design._common import AnalysisError, ct, fmt_complex
from tools.design.aspr import (
    augmented_realisation,
    damping_ratio,
    dc_gain,
    is_waspr,
    plant_tf,
    tf_coefficients,
)
from tools.design.bands import discrete_bands, unstable_gain_bands

CORNERS = tuple(float(a) for a in np.round(np.logspace(-1, 2, 16), 4))  # a of C = g (s + a), 1/s
GAMMAS = (10.0, 30.0, 100.0, 300.0, 1000.0)
MARGIN = 3.0  # gain margin of C in feedback with T (9.5 dB)
KE_FLOOR = 50.0  # the sampled loop may go unstable only above this K_e (the law's K_e stays far below)
PM_MIN_DEG, GM_MIN_DB, CROSSOVER_MAX = 60.0, 10.0, 5.0


class PfcDesignError(AnalysisError):
    """No PFC of the family makes the plant W-ASPR with the required margin; the message says why."""


@dataclass
class PfcDesign:
    k: float
    a: float
    critical_gain: float  # g* of C = g (s + a)
    margin: float
    offset_deg: float  # steady-state error the PFC adds at a 10 deg command
    min_zero_damping: float
    considered: int  # corners tried
    accepted: int  # corners that passed every check
    rejected: dict = field(default_factory=dict)  # reason -> count

    @property
    def num(self) -> tuple[float, ...]:
        return (self.k,)

    @property
    def den(self) -> tuple[float, ...]:
        return (1.0, self.a)

    def explain(self) -> str:
        return (
            f"D(s) = 1/C(s), C(s) = {1 / self.k:.6g} (s + {self.a:g}) (Barkana, paper sec. 2): C stabilises the "
            f"plant up to the gain {self.critical_gain:.6g} (s + {self.a:g}), and flies at 1/{self.margin:g} of it; "
            f"the corner a = {self.a:g} 1/s is the one of {self.accepted} acceptable (of {self.considered} tried) "
            f"with the least steady-state offset ({self.offset_deg:.3g} deg at 10 deg)"
        )


def _critical_gain(tn: np.ndarray, td: np.ndarray, a: float, margin: float = MARGIN) -> float | str:
    """Least g > 0 making 1 + g (s + a) T unstable (inf if none); if it is unstable already for small g, why not (no
    gain stabilises it, or only a window of gains above 0 does).

    A plant with an unstable pole (J3Cub's slow spiral at 60 kt) is unstable for small g: C then stabilises it in a
    window (g_lo, g_hi), and the window's top is the critical gain if C can fly at g_hi / margin with a gain margin
    of ``margin`` below too (g_hi / margin >= margin g_lo); else the reason."""
    bands = unstable_gain_bands(np.polymul(tn, [1.0, a]), td)
    if not bands:
        return math.inf
    first = bands[0]
    if first.low > 1e-12:
        return first.low
    unstable = _open_loop_unstable(td)
    if math.isinf(first.high):
        return "no gain g > 0 of C = g (s + a) stabilises the plant" + unstable
    g_lo, g_hi = first.high, bands[1].low if len(bands) > 1 else math.inf
    if min(g_hi, 1e6) / margin >= margin * g_lo:
        return g_hi  # a window (g_lo, g_hi) wide enough to fly at g_hi / margin with a margin below as well
    return (
        f"C = g (s + a) stabilises the plant only in a window of gains ({g_lo:.3g}, {g_hi:.3g}), too narrow for a "
        f"gain margin of {margin:g} on both sides" + unstable
    )


def check_authority(tn: np.ndarray, td: np.ndarray, u_limit_rad: float, amplitude_rad: float, period_s: float) -> None:
    """Refuse a plant the surface cannot move enough to follow the reference scenario (the scenario the adaptation
    weights are chosen on): a command of amplitude A at the square wave's fundamental w0 = 2 pi / period needs
    |T(j w0)| u_limit >= A, whatever the controller (a necessary condition: the command's fundamental alone is
    4/pi A).  A surface gain of 1e-300, or a plant far slower than the command, is told here in numbers."""
    w0 = 2.0 * math.pi / period_s
    with np.errstate(all="ignore"):
        gain = abs(np.polyval(tn, 1j * w0) / np.polyval(td, 1j * w0))
    reach = gain * u_limit_rad
    if not reach >= amplitude_rad:  # NaN too
        raise PfcDesignError(
            f"the surface cannot move this plant enough: at its {math.degrees(u_limit_rad):.3g} deg limit it rolls it "
            f"by at most {math.degrees(reach):.3g} deg at {w0:.3g} rad/s (|T(j w)| = {gain:.3g}; the reference "
            f"scenario's {period_s:g} s square wave of {math.degrees(amplitude_rad):g} deg needs "
            f"{math.degrees(amplitude_rad):g} deg there)"
        )


def _open_loop_unstable(td: np.ndarray) -> str:
    poles = np.roots(td)
    bad = poles[poles.real >= 0]
    if not bad.size:
        return ""
    return f" (the plant is open-loop unstable: pole at {fmt_complex(bad[np.argmax(bad.real)])})"


KE_UNSTABLE_OPEN_LOOP = 0.01  # an unstable plant's band 0 < K_e < this: the adaptive K_e leaves it within ms


def _plant_band(band) -> bool:
    """A band of 1 + K_e F that starts at 0 and ends below ``KE_UNSTABLE_OPEN_LOOP``: the plant's own slow unstable
    mode (F has T's poles), which any K_e past it stabilises; not a reason to refuse a PFC."""
    return band.low <= 1e-12 and band.high < KE_UNSTABLE_OPEN_LOOP


def design_pfc(
    plant, *, rate_hz: float = 100.0, margin: float = MARGIN, corners=CORNERS, ke_floor: float = KE_FLOOR
) -> PfcDesign:
    """The PFC D = k/(s + a) for ``plant`` = (A_p, B_p, C_p); raises PfcDesignError if none qualifies."""
    t = plant_tf(plant)
    tn, td = tf_coefficients(t)
    return _design_pfc(t, tn, td, plant, rate_hz, margin, corners, ke_floor)


ILL_CONDITIONED = "its root locus is numerically too ill-conditioned to analyse"


def _design_pfc(t, tn, td, plant, rate_hz: float, margin: float, corners, ke_floor: float) -> PfcDesign:
    if td.size - tn.size < 2:
        raise PfcDesignError(
            f"the plant's relative degree is {td.size - tn.size}: a first-order PFC needs >= 2 for F of relative "
            "degree 1"
        )
    t_dc = dc_gain(tn, td)
    rejected: dict[str, int] = {}
    best = None
    for a in corners:
        try:
            cand = _corner(t, tn, td, t_dc, plant, a, rate_hz, margin, len(corners), ke_floor)
        except AnalysisError:
            cand = ILL_CONDITIONED
        if isinstance(cand, str):
            rejected[cand] = rejected.get(cand, 0) + 1
            continue
        offset, damping = cand.offset_deg, cand.min_zero_damping
        if best is None or (round(abs(offset), 9), -damping) < (round(abs(best.offset_deg), 9), -best.min_zero_damping):
            best = cand
        rejected["accepted"] = rejected.get("accepted", 0) + 1
    if best is None:
        why = "; ".join(f"{n} corner(s): {r}" for r, n in rejected.items())
        raise PfcDesignError(
            f"no PFC k/(s + a) makes this plant W-ASPR with a gain margin of {margin:g} ({why}){_unstable_note(td)}"
        )
    best.accepted = rejected.pop("accepted")
    best.rejected = rejected
    return best


def _corner(t, tn, td, t_dc, plant, a, rate_hz, margin, considered, ke_floor) -> PfcDesign | str:
    """The candidate PFC of the corner ``a``, or why the corner is rejected."""
    g = _critical_gain(tn, td, a, margin)
    if isinstance(g, str):
        return g
    if math.isinf(g):
        g = 1e6  # stable for every gain: fly a high one (a small PFC)
    k = margin / g
    num, den = (k,), (1.0, a)
    f = t + _tf(num, den)
    fn, fd = tf_coefficients(f)
    if not is_waspr(fn, fd):
        return "F not W-ASPR"
    real = augmented_realisation(num, den, plant)
    if [b for b in unstable_gain_bands(fn, fd, realisation=real) if not _plant_band(b)]:
        return "1 + Ke F unstable for some Ke"
    low = [b.low for b in discrete_bands(real, rate_hz) if not _plant_band(b)]
    if low and min(low) < ke_floor:
        return f"sampled loop unstable for Ke < {ke_floor:g}"
    zeros = np.roots(fn)
    damping = float(min(damping_ratio(z) for z in zeros)) if zeros.size else 1.0
    offset = _offset_deg(t_dc, k / a)
    return PfcDesign(k, a, g, margin, offset, damping, considered, 0)


def _unstable_note(td: np.ndarray) -> str:
    """The plant's unstable poles, when it has some: the reason C = g (s + a) cannot fly at small gains."""
    poles = [p for p in np.roots(td) if p.real >= 0.0]
    if not poles:
        return ""
    text = ", ".join(f"{p.real:+.4g}" if abs(p.imag) < 1e-9 else f"{p.real:+.4g}{p.imag:+.4g}j" for p in poles)
    return f"; the plant has {len(poles)} unstable pole(s) at {text} 1/s"


def _tf(num, den):
    from tools.design._common import ct

    return ct().tf(list(num), list(den))


def _offset_deg(t_dc: float, d_dc: float, command_deg: float = 10.0) -> float:
    """y_p = y_a - D(0) u at steady state, y_a = command: offset = command D(0)/(T(0) + D(0))."""
    if math.isinf(t_dc):
        return 0.0
    return command_deg * d_dc / (t_dc + d_dc)


@dataclass
class BaselineDesign:
    kp: float
    ki: float
    kd: float
    margins: dict


BASELINE_KPS = tuple(float(k) for k in np.logspace(-2, 1, 19))
BASELINE_TD_RATIOS = (0.0, 0.1, 0.2, 0.3)
CROSSOVER_GRID = 8000  # frequencies of the sampled loop's |L| scan (log-spaced up to Nyquist): 0.16 % apart
CROSSOVER_SLACK = 1.01  # the scan's crossover brackets widened by 1 %


def crossover_range(loop, dt: float) -> tuple[float, float]:
    """Bounds (rad/s) on every gain crossover of the sampled loop ``loop`` (a python-control tf in z): |L(e^{jwT})|
    on a log grid up to Nyquist, each sign change of |L| - 1 bracketed by its two grid points and widened by
    ``CROSSOVER_SLACK``; (lowest, highest) of those brackets, or (0, inf) when the scan cannot bound them (no sign
    change, or |L| >= 1 still at Nyquist)."""
    num, den = (np.asarray(c, dtype=float) for c in (loop.num[0][0], loop.den[0][0]))
    w = np.logspace(-3, math.log10(0.999 * math.pi / dt), CROSSOVER_GRID)
    z = np.exp(1j * w * dt)
    mag = np.abs(np.polyval(num, z) / np.polyval(den, z))
    above = mag >= 1.0
    flips = np.flatnonzero(above[1:] != above[:-1])
    if not len(flips) or above[-1] or not np.all(np.isfinite(mag)):
        return 0.0, math.inf
    return float(w[flips[0]] / CROSSOVER_SLACK), float(w[flips[-1] + 1] * CROSSOVER_SLACK)


def design_baseline(plant, *, rate_hz: float = 100.0, delay_steps: int = 0) -> BaselineDesign:
    """The fixed-gain PID for ``plant``: the largest crossover <= 5 rad/s at PM >= 60 deg and GM >= 10 dB;
    ``delay_steps``: with that many control periods of delay in front of the plant (``baseline_margins``).

    The grid (``BASELINE_KPS`` x ``BASELINE_TD_RATIOS``, K_i = K_p/10) is searched for the design the brute-force
    search gives (every point's margins, python-control's, the first of equal crossovers in grid order), in fewer
    margin computations: each point's gain crossovers are bracketed by a scan of |L| (``crossover_range``); a point
    all of whose crossovers lie above 5 rad/s cannot qualify, and the points are taken by their highest bracket, so
    once one qualifies with crossover W, a point bracketed below W cannot beat it (python-control's crossover is one
    of the loop's).  ``tests/tools/design/test_pfc_design.py`` checks it against the brute force."""
    from autopilot.baseline import BaselineConfig
    from tools.design.aspr import plant_tf
    from tools.design.margins import baseline_margins, sampled_loop

    control = ct()
    dt = 1.0 / rate_hz
    sampled = control.c2d(plant_tf(plant), dt, "zoh")
    points = []
    for kp in BASELINE_KPS:
        for td_ratio in BASELINE_TD_RATIOS:
            cfg = BaselineConfig(control_rate_hz=rate_hz, kp=kp, ki=kp / 10.0, kd=kp * td_ratio)
            low, high = crossover_range(sampled_loop(cfg, delay_steps=delay_steps, sampled_plant=sampled), dt)
            if low <= CROSSOVER_MAX:  # else every crossover is above the limit: it cannot qualify
                points.append((len(points), cfg, high))
    best = None  # (crossover, grid index, design)
    for index, cfg, high in sorted(points, key=lambda p: -p[2]):  # stable: grid order among equal brackets
        if best is not None and high < best[0]:
            break  # this point's crossover, and every later one's, is below the best's
        m = baseline_margins(cfg, plant=plant, delay_steps=delay_steps)
        ok = (
            m["closed_loop_stable"]
            and m["phase_margin_deg"] >= PM_MIN_DEG
            and m["gain_margin_db"] >= GM_MIN_DB
            and m["gain_crossover_rad_s"] <= CROSSOVER_MAX
        )
        w = m["gain_crossover_rad_s"]
        if ok and (best is None or w > best[0] or (w == best[0] and index < best[1])):
            best = (w, index, BaselineDesign(cfg.kp, cfg.ki, cfg.kd, m))
    if best is None:
        raise PfcDesignError(
            f"no PID of the grid gives PM >= {PM_MIN_DEG:g} deg and GM >= {GM_MIN_DB:g} dB "
            f"below {CROSSOVER_MAX:g} rad/s"
        )
    return best[2]


def choose_gamma(plant_text: str, num, den, u_limit_rad: float, gammas=GAMMAS) -> tuple[float, list[dict]]:
    """Gamma (all six adaptation weights) for the plant file ``plant_text``: the smallest of ``gammas`` whose CL-SAC
    ise_ref on the reference scenario (in-process, linear plant) is within 1.5x of the grid's best, without
    saturating; returns (gamma, the rows flown)."""
    from dataclasses import replace

    from autopilot.config import ClSacConfig
    from tools.experiment.scenario import PAPER, PAPER_RUNS, run_inprocess

    scenario = replace(PAPER, plant=plant_text, u_limit_rad=u_limit_rad)
    rows = []
    for g in gammas:
        base = ClSacConfig(pfc_num=tuple(num), pfc_den=tuple(den), **{f"gamma_{n}": g for n in GAMMA_NAMES})
        res = run_inprocess(scenario, PAPER_RUNS[1], base=base)
        sat = bool(np.max(np.abs(res.series["u"])) >= u_limit_rad * (1 - 1e-9))
        rows.append({"gamma": g, "ise_ref": res.metrics["ise_ref"], "energy": res.metrics["energy"], "saturated": sat})
    gamma = pick_gamma(rows)
    if gamma is None:
        raise PfcDesignError("CL-SAC saturates the surface for every adaptation weight of the grid")
    return gamma, rows


GAMMA_WITHIN = 1.5  # a Gamma is good enough when its ise_ref is at most this times the grid's best


def pick_gamma(rows: list[dict]) -> float | None:
    """The rule of ``choose_gamma`` and ``tools.design.mimo.choose_gamma_mimo``: of the rows (``gamma``, ``ise_ref``,
    ``saturated``) that did not saturate and have a finite ise_ref, the smallest gamma whose ise_ref is at most
    GAMMA_WITHIN times the least of them (the weakest adaptation that tracks about as well as the best); None when
    no row qualifies.  The smallest, not the best: a larger Gamma buys little ise_ref for more effort and a loop
    nearer its sampled stability limit."""
    ok = [r for r in rows if not r["saturated"] and math.isfinite(r["ise_ref"])]
    if not ok:
        return None
    best = min(r["ise_ref"] for r in ok)
    return min(r["gamma"] for r in ok if r["ise_ref"] <= GAMMA_WITHIN * best)


GAMMA_NAMES = ("pe", "ie", "px", "ix", "pu", "iu")


# ---------------------------------------------------------------------------------------------- faulted plants
def faulted_plant(plant, roll_rate: int | None, effect):
    """The linear plant ``plant`` = (A_p, B_p, C_p), servo last, under a ``sitl.damage.Effect``'s airframe change, as
    the SITL flies it (docs/faults.md): effectiveness scales the deflection's column of the airframe rows and
    damping the roll rate's own term (``sitl.damage.airframe_matrix``).  A delay is not a change of (A, B, C): give
    it to ``design_baseline`` as ``delay_steps``.  Stuck, off and a rate limit are no linear plant (ValueError): the
    kinds whose record (``sitl.fault_kinds.FaultKind.design``) has no design."""
    from sitl import damage
    from sitl.fault_kinds import KINDS

    if any(k.design is None and k.group == "servo" and k.active(effect) for k in KINDS.values()):
        raise ValueError("stuck, off and rate faults are not a linear plant: nothing to design on")
    a_p, b_p, c_p = (np.asarray(m, dtype=float) for m in plant)
    return damage.airframe_matrix(a_p, effect, roll_rate), b_p, c_p


# ------------------------------------------------------------------------------- the PID bound (continuous gains)
TD_MAX = 1.0  # s: the derivative time K_d/K_p searched, 0..TD_MAX (the grid's stops at 0.3)
KP_RANGE = (1e-2, 10.0)  # the grid's K_p range
FREQ_POINTS = 3000  # the fast margins' frequency grid (log-spaced to Nyquist); each crossing refined by Brent


class _Loop:
    """The sampled PID loop L(z) = K_p L1(z; T_d) on a ZOH-sampled plant with z^-d, K_i = K_p/10 (the rule's),
    evaluated with numpy: its margins as ``tools.design.margins.baseline_margins`` gives them (python-control's
    ``stability_margins``: the phase crossing nearest |L| = 1, the gain crossing of least |PM|), faster."""

    def __init__(self, plant, rate_hz: float, delay_steps: int):
        control = ct()
        self.T = 1.0 / rate_hz
        sampled = control.c2d(plant_tf(plant), self.T, "zoh")
        self.pn = np.asarray(sampled.num[0][0], dtype=float)
        self.pd = np.polymul(np.asarray(sampled.den[0][0], dtype=float), [1.0] + [0.0] * int(delay_steps))
        self.den = np.polymul([self.T, -self.T, 0.0], self.pd)  # C's (T z^2 - T z) times the plant's and z^d
        self.w = np.logspace(-3, math.log10(0.999 * math.pi * rate_hz), FREQ_POINTS)

    def num(self, kp: float, td: float) -> np.ndarray:
        T, ki, kd = self.T, kp / 10.0, kp * td
        return np.polymul([kd + kp * T + ki * T * T, -(kp * T + 2 * kd), kd], self.pn)

    def response(self, num: np.ndarray, w) -> np.ndarray:
        z = np.exp(1j * np.asarray(w) * self.T)
        return np.polyval(num, z) / np.polyval(self.den, z)

    def margins(self, kp: float, td: float) -> dict:
        """``baseline_margins``' dict for the PID (kp, kp/10, kp td) on this loop."""
        from scipy.optimize import brentq

        num = self.num(kp, td)
        resp = self.response(num, self.w)

        def mod(w):
            return abs(self.response(num, w)) - 1.0

        def arg(w):
            return float(np.angle(-self.response(num, w)))

        a = np.angle(-resp)
        idx = np.flatnonzero(np.diff(np.sign(a)))
        idx = idx[np.real(resp[idx]) <= 0]
        w180 = np.array([brentq(arg, self.w[i], self.w[i + 1]) for i in idx])
        m = np.abs(resp) - 1.0
        wc = np.array([brentq(mod, self.w[i], self.w[i + 1]) for i in np.flatnonzero(np.diff(np.sign(m)))])
        with np.errstate(all="ignore"):
            gm_all = 1.0 / np.abs(self.response(num, w180)) if w180.size else np.array([])
        pm_all = np.remainder(np.angle(self.response(num, wc), deg=True), 360.0) - 180.0 if wc.size else np.array([])
        if gm_all.size and not np.isinf(gm_all).all():
            with np.errstate(all="ignore"):
                g = int(np.flatnonzero(np.abs(np.log(gm_all)) == np.min(np.abs(np.log(gm_all))))[0])
            gm, wg = float(gm_all[g]), float(w180[g])
        else:
            gm, wg = math.inf, math.nan
        if pm_all.size:
            p = int(np.flatnonzero(np.abs(pm_all) == np.min(np.abs(pm_all)))[0])
            pm, wp = float(pm_all[p]), float(wc[p])
        else:
            pm, wp = math.inf, math.nan
        poles = np.roots(np.polyadd(self.den, num))
        return {
            "gain_margin_db": 20.0 * math.log10(gm) if gm > 0 and math.isfinite(gm) else math.inf,
            "phase_margin_deg": pm,
            "phase_crossover_rad_s": wg,
            "gain_crossover_rad_s": wp,
            "closed_loop_stable": bool(np.max(np.abs(poles)) < 1.0),
        }

    def kp_at(self, w: float, td: float) -> float:
        """The K_p that puts |L| = 1 at ``w`` (L is linear in K_p for a fixed T_d)."""
        return 1.0 / abs(self.response(self.num(1.0, td), w))


def meets(m: dict) -> bool:
    """The design rule's constraints: closed loop stable, PM >= 60 deg, GM >= 10 dB, crossover <= 5 rad/s."""
    return bool(
        m["closed_loop_stable"]
        and m["phase_margin_deg"] >= PM_MIN_DEG
        and m["gain_margin_db"] >= GM_MIN_DB
        and m["gain_crossover_rad_s"] <= CROSSOVER_MAX
    )


def _score(m: dict, td: float) -> tuple:
    """The rule's objective, to maximise: the crossover (to 1e-4 rad/s), then the least derivative time T_d (ties:
    the crossover's 5 rad/s cap is reached along a curve of gains; the least derivative action amplifies the
    turbulence least, and in the flights it tracks best)."""
    return (round(m["gain_crossover_rad_s"], 4), -td)


def _best_at(loop: _Loop, td: float) -> tuple | None:
    """(score, kp, margins) of the largest crossover meeting the rule at derivative time ``td``: K_p = 1/|L1(w)|
    for w scanned down from 5 rad/s by 10 % steps, the first that meets the rule refined by bisection against the
    step above it; None if no w down to 0.05 rad/s does."""

    def at(w):
        kp = loop.kp_at(w, td)
        if not KP_RANGE[0] <= kp <= KP_RANGE[1]:
            return kp, None
        m = loop.margins(kp, td)
        return kp, (m if meets(m) else None)

    w_hi, w = None, CROSSOVER_MAX * (1.0 - 1e-7)  # the cap, a hair inside (|L| = 1 is solved to ~1e-8)
    while w >= 0.05:
        kp, m = at(w)
        if m is not None:
            break
        w_hi, w = w, w * 0.9
    else:
        return None
    lo = (w, kp, m)
    if w_hi is not None:
        a, b = w, w_hi
        for _ in range(16):  # 10 % / 2^16: 2e-6 relative
            mid = 0.5 * (a + b)
            kp_m, m_m = at(mid)
            if m_m is not None:
                a, lo = mid, (mid, kp_m, m_m)
            else:
                b = mid
    _, kp, m = lo
    return _score(m, td), kp, m


def design_pid_bound(plant, *, rate_hz: float = 100.0, delay_steps: int = 0, td_max: float = TD_MAX) -> BaselineDesign:
    """The rule of ``design_baseline`` (the largest crossover <= 5 rad/s at PM >= 60 deg, GM >= 10 dB, K_i = K_p/10)
    over continuous gains: K_p in ``KP_RANGE`` and T_d = K_d/K_p in [0, ``td_max``] s, ties at the 5 rad/s cap
    broken by the least T_d; ``delay_steps`` control periods of delay in the loop (z^-d).

    For each T_d the crossover fixes K_p (|L| = 1 there and L is linear in K_p), so the search is over (w, T_d):
    w by a 10 % scan down from the cap then bisection, T_d on a grid of 21 refined three times around the best
    (7 points each: T_d to 1e-3 s).  The winner's margins are checked with python-control (``baseline_margins``);
    ``tests/tools/experiment/damage/test_damage.py`` checks it against a brute-force search over (K_p, T_d)."""
    from autopilot.baseline import BaselineConfig
    from tools.design.margins import baseline_margins

    loop = _Loop(plant, rate_hz, delay_steps)
    found = []
    tds = np.linspace(0.0, td_max, 21)
    step = tds[1] - tds[0]
    for _round in range(4):
        for td in tds:
            r = _best_at(loop, float(td))
            if r is not None:
                found.append((r[0], float(td), r[1], r[2]))
        if not found:
            break
        best_td = max(found)[1]
        tds = np.clip(np.linspace(best_td - step, best_td + step, 7), 0.0, td_max)
        step = tds[1] - tds[0]
    if not found:
        raise PfcDesignError(
            f"no PID with K_p in {KP_RANGE} and K_d/K_p <= {td_max:g} s gives PM >= {PM_MIN_DEG:g} deg and GM >= "
            f"{GM_MIN_DB:g} dB below {CROSSOVER_MAX:g} rad/s"
        )
    _score_, td, kp, _m = max(found)
    for _ in range(20):  # python-control's margins on the winner: the rule as design_baseline checks it
        cfg = BaselineConfig(control_rate_hz=rate_hz, kp=kp, ki=kp / 10.0, kd=kp * td)
        m = baseline_margins(cfg, plant=plant, delay_steps=delay_steps)
        if meets(m):
            return BaselineDesign(cfg.kp, cfg.ki, cfg.kd, m)
        kp *= 0.999  # on the constraint's edge: a hair inside
    raise PfcDesignError(f"the PID bound ({kp:.6g}, T_d {td:.6g} s) fails python-control's margins")
