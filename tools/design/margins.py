"""Stability margins of the fixed-gain baseline (``autopilot.baseline``) on the nominal plant, with python-control."""

from __future__ import annotations

import math
import warnings

from autopilot.baseline import BaselineConfig
from tools.design._common import ct
from tools.design.aspr import plant_tf


def sampled_loop(cfg: BaselineConfig, plant=None, delay_steps: int = 0, sampled_plant=None):
    """The baseline's loop sampled at its control rate: C(z) = K_p + K_i T z/(z - 1) + K_d (z - 1)/(T z) times the
    ZOH-sampled plant (``sampled_plant``: that, computed once by the caller) times z^-d, a python-control tf."""
    control = ct()
    T = cfg.dt
    if sampled_plant is None:
        sampled_plant = control.c2d(plant_tf(plant), T, "zoh")
    num = [cfg.kd + cfg.kp * T + cfg.ki * T * T, -(cfg.kp * T + 2 * cfg.kd), cfg.kd]
    loop = control.tf(num, [T, -T, 0.0], T) * sampled_plant
    if delay_steps:
        loop = loop * control.tf([1.0], [1.0] + [0.0] * int(delay_steps), T)
    return loop


def baseline_margins(
    config: BaselineConfig | None = None, *, pfc_inverse: bool = False, plant=None, delay_steps: int = 0
) -> dict[str, float]:
    """Gain margin (dB), phase margin (deg) and the crossover frequencies (rad/s) of the loop on the nominal plant.

    Default: the baseline PID sampled at its control rate, C(z) = K_p + K_i T z/(z - 1) + K_d (z - 1)/(T z),
    times the ZOH-sampled plant.  ``pfc_inverse``: the continuous loop C(s) T(s) with the C(s) = (4s + 40)/10
    whose inverse is the paper's PFC (sec. 5.1).  ``plant``: another plant's (A_p, B_p, C_p); default the KH2013A's.
    ``delay_steps``: a delay of that many control periods in front of the plant (z^-d in the sampled loop: a command
    held over a period and applied d periods late), for the sampled loop only.
    """
    control = ct()
    cfg = config or BaselineConfig()
    if pfc_inverse:
        loop = control.tf([4.0, 40.0], [10.0]) * plant_tf(plant)
    else:
        loop = sampled_loop(cfg, plant, delay_steps)
    with warnings.catch_warnings():  # python-control notes it falls back to its frequency-response method
        warnings.simplefilter("ignore", UserWarning)
        gm, pm, wcg, wcp = control.margin(loop)
    closed = control.feedback(loop, 1)
    poles = control.poles(closed)
    stable = bool(max(abs(poles)) < 1.0) if loop.dt else bool(max(poles.real) < 0.0)
    return {
        "gain_margin_db": 20.0 * math.log10(gm) if gm > 0 and math.isfinite(gm) else math.inf,
        "phase_margin_deg": float(pm),
        "phase_crossover_rad_s": float(wcg),
        "gain_crossover_rad_s": float(wcp),
        "closed_loop_stable": stable,
    }
