"""Sensor errors on the roll angle and roll rate the SITL reports: delay in samples, bias, white noise.  Seeded, no I/O.

Measured value at sample k (one sample = one ATTITUDE message: one control frame in lockstep, one sensor
period in real time)::

    phi_m[k] = phi[k - D] + b_phi + sigma_phi n1[k]      p_m[k] = p[k - D] + b_p + sigma_p n2[k]
    r_m[k]   = r[k - D]                                    (n1, n2 ~ N(0, 1), drawn only when sigma > 0)

For k < D the first sample is repeated.  Works on scalars or on numpy arrays (a batch of aircraft).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np


class SensorConfigError(ValueError):
    """A sensor error value is out of range."""


@dataclass(frozen=True)
class SensorConfig:
    """roll_noise (rad), roll_bias (rad), rate_noise (rad/s), rate_bias (rad/s), delay (whole samples)."""

    roll_noise: float = 0.0
    roll_bias: float = 0.0
    rate_noise: float = 0.0
    rate_bias: float = 0.0
    delay: int = 0

    def __post_init__(self) -> None:
        for name in ("roll_noise", "rate_noise"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise SensorConfigError(f"{name} must be >= 0 and finite, got {v!r}")
        for name in ("roll_bias", "rate_bias"):
            if not math.isfinite(getattr(self, name)):
                raise SensorConfigError(f"{name} must be finite, got {getattr(self, name)!r}")
        if not (isinstance(self.delay, int) and self.delay >= 0):
            raise SensorConfigError(f"sensor delay must be a whole number of samples >= 0, got {self.delay!r}")

    @property
    def active(self) -> bool:
        return any((self.roll_noise, self.roll_bias, self.rate_noise, self.rate_bias, self.delay))


class Sensors:
    """Applies :class:`SensorConfig` sample by sample.

    Example::

        s = Sensors(SensorConfig(roll_bias=0.01, delay=2), np.random.default_rng(0))
        phi_m, p_m, r_m = s.measure(phi, p, r)     # once per ATTITUDE
    """

    def __init__(self, cfg: SensorConfig, rng: np.random.Generator):
        self.cfg = cfg
        self.rng = rng
        self._hist: deque = deque(maxlen=cfg.delay + 1)

    def measure(self, phi, p, r):
        """(phi_m, p_m, r_m) for this sample from the truth (phi, p, r); scalars or arrays of one shape."""
        cfg = self.cfg
        hist = self._hist
        hist.append((phi, p, r))
        phi_d, p_d, r_d = hist[0]  # D samples old once the buffer is full, the first sample before
        phi_m = phi_d + cfg.roll_bias
        p_m = p_d + cfg.rate_bias
        if cfg.roll_noise > 0:
            phi_m = phi_m + cfg.roll_noise * self._normal(phi)
        if cfg.rate_noise > 0:
            p_m = p_m + cfg.rate_noise * self._normal(p)
        return phi_m, p_m, r_d

    def _normal(self, like):
        shape = np.shape(like)
        return self.rng.standard_normal(shape) if shape else float(self.rng.standard_normal())
