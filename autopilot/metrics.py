"""Run metrics of the reference scenario (docs/spec.md, "Metrics"), accumulated one control sample at a time.

One implementation for every transport: the in-process runner and the autopilot process both feed
``MetricsAccumulator.add`` once per control step, so runs compare like for like.  No I/O.
"""

from __future__ import annotations

import math

METRIC_NAMES = ("ise_ref", "ise_crm", "energy", "tv", "max_abs_u")


class MetricsAccumulator:
    """Rectangle-rule integrals over the control-rate samples, dt = control period.

    ise_ref   = sum (phi - ym_ol)^2 dt    tracking of the open-loop (L_v = 0) reference model
    ise_crm   = sum e^2 dt                the error the adaptive law sees
    energy    = sum u^2 dt                rudder command in rad
    tv        = sum_k>=1 |u[k] - u[k-1]|  total variation of the command
    max_abs_u = max |u|
    """

    def __init__(self, dt: float):
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be positive and finite, got {dt!r}")
        self.dt = dt
        self.reset()

    def reset(self) -> None:
        self.n = 0
        self._ise_ref = self._ise_crm = self._energy = self._tv = self._max_abs_u = 0.0
        self._u_prev: float | None = None

    def add(self, phi: float, ym_ol: float, e: float, u: float) -> None:
        d = phi - ym_ol
        self._ise_ref += d * d
        self._ise_crm += e * e
        self._energy += u * u
        if self._u_prev is not None:
            self._tv += abs(u - self._u_prev)
        self._u_prev = u
        a = abs(u)
        if a > self._max_abs_u:
            self._max_abs_u = a
        self.n += 1

    def result(self) -> dict[str, float]:
        dt = self.dt
        return {
            "ise_ref": self._ise_ref * dt,
            "ise_crm": self._ise_crm * dt,
            "energy": self._energy * dt,
            "tv": self._tv,
            "max_abs_u": self._max_abs_u,
        }
