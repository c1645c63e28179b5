"""The adaptive-law bench's designs for any plant (issue 38): MRAC, CRM-MRAC, L1 and INDI gains from the plant's
linear roll model, each by a stated rule; ``python -m tools.design.laws PLANT [--out FILE]`` writes them as the
``NAME value`` lines of a parameter file (``sitl/plants/*.params``).

The roll model.  A plant's linear model (``tools.design.linearise.linear_model``: A_p, B_p, C_p with the servo's two
states last, and the index of the roll-rate state) gives every law's design model on x = [phi, p] by residualising
the other states x_2 (sideslip, yaw rate, the servo: x_2' = 0, the singular perturbation approximation, which keeps
the plant's steady-state gain):

    x' = A x + b u,   A = A_11 - A_12 A_22^-1 A_21,   b = b_1 - A_12 A_22^-1 b_2

On the KH2013A the rudder rolls the aircraft mostly through the dutch roll (r and v), so b_p = 196 1/s^2 per rad,
three times the rudder's immediate A_p[p, delta] = 59.7.  A plant with no roll-rate state, an output other than
one state, or no positive effectiveness cannot be designed: the reason is returned instead of a design.

The rules (a = 5 1/s, the paper's reference model 5 / (s + 5), Jana & Bhat 2017 sec. 5.1; ROBUST_GAINS = the
surface's effect x 0.5, 1, 1.4, i.e. -6 dB and +3 dB of gain margin):

* MRAC: the baseline K = [k_i, k_phi, k_p] places the integral-extended design model's poles at -a (1, 2, 3),
  scaled by 0.8^j until u = -K z leaves the full continuous plant (dutch roll and servo included) stable at every
  ROBUST_GAINS factor, and at every gain multiplied by its own factor (all 27 points of ROBUST_GAINS^3); A_ref =
  A - B K; P from A_c^T P + P A_c = -I; the projection box: each gain of K - dK within [min, max] of ROBUST_GAINS
  times its baseline (g_min = 0.5, g_max = 1.4: the gains the baseline was just verified at, so no adaptation,
  a disturbance's drift included, takes the unfaulted plant outside them; docs/adaptive-laws.md), and the ball
  k_max = sqrt(1 + eps) x the box's farthest corner (idle on the box); gamma: the smallest of GAMMAS whose roll
  ise_ref (the paper's +-10 deg square wave, 30 s, on the full linear plant sampled at the control rate, with the
  surface's effect halved) is within 1.5 times the best of the grid without saturating the surface (the rule
  CL-SAC's Gamma is designed by).
* CRM-MRAC: the same, with l = 4 x the reference model's dominant pole (the ratio of the paper's CL-SAC, L_v = 20
  on A_m = -5); gamma by the same rule, flown as CRM-MRAC.
* L1: k_m places A_m's poles at -a (1, 3), scaled as MRAC's; w_c = the largest of the servo's w_n / 2 x 10^(-i/5)
  (i = 0..10; without a servo, a fifth of the Nyquist frequency and down) whose flights at every ROBUST_GAINS
  factor ``settle``; the L1-norm condition lambda = ||G||_L1 L < 1 is then checked with L = |A[p, p]| / b_p (a
  100 % error in the roll damping) and a design whose lambda >= 1 is refused with the value; the largest L the
  chosen w_c covers, 1 / ||G||_L1, is reported.
* INDI: G0 = b_p (the effectiveness at the outer loop's bandwidth); the actuator model tau = 2 zeta / w_n (the
  servo's first moment; 0 without a servo); outer loop k_att = w_n^2, k_rate = 2 zeta w_n with w_n = 2a, zeta = 0.7;
  the command filter a; G_min = G0 / 100; the synchronising filter w_f = the largest of 50 rad/s (Smeur et al.
  2016; at most 0.45 of the Nyquist frequency) x 10^(-i/5), i = 0..5, whose flights with G fixed settle at every
  ROBUST_GAINS factor, zeta_f = 0.55; mu by the gamma rule over MUS.
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from dataclasses import dataclass

import numpy as np

from autopilot.indi import PARAMETERS as INDI_PARAMETERS
from autopilot.indi import Indi, IndiConfig
from autopilot.l1 import L1, L1Config, l1_condition
from autopilot.l1 import PARAMETERS as L1_PARAMETERS
from autopilot.mrac import CRM_PARAMETERS, Mrac, MracConfig
from autopilot.mrac import PARAMETERS as MRAC_PARAMETERS
from autopilot.shared.numerics import zoh

REF_POLE = 5.0  # 1/s, the paper's reference model 5 / (s + 5)
GAMMAS = (0.3, 1.0, 3.0, 10.0, 30.0, 100.0)
MUS = (0.01, 0.1, 1.0, 10.0, 100.0, 1000.0)
# The surface's effect scaled by these in every robustness check: -6 dB and +3 dB of gain margin (the KH2013A's
# rudder-driven dutch roll, 43 rad/s at damping 0.34, leaves little room upwards).
ROBUST_GAINS = (0.5, 1.0, 1.4)
STEPS_DOWN = tuple(10 ** (-i / 5) for i in range(11))  # 1 down to 1/100, five to a decade
LAWS = ("mrac", "crm-mrac", "l1", "indi")


@dataclass(frozen=True)
class RollModel:
    """The design model of a plant's roll channel, and the full linear plant it was read from."""

    a: np.ndarray  # 2 x 2 on [phi, p]: the plant with its other states residualised
    b: np.ndarray  # 2: [b_phi, b_p]
    g_hf: float  # 1/s^2 per rad: the surface deflection's immediate effect on p' (A_p[p, delta]), INDI's G
    servo_wn: float | None  # rad/s
    servo_zeta: float | None
    a_p: np.ndarray
    b_p: np.ndarray
    roll: int  # index of phi in the plant's state
    rate: int  # index of p


def roll_model(a_p, b_p, c_p, rate: int | None) -> RollModel | str:
    """The ``RollModel`` of a linear plant with its servo last, or the reason it has none.  The design model keeps
    x = [phi, p] and residualises the other states x_2 (sideslip, yaw rate, the servo): x_2' = 0, the singular
    perturbation approximation with the plant's steady-state gain (A = A_11 - A_12 A_22^-1 A_21, b = b_1 - A_12
    A_22^-1 b_2)."""
    a_p = np.asarray(a_p, dtype=float)
    b_p = np.asarray(b_p, dtype=float).reshape(-1, 1)
    if rate is None:
        return "no roll-rate state in the plant's model (the roll rate is not one state): no state-feedback law"
    n = a_p.shape[0]
    c = np.asarray(c_p, dtype=float).reshape(-1, n)
    if c.shape[0] != 1 or np.count_nonzero(c[0]) != 1:
        return "the output is not one state (roll): the laws feed back phi and p"
    roll = int(np.flatnonzero(c[0])[0])
    keep = [roll, int(rate)]
    rest = [i for i in range(n) if i not in keep]
    a22 = a_p[np.ix_(rest, rest)]
    if abs(np.linalg.det(a22)) < 1e-12:
        return "the states other than phi and p have a pole at 0: no residualised roll model"
    a = a_p[np.ix_(keep, keep)] - a_p[np.ix_(keep, rest)] @ np.linalg.solve(a22, a_p[np.ix_(rest, keep)])
    b = b_p[keep, 0] - a_p[np.ix_(keep, rest)] @ np.linalg.solve(a22, b_p[rest, 0])
    g_hf = float(a_p[rate, n - 2])
    if not b[1] > 0.0 or not g_hf > 0.0:
        return f"no positive surface effectiveness on the roll rate (b_p = {b[1]:g}, A_p[p, delta] = {g_hf:g})"
    wn2, two_zw = -float(a_p[n - 1, n - 2]), -float(a_p[n - 1, n - 1])
    wn = math.sqrt(wn2) if wn2 > 0 else None
    return RollModel(a, b, g_hf, wn, None if wn is None else two_zw / (2 * wn), a_p, b_p, roll, int(rate))


def place(a: np.ndarray, b: np.ndarray, poles) -> np.ndarray:
    """K with eig(A - b K) = ``poles`` (Ackermann: K = e_n^T [b, A b, ...]^-1 p(A))."""
    n = a.shape[0]
    ctrb = np.column_stack([np.linalg.matrix_power(a, i) @ b for i in range(n)])
    coeffs = np.real(np.poly(poles))
    p_a = sum(c * np.linalg.matrix_power(a, n - i) for i, c in enumerate(coeffs))
    return np.linalg.solve(ctrb.T, np.eye(n)[-1]) @ p_a


def square_wave(t: float, amplitude: float = math.radians(10.0), period: float = 10.0) -> float:
    """The paper's command: +-amplitude, period ``period``, + first."""
    return amplitude if (t % period) < period / 2 else -amplitude


def fly(law, model: RollModel, duration: float = 30.0, effectiveness=None) -> dict[str, np.ndarray]:
    """``law`` flying the full linear plant (its servo included), exact ZOH at the law's rate; ``effectiveness``:
    (t_onset, factor) scaling the surface's effect on the airframe from t_onset on (None: nominal).  Returns the
    time, roll, surface command and the reference 5/(s+5) of the command (rad)."""
    T = law.dt
    a = model.a_p.copy()
    n = a.shape[0]
    nominal = zoh(a, model.b_p, T)
    faulted = nominal
    if effectiveness is not None:
        a_f = a.copy()
        a_f[: n - 2, n - 2] *= effectiveness[1]
        faulted = zoh(a_f, model.b_p, T)
    x = np.zeros(n)
    steps = int(round(duration / T))
    out = {k: np.zeros(steps) for k in ("t", "phi", "u", "ref", "cmd")}
    ref, dec = 0.0, math.exp(-REF_POLE * T)
    for k in range(steps):
        t = k * T
        cmd = square_wave(t)
        u = law.step(x[model.roll], x[model.rate], 0.0, cmd)
        out["t"][k], out["phi"][k], out["u"][k], out["ref"][k], out["cmd"][k] = t, x[model.roll], u, ref, cmd
        phi_d, gam_d = faulted if effectiveness is not None and t >= effectiveness[0] else nominal
        x = phi_d @ x + gam_d[:, 0] * u
        ref = dec * ref + (1 - dec) * cmd
        if not np.all(np.abs(x) < 1e6):
            out = {k2: v[: k + 1] for k2, v in out.items()}
            break
    return out


def ise_ref(run) -> float:
    """int (phi_ref - phi)^2 dt of a ``fly`` run (rad^2 s), inf if it diverged."""
    if len(run["t"]) < 2 or not np.all(np.isfinite(run["phi"])) or np.max(np.abs(run["phi"])) > math.pi:
        return math.inf
    dt = run["t"][1] - run["t"][0]
    return float(np.sum((run["ref"] - run["phi"]) ** 2) * dt)


def settles(run, limit: float, tol_deg: float = 1.0) -> bool:
    """A ``fly`` run of 30 s is finite, its roll within ``tol_deg`` of the reference in the last second of every
    5 s half-period, and its surface saturated at most 25 % of the time."""
    t = run["t"]
    if len(t) < 2 or not math.isfinite(ise_ref(run)) or t[-1] < 29.0:
        return False
    late = (t % 5.0) >= 4.0
    err = np.degrees(np.abs(run["phi"] - run["ref"]))[late]
    return bool(np.max(err) <= tol_deg and np.mean(np.abs(run["u"]) >= limit) <= 0.25)


def _pick(make, grid, model, limit) -> tuple[float, str]:
    """The smallest grid value whose ise_ref is within 1.5x of the best without saturating (module docstring)."""
    scores = []
    for v in grid:
        run = fly(make(v), model)
        scores.append((v, ise_ref(run), bool(np.any(np.abs(run["u"]) >= limit))))
    ok = [s for s in scores if math.isfinite(s[1]) and not s[2]] or [s for s in scores if math.isfinite(s[1])]
    if not ok:
        return math.nan, "every value diverged"
    best = min(s[1] for s in ok)
    chosen = next(s[0] for s in ok if s[1] <= 1.5 * best)
    text = ", ".join(f"{v:g}: {i:.4g}{' (saturated)' if sat else ''}" for v, i, sat in scores)
    return chosen, text


def _unstable(model: RollModel, k: np.ndarray, integral: bool) -> float:
    """The largest real part of the full continuous plant's poles under u = -k_i x_I - k_phi phi - k_p p
    (x_I' = phi)."""
    a, b = model.a_p, model.b_p
    n = a.shape[0]
    m = n + 1 if integral else n
    cl = np.zeros((m, m))
    cl[:n, :n] = a
    gain = np.zeros(m)
    gain[model.roll], gain[model.rate] = k[-2], k[-1]
    if integral:
        cl[n, model.roll] = 1.0
        gain[n] = k[0]
    cl[:n, :] -= np.outer(b[:, 0], gain)
    return float(np.max(np.linalg.eigvals(cl).real))


def box_points(n: int) -> list[np.ndarray]:
    """The gain multipliers the MRAC projection box is verified at: every point of ROBUST_GAINS^n (its corners, the
    middles of its edges and faces, and the baseline's diagonal f (1, ..., 1))."""
    return [np.array(g) for g in itertools.product(ROBUST_GAINS, repeat=n)]


def baseline_gains(model: RollModel, speeds, integral: bool, box: bool = False) -> tuple[np.ndarray, float] | str:
    """K placing the (integral-extended) design model's poles at -a s (a = REF_POLE, s in ``speeds``), scaled by
    0.8^j (j = 0..15) until f K (f in ROBUST_GAINS) all leave the full continuous plant stable (the plant with the
    states the design model residualised: the dutch roll, the servo); with ``box``, also every gain multiplied by
    its own factor of ROBUST_GAINS (``box_points``: MRAC's projection box, the gains its adaptation may reach);
    (K, the scale), or the reason."""
    a_x, b_x = model.a, model.b
    if integral:
        a_x = np.block([[np.zeros((1, 1)), np.eye(1, 2)], [np.zeros((2, 1)), model.a]])
        b_x = np.concatenate([[0.0], model.b])
    for j in range(16):
        scale = 0.8**j
        k = place(a_x, b_x, [-REF_POLE * scale * s for s in speeds])
        gains = [f * k for f in ROBUST_GAINS] + ([g * k for g in box_points(len(k))] if box else [])
        if all(_unstable(model, g, integral) < 0 for g in gains):
            return k, scale
    return "no pole placement down to 0.8^15 of the rule's keeps the full plant stable at gains x 0.5 to x 1.4"


def _robust(make, grid, model: RollModel, limit: float) -> tuple[float, str]:
    """The first value of ``grid`` (fastest first) whose flights of the paper's scenario on the full linear plant with
    the surface's effect scaled by ROBUST_GAINS all ``settle``); (nan, table) if none."""
    table = []
    for v in grid:
        oks = []
        for f in ROBUST_GAINS:
            run = fly(make(v), RollModel(**{**vars(model), "a_p": _scaled(model, f)}))
            oks.append(settles(run, limit))
        table.append(f"{v:.4g}: {'ok' if all(oks) else 'does not settle'}")
        if all(oks):
            return v, ", ".join(table)
    return math.nan, ", ".join(table)


def _model_fields(model: RollModel) -> dict:
    (a11, a12), (a21, a22) = model.a
    return dict(
        a11=float(a11), a12=float(a12), a21=float(a21), a22=float(a22), b1=float(model.b[0]), b2=float(model.b[1])
    )


def design(model: RollModel, control_rate_hz: float = 100.0, u_limit_rad: float = math.radians(30.0)) -> dict:
    """{law: (config, notes) or reason} for ``LAWS`` (module docstring's rules)."""
    a = REF_POLE
    base = dict(control_rate_hz=control_rate_hz, u_limit_rad=u_limit_rad)
    out: dict = {}
    half = RollModel(**{**vars(model), "a_p": _scaled(model, 0.5)})
    placed = baseline_gains(model, (1.0, 2.0, 3.0), integral=True, box=True)
    for name, crm in (("mrac", 0.0), ("crm-mrac", 4.0)):
        if isinstance(placed, str):
            out[name] = placed
            continue
        k, scale = placed
        g_min, g_max = min(ROBUST_GAINS), max(ROBUST_GAINS)
        corner = np.maximum(np.abs(k * (1 - g_max)), np.abs(k * (1 - g_min)))  # the box's farthest corner
        k_max = math.sqrt(1 + MracConfig.proj_eps) * float(np.linalg.norm(corner))  # the ball idle on the box
        cfg = MracConfig(**base, **_model_fields(model), k_i=float(k[0]), k_phi=float(k[1]), k_p=float(k[2]),
                         k_max=k_max, g_min=g_min, g_max=g_max, crm_l=crm * a * scale)  # fmt: skip
        gamma, scores = _pick(lambda g, c=cfg: Mrac(c.with_(gamma=g)), GAMMAS, half, u_limit_rad)
        if not math.isfinite(gamma):
            out[name] = f"no adaptation rate flies the halved effectiveness ({scores})"
            continue
        poles = ", ".join(f"-{a * scale * s:.4g}" for s in (1, 2, 3))
        out[name] = (cfg.with_(gamma=gamma), [
            f"poles {poles} (the rule's x {scale:.4g}): K = [{k[0]:.5g}, {k[1]:.5g}, {k[2]:.5g}]"
            + (f", l = {cfg.crm_l:.4g} 1/s" if crm else ""),
            f"projection box: each gain of K - dK in [{g_min:g}, {g_max:g}] x its baseline (the full plant stable at "
            f"all {3 ** len(k)} points of ROBUST_GAINS^3), k_max = {cfg.k_max:.5g} (the ball around the box)",
            f"gamma = {gamma:g} (ise_ref with the effectiveness halved: {scores})",
        ])  # fmt: skip
    placed = baseline_gains(model, (1.0, 3.0), integral=False)
    if isinstance(placed, str):
        out["l1"] = placed
    else:
        km, scale = placed
        top = model.servo_wn / 2 if model.servo_wn else math.pi * control_rate_hz / 5
        cfg = L1Config(**base, **_model_fields(model), k_phi=float(km[0]), k_p=float(km[1]), omega_c=top)
        w_c, table = _robust(lambda w, c=cfg: L1(c.with_(omega_c=w)), [top * f for f in STEPS_DOWN], model, u_limit_rad)
        big_l = abs(float(model.a[1, 1])) / float(model.b[1])
        if not math.isfinite(w_c):
            out["l1"] = f"no filter bandwidth from {top:.4g} rad/s down to 1/100 of it settles ({table})"
        else:
            cfg = cfg.with_(omega_c=w_c)
            g_norm = l1_condition(cfg, 1.0)
            lam = g_norm * big_l
            if not lam < 1.0:
                out["l1"] = (
                    f"the L1-norm condition fails: ||G||_L1 L = {lam:.4g} >= 1 (w_c = {w_c:.4g} rad/s, L = {big_l:.4g})"
                )
            else:
                out["l1"] = (cfg, [
                    f"A_m poles -{a * scale:.4g}, -{3 * a * scale:.4g} (the rule's x {scale:.4g}): k_m = [{km[0]:.5g}, "
                    f"{km[1]:.5g}]",
                    f"w_c = {w_c:.5g} rad/s: the largest from {top:.4g} down whose flights at surface effect "
                    f"x 0.5, 1, 1.4 settle ({table})",
                    f"L1-norm condition ||G||_L1 L = {g_norm:.4g} x {big_l:.4g} = {lam:.4g} < 1; covers L up to "
                    f"{1 / g_norm:.4g} ({1 / g_norm / (abs(km[0]) + abs(km[1])):.3g} ||k_m||_1)",
                ])  # fmt: skip
    tau = 2 * model.servo_zeta / model.servo_wn if model.servo_wn else 0.0
    top = min(50.0, 0.45 * math.pi * control_rate_hz)
    wn = 2 * a
    g0 = float(model.b[1])
    cfg = IndiConfig(**base, g0=g0, g_min=g0 / 100, omega_f=top, zeta_f=0.55, tau_act=tau, k_att=wn**2,
                     k_rate=2 * 0.7 * wn, omega_r=a, mu=0.0)  # fmt: skip
    w_f, table = _robust(lambda w, c=cfg: Indi(c.with_(omega_f=w)), [top * f for f in STEPS_DOWN[:6]], model,
                         u_limit_rad)  # fmt: skip
    if not math.isfinite(w_f):
        out["indi"] = f"no filter from {top:.4g} rad/s down to a tenth settles ({table})"
        return out
    cfg = cfg.with_(omega_f=w_f)
    mu, scores = _pick(lambda m, c=cfg: Indi(c.with_(mu=m)), MUS, half, u_limit_rad)
    if not math.isfinite(mu):
        out["indi"] = f"no LMS rate flies the halved effectiveness ({scores})"
    else:
        out["indi"] = (cfg.with_(mu=mu), [
            f"G0 = b_p of the design model = {g0:.5g} (A_p[p, delta] = {model.g_hf:.5g}), tau_act = {tau:.4g} s, "
            f"k_att = {wn**2:g}, k_rate = {2 * 0.7 * wn:g}",
            f"w_f = {w_f:.4g} rad/s: the largest from {top:.4g} down whose flights at surface effect x 0.5, 1, "
            f"1.4 (G fixed) settle ({table})",
            f"mu = {mu:g} (ise_ref with G0 twice the true effectiveness: {scores})",
        ])  # fmt: skip
    return out


def _scaled(model: RollModel, factor: float) -> np.ndarray:
    """A_p with the surface's effect on the airframe scaled by ``factor``."""
    a = model.a_p.copy()
    n = a.shape[0]
    a[: n - 2, n - 2] *= factor
    return a


_TABLES = {"mrac": MRAC_PARAMETERS, "crm-mrac": CRM_PARAMETERS, "l1": L1_PARAMETERS, "indi": INDI_PARAMETERS}


def params_lines(designs: dict) -> list[str]:
    """The designs as parameter-file lines: ``# law: note`` comments, then ``NAME value`` per parameter; a law that
    could not be designed as ``# law: not designed: reason``."""
    lines = []
    for law in LAWS:
        d = designs.get(law)
        if d is None:
            continue
        if isinstance(d, str):
            lines.append(f"# {law}: not designed: {d}")
            continue
        cfg, notes = d
        lines += [f"# {law}: {n}" for n in notes]
        lines += [f"{name:<16} {getattr(cfg, field)!r}" for name, field, *_ in _TABLES[law]]
    return lines


def design_plant(plant: str, control_rate_hz: float = 100.0) -> dict | str:
    """``design`` of a plant spec (kh2013a, a plant file, jsbsim:MODEL with its shipped linearisation), at the
    surface limit of its file (+-30 deg for the KH2013A, paper sec. 5.1): the plant file beside its design
    (``sitl.plant_kinds.PlantSpec.design_file``: a plant file itself, a JSBSim model's shipped linearisation)."""
    from sitl import plant as plants

    ps = plants.spec(plant)
    lin = ps.linear_model
    if lin is None:
        return f"no linear model of {plant} (python -m tools.pfc design designs one)"
    limit = math.radians(30.0)
    if ps.design_file is not None:
        limit = plants.spec(str(ps.design_file.with_suffix(".toml"))).model.limit_rad or limit
    model = roll_model(*lin)
    if isinstance(model, str):
        return model
    return design(model, control_rate_hz, limit)


def late_error_deg(run) -> float:
    """max |phi - ref| over the last second of every 5 s half-period of a ``fly`` run (deg); inf if it diverged."""
    if not math.isfinite(ise_ref(run)) or len(run["t"]) < 2:
        return math.inf
    late = (run["t"] % 5.0) >= 4.0
    return float(np.degrees(np.max(np.abs(run["phi"] - run["ref"])[late])))


def fly_report(plant: str, designs: dict) -> list[str]:
    """Each designed law flying the paper's scenario on the plant's full linear model, as designed and with the
    surface's effectiveness dropped to 0.3 at 10 s: ise_ref, the late error, the largest surface."""
    from tools.design.linearise import linear_model

    model = roll_model(*linear_model(plant))
    make = {"mrac": Mrac, "crm-mrac": Mrac, "l1": L1, "indi": Indi}
    lines = [f"# {plant}, linear, 100 Hz: ise_ref (rad^2 s) / late |phi - ref| (deg) / max |u| (deg)"]
    for law in LAWS:
        d = designs.get(law)
        if d is None or isinstance(d, str):
            continue
        cells = []
        for eff in (None, (10.0, 0.3)):
            run = fly(make[law](d[0]), model, effectiveness=eff)
            u_max = math.degrees(np.max(np.abs(run["u"])))
            cells.append(f"{ise_ref(run):.4g} / {late_error_deg(run):.3g} / {u_max:.3g}")
        lines.append(f"#   {law:<9} as designed {cells[0]};  effectiveness 0.3 at 10 s {cells[1]}")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.design.laws", description=__doc__.split("\n\n")[0])
    p.add_argument("plant", help="kh2013a, a plant file, or jsbsim:MODEL")
    p.add_argument("--out", help="write the lines to this file (default: print)")
    p.add_argument("--fly", action="store_true", help="also fly each design on the linear plant and print the numbers")
    args = p.parse_args(argv)
    try:
        designs = design_plant(args.plant)
    except (ValueError, OSError) as exc:  # a plant spec or file that does not read (PlantFileError is a ValueError)
        designs = str(exc)
    if isinstance(designs, str):
        print(f"error: {designs}", file=sys.stderr)
        return 2
    text = "\n".join(
        [f"# adaptive-law bench designs for {args.plant} by python -m tools.design.laws", *params_lines(designs)]
    )
    if args.fly:
        print("\n".join(fly_report(args.plant, designs)))
    if args.out:
        with open(args.out, "w", encoding="utf-8") as f:
            f.write(text + "\n")
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
