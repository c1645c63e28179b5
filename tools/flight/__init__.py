"""``Flight``: one flight of SITL + autopilot + GCS script as real processes over loopback UDP.

The programmatic form of ``python -m tools.launch``; its keywords are the launcher's long flags (``rrd=False`` for
``--no-rrd``, ``series=False`` for ``--no-series``, ``profile="sine"`` for the positional profile), with the same
defaults and units (degrees and Hz as on the flags)::

    from tools.flight import Flight

    result = Flight(lockstep=True, duration=5, controller="sac", out="runs/x").run()
    result.ok, result.metrics["ise_ref"], result.series["phi"]
    result.completed, result.controlled, result.reason    # True, False, "out of envelope: |roll| reached ..."

    with Flight(lockstep=True, duration=600, out="runs/y") as flight:   # starts the three processes
        flight.wait(timeout=2.0)                                          # fly 2 s of wall clock, then leave
    flight.result.reason                                                  # "stopped by the caller after ..."

Every flight, however it ends, leaves in its folder ``flight.tlog`` (every packet the autopilot sent and received),
``summary.json`` (one run with the metrics of what flew, plus counters, timing, events and exit codes),
``<process>.log`` for each child (and ``web.log``, the ``--web`` server's, with ``web``), ``flight.rrd`` (``rrd``)
and ``autopilot_series.npz``/``sitl_series.npz`` (``series``).  A bad keyword value raises ``FlightConfigError`` at
construction, an unknown keyword TypeError.
"""

from __future__ import annotations

from tools.flight.config import (
    DEFAULT_DURATION_S,
    LOCKSTEP_IDLE_EXIT_S,
    MERGE_MAX_MB,
    PROCESSES,
    PROFILES,
    RUDDER_MAX_DEG,
    VEHICLE_TIMEOUT_S,
    FlightConfig,
    FlightConfigError,
    child_argvs,
)
from tools.flight.files import (
    PNG_MAX_POINTS,
    STALE_FILES,
    build_summary,
    load_series,
    provisional_summary,
    write_flight_png,
    write_refusal,
)
from tools.flight.outcome import (
    GCS_END_SLACK_S,
    HEARD_BY,
    STALL_S,
    _reached_end,
    envelope_verdict,
    fault_recoveries,
    first_stall,
    flown_report,
    outcome_of,
    recovery_text,
    shortfall,
    silences,
    verdict,
)
from tools.flight.supervision import Flight, FlightResult, run_lockstep, serve_web

__all__ = [
    "DEFAULT_DURATION_S",
    "Flight",
    "FlightConfig",
    "FlightConfigError",
    "FlightResult",
    "GCS_END_SLACK_S",
    "HEARD_BY",
    "LOCKSTEP_IDLE_EXIT_S",
    "MERGE_MAX_MB",
    "PNG_MAX_POINTS",
    "PROCESSES",
    "PROFILES",
    "RUDDER_MAX_DEG",
    "STALE_FILES",
    "STALL_S",
    "VEHICLE_TIMEOUT_S",
    "_reached_end",
    "build_summary",
    "child_argvs",
    "envelope_verdict",
    "fault_recoveries",
    "first_stall",
    "flown_report",
    "load_series",
    "outcome_of",
    "provisional_summary",
    "recovery_text",
    "run_lockstep",
    "serve_web",
    "shortfall",
    "silences",
    "verdict",
    "write_flight_png",
    "write_refusal",
]
