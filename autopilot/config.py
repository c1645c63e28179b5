"""Controller configuration: a frozen dataclass whose defaults are the paper's values (section 5)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

# Parallel feedforward compensators D(s) = num/den (highest power first).  "paper": section 5's
# D = 1/C, C = (4s + 40)/10.  "robust": the same C at a quarter of its gain, D = 10/(s + 10): no band of
# constant K_e > 0 makes 1 + K_e (T + D) unstable (``python -m tools.pfc --pfc robust``; docs/experiments.md, "W-ASPR").
PFC_PRESETS: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {
    "paper": ((10.0,), (4.0, 40.0)),
    "robust": ((10.0,), (1.0, 10.0)),
}


class ConfigError(ValueError):
    """A configuration value is invalid; the message names the field and the value."""


class NonFiniteInputError(ValueError):
    """A measurement or command given to the controller was NaN or infinite."""


def _as_matrix(name: str, value, shape: tuple[int, int] | None = None) -> np.ndarray:
    try:
        arr = np.atleast_2d(np.asarray(value, dtype=float))
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{name} must be a number or a matrix of numbers, got {value!r}") from exc
    if arr.ndim != 2:
        raise ConfigError(f"{name} must be a scalar or a 2-D matrix, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} must be finite, got {value!r}")
    if shape is not None and arr.shape != shape:
        if arr.shape == (1, 1) and shape[0] == shape[1]:
            return arr[0, 0] * np.eye(shape[0])  # a scalar weight means scalar * identity
        raise ConfigError(f"{name} must have shape {shape}, got {arr.shape}")
    return arr


@dataclass(frozen=True)
class ClSacConfig:
    """CL-SAC settings (paper sections 2, 3 and 5).  SAC is the same law with ``lv = 0``.

    Scalars describe the SISO roll loop; ``am``, ``bm``, ``cm``, ``lv`` and the Gammas may also be
    matrices (m x m square plant, reference model of order n_m), see :meth:`dims`.
    """

    control_rate_hz: float = 100.0
    # Reference model x_m' = A_m x_m + B_m u_m - L_v (y_m - y_a), y_m = C_m x_m  (paper sec. 3, eqs. (18)-(19))
    am: float | tuple = -5.0
    bm: float | tuple = 5.0
    cm: float | tuple = 1.0
    lv: float | tuple = 20.0
    # Adaptation weights (paper section 5: all ten) and sigma-modification (paper: 5)
    gamma_pe: float | tuple = 10.0
    gamma_ie: float | tuple = 10.0
    gamma_px: float | tuple = 10.0
    gamma_ix: float | tuple = 10.0
    gamma_pu: float | tuple = 10.0
    gamma_iu: float | tuple = 10.0
    sigma: float = 5.0
    # Optional sigma-modification of K_Ix and K_Iu too (not in the paper, which leaks K_Ie only: 0 = paper).
    # Without it K_Ix, K_Iu drift over long flights (see docs/experiments.md, "Long flights").
    sigma_x: float = 0.0
    sigma_u: float = 0.0
    # Initial integral gains K_I(0) (paper: 0)
    ki_e0: float | tuple = 0.0
    ki_x0: float | tuple = 0.0
    ki_u0: float | tuple = 0.0
    # Parallel feedforward compensator D(s) = 1/C(s), C(s) = (4 s + 40)/10  (paper section 5)
    pfc_num: tuple[float, ...] = (10.0,)
    pfc_den: tuple[float, ...] = (4.0, 40.0)
    # Rudder command limit |u| <= u_limit_rad (docs/spec.md, "Reference scenario": 30 deg)
    u_limit_rad: float = math.radians(30.0)
    # Conditional integration when the command saturates (see ClSac docstring)
    anti_windup: bool = True
    # Optional robustness modifications (not in the paper; each off by default, so the default is the paper's law).
    # Dead-zone: no integral adaptation (K_Ie, K_Ix, K_Iu increments) while |e| <= dead_zone_rad (MIMO: ||e||_inf).
    dead_zone_rad: float = 0.0
    # Projection: every element of K_Ie, K_Ix, K_Iu is projected onto [-ki_max, ki_max] after its update.
    ki_max: float | None = None
    # Freeze every integral channel while the command saturates (anti_windup skips only the channels that push
    # further past the limit).
    freeze_when_saturated: bool = False
    # A square MIMO plant (m > 1; docs/spec.md, "Square MIMO CL-SAC"): a PFC per channel, D(s) = diag(D_1, ..., D_m)
    # with D_i = num_i/den_i (``pfc_num``/``pfc_den`` are then unused), and a command limit per channel (each surface
    # its own stop).  None: every channel the same D(s) = pfc_num/pfc_den and the one ``u_limit_rad``.
    pfc_channels: tuple | None = None
    u_limits_rad: tuple | None = None
    _dims: tuple = field(default=(), init=False, repr=False, compare=False)

    @classmethod
    def sac(cls, **overrides) -> "ClSacConfig":
        """Plain SAC (open-loop reference model): the same law with L_v = 0 (paper section 2)."""
        return cls(**{"lv": 0.0, **overrides})

    def with_pfc(self, name: str) -> "ClSacConfig":
        """A copy using the named PFC of ``PFC_PRESETS`` ("paper" or "robust")."""
        try:
            num, den = PFC_PRESETS[name]
        except KeyError:
            raise ConfigError(f"unknown PFC {name!r} (known: {', '.join(PFC_PRESETS)})") from None
        return self.with_(pfc_num=num, pfc_den=den)

    def with_(self, **changes) -> "ClSacConfig":
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)

    @property
    def dt(self) -> float:
        return 1.0 / self.control_rate_hz

    def __post_init__(self) -> None:
        rate = self.control_rate_hz
        if not isinstance(rate, (int, float)) or not math.isfinite(rate) or rate <= 0:
            raise ConfigError(f"control_rate_hz must be a positive finite number, got {rate!r}")
        for name in ("sigma", "sigma_x", "sigma_u"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ConfigError(f"{name} must be finite and >= 0, got {v!r}")
        dz = self.dead_zone_rad
        if not (isinstance(dz, (int, float)) and math.isfinite(dz) and dz >= 0):
            raise ConfigError(f"dead_zone_rad must be finite and >= 0, got {dz!r}")
        km = self.ki_max
        if km is not None and not (isinstance(km, (int, float)) and math.isfinite(km) and km > 0):
            raise ConfigError(f"ki_max must be positive and finite (or None), got {km!r}")
        if not (
            isinstance(self.u_limit_rad, (int, float)) and math.isfinite(self.u_limit_rad) and self.u_limit_rad > 0
        ):
            raise ConfigError(f"u_limit_rad must be positive and finite, got {self.u_limit_rad!r}")
        am = _as_matrix("am", self.am)
        n_m = am.shape[0]
        if am.shape != (n_m, n_m):
            raise ConfigError(f"am must be square, got shape {am.shape}")
        cm = _as_matrix("cm", self.cm)
        m = cm.shape[0]
        if cm.shape[1] != n_m:
            raise ConfigError(f"cm must have {n_m} columns to match am, got shape {cm.shape}")
        bm = _as_matrix("bm", self.bm)
        if bm.shape[0] != n_m:
            raise ConfigError(f"bm must have {n_m} rows to match am, got shape {bm.shape}")
        m_m = bm.shape[1]
        lv = _as_matrix("lv", self.lv, (n_m, m))
        if np.any(lv < 0):
            raise ConfigError(f"lv must be >= 0, got {self.lv!r}")
        for name, shape in (
            ("gamma_pe", (m, m)),
            ("gamma_ie", (m, m)),
            ("gamma_px", (n_m, n_m)),
            ("gamma_ix", (n_m, n_m)),
            ("gamma_pu", (m_m, m_m)),
            ("gamma_iu", (m_m, m_m)),
        ):
            g = _as_matrix(name, getattr(self, name), shape)
            # The adaptation weights must be positive (semi-)definite (paper section 2, Lyapunov function).
            sym = 0.5 * (g + g.T)
            if np.min(np.linalg.eigvalsh(sym)) < 0:
                raise ConfigError(f"{name} must be non-negative (positive semi-definite), got {getattr(self, name)!r}")
        _as_matrix("ki_e0", self.ki_e0, (m, m))
        _as_matrix("ki_x0", self.ki_x0, (m, n_m))
        _as_matrix("ki_u0", self.ki_u0, (m, m_m))
        if np.any(np.linalg.eigvals(am).real >= 0):
            raise ConfigError(f"am must be Hurwitz (all eigenvalues in the open left half plane), got {self.am!r}")
        if np.any(np.linalg.eigvals(am - lv @ cm).real >= 0):
            raise ConfigError(
                f"am - lv cm must be Hurwitz so the closed-loop reference model is stable, got lv={self.lv!r}"
            )
        self._check_pfc()
        self._check_channels(m)
        object.__setattr__(self, "_dims", (m, n_m, m_m))

    def _check_channels(self, m: int) -> None:
        """``pfc_channels`` and ``u_limits_rad``: m of each, every PFC as ``pfc_num``/``pfc_den`` are checked."""
        if self.pfc_channels is not None:
            if len(self.pfc_channels) != m:
                raise ConfigError(f"pfc_channels must have one (num, den) per channel ({m}), got {self.pfc_channels!r}")
            for num, den in self.pfc_channels:
                replace(self, pfc_num=tuple(num), pfc_den=tuple(den), pfc_channels=None, u_limits_rad=None)
        if self.u_limits_rad is not None:
            lim = self.u_limits_rad
            if len(lim) != m or not all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in lim):
                raise ConfigError(f"u_limits_rad must be {m} positive finite limits, one per channel, got {lim!r}")

    def _check_pfc(self) -> None:
        try:
            num = np.trim_zeros(np.asarray(self.pfc_num, dtype=float).ravel(), "f")
            den = np.trim_zeros(np.asarray(self.pfc_den, dtype=float).ravel(), "f")
        except (TypeError, ValueError) as exc:
            raise ConfigError(
                f"pfc_num/pfc_den must be sequences of numbers, got {self.pfc_num!r} / {self.pfc_den!r}"
            ) from exc
        if not (np.all(np.isfinite(num)) and np.all(np.isfinite(den))):
            raise ConfigError(f"PFC coefficients must be finite, got num={self.pfc_num!r} den={self.pfc_den!r}")
        if den.size < 2:
            raise ConfigError(f"pfc_den must have degree >= 1, got {self.pfc_den!r}")
        if num.size == 0:
            raise ConfigError(f"pfc_num must not be all zeros, got {self.pfc_num!r}")
        if num.size >= den.size:
            # A feedthrough term would make y_a depend on u, which depends on y_a: an algebraic loop.
            raise ConfigError(
                f"the PFC must be strictly proper (deg num < deg den), got num={self.pfc_num!r} den={self.pfc_den!r}"
            )
        if np.any(np.roots(den).real >= 0):
            raise ConfigError(
                f"the PFC must be stable (roots of pfc_den in the open left half plane), got {self.pfc_den!r}"
            )

    def dims(self) -> tuple[int, int, int]:
        """(m outputs, n_m reference-model states, m_m reference inputs)."""
        return self._dims

    @property
    def is_siso(self) -> bool:
        return self._dims == (1, 1, 1)
