"""Rerun telemetry primitives every process shares: how a recording is written, not what it holds.

* ``layout``   plain data: timelines ``SIM_TIME`` / ``WALL_TIME``, ``Plot``, ``TableLayout``, the colour
               palette, ``APPLICATION_ID``;
* ``buffers``  the rows a process queues: ``Table``, ``NullTable``, ``StateChannel`` (no rerun);
* ``writer``   the buffered per-process writer: ``Telemetry`` (its thread drains the buffers into a sink);
* ``rerun_sink`` rows into Rerun (``RerunSink``, the one code of both a live writer and ``record_spools``);
* ``spool``    rows into a spool file for another process to record (``SpoolSink``, ``SpoolReader``,
               ``spool_paths``; no rerun);
* ``columns``  Arrow columns for ``RecordingStream.send_columns`` (scalars, time columns, series styles);
* ``viewer``   a live viewer: URL, reachability, spawning one, showing a blueprint in it;
* ``files``    one recording from several processes: ``new_recording_id``, ``part_paths``, ``merge_recordings``,
               ``concatenate_recordings``, ``install_recording``, ``verify_rrd``, ``RrdError``;
* ``flags``    the command-line flags (``add_arguments``, ``requested``, ``from_args``, ``attach``);
* ``hooks``    ``ProcessHook``, the part every process's telemetry hook shares (status events).

What a process logs is its own: ``autopilot.telemetry`` (controller row, links, mode, failsafe) and
``sitl.telemetry`` (truth state); the viewer layouts that join both are in ``tools.view.views``.  This package
imports nothing of the project outside ``autopilot.shared``.  Names are imported on first use: ``rerun``
costs about 0.45 CPU s and only ``rerun_sink``, ``columns``, a live ``Telemetry`` and
``viewer.spawn_viewer``/``send_blueprint`` load it, so processes that log nothing, or only spool, never do.
"""

import os as _os

# Part files are written without rerun's footer (see Telemetry.write_footer); rerun warns about that on
# every FileSink.  Keep its other warnings.  Only effective if rerun is not imported yet.
_os.environ.setdefault("RUST_LOG", "warn,re_log_encoding::rrd::file_sink=error")

_LAZY = {
    "APPLICATION_ID": "layout",
    "PALETTE": "layout",
    "Plot": "layout",
    "Rgb": "layout",
    "SIM_TIME": "layout",
    "TableLayout": "layout",
    "WALL_TIME": "layout",
    "DEFAULT_FLUSH_INTERVAL_S": "writer",
    "NullTable": "buffers",
    "StateChannel": "buffers",
    "Table": "buffers",
    "RerunSink": "rerun_sink",
    "record_spools": "rerun_sink",
    "SpoolError": "spool",
    "SpoolReader": "spool",
    "SpoolSink": "spool",
    "spool_paths": "spool",
    "Telemetry": "writer",
    "DEFAULT_VIEWER_PORT": "viewer",
    "has_display": "viewer",
    "rerun_cli_path": "viewer",
    "send_blueprint": "viewer",
    "spawn_viewer": "viewer",
    "viewer_reachable": "viewer",
    "viewer_url": "viewer",
    "RrdError": "files",
    "merge_recordings": "files",
    "new_recording_id": "layout",
    "part_paths": "files",
    "concatenate_recordings": "files",
    "install_recording": "files",
    "check_recording_target": "files",
    "verify_rrd": "files",
    "add_arguments": "flags",
    "attach": "flags",
    "from_args": "flags",
    "requested": "flags",
    "ProcessHook": "hooks",
}
_MODULES = ("buffers", "columns", "files", "flags", "hooks", "layout", "rerun_sink", "spool", "viewer", "writer")


def __getattr__(name: str):
    """Import submodules on first use, so that ``import autopilot.shared.telemetry`` never loads rerun."""
    import importlib

    if name in _MODULES:
        return importlib.import_module(f"{__name__}.{name}")
    try:
        module = _LAZY[name]
    except KeyError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)


__all__ = sorted(_LAZY)
