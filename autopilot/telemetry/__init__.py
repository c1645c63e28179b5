"""Live and recorded telemetry in the Rerun viewer (rerun-sdk 0.41).

Per process (flags ``--rrd``, ``--recording-id``, ``--connect``, ``--viewer`` from ``add_arguments``)::

    from autopilot import telemetry as tm

    tel = tm.from_args(args, "autopilot")      # or tm.Telemetry("autopilot", rid, part_path, connect_url=url)
    hook = tm.AutopilotHook(tel)               # Autopilot.hooks / event_hooks callables
    autopilot.hooks.append(hook); autopilot.event_hooks.append(hook.event)
    with tel:
        autopilot.run()

or by hand, one row per step::

    ap, links, mode, failsafe = tel.autopilot_tables(links=("sitl", "gcs"))
    ap.append(sim_t, time.time(), ctrl.telemetry() + (p, pwm, period, compute, jitter, missed))

A launcher merges the parts of a flight into one recording with ``tm.merge_recordings``; experiments
go through ``tm.log_experiment``.  Entity paths, row layouts and colours: ``autopilot.telemetry.layout``.
"""

import os as _os

# Part files are written without rerun's footer (see Telemetry.write_footer); rerun warns about that on
# every FileSink.  Keep its other warnings.  Only effective if rerun is not imported yet.
_os.environ.setdefault("RUST_LOG", "warn,re_log_encoding::rrd::file_sink=error")

_LAZY = {
    "APPLICATION_ID": "layout",
    "AUTOPILOT": "layout",
    "AUTOPILOT_FIELDS": "layout",
    "AutopilotHook": "hooks",
    "DEFAULT_FLUSH_INTERVAL_S": "writer",
    "LINK_FIELDS": "layout",
    "NullTable": "writer",
    "Plot": "layout",
    "RrdError": "files",
    "SIM_TIME": "layout",
    "SITL_FIELDS": "layout",
    "SITL_TABLE": "layout",
    "SitlHook": "hooks",
    "StateChannel": "writer",
    "Table": "writer",
    "TableLayout": "layout",
    "Telemetry": "writer",
    "WALL_TIME": "layout",
    "add_arguments": "hooks",
    "experiment_blueprint": "blueprints",
    "flight_blueprint": "blueprints",
    "from_args": "hooks",
    "has_display": "writer",
    "install_signal_handlers": "writer",
    "link_layout": "layout",
    "log_experiment": "experiment",
    "merge_recordings": "files",
    "new_recording_id": "writer",
    "part_paths": "files",
    "rerun_cli_path": "writer",
    "spawn_viewer": "writer",
    "verify_rrd": "files",
    "viewer_reachable": "writer",
    "viewer_url": "writer",
}


def __getattr__(name: str):
    """Import submodules on first use: ``rerun`` costs ~1 s and processes that log nothing never need it."""
    import importlib

    if name == "layout":
        return importlib.import_module("autopilot.telemetry.layout")
    try:
        module = _LAZY[name]
    except KeyError:
        raise AttributeError(f"module 'autopilot.telemetry' has no attribute {name!r}") from None
    return getattr(importlib.import_module(f"autopilot.telemetry.{module}"), name)


__all__ = [
    "AutopilotHook", "SitlHook", "add_arguments", "from_args",
    "APPLICATION_ID", "AUTOPILOT", "AUTOPILOT_FIELDS", "DEFAULT_FLUSH_INTERVAL_S", "LINK_FIELDS", "NullTable",
    "Plot", "RrdError", "SIM_TIME", "SITL_FIELDS", "SITL_TABLE", "StateChannel", "Table", "TableLayout",
    "Telemetry", "WALL_TIME", "experiment_blueprint", "flight_blueprint", "has_display", "install_signal_handlers",
    "layout", "link_layout", "log_experiment", "merge_recordings", "new_recording_id", "part_paths",
    "rerun_cli_path", "spawn_viewer", "verify_rrd", "viewer_reachable", "viewer_url",
]
