"""State-feedback MRAC with integral action on the roll channel, with an open (``mrac``) or a closed-loop
(``crm-mrac``) reference model.  Lavretsky & Wise (2013), ch. 9-10 ("MRAC with integral action", the servo form
of the baseline LQR-PI plus adaptive augmentation), projection of ch. 11; the closed-loop reference model of
Gibson, Annaswamy & Lavretsky (2013).  No I/O.

The plant's roll channel, x = [phi, p], u = the surface (rad), with an unknown effectiveness lambda > 0:

    x' = A_x x + b lambda u,   A_x = [[a11, a12], [a21, a22]],  b = [b1, b2]^T   (the design model,
                                                                               ``tools.design.laws.roll_model``)

extended with the integral of the tracking error (L&W ch. 10), z = [x_I, phi, p]:

    x_I' = phi - r                                                            r: the roll command
    z'   = A z + B lambda u + B_ref r,  A = [[0, e_1^T], [0, A_x]],  B = [0, b]^T,  B_ref = [-1, 0, 0]^T

Baseline (LQR-PI / pole placement, ``tools.design.laws``): u_bl = -K z, K = [k_i, k_phi, k_p].  Reference model:
the nominal baseline loop A_ref = A - B K, plus for CRM-MRAC the error feedback L = l I (Gibson et al. 2013):

    x_ref' = A_ref x_ref + B_ref r + l (z - x_ref)                            (l = 0: the open-loop model, mrac)
    e      = z - x_ref
    u      = -K z + dK z,    dK' = gamma Proj(dK, -z e^T P B)                 (L&W ch. 10, Theorem: V = e^T P e +
                                                                               lambda dK~ dK~^T / gamma)
    A_c^T P + P A_c = -I,  A_c = A_ref - l I                                  (Lyapunov; e' = A_c e + B lambda dK~ z)

dK is the adaptive increment on the baseline (dK(0) = 0; the ideal dK* = K (1 - 1/lambda)).  Proj (L&W ch. 11,
``autopilot.lawkit.proj``, eps = ``proj_eps``) acts element-wise on the box (each scalar dK_j - c_j with its bound
h_j, L&W's Proj applied to each parameter), then on the ball ||dK|| <= k_max:

    box:  dK_j in [k_j (1 - g_max), k_j (1 - g_min)], c_j its centre, h_j its half-width  (every gain of K - dK
          within [g_min, g_max] x its baseline gain; h_j = 0: dK_j does not adapt)

The sampled (Euler) step can overshoot the box and the ball the continuous law never leaves, so it is put back
(clipped onto the box, scaled onto the ball; idle while Proj is).  Why the box: a disturbance drifts dK along the
gradient without bound (Rohrs et al. 1985; L&W ch. 11): on the KH2013A in light turbulence the roll rate's gusts
drive dK_p' = -gamma p e^T P B with e_p ~ p towards ever more rate damping, and the plant is unstable from twice
the baseline's k_p (the rudder-driven dutch roll, the servo), so the bound must be on each gain, from the gains
the design verified (docs/adaptive-laws.md).

Sampled at T = 1 / control_rate_hz, every signal held over the period (the law knows its signals at the samples,
as ``autopilot.clsac``): at step k with z_k, r_k

    u_raw  = (-K + dK_k) z_k,   u = clip(u_raw, -u_limit, u_limit)
    x_I[k+1]   = x_I + T (phi_k - r_k)       not integrated while saturated and pushing further past the limit
    x_ref[k+1] = e^{A_c T} x_ref + A_c^{-1}(e^{A_c T} - I) (B_ref r_k + l z_k)           exact ZOH
    dK[k+1]    = dK + T gamma Proj(dK_k, -z_k (e_k^T P B))                   exact for held z, e while Proj is idle

``hold(u_applied)`` (the surface it asked for was not applied, or no fresh data): dK and x_I frozen, x_ref
advanced on the last command and measurement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from autopilot.config import ConfigError
from autopilot.lawkit import (
    DESIGN_MODEL_ROWS,
    DesignModelConfig,
    Reconfigurable,
    check_fields,
    finite,
    lyapunov,
    prefixed,
    proj,
)
from autopilot.shared.numerics import zoh

# (name, field, unit, lower, upper, description); the CRM-MRAC's are the same fields under CRM_ plus CRM_L.
_ROWS = DESIGN_MODEL_ROWS + (
    ("KI", "k_i", "1/(rad s)", 0.0, 1e4, "baseline integral gain k_i"),
    ("KPHI", "k_phi", "1", 0.0, 1e4, "baseline roll gain k_phi"),
    ("KP", "k_p", "s", 0.0, 1e4, "baseline roll-rate gain k_p"),
    ("GAM_X", "gamma", "1", 0.0, 1e6, "adaptation rate gamma of dK"),
    ("KMAX", "k_max", "1", 1e-6, 1e6, "projection bound on ||dK|| (outer; the design's circumscribes the box)"),
    ("EPS", "proj_eps", "1", 1e-3, 1.0, "projection tolerance eps"),
    ("GMIN", "g_min", "1", 0.0, 1e3, "projection box: each gain of K - dK at least g_min x its baseline"),
    ("GMAX", "g_max", "1", 0.0, 1e3, "projection box: each gain of K - dK at most g_max x its baseline"),
)
PARAMETERS = prefixed("MRAC_", _ROWS)
CRM_PARAMETERS = prefixed("CRM_", _ROWS) + (
    ("CRM_L", "crm_l", "1/s", 1e-6, 1e4, "closed-loop reference model gain l (L = l I)"),
)
TELEMETRY_FIELDS = (
    "r", "xi", "phi_ref", "p_ref", "e_i", "e_phi", "e_p", "dk_i", "dk_phi", "dk_p", "u_raw", "u", "saturated", "proj",
)  # fmt: skip


@dataclass(frozen=True)
class MracConfig(DesignModelConfig):
    """MRAC settings: the control rate, the surface limit and the design model (the KH2013A's, ``DesignModelConfig``),
    then the law's own.  Defaults: the KH2013A design of ``python -m tools.design.laws kh2013a`` (poles -3.2, -6.4,
    -9.6, the rule's -5, -10, -15 scaled by 0.64 for the dutch roll; the projection box, k_max and gamma by its
    rules), open-loop reference model (crm_l = 0)."""

    k_i: float = 0.9407967124566005  # rad of surface per (rad s)
    k_phi: float = 0.5521677294782774  # rad per rad
    k_p: float = 0.08246983127466834  # s
    gamma: float = 0.3  # 1 (dK is dimensionless per state unit)
    k_max: float = 0.5736871581246389  # bound on ||dK||: the ball around the box, sqrt(1 + eps) x its far corner
    proj_eps: float = 0.1
    # The projection box: every gain of K - dK within [g_min, g_max] x its baseline gain (tools.design.laws: the
    # loop gains the baseline is verified robust to, ROBUST_GAINS).
    g_min: float = 0.5
    g_max: float = 1.4
    crm_l: float = 0.0  # 1/s; 0: open-loop reference model (mrac), > 0: CRM-MRAC

    def __post_init__(self) -> None:
        check_fields(self, PARAMETERS)
        if not self.g_min <= 1.0 <= self.g_max:
            raise ConfigError(f"g_min <= 1 <= g_max must hold (dK = 0 in the box), got {self.g_min!r}, {self.g_max!r}")
        if not (isinstance(self.crm_l, (int, float)) and math.isfinite(self.crm_l) and 0.0 <= self.crm_l <= 1e4):
            raise ConfigError(f"crm_l must be in [0, 10000] 1/s, got {self.crm_l!r}")


def crm_config(**changes) -> MracConfig:
    """The CRM-MRAC default: the same design with l = 12.8 1/s (4 x the reference model's dominant pole 3.2 1/s,
    the ratio of the paper's CL-SAC, L_v = 20 on A_m = -5)."""
    return MracConfig(**{"crm_l": 4.0 * 5.0 * 0.8**2, **changes})  # as tools.design.laws computes it


def matrices(cfg: MracConfig):
    """(A, B, B_ref, K, A_ref) of the extended design model z = [x_I, phi, p] (module docstring)."""
    a = np.array([[0.0, 1.0, 0.0], [0.0, cfg.a11, cfg.a12], [0.0, cfg.a21, cfg.a22]])
    b = np.array([[0.0], [cfg.b1], [cfg.b2]])
    b_ref = np.array([[-1.0], [0.0], [0.0]])
    k = np.array([[cfg.k_i, cfg.k_phi, cfg.k_p]])
    return a, b, b_ref, k, a - b @ k


class Mrac(Reconfigurable):
    """MRAC with integral action (``crm_l`` = 0) or CRM-MRAC (``crm_l`` > 0): ``u = law.step(phi, p, r, command)``."""

    TELEMETRY_FIELDS = TELEMETRY_FIELDS
    Config = MracConfig  # the law interface (autopilot.law): its configuration and its parameter table
    PARAMETERS = PARAMETERS

    def __init__(self, config: MracConfig | None = None):
        self.config = cfg = config or MracConfig()
        self.dt = T = cfg.dt
        _a, b, b_ref, k, a_ref = matrices(cfg)
        a_c = a_ref - cfg.crm_l * np.eye(3)
        if np.max(np.linalg.eigvals(a_c).real) >= 0.0:
            raise ConfigError(f"the reference model A_ref - l I is not stable (eigenvalues {np.linalg.eigvals(a_c)})")
        self._k = k[0]
        self._phi, gam = zoh(a_c, np.hstack([b_ref, cfg.crm_l * np.eye(3)]), T)
        self._g_r, self._g_z = gam[:, 0], gam[:, 1:]
        self._pb = (lyapunov(a_c, np.eye(3)) @ b)[:, 0]  # P B
        self._umax = float(cfg.u_limit_rad)
        # The box, element-wise: dK_j in [k_j (1 - g_max), k_j (1 - g_min)], centre c_j, half-width h_j
        self._lo, self._hi = self._k * (1.0 - cfg.g_max), self._k * (1.0 - cfg.g_min)
        self._c, self._h = 0.5 * (self._lo + self._hi), 0.5 * (self._hi - self._lo)
        self.reset()

    def _proj(self, y: np.ndarray) -> np.ndarray:
        """Proj of y at dK: element-wise on the box (Proj of L&W ch. 11 on each scalar dK_j - c_j with the bound
        h_j; a gain with h_j = 0 does not adapt), then on the ball ||dK|| <= k_max."""
        cfg = self.config
        out = np.zeros(3)
        for j in range(3):
            if self._h[j] > 0.0:
                out[j] = proj(self.dk[j : j + 1] - self._c[j], y[j : j + 1], self._h[j], cfg.proj_eps)[0]
        return proj(self.dk, out, cfg.k_max, cfg.proj_eps)

    def reset(self) -> None:
        """Back to rest: x_I = 0, x_ref = 0, dK = 0."""
        self.xi = 0.0
        self.x_ref = np.zeros(3)
        self.dk = np.zeros(3)
        self._z = np.zeros(3)
        self.r = self.u_raw = self.u = 0.0
        self.e = np.zeros(3)
        self.saturated = self.projecting = False
        self.steps = 0

    def step(self, roll: float, roll_rate: float, yaw_rate: float, command: float) -> float:  # noqa: ARG002
        """One control step: measured roll (rad), roll rate and yaw rate (rad/s), roll command (rad) in; the surface
        command (rad, within +-u_limit) out."""
        phi, p, r = finite(roll, roll_rate, command)
        finite(yaw_rate)
        cfg, T = self.config, self.dt
        z = np.array([self.xi, phi, p])
        e = z - self.x_ref
        u_raw = float((self.dk - self._k) @ z)  # u = -K z + dK z
        u = min(max(u_raw, -self._umax), self._umax)
        sat = u != u_raw
        # dK' = gamma Proj(dK, -z e^T P B)
        y = -z * float(e @ self._pb)
        py = self._proj(y)
        self.projecting = bool(np.any(py != y))
        dk = np.clip(self.dk + T * cfg.gamma * py, self._lo, self._hi)  # the sampled step kept in Proj's box
        norm = float(np.linalg.norm(dk))
        self.dk = dk if norm <= cfg.k_max else dk * (cfg.k_max / norm)  # ... and ball
        # x_I' = phi - r, conditional integration: d u / d x_I = dK_0 - k_i
        dxi = T * (phi - r)
        if not (sat and dxi * (self.dk[0] - self._k[0]) * u_raw > 0.0):
            self.xi += dxi
        self._advance_ref(r, z)
        self._z, self.e, self.r = z, e, r
        self.u_raw, self.u, self.saturated = u_raw, u, sat
        self.steps += 1
        return u

    def hold(self, u_applied: float = 0.0) -> None:
        """The surface asked for was not applied (``u_applied`` flew), or no fresh data: dK and x_I frozen, the
        reference model advanced on the last command and measurement."""
        self._advance_ref(self.r, self._z)
        self.u = self.u_raw = float(u_applied)

    def _advance_ref(self, r: float, z: np.ndarray) -> None:
        """x_ref to the next sample on the held command and measurement (exact ZOH, module docstring)."""
        self.x_ref = self._phi @ self.x_ref + self._g_r * r + self._g_z @ z

    def telemetry(self) -> dict[str, float]:
        """This law's internals after the last step, by ``TELEMETRY_FIELDS``."""
        e, dk, xr = self.e, self.dk, self.x_ref
        return dict(
            r=self.r, xi=self.xi, phi_ref=float(xr[1]), p_ref=float(xr[2]), e_i=float(e[0]), e_phi=float(e[1]),
            e_p=float(e[2]), dk_i=float(dk[0]), dk_phi=float(dk[1]), dk_p=float(dk[2]), u_raw=self.u_raw, u=self.u,
            saturated=float(self.saturated), proj=float(self.projecting),
        )  # fmt: skip
