"""The autopilot's per-step series (``--series``): the keys and the step hook that records them."""

from __future__ import annotations

from autopilot.clsac import GAIN_FIELDS, MODEL_FIELDS, gains_of, model_of
from autopilot.loop.common import StepRecord
from autopilot.shared.series import SeriesRecorder
from autopilot.step import Failsafe

# The autopilot's per-step series (``--series``): keys as tools.experiment.scenario.SERIES where the autopilot knows
# them.
SERIES_KEYS = (
    "t",
    "um",
    "phi",
    "p",
    "r",
    "u",
    "u_cmd",
    "pwm",
    "failsafe",
    *MODEL_FIELDS,
    *GAIN_FIELDS,
    "mode",
    "armed",
)


def _series_row(rec: StepRecord) -> tuple:
    r, c = rec.result, rec.ctrl
    return (
        r.t,
        r.um,
        r.phi,
        rec.p,
        rec.r,
        r.u,
        c.u,
        r.pwm,
        r.failsafe is not Failsafe.NONE,
        *model_of(c),
        *gains_of(c),
        int(rec.ap.vehicle.mode),  # HEARTBEAT.custom_mode (autopilot.vehicle.Mode)
        rec.ap.control.armed,
    )


def series_recorder(mimo: bool = False, law_fields: tuple = ()) -> SeriesRecorder:
    """A step hook recording every control step (t, um, phi, p, r, u sent after PWM, the law's internals);
    ``mimo``: a square MIMO law's second channel and K_e too (``autopilot.mimo.MIMO_FIELDS``); ``law_fields``: a law
    on autopilot.law's interface, its own telemetry too, as ``law_<field>`` (``autopilot.law.Flown.law_row``)."""
    if law_fields:
        keys = SERIES_KEYS + tuple(f"law_{f}" for f in law_fields)
        return SeriesRecorder(keys, lambda rec: _series_row(rec) + rec.ctrl.law_row())
    if mimo:
        from autopilot.mimo import MIMO_FIELDS

        return SeriesRecorder(SERIES_KEYS + MIMO_FIELDS, lambda rec: _series_row(rec) + rec.ctrl.mimo_row())
    return SeriesRecorder(SERIES_KEYS, _series_row)
