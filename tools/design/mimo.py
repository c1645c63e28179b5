"""The design of a square MIMO plant (m inputs, m outputs: ``jsbsim:MODEL:surface=aileron+rudder``).  No I/O.

What ``python -m tools.pfc design`` does when the plant has m > 1 inputs, item by item (the printout says the same):

PFC.  D(s) = diag(D_1, ..., D_m), D_i = k_i/(s + a_i), each the SISO design (``tools.design.tuning.design_pfc``,
Barkana's rule: D_i = 1/C_i, C_i = g_i (s + a_i) at 1/margin of the gain that destabilises the diagonal element
T_ii) of its own loop.  Then the coupled plant is checked, not assumed: with C(s) = diag(C_i), F = T + D =
C^-1 (I + C T), so the transmission zeros of F are the closed-loop poles of T with C(s) in negative feedback.  As
T has relative degree >= 2 in every entry (C_p B_p = 0: the servos), u = -C y = -G (A_c y + y') with y' = C_p A_p x
is a state feedback, and the zeros are the eigenvalues of A_z = A_p - B_p G (C_p A_p + A_c C_p), A_c = diag(a_i),
G = diag(g_i) (``barkana_matrix``).  They are also computed as the finite generalised eigenvalues of F's Rosenbrock
pencil (``transmission_zeros``); the two must agree.  The design is refused unless they lie in the open left half
plane, and the coupled loop's own gain margin rho* (the least rho > 0 making A_p - rho B_p G (...) unstable) is
printed.  W-ASPR (paper sec. 2, MIMO form): F minimum phase, C_F B_F = diag(k_i) symmetric positive definite, so
relative degree 1 in every channel (C_F B_F nonsingular).

K_e bands.  The loop u = -K_e y_a on F along the rays K_e = k I and K_e = k diag(1, 0.1), k diag(0.1, 1) (m = 2):
unstable where an eigenvalue of A_F - k B_F K C_F (continuous) or of e^{A_F T} - k Gamma_F K C_F (the ZOH loop at
the control rate) leaves the left half plane (the unit disc), scanned on a log grid of ``KE_GRID`` points of
k in [1e-4, 1e5] and each edge bisected to 1e-6 relative: a band narrower than the grid's spacing (4 %) can be
missed; the rays are the ones checked, not every matrix K_e.

Adaptation weights.  As SISO (``choose_gamma``): the reference scenario (the roll's +-10 deg, 10 s square wave,
sideslip command 0) flown in-process on the linear MIMO plant with the matrix law for Gamma in ``GAMMAS`` (all six
Gamma = gamma I), the smallest whose roll ise_ref is within 1.5x of the grid's best without saturating a surface.

Baseline.  Two PIDs, one per channel (``autopilot.baseline``'s PID on each error), each ``design_baseline`` of its
diagonal element (loop at a time, the other open), then checked on the coupled sampled plant: each loop's gain and
phase margins with the other loop closed (``loop_margins``, from the frequency response of the loop broken at that
input), each loop's symmetric disk margin (Seiler, Packard, Gahinet 2020: alpha = 1/||S_i - 1/2||_inf) with the
other closed, and the multivariable disk margin's lower bound alpha >= 1/max_w sigma_max(S(e^{jwT}) - I/2) at the
plant input (a full complex perturbation, conservative against the diagonal one a two-loop autopilot meets).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from tools.design._common import AnalysisError

GAMMAS = (10.0, 30.0, 100.0, 300.0, 1000.0)
KE_GRID = 600
KE_RANGE = (1e-4, 1e5)
KE_FLOOR = 50.0  # the sampled loop may go unstable only above this k (as SISO: tuning.KE_FLOOR)


class MimoDesignError(AnalysisError):
    """A square MIMO plant the design cannot make W-ASPR, or a baseline it cannot close; the message says why."""


def channel(plant, i: int):
    """The diagonal element T_ii of ``plant`` = (A_p, B_p, C_p): input i to output i, as a SISO (A, B, C)."""
    a, b, c = (np.asarray(x, dtype=float) for x in plant)
    return a, b[:, i : i + 1], c[i : i + 1, :]


def realisation(plant, pfcs):
    """(A_F, B_F, C_F) of F = T + D, D = diag(k_i/(s + a_i)): the plant's states, then one PFC state per channel."""
    a, b, c = (np.asarray(x, dtype=float) for x in plant)
    n, m = a.shape[0], b.shape[1]
    a_f = np.zeros((n + m, n + m))
    a_f[:n, :n] = a
    a_f[n:, n:] = -np.diag([p[1] for p in pfcs])
    b_f = np.vstack([b, np.eye(m)])
    c_f = np.hstack([c, np.diag([p[0] for p in pfcs])])
    return a_f, b_f, c_f


def transmission_zeros(a, b, c) -> np.ndarray:
    """The finite transmission zeros of the square (A, B, C, 0): the finite generalised eigenvalues of the Rosenbrock
    pencil [[A, B], [C, 0]] - s [[I, 0], [0, 0]]."""
    n, m = a.shape[0], b.shape[1]
    big = np.block([[a, b], [c, np.zeros((m, m))]])
    e = np.zeros_like(big)
    e[:n, :n] = np.eye(n)
    alpha, beta = scipy.linalg.eig(big, e, right=False, homogeneous_eigvals=True)
    finite = np.abs(beta) > 1e-9 * np.maximum(1.0, np.abs(alpha))
    return np.sort_complex(alpha[finite] / beta[finite])


def barkana_matrix(plant, pfcs, rho: float = 1.0) -> np.ndarray:
    """A_p - rho B_p G (C_p A_p + A_c C_p): the plant with C(s) = rho diag(g_i (s + a_i)), g_i = 1/k_i, in negative
    feedback (valid as C_p B_p = 0).  Its eigenvalues at rho = 1 are F's transmission zeros (module docstring)."""
    a, b, c = (np.asarray(x, dtype=float) for x in plant)
    if np.max(np.abs(c @ b)) > 1e-12 * max(1.0, np.max(np.abs(c)) * np.max(np.abs(b))):
        raise MimoDesignError("C_p B_p != 0: a plant of relative degree 1 needs no PFC of this family")
    g = np.diag([1.0 / p[0] for p in pfcs])
    ac = np.diag([p[1] for p in pfcs])
    return a - rho * b @ g @ (c @ a + ac @ c)


def _stable(mat: np.ndarray, discrete: bool) -> bool:
    ev = np.linalg.eigvals(mat)
    return bool(np.max(np.abs(ev)) < 1.0) if discrete else bool(np.max(ev.real) < 0.0)


def _bisect(f, lo: float, hi: float) -> float:
    """The edge between ``lo`` (f false) and ``hi`` (f true), in log space, to 1e-6 relative (either order)."""
    for _ in range(60):
        mid = math.sqrt(lo * hi)
        if f(mid) == f(hi):
            hi = mid
        else:
            lo = mid
        if abs(hi / lo - 1.0) < 1e-6:
            break
    return math.sqrt(lo * hi)


def bands_along(unstable, grid=None) -> list[tuple[float, float]]:
    """The bands [low, high] of k on ``grid`` (default ``KE_GRID`` log points of ``KE_RANGE``) where ``unstable(k)``,
    each edge bisected; low 0 if unstable from the grid's start, high inf if to its end."""
    ks = np.logspace(math.log10(KE_RANGE[0]), math.log10(KE_RANGE[1]), KE_GRID) if grid is None else grid
    flags = [unstable(float(k)) for k in ks]
    out, start = [], (0.0 if flags[0] else None)
    for k0, k1, f0, f1 in zip(ks, ks[1:], flags, flags[1:]):
        if f1 and not f0:
            start = _bisect(unstable, float(k0), float(k1))
        elif f0 and not f1:
            out.append((start, _bisect(unstable, float(k0), float(k1))))
            start = None
    if start is not None:
        out.append((start, math.inf))
    return out


def ke_bands(real, direction: np.ndarray, rate_hz: float | None = None) -> list[tuple[float, float]]:
    """The bands of k > 0 where u = -k K y_a (K = ``direction``) on F = ``real`` is unstable; ``rate_hz``: the loop
    sampled with a zero-order hold at that rate."""
    a_f, b_f, c_f = real
    if rate_hz is None:
        return bands_along(lambda k: not _stable(a_f - k * b_f @ direction @ c_f, False))
    from autopilot.shared.numerics import zoh

    phi, gam = zoh(a_f, b_f, 1.0 / rate_hz)
    return bands_along(lambda k: not _stable(phi - k * gam @ direction @ c_f, True))


def directions(m: int) -> dict[str, np.ndarray]:
    """The rays of K_e checked: k I, and (m = 2) k diag(1, 0.1), k diag(0.1, 1)."""
    out = {"k I": np.eye(m)}
    if m == 2:
        out["k diag(1, 0.1)"] = np.diag([1.0, 0.1])
        out["k diag(0.1, 1)"] = np.diag([0.1, 1.0])
    return out


@dataclass
class MimoPfc:
    pfcs: list[tuple[float, float]]  # (k_i, a_i) of D_i = k_i/(s + a_i)
    designs: list  # tools.design.tuning.PfcDesign of each channel
    zeros: np.ndarray  # F's transmission zeros (Rosenbrock pencil)
    zeros_barkana: np.ndarray  # eig(A_z): the same, from the closed loop
    cb: np.ndarray  # C_F B_F
    coupled_margin: float  # rho*: the least rho making A_p - rho B_p G (...) unstable (inf if none up to 1e3)
    bands: dict = field(default_factory=dict)  # ray -> (continuous bands, sampled bands)

    @property
    def minimum_phase(self) -> bool:
        return bool(self.zeros.size == 0 or np.max(self.zeros.real) < 0.0)

    @property
    def cb_spd(self) -> bool:
        sym = 0.5 * (self.cb + self.cb.T)
        return bool(np.allclose(self.cb, self.cb.T, rtol=0, atol=1e-12) and np.min(np.linalg.eigvalsh(sym)) > 0.0)

    @property
    def waspr(self) -> bool:
        return self.minimum_phase and self.cb_spd


def closed_before(plant, pfcs, i: int):
    """(A, B, C) of channel ``i`` with the loops before it closed by their C_j = g_j (s + a_j), g_j = 1/k_j (the
    sequential loop closure of ``design_pfc_mimo``): A_p - sum_j B_j g_j (C_j A_p + a_j C_j), input i, output i."""
    a, b, c = (np.asarray(x, dtype=float) for x in plant)
    a = a.copy()
    for j, (k, corner) in enumerate(pfcs[:i]):
        a = a - b[:, j : j + 1] @ ((c[j : j + 1] @ np.asarray(plant[0], dtype=float) + corner * c[j : j + 1]) / k)
    return a, b[:, i : i + 1], c[i : i + 1, :]


@dataclass
class ChannelPfc:
    k: float
    a: float
    critical_gain: float
    accepted: int
    considered: int
    rejected: dict

    def explain(self, margin: float) -> str:
        why = "; ".join(f"{n} rejected: {r}" for r, n in self.rejected.items())
        return (
            f"D(s) = 1/C(s), C(s) = {1 / self.k:.6g} (s + {self.a:g}) (Barkana, paper sec. 2), designed on this "
            f"channel with the channels before it closed by their C: C stabilises it up to {self.critical_gain:.6g} "
            f"(s + {self.a:g}) and flies at 1/{margin:g} of it; the corner a = {self.a:g} 1/s is the one of "
            f"{self.accepted} acceptable on the coupled F (of {self.considered} tried; {why or 'none rejected'}) with "
            f"the least D(0) = {self.k / self.a:.3g} (the output's offset per rad of steady surface)"
        )


def _channel_pfc(plant, pfcs, i: int, rate_hz: float, margin: float) -> ChannelPfc:
    """Channel ``i``'s PFC given the ones before it (see ``design_pfc_mimo``)."""
    from tools.design.aspr import damping_ratio, plant_tf, tf_coefficients
    from tools.design.tuning import CORNERS, _critical_gain

    sub = closed_before(plant, pfcs, i)
    tn, td = tf_coefficients(plant_tf(sub))
    m = np.asarray(plant[1]).shape[1]
    rejected: dict[str, int] = {}
    best = None
    for corner in CORNERS:
        g = _critical_gain(tn, td, corner, margin)
        why = None
        if isinstance(g, str):
            why = g
        elif math.isinf(g):
            why = "C stabilises at every gain: no critical gain to take a margin of"
        else:
            trial = [*pfcs, (margin / g, corner)] + [(1.0, 1.0)] * (m - i - 1)
            real = realisation(plant, trial[:m]) if i == m - 1 else None
            if real is not None:
                zeros = transmission_zeros(*real)
                sampled = [b for b in ke_bands(real, np.eye(m), rate_hz) if b[0] < KE_FLOOR]
                if zeros.size and np.max(zeros.real) >= 0.0:
                    why = "F not minimum phase on the coupled plant"
                elif ke_bands(real, np.eye(m)):
                    why = "u = -k y_a (K_e = k I) unstable for some k"
                elif sampled:
                    why = f"sampled loop unstable for k < {KE_FLOOR:g}"
                else:
                    damping = float(min(damping_ratio(z) for z in zeros)) if zeros.size else 1.0
                    cand = (round(margin / g / corner, 12), -damping, ChannelPfc(margin / g, corner, g, 0, 0, {}))
                    if best is None or cand[:2] < best[:2]:
                        best = cand
                    rejected["accepted"] = rejected.get("accepted", 0) + 1
                    continue
        if why is not None:
            rejected[why] = rejected.get(why, 0) + 1
    if best is None:
        raise MimoDesignError(
            f"channel {i + 1}: no PFC k/(s + a) makes F = T + D W-ASPR on the coupled plant with a gain margin of "
            f"{margin:g} (" + "; ".join(f"{n} corner(s): {r}" for r, n in rejected.items()) + ")"
        )
    out = best[2]
    out.accepted, out.considered = rejected.pop("accepted"), len(CORNERS)
    out.rejected = rejected
    return out


def design_pfc_mimo(plant, *, rate_hz: float = 100.0, margin: float = 3.0) -> MimoPfc:
    """D(s) = diag(k_i/(s + a_i)) for the square ``plant`` = (A_p, B_p, C_p), checked on the coupled plant.

    Sequential loop closure: channel 1 (the roll on the aileron) is the SISO design of its diagonal element
    (``tools.design.tuning.design_pfc``: the aileron-only numbers); each next channel is designed on its own element
    with the loops before it closed by their C_j (``closed_before``: on the c172x the rudder-to-sideslip element alone
    has a zero at +0.034 1/s and a negative DC gain, the roll held by the aileron makes it minimum phase and positive),
    and its corner is judged on the coupled F of every channel: minimum phase, stable along K_e = k I for every k in
    continuous time and in the sampled loop below ``KE_FLOOR``; the least D_i(0) wins, ties the best-damped zeros."""
    from tools.design.tuning import PfcDesignError, design_pfc

    m = np.asarray(plant[1]).shape[1]
    try:
        first = design_pfc(channel(plant, 0), rate_hz=rate_hz, margin=margin)
    except PfcDesignError as exc:
        raise MimoDesignError(f"channel 1 (input 1 to output 1): {exc}") from None
    designs, pfcs = [first], [(first.k, first.a)]
    for i in range(1, m):
        d = _channel_pfc(plant, pfcs, i, rate_hz, margin)
        designs.append(d)
        pfcs.append((d.k, d.a))
    real = realisation(plant, pfcs)
    zeros = transmission_zeros(*real)
    az = barkana_matrix(plant, pfcs)
    rho = bands_along(lambda r: not _stable(barkana_matrix(plant, pfcs, r), False), np.logspace(-3, 3, 400))
    out = MimoPfc(
        pfcs=pfcs,
        designs=designs,
        zeros=zeros,
        zeros_barkana=np.sort_complex(np.linalg.eigvals(az)),
        cb=real[2] @ real[1],
        coupled_margin=rho[0][0] if rho else math.inf,
    )
    if not out.minimum_phase:
        worst = out.zeros[np.argmax(out.zeros.real)]
        raise MimoDesignError(
            f"the channels' PFCs leave F = T + D non-minimum phase on the coupled plant (a transmission zero at "
            f"{worst:.4g})"
        )
    for name, k in directions(m).items():
        out.bands[name] = (ke_bands(real, k), ke_bands(real, k, rate_hz))
    return out


# ---------------------------------------------------------------------------------------------- the MIMO flight
@dataclass
class MimoRun:
    metrics: list[dict]  # per channel: ise_ref, max_abs_y, max_abs_u, saturated_fraction
    series: dict  # t, y (N x m), u (N x m), ym_ol (N x m)


def fly_linear(plant, config, *, duration_s: float = 30.0, roll=None, law=None) -> MimoRun:
    """The reference scenario on the linear MIMO ``plant`` (command held over each control period, the plant's exact
    ZOH): channel 1 commanded ``roll(t)`` (default the paper's +-10 deg, 10 s square wave), the others 0; ``config``
    a ``ClSacConfig`` of m channels (or ``law`` any object stepping (y, um) -> u with ``ym_ol``)."""
    from autopilot.clsac import ClSac
    from autopilot.shared.numerics import zoh
    from tools.flight.profiles import Profile

    a, b, c = (np.asarray(x, dtype=float) for x in plant)
    m = b.shape[1]
    dt = 1.0 / config.control_rate_hz
    phi, gam = zoh(a, b, dt)
    profile = roll or Profile.square(amplitude_deg=10.0, period=10.0).value
    law = law or ClSac(config)
    x = np.zeros(a.shape[0])
    n = int(round(duration_s / dt))
    ys, us, yms, ts = np.zeros((n, m)), np.zeros((n, m)), np.zeros((n, m)), np.zeros(n)
    for k in range(n):
        t = k * dt
        y = c @ x
        um = np.zeros(m)
        um[0] = profile(t)
        u = np.asarray(law(y, um), dtype=float)
        ts[k], ys[k], us[k], yms[k] = t, y, u, getattr(law, "ym_ol", np.zeros(m))
        x = phi @ x + gam @ u
    limits = getattr(config, "u_limits_rad", None) or (config.u_limit_rad,) * m
    metrics = []
    for i in range(m):
        sat = np.abs(us[:, i]) >= limits[i] * (1 - 1e-9)
        metrics.append(
            {
                "ise_ref": float(np.sum((ys[:, i] - yms[:, i]) ** 2) * dt),
                "max_abs_y": float(np.max(np.abs(ys[:, i]))),
                "max_abs_u": float(np.max(np.abs(us[:, i]))),
                "saturated_fraction": float(np.mean(sat)),
            }
        )
    return MimoRun(metrics, {"t": ts, "y": ys, "u": us, "ym_ol": yms})


def mimo_config(pfcs, gamma: float, limits, *, lv: float = 20.0, rate_hz: float = 100.0):
    """The matrix CL-SAC of m channels: the paper's reference model per channel (A_m = -5, B_m = 5, C_m = 1, L_v),
    all six Gamma = gamma I, D = diag(k_i/(s + a_i)), each channel limited to its surface's stop."""
    from autopilot.config import ClSacConfig

    m = len(pfcs)
    eye = np.eye(m)
    return ClSacConfig(
        control_rate_hz=rate_hz,
        am=tuple(map(tuple, -5.0 * eye)),
        bm=tuple(map(tuple, 5.0 * eye)),
        cm=tuple(map(tuple, eye)),
        lv=tuple(map(tuple, lv * eye)),
        **{f"gamma_{n}": gamma for n in ("pe", "ie", "px", "ix", "pu", "iu")},
        pfc_channels=tuple(((k,), (1.0, a)) for k, a in pfcs),
        u_limit_rad=float(min(limits)),
        u_limits_rad=tuple(float(v) for v in limits),
    )


def choose_gamma_mimo(plant, pfcs, limits, *, lv: float = 20.0, rate_hz: float = 100.0, gammas=GAMMAS):
    """(gamma, rows): the smallest of ``gammas`` whose roll ise_ref is within 1.5x of the best without saturating."""
    rows = []
    for g in gammas:
        run = fly_linear(plant, mimo_config(pfcs, g, limits, lv=lv, rate_hz=rate_hz))
        sat = any(mt["saturated_fraction"] > 0 for mt in run.metrics)
        ise = run.metrics[0]["ise_ref"]
        rows.append({"gamma": g, "ise_ref": ise, "max_abs_beta": run.metrics[1]["max_abs_y"], "saturated": sat})
    from tools.design.tuning import pick_gamma

    gamma = pick_gamma(rows)
    if gamma is None:
        raise MimoDesignError("the MIMO CL-SAC saturates a surface for every adaptation weight of the grid")
    return gamma, rows
