"""What the adaptive-law bench's laws (``autopilot.mrac``, ``autopilot.l1``, ``autopilot.indi``) share.  No I/O.

* :func:`check_fields`: a law's config validated against its ``PARAMETERS`` table (ConfigError, one line);
* :func:`finite`: the measurements checked as ClSac checks them (NonFiniteInputError);
* :func:`proj`: the projection operator of Lavretsky & Wise (2013), ch. 11 (robust adaptive control);
* :func:`lyapunov`: P of A^T P + P A = -Q, by the Kronecker form (no scipy in the autopilot's start-up).

A ``PARAMETERS`` row is ``(ground-station name, field, unit, lower bound, upper bound, description)``.
"""

from __future__ import annotations

import math

import numpy as np

from autopilot.config import ConfigError, NonFiniteInputError


def check_fields(cfg, parameters) -> None:
    """Raise ConfigError unless ``control_rate_hz`` and ``u_limit_rad`` are positive and finite and every field of
    ``parameters`` is a finite number within its row's [lower, upper] bounds."""
    rows = [("", "control_rate_hz", "Hz", 1.0, 10000.0, ""), ("", "u_limit_rad", "rad", 1e-6, math.pi, "")]
    for _name, field, unit, lo, hi, _desc in rows + list(parameters):
        v = getattr(cfg, field)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ConfigError(f"{field} must be a finite number, got {v!r}")
        if not lo <= v <= hi:
            raise ConfigError(f"{field} must be in [{lo:g}, {hi:g}] {unit}, got {v!r}")


def finite(*values: float) -> tuple[float, ...]:
    """The measurements as floats; NonFiniteInputError if one is NaN or infinite (as ``ClSac`` raises)."""
    out = tuple(float(v) for v in values)
    if not all(math.isfinite(v) for v in out):
        raise NonFiniteInputError(f"controller inputs must be finite, got {out!r}")
    return out


def proj(theta: np.ndarray, y: np.ndarray, theta_max: float, eps: float) -> np.ndarray:
    """Proj(theta, y) of Lavretsky & Wise (2013), ch. 11 (the projection operator), with the convex function

        f(theta) = ((1 + eps) ||theta||^2 - theta_max^2) / (eps theta_max^2)
        grad f   = 2 (1 + eps) theta / (eps theta_max^2)

        Proj(theta, y) = y - (grad f grad f^T / ||grad f||^2) y f(theta)   if f(theta) > 0 and y^T grad f > 0
                       = y                                                otherwise

    f <= 0 inside the ball ||theta|| <= theta_max / sqrt(1 + eps) and f = 1 on ||theta|| = theta_max, so a
    parameter driven by theta' = Gamma Proj(theta, y) (Gamma = gamma I) never leaves ||theta|| <= theta_max."""
    f = ((1.0 + eps) * float(theta @ theta) - theta_max**2) / (eps * theta_max**2)
    grad = 2.0 * (1.0 + eps) * theta / (eps * theta_max**2)
    push = float(y @ grad)
    if f > 0.0 and push > 0.0:
        return y - grad * (push / float(grad @ grad)) * f
    return y


def lyapunov(a: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The symmetric P of A^T P + P A = -Q for a Hurwitz A: (I kron A^T + A^T kron I) vec P = -vec Q."""
    a = np.asarray(a, dtype=float)
    n = a.shape[0]
    m = np.kron(np.eye(n), a.T) + np.kron(a.T, np.eye(n))
    p = np.linalg.solve(m, -np.asarray(q, dtype=float).reshape(n * n)).reshape(n, n)
    return 0.5 * (p + p.T)
