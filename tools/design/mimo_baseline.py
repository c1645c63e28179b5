"""The MIMO baseline of a square plant: one PID per channel, and its margins on the coupled sampled plant.  No I/O.

Each channel flies ``autopilot.baseline``'s PID on its own error e_i = y_m,ol,i - y_i (C_i(z) = K_p + K_i T z/(z - 1)
+ K_d (z - 1)/(T z)), so the controller is K(z) = diag(C_i(z)) on the ZOH-sampled plant G(z) = C_p (zI - Phi)^-1
Gamma.  Design (``design_baseline_mimo``): channel 1 is the SISO design of its diagonal element
(``tools.design.tuning.design_baseline``: the aileron-only gains); each next channel's PID is chosen on the grid of
the SISO design with the loops before it closed, for the largest crossover up to 5 rad/s whose own loop-at-a-time
margins are at least 10 dB and 60 deg and with the whole closed loop stable.

Margins (``mimo_margins``), all at the plant input, from the frequency response on ``N_FREQ`` log-spaced points up
to the Nyquist frequency: the loop-at-a-time loop l_i of channel i with the others closed (for m = 2,
l_1 = L_11 - L_12 L_21 / (1 + L_22), L = K G), its gain margin (dB, at the phase crossover), phase margin (deg, at the
gain crossover) and symmetric disk margin alpha_i = 1/max_w |1/(1 + l_i) - 1/2| (Seiler, Packard and Gahinet, "An
introduction to disk margins", IEEE CSM 2020: the gain range [(1 - alpha/2)/(1 + alpha/2), (1 + alpha/2)/(1 -
alpha/2)] and phase 2 atan(alpha/2) a loop can take at once); and the multivariable disk margin's lower bound
alpha >= 1/max_w sigma_max(S(e^{jwT}) - I/2), S = (I + L)^-1 (a full complex perturbation at the input: conservative
against the independent per-channel ones, for which mu <= sigma_max).  Stability is the closed loop's eigenvalues
(plant, PID states, the backward difference), not the Nyquist plot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

N_FREQ = 800
PM_MIN_DEG, GM_MIN_DB, CROSSOVER_MAX = 60.0, 10.0, 5.0


def _pid_frequency(gains, z: np.ndarray, dt: float) -> np.ndarray:
    kp, ki, kd = gains
    return kp + ki * dt * z / (z - 1.0) + kd * (z - 1.0) / (dt * z)


def _pid_ss(gains, dt: float):
    """(A, B, C, D) of C(z) = K_p + K_i T z/(z - 1) + K_d (z - 1)/(T z), states [integral, last error]."""
    kp, ki, kd = gains
    a = np.array([[1.0, 0.0], [0.0, 0.0]])
    b = np.array([[ki * dt], [1.0]])
    c = np.array([[1.0, -kd / dt]])
    d = np.array([[kp + ki * dt + kd / dt]])
    return a, b, c, d


def closed_loop_stable(plant, gains, dt: float) -> bool:
    """Whether u = K(z) (r - y), K = diag(PID_i), stabilises the ZOH-sampled plant (the closed loop's eigenvalues)."""
    from autopilot.shared.numerics import zoh

    a, b, c = (np.asarray(x, dtype=float) for x in plant)
    phi, gam = zoh(a, b, dt)
    n, m = a.shape[0], b.shape[1]
    ak, bk, ck, dk = (np.zeros((2 * m, 2 * m)), np.zeros((2 * m, m)), np.zeros((m, 2 * m)), np.zeros((m, m)))
    for i, g in enumerate(gains):
        pa, pb, pc, pd = _pid_ss(g, dt)
        sl = slice(2 * i, 2 * i + 2)
        ak[sl, sl], bk[sl, i], ck[i, sl], dk[i, i] = pa, pb[:, 0], pc[0], pd[0, 0]
    # e = -y = -C x; u = Ck xk + Dk e; x+ = Phi x + Gam u; xk+ = Ak xk + Bk e
    top = np.hstack([phi - gam @ dk @ c, gam @ ck])
    bottom = np.hstack([-bk @ c, ak])
    big = np.vstack([top, bottom])
    return bool(np.max(np.abs(np.linalg.eigvals(big))) < 1.0 - 1e-12) and big.shape[0] == n + 2 * m


def loop_matrices(plant, gains, dt: float, freqs: np.ndarray) -> np.ndarray:
    """L(e^{jwT}) = K G at the plant input, one m x m matrix per frequency (shape (N, m, m))."""
    from autopilot.shared.numerics import zoh

    a, b, c = (np.asarray(x, dtype=float) for x in plant)
    phi, gam = zoh(a, b, dt)
    n, m = a.shape[0], b.shape[1]
    z = np.exp(1j * freqs * dt)
    out = np.empty((z.size, m, m), dtype=complex)
    for k, zk in enumerate(z):
        g = c @ np.linalg.solve(zk * np.eye(n) - phi, gam)
        kz = np.diag([_pid_frequency(gi, zk, dt) for gi in gains])
        out[k] = kz @ g
    return out


def _siso_margins(loop: np.ndarray, freqs: np.ndarray) -> dict:
    """Gain margin (dB), phase margin (deg), crossovers and symmetric disk margin of a SISO loop's response."""
    mag, ph = np.abs(loop), np.unwrap(np.angle(loop))
    gm, wpc = math.inf, math.nan
    for k in range(len(freqs) - 1):  # phase crossings of -180 deg (mod 360)
        p0, p1 = (ph[k] + math.pi) / (2 * math.pi), (ph[k + 1] + math.pi) / (2 * math.pi)
        if math.floor(p0) != math.floor(p1):
            t = (math.floor(max(p0, p1)) - p0) / (p1 - p0)
            g = 1.0 / (mag[k] + t * (mag[k + 1] - mag[k]))
            if not math.isfinite(gm) or abs(math.log(g)) < abs(math.log(gm)):
                gm, wpc = g, freqs[k] + t * (freqs[k + 1] - freqs[k])
    pm, wgc = math.inf, math.nan
    for k in range(len(freqs) - 1):
        if (mag[k] - 1.0) * (mag[k + 1] - 1.0) <= 0 and mag[k] != mag[k + 1]:
            t = (1.0 - mag[k]) / (mag[k + 1] - mag[k])
            p = math.degrees(ph[k] + t * (ph[k + 1] - ph[k]))
            margin = (p + 180.0) % 360.0
            margin = margin - 360.0 if margin > 180.0 else margin
            if abs(margin) < abs(pm):
                pm, wgc = margin, freqs[k] + t * (freqs[k + 1] - freqs[k])
    alpha = 1.0 / float(np.max(np.abs(1.0 / (1.0 + loop) - 0.5)))
    return {
        "gain_margin_db": 20.0 * math.log10(gm) if math.isfinite(gm) else math.inf,
        "phase_margin_deg": float(pm),
        "phase_crossover_rad_s": float(wpc),
        "gain_crossover_rad_s": float(wgc),
        "disk_margin": alpha,
        "disk_gain_db": _disk_gain_db(alpha),
        "disk_phase_deg": math.degrees(2.0 * math.atan(alpha / 2.0)),
    }


def _disk_gain_db(alpha: float) -> float:
    """The gain range of a symmetric disk margin alpha, +-dB: 20 log10((1 + alpha/2)/(1 - alpha/2)); inf for >= 2."""
    return math.inf if alpha >= 2.0 else 20.0 * math.log10((1.0 + alpha / 2.0) / (1.0 - alpha / 2.0))


def frequencies(dt: float) -> np.ndarray:
    return np.logspace(-3, math.log10(0.999 * math.pi / dt), N_FREQ)


def mimo_margins(plant, gains, dt: float) -> dict:
    """Each loop's margins with the others closed, the multivariable disk margin bound, closed-loop stability."""
    freqs = frequencies(dt)
    big = loop_matrices(plant, gains, dt, freqs)
    m = big.shape[1]
    loops = []
    for i in range(m):
        others = [j for j in range(m) if j != i]
        lo = big[:, others][:, :, others]
        li = np.empty(freqs.size, dtype=complex)
        for k in range(freqs.size):  # l_i = L_ii - L_io (I + L_oo)^-1 L_oi: channel i's loop with the others closed
            l_oi, l_io = big[k][others, i], big[k][i, others]
            li[k] = big[k][i, i] - l_io @ np.linalg.solve(np.eye(m - 1) + lo[k], l_oi)
        loops.append(_siso_margins(li, freqs))
    eye = np.eye(m)
    worst = max(float(np.linalg.svd(np.linalg.inv(eye + lk) - 0.5 * eye, compute_uv=False)[0]) for lk in big)
    alpha = 1.0 / worst
    return {
        "loops": loops,
        "disk_margin": alpha,
        "disk_gain_db": _disk_gain_db(alpha),
        "disk_phase_deg": math.degrees(2.0 * math.atan(alpha / 2.0)),
        "closed_loop_stable": closed_loop_stable(plant, gains, dt),
    }


@dataclass
class MimoBaselineDesign:
    gains: list[tuple[float, float, float]]
    margins: dict


def design_baseline_mimo(plant, *, rate_hz: float = 100.0) -> MimoBaselineDesign:
    """One PID per channel (module docstring); ``tools.design.tuning.PfcDesignError`` if none of the grid qualifies."""
    from tools.design.mimo import channel
    from tools.design.tuning import PfcDesignError, design_baseline

    dt = 1.0 / rate_hz
    m = np.asarray(plant[1]).shape[1]
    first = design_baseline(channel(plant, 0), rate_hz=rate_hz)
    gains = [(first.kp, first.ki, first.kd)]
    for i in range(1, m):
        best = None
        for kp in np.logspace(-2, 1, 19):
            for td_ratio in (0.0, 0.1, 0.2, 0.3):
                trial = [*gains, (float(kp), float(kp) / 10.0, float(kp * td_ratio))]
                sub = [g if j <= i else (0.0, 0.0, 0.0) for j, g in enumerate(trial + [(0.0, 0.0, 0.0)] * m)][:m]
                if not closed_loop_stable(plant, sub, dt):
                    continue
                mm = mimo_margins(plant, sub, dt)["loops"][i]
                ok = (
                    mm["phase_margin_deg"] >= PM_MIN_DEG
                    and mm["gain_margin_db"] >= GM_MIN_DB
                    and mm["gain_crossover_rad_s"] <= CROSSOVER_MAX
                )
                if ok and (best is None or mm["gain_crossover_rad_s"] > best[1]):
                    best = (trial[i], mm["gain_crossover_rad_s"])
        if best is None:
            raise PfcDesignError(
                f"channel {i + 1}: no PID of the grid gives PM >= {PM_MIN_DEG:g} deg and GM >= {GM_MIN_DB:g} dB below "
                f"{CROSSOVER_MAX:g} rad/s with the loops before it closed"
            )
        gains.append(best[0])
    return MimoBaselineDesign(gains, mimo_margins(plant, gains, dt))
