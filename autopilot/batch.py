"""The SISO laws for a batch of aircraft at once: numpy arrays of shape (N,), one element per aircraft.

``BatchClSac`` is ``ClSac._step_siso`` (autopilot/clsac.py, paper sections 2-3, eqs. (6), (18)-(21)) and
``BatchBaseline`` is ``Baseline.step`` (autopilot/baseline.py), written operation for operation in the same
order with the very coefficients the scalar law computes (read from a ``ClSac``/``Baseline`` built from the same
config).  Every operation is an elementwise IEEE-754 add, multiply, compare or select, so element i of the
batch is bit for bit what the scalar law computes for aircraft i, whatever N and whatever the other elements
(tests/autopilot/test_batch.py replays sampled runs through the scalar law).  No transcendental function is evaluated
per step.

Per-aircraft configs may differ in any coefficient (the study draws the PFC per run); the switches
(``anti_windup``, ``dead_zone_rad``, ``ki_max``, ``freeze_when_saturated``) and the limit must be the same for
the whole batch.

**The hooks the study reads** (``autopilot.controllers.Law``: ``batch``, ``kernel``; no list of names in the study).
A batch form is a class with ``accepts(config)`` (whether it flies that configuration: the plain PID, not pid-ff's
feed-forward) and ``of(configs)`` (the law for one config per aircraft).  Its C-kernel form is a function of a
batch law giving :class:`KernelForm`: its law number in the study's kernel (``tools/experiment/study/kernel.c``,
``Batch.kind``), its coefficients and states in the kernel's order, and its switches.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from autopilot.baseline import Baseline, BaselineConfig
from autopilot.clsac import ClSac
from autopilot.config import ClSacConfig, ConfigError

_COEFFS = (
    "phi_m",
    "g_mu",
    "g_my",
    "phi_ol",
    "g_ol",
    "cm",
    "phi_d",
    "g_d",
    "cd",
    "gpe",
    "gie",
    "gpx",
    "gix",
    "gpu",
    "giu",
)
_LEAKS = ("_decay", "_gain_ie", "_decay_x", "_gain_ix", "_decay_u", "_gain_iu")
_SWITCHES = ("_umax", "_aw", "_dz", "_kmax", "_freeze")


class KernelForm(NamedTuple):
    """A batch law as the study's C kernel flies it (kernel.c's ``Batch``): ``kind`` its law there (0 CL-SAC, 1 the
    fixed-gain PID), ``coef`` its coefficients (C_*/B_* in kernel.c; a float for every aircraft or an (N,) array),
    ``state`` its six states s0..s5, and its switches."""

    kind: int
    coef: list
    state: list
    anti_windup: bool
    dead_zone: float
    ki_max: float | None
    freeze: bool


def _column(values: list[float]):
    """A Python float when every aircraft has the same value (scalar * array is the same IEEE operation as
    array * array, and cheaper), else an (N,) array."""
    first = values[0]
    if all(v == first for v in values):
        return first
    return np.array(values, dtype=float)


class BatchClSac:
    """CL-SAC (SAC with L_v = 0) for N aircraft: ``u = law(y, um)`` with y, um arrays of shape (N,).

    After each call ``e``, ``ym``, ``ym_ol``, ``ya``, ``y_pfc``, ``u_raw``, ``u``, ``saturated`` and the gains
    ``kpe`` ... ``ku`` hold this step's values, as on ``ClSac``; ``ki_e``, ``ki_x``, ``ki_u``, ``xm``, ``xm_ol``,
    ``xd`` are the states carried to the next step.
    """

    def __init__(self, configs: Sequence[ClSacConfig]):
        if not configs:
            raise ConfigError("a batch needs at least one config")
        laws: dict[ClSacConfig, ClSac] = {}
        for cfg in configs:
            if cfg not in laws:
                law = ClSac(cfg, fast=True)
                if not law._fast:  # noqa: SLF001
                    raise ConfigError(f"the batch law is the SISO law with a first-order PFC; got {cfg!r}")
                laws[cfg] = law
        per = [laws[cfg] for cfg in configs]
        self.n = len(per)
        self.config = configs[0]
        for name in _SWITCHES:
            values = {getattr(law, name) for law in laws.values()}
            if len(values) != 1:
                raise ConfigError(f"every config of a batch must have the same {name.lstrip('_')}, got {values}")
        first = per[0]
        self._umax, self._aw, self._dz, self._kmax, self._freeze = (getattr(first, n) for n in _SWITCHES)
        self._c = {k: _column([law._s[k] for law in per]) for k in _COEFFS}  # noqa: SLF001
        self._leak = {k: _column([getattr(law, k) for law in per]) for k in _LEAKS}
        self._ki0 = tuple(np.array([law._ki0[i][0, 0] for law in per]) for i in range(3))  # noqa: SLF001
        self.reset()

    @staticmethod
    def accepts(config) -> bool:
        """It flies the SISO law with a first-order PFC (``ClSac``'s fast path)."""
        return bool(config.is_siso) and len(config.pfc_den) == 2

    @classmethod
    def of(cls, configs: Sequence[ClSacConfig]) -> BatchClSac:
        """The batch of one config per aircraft."""
        return cls(configs)

    def reset(self) -> None:
        n = self.n
        self.xm = np.zeros(n)
        self.xm_ol = np.zeros(n)
        self.xd = np.zeros(n)
        self.ki_e, self.ki_x, self.ki_u = (k.copy() for k in self._ki0)
        zero = np.zeros(n)
        self.um = self.y = self.ym = self.ym_ol = self.ya = self.y_pfc = self.e = zero
        self.u_raw = self.u = zero
        self.saturated = np.zeros(n, dtype=bool)
        self.steps = 0

    def __call__(self, y: np.ndarray, um: np.ndarray) -> np.ndarray:
        """One control step for every aircraft (the body of ``ClSac._step_siso``, elementwise)."""
        c = self._c
        lk = self._leak
        xm = self.xm
        y_pfc = c["cd"] * self.xd  # y_d = C_d x_d
        ya = y + y_pfc  # y_a = y_p + D(s) u_p
        ym = c["cm"] * xm  # y_m = C_m x_m
        e = ym - ya  # e_my = y_m - y_a  (paper eq. (20))
        kpe = e * e * c["gpe"]
        kpx = e * xm * c["gpx"]
        kpu = e * um * c["gpu"]
        kie, kix, kiu = self.ki_e, self.ki_x, self.ki_u
        ke = kpe + kie
        kx = kpx + kix
        ku = kpu + kiu
        u_raw = ke * e + kx * xm + ku * um  # paper eqs. (6), (21)
        umax = self._umax
        u = np.clip(u_raw, -umax, umax)
        sat = u != u_raw
        die = lk["_gain_ie"] * (e * e * c["gie"])
        dix = lk["_gain_ix"] * (e * xm * c["gix"])
        diu = lk["_gain_iu"] * (e * um * c["giu"])
        skip = None
        if self._dz > 0.0:
            skip = np.abs(e) <= self._dz  # dead-zone on e
        if self._freeze:
            skip = sat if skip is None else skip | sat
        if skip is not None:
            die = np.where(skip, 0.0, die)
            dix = np.where(skip, 0.0, dix)
            diu = np.where(skip, 0.0, diu)
        if self._aw:  # conditional integration, per channel (zeroing an already zero increment changes nothing)
            die = np.where(sat & (die * e * u_raw > 0), 0.0, die)
            dix = np.where(sat & (dix * xm * u_raw > 0), 0.0, dix)
            diu = np.where(sat & (diu * um * u_raw > 0), 0.0, diu)
        self.ki_e = lk["_decay"] * kie + die
        self.ki_x = lk["_decay_x"] * kix + dix
        self.ki_u = lk["_decay_u"] * kiu + diu
        if self._kmax is not None:  # projection onto |K_I| <= ki_max
            km = self._kmax
            self.ki_e = np.minimum(np.maximum(self.ki_e, -km), km)
            self.ki_x = np.minimum(np.maximum(self.ki_x, -km), km)
            self.ki_u = np.minimum(np.maximum(self.ki_u, -km), km)
        self.xm = c["phi_m"] * xm + (c["g_mu"] * um + c["g_my"] * ya)  # paper eq. (18), exact ZOH
        ym_ol = c["cm"] * self.xm_ol
        self.xm_ol = c["phi_ol"] * self.xm_ol + c["g_ol"] * um
        self.xd = c["phi_d"] * self.xd + c["g_d"] * u
        self.um, self.y, self.ym, self.ym_ol, self.ya, self.y_pfc, self.e = um, y, ym, ym_ol, ya, y_pfc, e
        self.u_raw, self.u, self.saturated = u_raw, u, sat
        self.kpe, self.kpx, self.kpu, self.ke, self.kx, self.ku = kpe, kpx, kpu, ke, kx, ku
        self.kie, self.kix, self.kiu = kie, kix, kiu
        self.steps += 1
        return u


class BatchBaseline:
    """The fixed-gain baseline (``autopilot.baseline.Baseline``) for N aircraft sharing one config."""

    def __init__(self, config: BaselineConfig | None, n: int):
        law = Baseline(config)
        if law.config.kff or law.config.derivative != "error":
            raise ValueError("BatchBaseline flies the plain baseline only (no feed-forward, derivative on the error)")
        self.config = law.config
        self.n = int(n)
        s = law._s  # noqa: SLF001
        self._phi_ol, self._g_ol, self._cm = s["phi_ol"], s["g_ol"], s["cm"]
        self._kp, self._ki_t, self._kd_t = law._kp, law._ki_t, law._kd_t  # noqa: SLF001
        self._umax, self._aw = law._umax, law._aw  # noqa: SLF001
        self.reset()

    @staticmethod
    def accepts(config) -> bool:
        """It flies the plain PID only: no feed-forward, the derivative on the error (not pid-ff)."""
        return not config.kff and config.derivative == "error"

    @classmethod
    def of(cls, configs: Sequence[BaselineConfig]) -> BatchBaseline:
        """The batch of one config per aircraft: the same config for all (ValueError otherwise)."""
        if not configs or any(c != configs[0] for c in configs):
            raise ValueError("BatchBaseline flies one config for the whole batch")
        return cls(configs[0], len(configs))

    def reset(self) -> None:
        n = self.n
        self.xm_ol = np.zeros(n)
        self.xi = np.zeros(n)
        self.e_prev = np.zeros(n)
        self.e = self.ym_ol = self.u = self.u_raw = np.zeros(n)
        self.saturated = np.zeros(n, dtype=bool)
        self.steps = 0

    def __call__(self, y: np.ndarray, um: np.ndarray) -> np.ndarray:
        """One step for every aircraft (the body of ``Baseline.step``, elementwise)."""
        ym_ol = self._cm * self.xm_ol
        e = ym_ol - y
        u_raw = self._kp * e + self.xi + self._kd_t * (e - self.e_prev)
        u = np.clip(u_raw, -self._umax, self._umax)
        sat = u != u_raw
        di = self._ki_t * e
        keep = sat & (di * u_raw > 0) if self._aw else np.zeros(self.n, dtype=bool)
        self.xi = np.where(keep, self.xi, self.xi + di)
        self.xm_ol = self._phi_ol * self.xm_ol + self._g_ol * um
        self.e_prev = e
        self.e, self.ym_ol, self.u_raw, self.u, self.saturated = e, ym_ol, u_raw, u, sat
        self.steps += 1
        return u


def clsac_kernel(law: BatchClSac) -> KernelForm:
    """CL-SAC's C-kernel form: kernel.c's law 0, coefficients ``_COEFFS`` then ``_LEAKS``, states xm, xm_ol, xd,
    K_Ie, K_Ix, K_Iu."""
    coef = [law._c[k] for k in _COEFFS] + [law._leak[k] for k in _LEAKS]  # noqa: SLF001
    state = [law.xm, law.xm_ol, law.xd, law.ki_e, law.ki_x, law.ki_u]
    return KernelForm(0, coef, state, law._aw, law._dz, law._kmax, law._freeze)  # noqa: SLF001


def baseline_kernel(law: BatchBaseline) -> KernelForm:
    """The fixed-gain PID's C-kernel form: kernel.c's law 1, coefficients phi_ol, g_ol, C_m, K_p, K_i T, K_d / T,
    states x_m,ol, x_i, e[k-1]."""
    coef = [law._phi_ol, law._g_ol, law._cm, law._kp, law._ki_t, law._kd_t]  # noqa: SLF001
    return KernelForm(1, coef, [law.xm_ol, law.xi, law.e_prev, 0.0, 0.0, 0.0], law._aw, 0.0, None, False)  # noqa: SLF001
