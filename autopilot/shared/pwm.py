"""Servo PWM calibration: rudder angle (rad) <-> pulse width (us), the same configuration on both sides.

Default (docs/spec.md, "MAVLink"): channel 4, 1500 us neutral, 1000..2000 us spanning -30..+30 deg.
Each side of the trim has its own slope, like an ArduPilot SERVOn_MIN/TRIM/MAX calibration, so an
asymmetric calibration still maps trim to 0 and min/max to -/+rudder_max.  Pulses are whole
microseconds: 1 us is 0.06 deg with the defaults (the quantisation the 2 % agreement budget covers).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

PWM_VALID_RANGE = (500, 2500)  # pulses outside this are not a servo command (0 = channel unused)


class PwmConfigError(ValueError):
    pass


@dataclass(frozen=True)
class PwmMap:
    pwm_min: int = 1000
    pwm_max: int = 2000
    pwm_trim: int = 1500
    rudder_max_rad: float = math.radians(30.0)
    channel: int = 4  # 1-based, SERVO_OUTPUT_RAW.servoN_raw

    def __post_init__(self) -> None:
        if not (PWM_VALID_RANGE[0] <= self.pwm_min < self.pwm_trim < self.pwm_max <= PWM_VALID_RANGE[1]):
            raise PwmConfigError(
                f"need {PWM_VALID_RANGE[0]} <= pwm-min < pwm-trim < pwm-max <= {PWM_VALID_RANGE[1]}, "
                f"got min={self.pwm_min} trim={self.pwm_trim} max={self.pwm_max}"
            )
        if not (math.isfinite(self.rudder_max_rad) and 0 < self.rudder_max_rad < math.pi):
            raise PwmConfigError(f"rudder max must be in (0, 180) deg, got {math.degrees(self.rudder_max_rad)!r}")
        if not 1 <= self.channel <= 16:
            raise PwmConfigError(f"rudder channel must be 1..16, got {self.channel}")
        object.__setattr__(self, "_up", (self.pwm_max - self.pwm_trim) / self.rudder_max_rad)
        object.__setattr__(self, "_dn", (self.pwm_trim - self.pwm_min) / self.rudder_max_rad)

    def to_pwm(self, rad: float) -> int:
        """Pulse width for a rudder angle, rounded to 1 us and clamped to [pwm_min, pwm_max]."""
        v = self.pwm_trim + rad * (self._up if rad >= 0.0 else self._dn)
        p = int(math.floor(v + 0.5))
        return self.pwm_min if p < self.pwm_min else (self.pwm_max if p > self.pwm_max else p)

    def to_rad(self, pwm: int) -> float:
        """Rudder angle of a pulse width (clamped to the calibrated range)."""
        p = self.pwm_min if pwm < self.pwm_min else (self.pwm_max if pwm > self.pwm_max else pwm)
        d = p - self.pwm_trim
        return d / (self._up if d >= 0 else self._dn)

    @property
    def neutral(self) -> int:
        return self.pwm_trim

    def servo_fields(self, pwm: int) -> list[int]:
        """servo1_raw..servo16_raw with the rudder on its channel and 0 (unused) elsewhere."""
        out = [0] * 16
        out[self.channel - 1] = pwm
        return out
