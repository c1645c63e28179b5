"""Incremental nonlinear dynamic inversion (INDI) of the roll channel with online control-effectiveness estimation:
Smeur, Chu & de Croon, "Adaptive incremental nonlinear dynamic inversion for attitude control of micro air
vehicles", JGCD 39(3), 2016 (sec. II-III: the increment law, the synchronising filters, the LMS estimate), as
Paparazzi's ``stabilization_indi.c`` flies it (PD outer loop to a desired angular acceleration).  No I/O.

The roll acceleration p' = f(x) + G delta: over one step the increment dp' = G d(delta) (the paper's eq. of the
incremental form, f's change neglected).  Per control step k (T = 1 / control_rate_hz), with the measured
roll phi_k, roll rate p_k and the command r_k:

    filters   H(s) = w_f^2 / (s^2 + 2 zeta_f w_f s + w_f^2) on p and on the actuator model's position u_act, each
              advanced over the period with its newest sample held (exact ZOH; Paparazzi filters the newest
              sample before using it):  p_f, p_f' (the filtered roll acceleration) and u_f, u_f'
              p_f'' = w_f^2 (p_k - p_f) - 2 zeta_f w_f p_f'                                   (the filter's ODE)
    reference phi_m: the command filter w_r / (s + w_r) on r (the paper's reference model 5 / (s + 5)), exact ZOH
    outer loop nu = k_att (phi_m - phi_k) - k_rate p_k                          (desired roll acceleration, 1/s^2)
    INDI      u_raw = u_f + (nu - p_f') / G_k                     Smeur et al. 2016: u_c = u_f + G^{-1}(nu - Omega'_f)
              u     = clip(u_raw, -u_limit, u_limit)
    actuator  u_act[k+1] = a u_act + (1 - a) u,  a = e^{-T / tau_act}    the modelled position (first order)
    LMS       G[k+1] = max(G_min, G_k - mu T (G_k u_f' - p_f'') u_f')     gradient of (G u_f' - p_f'')^2 / 2: the
              derivatives of the filtered signals (offsets drop out), as Paparazzi's lms_estimation does

``hold(u_applied)``: the surface asked for did not fly, or no fresh data: G frozen, the actuator model moved to what
flew, the filters and the reference model not advanced.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from autopilot.lawkit import LawConfig, Reconfigurable, check_fields, finite
from autopilot.shared.numerics import zoh

PARAMETERS = (
    ("INDI_G0", "g0", "1/s^2", 1e-3, 1e5, "initial control effectiveness G (roll acceleration per rad)"),
    ("INDI_GMIN", "g_min", "1/s^2", 1e-6, 1e5, "lower bound of the estimated G"),
    ("INDI_MU", "mu", "1/s", 0.0, 1e6, "LMS adaptation rate (0: G fixed)"),
    ("INDI_WF", "omega_f", "rad/s", 0.1, 1e4, "synchronising filter natural frequency"),
    ("INDI_ZF", "zeta_f", "1", 0.05, 5.0, "synchronising filter damping"),
    ("INDI_TAU", "tau_act", "s", 0.0, 10.0, "first-order actuator model time constant"),
    ("INDI_KATT", "k_att", "1/s^2", 0.0, 1e5, "outer loop roll gain"),
    ("INDI_KRATE", "k_rate", "1/s", 0.0, 1e4, "outer loop roll-rate gain"),
    ("INDI_WREF", "omega_r", "rad/s", 0.01, 1e3, "command filter bandwidth"),
)
TELEMETRY_FIELDS = ("r", "phi_m", "nu", "p_f", "pdot_f", "u_act", "u_f", "g", "u_raw", "u", "saturated")


@dataclass(frozen=True)
class IndiConfig(LawConfig):
    """INDI settings: the control rate and the surface limit (``LawConfig``), then the law's own.  Defaults: the
    KH2013A design of ``tools.design.laws``."""

    g0: float = 196.14607966050582  # 1/s^2 per rad: b_p of the residualised design model
    g_min: float = 1.9614607966050581  # G0 / 100
    mu: float = 1.0  # 1/s (the design's rule over 0.01 ... 1000)
    omega_f: float = 12.559432157547901  # rad/s (the design's rule: 50 rad/s of Smeur et al. 2016 and down)
    zeta_f: float = 0.55
    tau_act: float = 0.030511195606252636  # s: 2 zeta / w_n of the paper's servo (eq. (65))
    k_att: float = 100.0  # 1/s^2: w_n^2, w_n = 10 rad/s
    k_rate: float = 14.0  # 1/s: 2 zeta w_n, zeta = 0.7
    omega_r: float = 5.0  # rad/s: the paper's reference model 5 / (s + 5)

    def __post_init__(self) -> None:
        check_fields(self, PARAMETERS)


def filter_matrices(omega: float, zeta: float) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of H(s) = w^2 / (s^2 + 2 zeta w s + w^2), states [y, y']."""
    return np.array([[0.0, 1.0], [-(omega**2), -2.0 * zeta * omega]]), np.array([[0.0], [omega**2]])


class Indi(Reconfigurable):
    """Adaptive INDI: ``u = law.step(phi, p, r, command)`` once per control step."""

    TELEMETRY_FIELDS = TELEMETRY_FIELDS
    Config = IndiConfig  # the law interface (autopilot.law): its configuration and its parameter table
    PARAMETERS = PARAMETERS

    def __init__(self, config: IndiConfig | None = None):
        self.config = cfg = config or IndiConfig()
        self.dt = T = cfg.dt
        phi_f, gam_f = zoh(*filter_matrices(cfg.omega_f, cfg.zeta_f), T)
        self._phi_f, self._gam_f = phi_f, gam_f[:, 0]
        self._w2, self._2zw = cfg.omega_f**2, 2.0 * cfg.zeta_f * cfg.omega_f
        self._a_act = math.exp(-T / cfg.tau_act) if cfg.tau_act > 0 else 0.0
        self._a_ref = math.exp(-cfg.omega_r * T)
        self._umax = float(cfg.u_limit_rad)
        self.reset()

    def reset(self) -> None:
        """Back to rest: filters, actuator model and reference at zero, G = G0."""
        self.xp = np.zeros(2)
        self.xu = np.zeros(2)
        self.u_act = 0.0
        self.phi_m = 0.0
        self.g = float(self.config.g0)
        self.r = self.nu = self.u_raw = self.u = 0.0
        self.saturated = False
        self.steps = 0

    def step(self, roll: float, roll_rate: float, yaw_rate: float, command: float) -> float:  # noqa: ARG002
        """One step: measured roll (rad), roll rate and yaw rate (rad/s), command (rad) in; surface (rad) out."""
        phi, p, r = finite(roll, roll_rate, command)
        finite(yaw_rate)
        cfg = self.config
        self.xp = xp = self._phi_f @ self.xp + self._gam_f * p
        self.xu = xu = self._phi_f @ self.xu + self._gam_f * self.u_act
        pdd = self._w2 * (p - xp[0]) - self._2zw * xp[1]  # p_f''
        self.nu = nu = cfg.k_att * (self.phi_m - phi) - cfg.k_rate * p
        u_raw = float(xu[0]) + (nu - float(xp[1])) / self.g
        u = min(max(u_raw, -self._umax), self._umax)
        du = float(xu[1])
        self.g = max(cfg.g_min, self.g - cfg.mu * self.dt * (self.g * du - pdd) * du)
        self.u_act = self._a_act * self.u_act + (1.0 - self._a_act) * u
        self.phi_m = self._a_ref * self.phi_m + (1.0 - self._a_ref) * r
        self.r, self.u_raw, self.u, self.saturated = r, u_raw, u, u != u_raw
        self.steps += 1
        return u

    def hold(self, u_applied: float = 0.0) -> None:
        """G frozen; the actuator model moved by what flew; filters and reference not advanced."""
        u = float(u_applied)
        self.u_act = self._a_act * self.u_act + (1.0 - self._a_act) * u
        self.u = self.u_raw = u

    def telemetry(self) -> dict[str, float]:
        """This law's internals after the last step, by ``TELEMETRY_FIELDS``."""
        return dict(
            r=self.r, phi_m=self.phi_m, nu=self.nu, p_f=float(self.xp[0]), pdot_f=float(self.xp[1]),
            u_act=self.u_act, u_f=float(self.xu[0]), g=self.g, u_raw=self.u_raw, u=self.u,
            saturated=float(self.saturated),
        )  # fmt: skip
