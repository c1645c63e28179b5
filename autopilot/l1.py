"""L1 adaptive control of the roll channel (Hovakimyan & Cao, "L1 Adaptive Control Theory", SIAM 2010): a state
predictor, the piecewise-constant adaptation law at the control rate, and the low-pass filter C(s).  No I/O.

Design model x = [phi, p], u = the surface (rad):  x' = A x + b u,  A = [[a11, a12], [a21, a22]],  b = [b1, b2]^T
(``tools.design.laws.roll_model``).
A state feedback k_m = [k_phi, k_p] gives the desired A_m = A - b k_m^T (book ch. 2: u = -k_m^T x + u_ad); the
uncertain plant is written x' = A_m x + b (u_ad + sigma_m(t)) + b_um sigma_um(t), with B_bar = [b, b_um] spanning
R^2 (b_um = [b2, -b1]^T / ||b||, orthogonal to b), sigma lumping every uncertainty (input gain,
state-dependent, disturbance).

Per control step k (period T_s = 1 / control_rate_hz), with the measured x_k and the command r_k:

    x~_k      = x^_k - x_k                                                prediction error
    sigma^_k  = -B_bar^{-1} Phi(T_s)^{-1} e^{A_m T_s} x~_k,  Phi(T_s) = A_m^{-1}(e^{A_m T_s} - I)
                                                                          piecewise-constant adaptation law (the
                                                                          estimate that would zero x~ one period on)
    u_ad      = C(s) [k_g r - sigma^_m],  C(s) = w_c / (s + w_c),  k_g = -1 / (c^T A_m^{-1} b)  (c = [1, 0])
                u_f,k = e^{-w_c T_s} u_f,k-1 + (1 - e^{-w_c T_s}) (k_g r_k - sigma^_m,k)   (input held over a period)
    u         = clip(-k_m^T x_k + u_f,k, -u_limit, u_limit)
    x^_k+1    = e^{A_m T_s} x^_k + Phi(T_s) (b (u_k + k_m^T x_k + sigma^_m,k) + b_um sigma^_um,k)    state predictor,
                                                                          driven by the surface that flew, exact ZOH

The unmatched estimate sigma^_um feeds the predictor only; the book's unmatched compensation (a second filter
through H_m^{-1} H_um) is not built: on the roll channel an effectiveness or damping change is matched.

The L1-norm condition (book ch. 2, the sufficient condition for stability of the closed loop's reference system):

    lambda = ||G(s)||_L1 L < 1,   G(s) = H(s) (1 - C(s)),   H(s) = (sI - A_m)^{-1} b

L bounds the state-dependent uncertainty, ||theta||_1 <= L for sigma_m = theta^T x; :func:`l1_condition` returns
lambda (``tools.design.laws`` picks w_c by it).  ``hold(u_applied)``: the adaptation frozen (sigma^ held), the
predictor advanced on the surface that flew.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from autopilot.lawkit import DESIGN_MODEL_ROWS, DesignModelConfig, Reconfigurable, check_fields, finite, prefixed
from autopilot.shared.numerics import expm, zoh

PARAMETERS = prefixed("L1_", DESIGN_MODEL_ROWS) + (
    ("L1_KPHI", "k_phi", "1", 0.0, 1e4, "state feedback k_phi (A_m = A - b k_m^T)"),
    ("L1_KP", "k_p", "s", 0.0, 1e4, "state feedback k_p"),
    ("L1_WC", "omega_c", "rad/s", 1e-3, 1e4, "bandwidth w_c of C(s) = w_c / (s + w_c)"),
)
TELEMETRY_FIELDS = ("r", "phi_hat", "p_hat", "sigma_m", "sigma_um", "u_f", "u_raw", "u", "saturated")


@dataclass(frozen=True)
class L1Config(DesignModelConfig):
    """L1 settings: the control rate, the surface limit and the design model (the KH2013A's, ``DesignModelConfig``),
    then the law's own.  Defaults: the KH2013A design of ``python -m tools.design.laws kh2013a``."""

    k_phi: float = 0.3735347734217771  # A_m's poles -5, -15
    k_p: float = 0.08663789381751384
    omega_c: float = 2.4325912110340284  # rad/s: the servo's w_n / 20 (the design's robustness rule)

    def __post_init__(self) -> None:
        check_fields(self, PARAMETERS)


def desired(cfg: L1Config) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A_m, b, k_m) of the design model."""
    a = np.array([[cfg.a11, cfg.a12], [cfg.a21, cfg.a22]])
    b = np.array([cfg.b1, cfg.b2])
    k_m = np.array([cfg.k_phi, cfg.k_p])
    return a - np.outer(b, k_m), b, k_m


def l1_norm_rows(a: np.ndarray, b: np.ndarray, c: np.ndarray, horizon: float, h: float) -> np.ndarray:
    """||g_i||_L1 = int_0^horizon |g_i(t)| dt of each output of the SISO impulse response g(t) = C e^{A t} b
    (a direct term's impulse is not part of it), by the trapezoid rule
    on the grid h (e^{A h} by ``expm``)."""
    step = expm(np.asarray(a, float) * h)
    x = np.asarray(b, float).copy()
    c = np.asarray(c, float)
    prev = np.abs(c @ x)
    total = np.zeros(c.shape[0])
    for _ in range(int(math.ceil(horizon / h))):
        x = step @ x
        cur = np.abs(c @ x)
        total += 0.5 * h * (prev + cur)
        prev = cur
    return total


def l1_condition(cfg: L1Config, lipschitz: float) -> float:
    """lambda = ||G(s)||_L1 L of the L1-norm condition (module docstring): L1 needs lambda < 1.

    G(s) = (sI - A_m)^{-1} b (1 - C(s)) as one state space: v -> f' = -w_c f + w_c v, x' = A_m x + b (v - f),
    outputs x; its impulse response starts at x(0+) = b, f(0+) = w_c.  ||G||_L1 = max over the outputs of
    int |g_i| dt (the induced inf-norm of a MIMO map with one input)."""
    a_m, b, _ = desired(cfg)
    w = cfg.omega_c
    a = np.zeros((3, 3))
    a[:2, :2] = a_m
    a[:2, 2] = -b
    a[2, 2] = -w
    x0 = np.array([b[0], b[1], w])
    slow = min(min(abs(np.linalg.eigvals(a_m).real)), w)
    fast = max(max(abs(np.linalg.eigvals(a_m))), w)
    norms = l1_norm_rows(a, x0, np.eye(3)[:2], horizon=40.0 / slow, h=0.02 / fast)
    return float(max(norms) * lipschitz)


class L1(Reconfigurable):
    """The L1 adaptive controller: ``u = law.step(phi, p, r, command)`` once per control step."""

    TELEMETRY_FIELDS = TELEMETRY_FIELDS
    Config = L1Config  # the law interface (autopilot.law): its configuration and its parameter table
    PARAMETERS = PARAMETERS

    def __init__(self, config: L1Config | None = None):
        self.config = cfg = config or L1Config()
        self.dt = T = cfg.dt
        a_m, b, k_m = desired(cfg)
        self._km = k_m
        self._kg = -1.0 / float(np.linalg.solve(a_m, b)[0])  # k_g = -1 / (c^T A_m^{-1} b)
        b_bar = np.column_stack([b, np.array([b[1], -b[0]]) / float(np.hypot(*b))])
        self._e, g_bar = zoh(a_m, b_bar, T)  # e^{A_m T}, Phi(T) B_bar
        self._gb = g_bar
        self._adapt = -np.linalg.solve(g_bar, self._e)  # sigma^ = -(Phi B_bar)^{-1} e^{A_m T} x~
        self._a = math.exp(-cfg.omega_c * T)
        self._umax = float(cfg.u_limit_rad)
        self.reset()

    def reset(self) -> None:
        """Back to rest: predictor, estimates and filter at zero."""
        self.x_hat = np.zeros(2)
        self.sigma = np.zeros(2)
        self.u_f = 0.0
        self._x = np.zeros(2)
        self.r = self.u_raw = self.u = 0.0
        self.saturated = False
        self.steps = 0

    def step(self, roll: float, roll_rate: float, yaw_rate: float, command: float) -> float:  # noqa: ARG002
        """One step: measured roll (rad), roll rate and yaw rate (rad/s), command (rad) in; surface (rad) out."""
        phi, p, r = finite(roll, roll_rate, command)
        finite(yaw_rate)
        x = np.array([phi, p])
        self.sigma = sig = self._adapt @ (self.x_hat - x)  # piecewise-constant adaptation law
        self.u_f = self._a * self.u_f + (1.0 - self._a) * (self._kg * r - sig[0])  # C(s), exact for held input
        k_x = float(self._km @ x)
        u_raw = -k_x + self.u_f
        u = min(max(u_raw, -self._umax), self._umax)
        self._predict(u + k_x)
        self._x, self.r = x, r
        self.u_raw, self.u, self.saturated = u_raw, u, u != u_raw
        self.steps += 1
        return u

    def _predict(self, u_ad: float) -> None:
        """x^ to the next sample: x^' = A_m x^ + b (u_ad + sigma^_m) + b_um sigma^_um, inputs held (exact ZOH)."""
        self.x_hat = self._e @ self.x_hat + self._gb @ np.array([u_ad + self.sigma[0], self.sigma[1]])

    def hold(self, u_applied: float = 0.0) -> None:
        """Adaptation frozen (sigma^ held); the predictor advanced on the surface that flew and the last state."""
        self._predict(float(u_applied) + float(self._km @ self._x))
        self.u = self.u_raw = float(u_applied)

    def telemetry(self) -> dict[str, float]:
        """This law's internals after the last step, by ``TELEMETRY_FIELDS``."""
        return dict(
            r=self.r, phi_hat=float(self.x_hat[0]), p_hat=float(self.x_hat[1]), sigma_m=float(self.sigma[0]),
            sigma_um=float(self.sigma[1]), u_f=self.u_f, u_raw=self.u_raw, u=self.u, saturated=float(self.saturated),
        )  # fmt: skip
