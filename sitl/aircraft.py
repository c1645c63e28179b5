"""The linear aircraft (the KH2013A + rudder servo, or a plant file's), integrated exactly with a zero-order hold.

One small interface (ArduPilot SITL style): ``step(delta_command) -> state`` advances one physics step,
``advance(delta_command, n)`` advances ``n`` steps with the command held.  No I/O here.

Optional disturbance input d = [v_g, p_g, r_g] (``sitl.atmosphere``): x' = A_p x + B_p u + E d, E from
``sitl.atmosphere.disturbance_matrix``, d held over each physics step (exact ZOH of E).  Without ``d`` the
update is the undisturbed one, unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from autopilot.shared.numerics import zoh
from sitl import damage, model


class AircraftConfigError(ValueError):
    """An aircraft configuration value is out of range."""


class NonFiniteCommandError(ValueError):
    """A servo command was NaN or infinite."""


@dataclass(frozen=True)
class AircraftConfig:
    """Simulation settings.  Defaults: 1 kHz physics, no rudder limits (the paper's linear model)."""

    physics_rate_hz: float = 1000.0
    rudder_limit_rad: float | None = None  # |delta_r| limit, applied after each physics step
    rudder_rate_limit_rad_s: float | None = None  # |delta_r_dot| limit, applied after each physics step

    def __post_init__(self) -> None:
        if not (math.isfinite(self.physics_rate_hz) and self.physics_rate_hz > 0):
            raise AircraftConfigError(f"physics_rate_hz must be a positive finite number, got {self.physics_rate_hz!r}")
        for name in ("rudder_limit_rad", "rudder_rate_limit_rad_s"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise AircraftConfigError(f"{name} must be positive and finite (or None), got {value!r}")

    @property
    def dt(self) -> float:
        return 1.0 / self.physics_rate_hz


class Aircraft:
    """KH2013A lateral dynamics with the rudder servo, x_p = [v, p, r, phi, delta_r, delta_r_dot].

    Any linear plant with the servo's two states last flies the same way (``sitl.linear_plant``): ``params``
    holds its ``A`` (n x n) and ``B`` (n x 1) and ``truth`` (4 x n-2, optional) maps its airframe states onto
    [v, p, r, phi]; :attr:`truth` is then [v, p, r, phi, delta, delta_dot] whatever the plant's states.

    Example::

        ac = Aircraft()
        for _ in range(1000):
            x = ac.step(0.01)    # 1 s of a 0.01 rad rudder command
    """

    def __init__(self, config: AircraftConfig | None = None, x0: np.ndarray | None = None, params: dict | None = None):
        self.config = config or AircraftConfig()
        params = params or {}
        self._a = np.asarray(params.get("A", model.A_P), dtype=float)
        self.n = n = self._a.shape[0]
        self._b = np.asarray(params.get("B", model.B_P), dtype=float).reshape(n, 1)
        self._i_delta, self._i_delta_dot = n - 2, n - 1  # the servo's states are the last two
        self._truth_map = params.get("truth")  # None: the states are [v, p, r, phi, delta, delta_dot] already
        # x[k+1] = Ad x[k] + Bd u[k]  (exact ZOH of x' = A_p x + B_p u over one physics step)
        self._ad, bd = zoh(self._a, self._b, self.config.dt)
        self._bd = bd.ravel()
        self._multi: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._ed: np.ndarray | None = None  # ZOH of the disturbance input, built on first use
        self._multi_d: dict[int, np.ndarray] = {}
        self._x0 = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float).copy()
        if self._x0.shape != (n,):
            raise AircraftConfigError(
                f"x0 must have {n} elements (KH2013A: [v, p, r, phi, delta_r, delta_r_dot]), got shape {self._x0.shape}"
            )
        self._limited = self.config.rudder_limit_rad is not None or self.config.rudder_rate_limit_rad_s is not None
        self._effect = damage.NOMINAL  # the faults' effect flown (sitl.damage, set_effect)
        self._act: damage.Actuator | None = None  # the servo's path under a servo fault
        self._u_last = 0.0  # the command of the last advance (a delay line starts full of it)
        self._dynamics: dict = {}  # (effectiveness, damping) -> the matrices and caches flown under them
        self.reset()

    def reset(self, x0: np.ndarray | None = None) -> None:
        """Back to the initial state (or ``x0``) at t = 0."""
        self.x = (self._x0 if x0 is None else np.asarray(x0, dtype=float)).copy()
        self.steps = 0

    @property
    def time(self) -> float:
        """Simulated time in seconds (steps * dt, so it never drifts)."""
        return self.steps * self.config.dt

    @property
    def state(self) -> np.ndarray:
        """A copy of the truth state [v, p, r, phi, delta_r, delta_r_dot]."""
        return self.x.copy()

    @property
    def truth(self) -> np.ndarray:
        """[v, p, r, phi, delta, delta_dot] (``sitl.model.STATE_NAMES``): the state itself for KH2013A (a view, do
        not modify), the airframe states mapped through the plant file's ``truth`` rows otherwise."""
        if self._truth_map is None:
            return self.x
        return np.concatenate((self._truth_map @ self.x[: self.n - 2], self.x[self.n - 2 :]))

    def attitude(self) -> tuple[float, float, float | None, float, float, float]:
        """(roll, pitch, yaw, p, q, r): the lateral model has no pitch (0) and no heading state (None: the endpoint
        integrates psi' = r)."""
        x = self.truth
        return float(x[model.PHI]), 0.0, None, float(x[model.P]), 0.0, float(x[model.R])

    @property
    def phi(self) -> float:
        return float(self.truth[model.PHI])

    @property
    def p(self) -> float:
        return float(self.truth[model.P])

    @property
    def r(self) -> float:
        return float(self.truth[model.R])

    def _check(self, delta_command: float) -> float:
        u = float(delta_command)
        if not math.isfinite(u):
            raise NonFiniteCommandError(f"servo command must be finite, got {delta_command!r}")
        return u

    def _apply_limits(self) -> None:
        cfg = self.config
        x = self.x
        i, j = self._i_delta, self._i_delta_dot
        if cfg.rudder_limit_rad is not None and abs(x[i]) >= cfg.rudder_limit_rad:
            # Mechanical stop: deflection clamped, rate into the stop removed.
            x[i] = math.copysign(cfg.rudder_limit_rad, x[i])
            if x[i] * x[j] > 0:
                x[j] = 0.0
        if cfg.rudder_rate_limit_rad_s is not None and abs(x[j]) > cfg.rudder_rate_limit_rad_s:
            x[j] = math.copysign(cfg.rudder_rate_limit_rad_s, x[j])

    @property
    def disturbance_zoh(self) -> np.ndarray:
        """E_d = int_0^h e^{A_p s} ds E (6x3): x[k+1] = Ad x[k] + Bd u[k] + E_d d[k]."""
        if self._ed is None:
            if self.n != 6 or self._truth_map is not None:
                raise AircraftConfigError(
                    "the atmosphere (turbulence, gusts, crosswind) needs the airframe states [v, p, r, phi]"
                )
            from sitl.atmosphere import disturbance_matrix

            self._ed = zoh(self._a, disturbance_matrix(self._a), self.config.dt)[1]
        return self._ed

    def step(self, delta_command: float, d: np.ndarray | None = None) -> np.ndarray:
        """Advance one physics step with the servo command (and the disturbance ``d``, if any) held (ZOH);
        returns the state (a view, do not modify)."""
        u = float(delta_command)
        if u - u != 0.0:  # NaN or +-Inf (cheaper than math.isfinite on the hot path)
            raise NonFiniteCommandError(f"servo command must be finite, got {delta_command!r}")
        x = self._ad.dot(self.x)  # x[k+1] = Ad x[k] + Bd u[k]
        x += self._bd * u
        if d is not None:
            x += self.disturbance_zoh @ d
        self.x = x
        if self._limited:
            self._apply_limits()
        self.steps += 1
        return self.x

    def advance(self, delta_command: float, n: int, d: np.ndarray | None = None) -> np.ndarray:
        """Advance ``n`` physics steps with the command held; ``d`` (n, 3), if given, is the disturbance of each step.

        Without rudder limits the system is linear and the n steps collapse into one exact update
        x[k+n] = Ad^n x[k] + (sum_{i<n} Ad^i) Bd u (+ sum_i Ad^(n-1-i) E_d d[i]), cached per n.  With limits
        it steps one by one.
        """
        if n < 0:
            raise ValueError(f"n must be >= 0, got {n}")
        u = self._check(delta_command)
        self._u_last = u
        if d is not None:
            d = np.asarray(d, dtype=float)
            if d.shape != (n, 3):
                raise ValueError(f"d must have shape ({n}, 3) [v_g, p_g, r_g] per step, got {d.shape}")
        if self._act is not None:
            return self._advance_servo_fault(u, n, d)
        if self._limited:
            for i in range(n):
                self.step(u, None if d is None else d[i])
            return self.x
        if n == 0:
            return self.x
        pair = self._multi.get(n)
        if pair is None:
            ad_n = np.eye(self.n)
            bd_n = np.zeros(self.n)
            for _ in range(n):
                bd_n = self._ad @ bd_n + self._bd
                ad_n = self._ad @ ad_n
            pair = (ad_n, bd_n)
            self._multi[n] = pair
        self.x = pair[0] @ self.x + pair[1] * u
        if d is not None:
            self.x += self._multi_disturbance(n) @ d.ravel()
        self.steps += n
        return self.x

    def _multi_disturbance(self, n: int) -> np.ndarray:
        """[Ad^(n-1) E_d, ..., Ad E_d, E_d] (6 x 3n), cached per n."""
        m = self._multi_d.get(n)
        if m is None:
            blocks = [self.disturbance_zoh]
            for _ in range(n - 1):
                blocks.append(self._ad @ blocks[-1])
            m = np.hstack(blocks[::-1])
            self._multi_d[n] = m
        return m

    # ------------------------------------------------------------------ faults (sitl.damage)
    @property
    def roll_rate_state(self) -> int | None:
        """The state whose own term is the roll damping L_p (p itself), None when p is not one state (a transfer
        function's roll rate is a combination of them)."""
        return damage.roll_rate_index(self._truth_map)

    def set_effect(self, effect: damage.Effect) -> None:
        """Fly under ``effect`` (``sitl.damage.Effect``) from the next step; ``damage.NOMINAL`` is the plant as built.

        Effectiveness and damping change the airframe's rows of A_p (``damage.airframe_matrix``), discretised
        exactly again; the servo faults put ``damage.Actuator`` on the servo's path (``_advance_servo_fault``)."""
        old, self._effect = self._effect, effect
        key = (effect.effectiveness, effect.damping)
        if key != (old.effectiveness, old.damping):
            self._dynamics[(old.effectiveness, old.damping)] = (
                self._a,
                self._ad,
                self._bd,
                self._multi,
                self._ed,
                self._multi_d,
            )
            if key not in self._dynamics:
                a0 = self._dynamics[(1.0, 1.0)][0]
                a = damage.airframe_matrix(a0, effect, self.roll_rate_state)
                ad, bd = zoh(a, self._b, self.config.dt)
                self._dynamics[key] = (a, ad, bd.ravel(), {}, None, {})
            self._a, self._ad, self._bd, self._multi, self._ed, self._multi_d = self._dynamics[key]
        if not effect.servo:
            self._act = None
            return
        if self._act is None or effect.servo_differs(self._act.effect):
            self._act = damage.Actuator(effect, self.config.dt, self._u_last)
        self._act.effect = effect
        self._adc = zoh(damage.coasting_matrix(self._a), np.zeros((self.n, 1)), self.config.dt)[0]
        x, i, j = self.x, self._i_delta, self._i_delta_dot
        jump = damage.jammed(old, effect, float(x[i]))
        if jump is not None:
            x[i], x[j] = jump, 0.0
        if effect.rate is not None:
            x[j] = min(effect.rate, max(-effect.rate, x[j]))
        if self._limited:
            self._apply_limits()

    def _advance_servo_fault(self, u: float, n: int, d: np.ndarray | None) -> np.ndarray:
        """``n`` steps with a servo fault, one at a time: the servo driven with ``Actuator.command(u)``; a stuck or
        rate-limited surface coasts at its rate over the step (the exact ZOH of ``damage.coasting_matrix``: the
        airframe sees the ramp), else the free step with its rate clipped to the limit."""
        act, ad, bd, adc = self._act, self._ad, self._bd, self._adc
        i, j = self._i_delta, self._i_delta_dot
        ed = None if d is None else self.disturbance_zoh
        x = self.x
        for k in range(n):
            ue = act.command(u)
            xf = ad.dot(x)
            xf += bd * ue
            coast, rate = act.surface(x[i], xf[i], xf[j])
            if coast:
                xc = x.copy()
                xc[j] = rate
                xf = adc.dot(xc)
            else:
                xf[j] = rate
            if ed is not None:
                xf += ed @ d[k]
            self.x = x = xf
            if self._limited:
                self._apply_limits()
                x = self.x
        self.steps += n
        return self.x
