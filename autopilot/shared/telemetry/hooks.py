"""What every process's telemetry hook shares: status events in ``/<process>/events``, None as NaN."""

from __future__ import annotations

import time

_NAN = float("nan")


def nan_if_none(v) -> float:
    """``float(v)``, NaN for None (a value the step did not have, e.g. no PWM sent)."""
    return _NAN if v is None else float(v)


def severity_level(severity) -> str:
    """The TextLog level of a MAVLink severity: ERROR up to MAV_SEVERITY_ERROR (3), WARN for WARNING (4)."""
    if isinstance(severity, int) and severity <= 3:
        return "ERROR"
    if isinstance(severity, int) and severity <= 4:
        return "WARN"
    return "INFO"


class ProcessHook:
    """Base of a process's hook: ``event(severity, text)`` logs a status event at the last sample's sim time.

    Subclasses set ``last_t`` (s) on every record they log.
    """

    def __init__(self, tel):
        self.tel = tel
        self.last_t = 0.0

    def event(self, severity, text: str) -> None:
        """An ``event_hooks`` callable: the status text in ``/<process>/events``."""
        self.tel.log_event(self.last_t, time.time(), str(text), severity_level(severity))
