"""The CL-SAC roll autopilot (Jana & Bhat 2017): the control law, one control step, the loop and its links.

Public API::

    from autopilot import ClSac, ClSacConfig

    ctrl = ClSac(ClSacConfig())          # the paper's CL-SAC: L_v = 20, 100 Hz
    u = ctrl(phi_measured, phi_command)  # one control step: rudder command in rad, already limited

``ControlStep`` adds the setpoint schedule, the PWM map and the metrics around the law (what the
autopilot process, the in-process runner and the benchmarks all call once per step).

Names are imported on first use (PEP 562), so ``import autopilot.shared`` (the layer the SITL uses)
never loads the control law, and the command-line entry points start fast.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "ClSac": "autopilot.clsac",
    "TELEMETRY_FIELDS": "autopilot.clsac",
    "ClSacConfig": "autopilot.config",
    "ConfigError": "autopilot.config",
    "NonFiniteInputError": "autopilot.config",
    "PFC_PRESETS": "autopilot.config",
    "MetricsAccumulator": "autopilot.metrics",
    "METRIC_NAMES": "autopilot.metrics",
    "ControlStep": "autopilot.step",
    "StepResult": "autopilot.step",
    "Failsafe": "autopilot.step",
    "SetpointQueue": "autopilot.step",
    "PwmMap": "autopilot.shared.pwm",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    try:
        module = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'autopilot' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(list(globals()) + __all__)
