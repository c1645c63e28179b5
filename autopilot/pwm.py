"""Servo PWM calibration: rudder angle (rad) <-> pulse width (us), the same configuration on both sides.

Default (DESIGN.md section 5): channel 4, 1500 us neutral, 1000..2000 us spanning -30..+30 deg.
Each side of the trim has its own slope, like an ArduPilot SERVOn_MIN/TRIM/MAX calibration, so an
asymmetric calibration still maps trim to 0 and min/max to -/+rudder_max.  Pulses are whole
microseconds: 1 us is 0.06 deg with the defaults (the quantisation the 2 % agreement budget covers).
"""

from __future__ import annotations

import argparse
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
        """servo1_raw..servo8_raw with the rudder on its channel and 0 (unused) elsewhere."""
        out = [0] * 16
        out[self.channel - 1] = pwm
        return out


def add_pwm_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("servo calibration (must match on the SITL and the autopilot)")
    g.add_argument("--pwm-min", type=int, default=1000, help="pulse at -rudder-max, us (default 1000)")
    g.add_argument("--pwm-max", type=int, default=2000, help="pulse at +rudder-max, us (default 2000)")
    g.add_argument("--pwm-trim", type=int, default=1500, help="pulse at 0 deg (neutral), us (default 1500)")
    g.add_argument("--rudder-max-deg", type=float, default=30.0, help="deflection at pwm-min/max, deg (default 30)")
    g.add_argument("--rudder-channel", type=int, default=4, help="SERVO_OUTPUT_RAW channel of the rudder, 1..16 (default 4)")


def pwm_from_args(parser: argparse.ArgumentParser, args) -> PwmMap:
    try:
        return PwmMap(args.pwm_min, args.pwm_max, args.pwm_trim, math.radians(args.rudder_max_deg), args.rudder_channel)
    except PwmConfigError as exc:
        parser.error(str(exc))
        raise  # unreachable


def pwm_argv(pwm: PwmMap) -> list[str]:
    """Command-line flags reproducing a calibration (for the launcher)."""
    return [
        "--pwm-min", str(pwm.pwm_min), "--pwm-max", str(pwm.pwm_max), "--pwm-trim", str(pwm.pwm_trim),
        "--rudder-max-deg", repr(math.degrees(pwm.rudder_max_rad)), "--rudder-channel", str(pwm.channel),
    ]
