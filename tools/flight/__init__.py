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

import importlib

_WHERE = {  # public name -> its module, imported on first use (PEP 562): importing a submodule such as
    # tools.flight.children (the picture helper, the launcher's first lines) does not load the whole launcher
    "DEFAULT_DURATION_S": "tools.flight.config",
    "LOCKSTEP_IDLE_EXIT_S": "tools.flight.config",
    "MERGE_MAX_MB": "tools.flight.config",
    "LIVE_RATE_HZ": "tools.flight.config",
    "LIVE_WINDOW_S": "tools.flight.config",
    "PROCESSES": "tools.flight.config",
    "PROFILES": "tools.flight.config",
    "RUDDER_MAX_DEG": "tools.flight.command_lines",
    "VEHICLE_TIMEOUT_S": "tools.flight.config",
    "FlightConfig": "tools.flight.config",
    "FlightConfigError": "tools.flight.config",
    "child_argvs": "tools.flight.command_lines",
    "PNG_MAX_POINTS": "tools.flight.files",
    "STALE_FILES": "tools.flight.files",
    "build_summary": "tools.flight.files",
    "load_series": "tools.flight.files",
    "provisional_summary": "tools.flight.files",
    "write_flight_png": "tools.flight.files",
    "write_refusal": "tools.flight.files",
    "GCS_END_SLACK_S": "tools.flight.outcome",
    "HEARD_BY": "tools.flight.outcome",
    "STALL_S": "tools.flight.outcome",
    "_reached_end": "tools.flight.outcome",
    "envelope_verdict": "tools.flight.outcome",
    "fault_recoveries": "tools.flight.outcome",
    "recovery_text": "tools.flight.outcome",
    "first_stall": "tools.flight.outcome",
    "flown_report": "tools.flight.outcome",
    "outcome_of": "tools.flight.outcome",
    "shortfall": "tools.flight.outcome",
    "silences": "tools.flight.outcome",
    "verdict": "tools.flight.outcome",
    "Flight": "tools.flight.supervision",
    "FlightResult": "tools.flight.supervision",
    "OutputError": "tools.flight.supervision",
    "fly_run_over_mavlink": "tools.flight.supervision",
    "serve_web": "tools.flight.supervision",
}

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
    "OutputError",
    "LIVE_RATE_HZ",
    "LIVE_WINDOW_S",
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
    "fly_run_over_mavlink",
    "load_series",
    "outcome_of",
    "provisional_summary",
    "recovery_text",
    "serve_web",
    "shortfall",
    "silences",
    "verdict",
    "write_flight_png",
    "write_refusal",
]


def __getattr__(name: str):
    if name in _WHERE:
        value = getattr(importlib.import_module(_WHERE[name]), name)
    else:
        try:
            value = importlib.import_module(f"{__name__}.{name}")  # a submodule: tools.flight.config, ...
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
