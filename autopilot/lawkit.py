"""What the adaptive-law bench's laws (``autopilot.mrac``, ``autopilot.l1``, ``autopilot.indi``) share.  No I/O.

* :class:`LawConfig`: what every law's configuration has (the control rate, the surface limit, ``dt``, ``with_``), and
  :class:`DesignModelConfig` with the design model on [phi, p] (MRAC, L1), whose rows are ``DESIGN_MODEL_ROWS``;
* :class:`Reconfigurable`: ``reconfigure``, a parameter set live, the states and the adaptation kept;
* :func:`check_fields`: a law's config validated against its ``PARAMETERS`` table (ConfigError, one line);
* :func:`finite`: the measurements checked as ClSac checks them (NonFiniteInputError);
* :func:`proj`: the projection operator of Lavretsky & Wise (2013), ch. 11 (robust adaptive control);
* :func:`lyapunov`: P of A^T P + P A = -Q, by the Kronecker form (no scipy in the autopilot's start-up).

A ``PARAMETERS`` row is ``(ground-station name, field, unit, lower bound, upper bound, description)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from autopilot.config import ConfigError, NonFiniteInputError

# The design model x' = A x + b u on [phi, p] (tools.design.laws.roll_model), without the law's name prefix
DESIGN_MODEL_ROWS = (
    ("A11", "a11", "1/s", -1e4, 1e4, "design model A[phi, phi]"),
    ("A12", "a12", "1", -1e4, 1e4, "design model A[phi, p]"),
    ("A21", "a21", "1/s^2", -1e4, 1e4, "design model A[p, phi]"),
    ("A22", "a22", "1/s", -1e4, 1e4, "design model A[p, p] (roll damping)"),
    ("B1", "b1", "1/s", -1e5, 1e5, "design model b[phi]"),
    ("B2", "b2", "1/s^2", 1e-3, 1e5, "design model b[p] (surface effectiveness)"),
)


def prefixed(prefix: str, rows) -> tuple:
    """``rows`` with their ground-station names prefixed (``MRAC_``, ``CRM_``, ``L1_``)."""
    return tuple((f"{prefix}{name}", *rest) for name, *rest in rows)


@dataclass(frozen=True)
class LawConfig:
    """What every law's configuration has: the law interface's control rate and surface limit, its period ``dt``
    and ``with_`` (a copy with changes)."""

    control_rate_hz: float = 100.0
    u_limit_rad: float = math.radians(30.0)

    @property
    def dt(self) -> float:
        return 1.0 / self.control_rate_hz

    def with_(self, **changes):
        return replace(self, **changes)


@dataclass(frozen=True)
class DesignModelConfig(LawConfig):
    """A law's configuration with the design model x' = A x + b u on [phi, p] (``DESIGN_MODEL_ROWS``); the defaults are
    the KH2013A's: the paper's plant (sec. 5) with v, r and the servo residualised (``tools.design.laws``)."""

    a11: float = 0.26410314075222957
    a12: float = 1.0638124268665718
    a21: float = -2.161188445133773
    a22: float = -3.233723389772091
    b1: float = 0.09824126491749602
    b2: float = 196.14607966050582


class Reconfigurable:
    """``reconfigure`` for a law whose public attributes are its states and adaptation (the private ones, ``config``
    and ``dt`` are what ``__init__`` derives from its configuration)."""

    def reconfigure(self, config) -> None:
        """Fly ``config`` from the next step on (a parameter set live), keeping the states and the adaptation."""
        kept = {k: v for k, v in vars(self).items() if not k.startswith("_") and k not in ("config", "dt")}
        self.__init__(config)
        vars(self).update(kept)


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
