"""The autopilot process's schedulers: the control step between a SITL link and a GCS link.

The step itself (setpoint, law, rudder limit, PWM map, metrics) is ``autopilot.step.ControlStep``; the links
are ``autopilot.shared.link``; this module reads the links, decides *when* to step and sends the answer
(docs/spec.md, "Timing modes").  Two modes:

* real time (:class:`RealtimeScheduler`): one control step per period on a fixed grid of
  deadlines (sleep in ``select`` until shortly before the deadline, then spin; never ``sleep(period)``),
  using the newest ATTITUDE.  Failsafes: no attitude for ``attitude_timeout_s`` (wall clock) ->
  rudder neutral, adaptation frozen (``ClSac.hold``), HEARTBEAT CRITICAL, STATUSTEXT; recovers by
  itself.  No setpoint for ``setpoint_timeout_s`` -> wings level (0 deg), STATUSTEXT.
* lockstep (:class:`LockstepScheduler`): one step per SITL frame.  Frame k is recovered from
  ATTITUDE.time_boot_ms and the control rate; the answer is SERVO_OUTPUT_RAW with time_usec =
  t_k in us mod 2**32.  A duplicate frame is answered by resending the stored answer (signed again; no second step),
  an older frame is counted and ignored.  With pacing on (default), frame k waits until a GCS has
  scheduled setpoints up to t_k (the schedule horizon), so results do not depend on speed.

Per-step hook point for telemetry (Rerun, series): ``Autopilot.hooks`` is a list of callables called
with one :class:`StepRecord` after the servo command has been sent (outside the critical path), and
``Autopilot.event_hooks`` with ``(severity, text)`` for every status event (failsafe, clamp, ...).

Layout: ``common`` (options, the step record, timing statistics), ``handlers`` (the link handlers),
``lockstep`` and ``realtime`` (the two schedulers), ``autopilot`` (``Autopilot``: its state and handlers, and the
scheduler it holds, which drives it),
``series`` (the per-step series); ``from autopilot.loop import ...`` gives each public name.
"""

from __future__ import annotations

from autopilot.loop.autopilot import Autopilot
from autopilot.loop.common import AutopilotOptions, StepRecord, TimingStats
from autopilot.loop.handlers import LinkHandlers, refusal_text
from autopilot.loop.lockstep import LockstepScheduler
from autopilot.loop.realtime import RealtimeScheduler
from autopilot.loop.series import SERIES_KEYS, series_recorder

__all__ = [
    "Autopilot",
    "AutopilotOptions",
    "LinkHandlers",
    "LockstepScheduler",
    "RealtimeScheduler",
    "SERIES_KEYS",
    "StepRecord",
    "TimingStats",
    "refusal_text",
    "series_recorder",
]
