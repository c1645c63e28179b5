"""A fixed-gain baseline: a PID on the roll error to the open-loop reference model, tuned on the nominal model.

It shows what adaptation buys (issue 13, item 4).  The law, per control step k (period T):

    y_m,ol = C_m x_m,ol[k]                      open-loop reference model (paper eq. (3)), the command filter
    e      = y_m,ol - y[k]
    u_raw  = K_p e + x_i[k] + K_d (e - e[k-1]) / T
    u      = clip(u_raw, -u_limit, +u_limit)
    x_i[k+1] = x_i[k] + K_i T e                 not integrated while saturated and pushing further past the limit
    x_m,ol[k+1] = e^{A_m T} x_m,ol + A_m^-1 (e^{A_m T} - I) B_m u_m

Why not the C(s) = (4s + 40)/10 whose inverse is the paper's PFC (paper sec. 5.1)?  It does stabilise the
nominal plant in negative feedback, but only just: the continuous loop C(s) T(s) has a gain margin of 0.17 dB
and a phase margin of 1.1 deg (``tools.design.margins.baseline_margins(pfc_inverse=True)``), far too little
to fly.  The default gains K_p = 0.1, K_i = 0.1 s^-1, K_d = 0.02 s give the sampled loop (100 Hz, ZOH plant,
backward-difference derivative) a gain margin of 23.9 dB at 48.9 rad/s and a phase margin of 59.3 deg at
a 4.7 rad/s crossover
(``tools.design.margins.baseline_margins()``, python-control; checked by tests/autopilot/test_baseline.py).

**Feed-forward and derivative on the measurement** (``--controller pid-ff``, ``kff > 0``, ``derivative =
"measurement"``; both off by default, so the baseline above is unchanged).  The adaptive laws feed the command
forward (K_u u_m, K_x x_m, paper eq. (21)); this option gives the PID a feed-forward of the reference model's roll
rate, as ArduPilot's roll controller's FF term (the surface for a roll rate), and takes the derivative of the
measurement instead of the error, as simple-pid does (``differential_on_measurement``), so a command step no
longer kicks the surface:

    ydot_m  = C_m (A_m x_m,ol[k] + B_m u_m[k])   the reference model's roll rate (paper eq. (3), differentiated)
    u_raw   = K_ff ydot_m + K_p e + x_i[k] - K_d (y[k] - y[k-1]) / T       (0 for the derivative at step 0)

K_ff is the roll-mode inverse -L_p / L_delta of the plant's roll-rate row (``tools.design.linearise.feedforward_gain``;
the KH2013A's :data:`KFF_KH2013A`).  The integrator, its anti-windup and the limit are the baseline's.

``set_gains`` changes K_p, K_i, K_d in flight, from the next step, with the integrator's state kept (a gain
schedule: the damage study's PID retuned for the faulted plant, ``tools.experiment.damage``).

``Baseline`` quacks like ``autopilot.clsac.ClSac`` wherever ``autopilot.step.ControlStep``, the metrics and
the telemetry use a law: ``__call__(y, um)``, ``hold(u)``, ``reset()``, ``telemetry()`` and the attributes of
``TELEMETRY_FIELDS`` (``ym`` = ``ym_ol``, ``ya`` = y, ``kpe`` = ``ke`` = K_p; ``y_pfc`` and CL-SAC's other gains,
which it does not have, NaN: not drawn, never a faked 0).  Its ``e`` is y_m,ol - y, so its ``ise_crm`` equals its
``ise_ref``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from autopilot.clsac import telemetry_of
from autopilot.config import ConfigError, NonFiniteInputError
from autopilot.shared.numerics import zoh

# The KH2013A's roll-mode feed-forward -L_p / L_delta (paper sec. 5.1: A_lp[1, 1] = -2.22 1/s, B_lp[1] = 59.7
# 1/s^2 per rad): s of rudder per rad/s of roll rate; tests/autopilot/test_baseline.py checks it against sitl.model.
KFF_KH2013A = 2.22 / 59.7
DERIVATIVES = ("error", "measurement")


@dataclass(frozen=True)
class BaselineConfig:
    """Fixed-gain baseline settings: PID gains, the open-loop reference model (paper sec. 5.1 values), limit."""

    control_rate_hz: float = 100.0
    kp: float = 0.1  # rad of rudder per rad of roll error
    ki: float = 0.1  # per s
    kd: float = 0.02  # s
    am: float = -5.0  # reference model x_m' = A_m x_m + B_m u_m, y_m = C_m x_m (paper sec. 5.1)
    bm: float = 5.0
    cm: float = 1.0
    u_limit_rad: float = math.radians(30.0)
    anti_windup: bool = True  # conditional integration, as ClSac's
    kff: float = 0.0  # s: feed-forward of the reference model's roll rate (0: none, the baseline)
    derivative: str = "error"  # "error" (the baseline) or "measurement" (simple-pid's, pid-ff)

    def __post_init__(self) -> None:
        for name in ("control_rate_hz", "u_limit_rad"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be positive and finite, got {v!r}")
        for name in ("kp", "ki", "kd", "bm", "cm"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ConfigError(f"{name} must be a finite number, got {v!r}")
        if not (isinstance(self.kff, (int, float)) and math.isfinite(self.kff)):
            raise ConfigError(f"kff must be a finite number, got {self.kff!r}")
        if self.derivative not in DERIVATIVES:
            raise ConfigError(f"derivative must be one of {', '.join(DERIVATIVES)}, got {self.derivative!r}")
        for name in ("kp", "ki", "kd", "kff"):
            if getattr(self, name) < 0:
                raise ConfigError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if not (isinstance(self.am, (int, float)) and math.isfinite(self.am) and self.am < 0):
            raise ConfigError(f"am must be negative (a stable reference model), got {self.am!r}")

    @property
    def dt(self) -> float:
        return 1.0 / self.control_rate_hz

    @property
    def lv(self) -> None:
        """No closed-loop reference model (stats files report Lv as null)."""
        return None

    def with_(self, **changes) -> BaselineConfig:
        return replace(self, **changes)


class Baseline:
    """The fixed-gain baseline law: ``u = law(y, um)`` once per control step (rad in, rad out, limited)."""

    def __init__(self, config: BaselineConfig | None = None):
        self.config = cfg = config or BaselineConfig()
        self.dt = T = cfg.dt
        phi, gam = zoh(np.array([[float(cfg.am)]]), np.array([[float(cfg.bm)]]), T)
        # The same coefficient names as ClSac's SISO path, read by autopilot.batch.
        self._s = dict(phi_ol=float(phi[0, 0]), g_ol=float(gam[0, 0]), cm=float(cfg.cm))
        self._set(cfg.kp, cfg.ki, cfg.kd)
        self._kff = float(cfg.kff)
        self._am, self._bm = float(cfg.am), float(cfg.bm)
        self._on_y = cfg.derivative == "measurement"
        self._umax = float(cfg.u_limit_rad)
        self._aw = bool(cfg.anti_windup)
        self.reset()

    def _set(self, kp, ki, kd) -> None:
        T = self.dt
        self._kp, self._ki_t, self._kd_t = float(kp), float(ki) * T, float(kd) / T

    def set_gains(self, kp: float, ki: float, kd: float) -> None:
        """New PID gains from the next step (a gain schedule); the integrator's state, the model and the limit
        stay.  ConfigError for a gain that is negative or not finite."""
        gains = (float(kp), float(ki), float(kd))
        if not all(math.isfinite(g) and g >= 0 for g in gains):
            raise ConfigError(f"PID gains must be finite and >= 0, got {gains!r}")
        self._set(*gains)

    def reconfigure(self, config: BaselineConfig) -> None:
        """Fly ``config``'s gains and limit from the next step (a ground station's PARAM_SET), keeping the states."""
        T = self.dt
        if config.control_rate_hz != self.config.control_rate_hz or (config.am, config.bm, config.cm) != (
            self.config.am,
            self.config.bm,
            self.config.cm,
        ):
            raise ConfigError("the baseline's rate and reference model cannot change in flight")
        self.config = config
        self._kp, self._ki_t, self._kd_t = float(config.kp), float(config.ki) * T, float(config.kd) / T
        self._umax = float(config.u_limit_rad)
        self._aw = bool(config.anti_windup)
        self.kpe = self.ke = self._kp

    def reset(self) -> None:
        self.steps = 0
        self.frozen = False
        self.xm_ol = self.xi = self.e_prev = 0.0
        self.y_prev = None
        self.um = self.y = self.ym = self.ym_ol = self.ya = self.e = 0.0
        self.y_pfc = math.nan  # no PFC: not drawn (autopilot.law: no faked field of another law)
        self.u_raw = self.u = 0.0
        self.saturated = False
        self.kpe = self.ke = self._kp
        # K_p is its K_e (what a PARAM_SET marker sits on); CL-SAC's other gains are not its own: NaN, not drawn
        self.kie = self.kpx = self.kix = self.kx = self.kpu = self.kiu = self.ku = math.nan

    def telemetry(self) -> tuple:
        """The internals after the last step, ordered like ``autopilot.clsac.TELEMETRY_FIELDS``."""
        return telemetry_of(self)

    def __call__(self, y, um):
        return self.step(y, um)

    def step(self, y, um) -> float:
        y = float(y)
        um = float(um)
        if not (math.isfinite(y) and math.isfinite(um)):
            raise NonFiniteInputError(f"controller inputs must be finite, got y={y!r}, um={um!r}")
        s = self._s
        ym_ol = s["cm"] * self.xm_ol  # y_m,ol = C_m x_m,ol (paper eq. (3))
        e = ym_ol - y
        if self._on_y or self._kff:  # pid-ff: rate feed-forward, derivative on the measurement (module docstring)
            if self._on_y:
                d = 0.0 if self.y_prev is None else -self._kd_t * (y - self.y_prev)
            else:
                d = self._kd_t * (e - self.e_prev)
            ff = self._kff * s["cm"] * (self._am * self.xm_ol + self._bm * um)
            u_raw = ff + self._kp * e + self.xi + d
        else:
            u_raw = self._kp * e + self.xi + self._kd_t * (e - self.e_prev)  # PID, backward-difference derivative
        umax = self._umax
        u = umax if u_raw > umax else (-umax if u_raw < -umax else u_raw)
        sat = u != u_raw
        di = self._ki_t * e
        if not (sat and self._aw and di * u_raw > 0):  # conditional integration
            self.xi = self.xi + di
        self.xm_ol = s["phi_ol"] * self.xm_ol + s["g_ol"] * um
        self.e_prev = e
        self.y_prev = y
        self.um, self.y, self.ym, self.ym_ol, self.ya, self.e = um, y, ym_ol, ym_ol, y, e
        self.u_raw, self.u, self.saturated = u_raw, u, sat
        self.frozen = False
        self.steps += 1
        return u

    def hold(self, u_applied=0.0) -> None:
        """Failsafe step: someone else applies ``u_applied``; the integrator and the model are frozen."""
        self.u = self.u_raw = float(u_applied)
        self.frozen = True
