"""A linear policy of ``tools.experiment.gym.ars`` flown as a law (the law interface, docs/adding-a-law.md).

    u = M (s - mu) / sigma,   s = (phi, p, r, u_m, u_last)        (ARS V2, Mania, Guy & Recht 2018)

on the observation ``Roll-v0`` gives (``tools.experiment.gym.roll.OBSERVATION``): roll, roll rate and yaw rate as
ATTITUDE carries them (float32), the command u_m, and the last surface command flown: the law's own last command
clipped to +-u_limit and through the servo's 1 us pulse (``autopilot.shared.pwm``, the launcher's 30 deg
calibration), or what flew instead (``hold``).  So for the same inputs its command is the env policy's action.

``PolicyLaw`` has no numbers; ``python -m tools.experiment.gym.ars --out DIR`` writes ``DIR/policy_law.py``, a
subclass ``Policy`` with M, mu and sigma as literals (:func:`law_source`): fly it with
``--controller DIR/policy_law.py:Policy``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from autopilot.shared.pwm import PwmMap

SERVO_FULL_RAD = math.radians(30.0)  # the launcher's servo calibration (tools.experiment.gym.flight.U_LIMIT_RAD)


@dataclass(frozen=True)
class PolicyConfig:
    control_rate_hz: float = 100.0  # Hz (the autopilot sets it)
    u_limit_rad: float = SERVO_FULL_RAD  # rad (the autopilot sets it)


class PolicyLaw:
    """A saved linear policy as a law; a subclass sets ``M`` (1 x 5), ``MU`` and ``SIGMA`` (5)."""

    NAME = "ars-policy"
    LABEL = "ARS linear policy"
    Config = PolicyConfig
    PARAMETERS = ()
    TELEMETRY_FIELDS = ("u_last",)
    M: tuple = ()
    MU: tuple = ()
    SIGMA: tuple = ()

    def __init__(self, config):
        self.config = config
        self._m = np.array(self.M, dtype=np.float64).reshape(1, -1)
        self._mu = np.array(self.MU, dtype=np.float64)
        self._sigma = np.array(self.SIGMA, dtype=np.float64)
        if not (self._m.shape == (1, 5) and self._mu.shape == (5,) and self._sigma.shape == (5,)):
            raise ValueError(f"{type(self).__name__}: M must be 1 x 5 and MU, SIGMA 5 numbers (s = phi, p, r, um, u)")
        self.reset()

    def reset(self):
        self.u_last = 0.0

    def _flown(self, u: float) -> float:
        """The angle the servo flies for ``u``: clipped to +-u_limit, through the 1 us pulse (``Lane.act``)."""
        lim = float(self.config.u_limit_rad)
        u = lim if u > lim else (-lim if u < -lim else u)
        pwm = PwmMap(rudder_max_rad=max(SERVO_FULL_RAD, lim))
        return pwm.to_rad(pwm.to_pwm(u))

    def step(self, roll, roll_rate, yaw_rate, command):
        phi, p, r = (float(np.float32(v)) for v in (roll, roll_rate, yaw_rate))  # ATTITUDE's float32
        s = np.array([phi, p, r, float(command), self.u_last], dtype=np.float64)
        u = ((s - self._mu) / self._sigma) @ self._m.T  # the same expression as ars.Linear
        lim = float(self.config.u_limit_rad)
        u = min(max(float(u[0]), -lim), lim)
        self.u_last = self._flown(u)
        return u

    def hold(self, u_applied):
        self.u_last = float(u_applied)  # someone else's command flew: the next observation's u_last

    def telemetry(self):
        return {"u_last": self.u_last}


def law_source(record: dict) -> str:
    """A self-contained law file for ``policy.json``'s record: ``class Policy(PolicyLaw)`` with its numbers."""

    def nums(v) -> str:
        return "(" + ", ".join(repr(float(x)) for x in np.ravel(v)) + ",)"

    return (
        f'"""The ARS policy of this folder\'s policy.json as a law: python -m tools.launch --controller '
        f'policy_law.py:Policy."""\n\n'
        "from tools.experiment.gym.policy_law import PolicyLaw\n\n\n"
        "class Policy(PolicyLaw):\n"
        '    NAME = "ars-policy"\n'
        f"    M = {nums(record['M'])}\n"
        f"    MU = {nums(record['mu'])}\n"
        f"    SIGMA = {nums(record['sigma'])}\n"
    )


__all__ = ["PolicyConfig", "PolicyLaw", "law_source"]
