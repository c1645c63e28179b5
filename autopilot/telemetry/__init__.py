"""The autopilot's telemetry: its layout (``layout``) and its hook (``hooks.AutopilotHook``) on the shared writer.

``python -m autopilot`` with a telemetry flag (``autopilot.shared.telemetry.flags.add_arguments``)::

    tel = attach(args, autopilot, control_rate_hz=args.rate)    # None without flags: rerun never imported
    try:
        autopilot.run()
    finally:
        if tel is not None:
            tel.close()

The writer primitives are ``autopilot.shared.telemetry``; the SITL's side is ``sitl.telemetry``; the viewer
layout that joins both is ``tools.view.views``.
"""

from __future__ import annotations

import argparse


def attach(args: argparse.Namespace, autopilot, *, control_rate_hz: float | None = None):
    """If a telemetry flag was given, build the writer and register an ``AutopilotHook`` on ``autopilot``.

    Returns the writer (close it after the loop) or None.
    """
    from autopilot.shared.telemetry.flags import attach as attach_hook

    def make_hook(tel):
        from autopilot.telemetry.hooks import AutopilotHook

        hook = AutopilotHook(tel, control_rate_hz=control_rate_hz, surface=getattr(args, "surface", "rudder"))
        vehicle = getattr(autopilot, "vehicle", None)
        if vehicle is not None:  # each PARAM_SET: a line in the event log and a marker on the gain plots
            vehicle.param_hooks.append(hook.param_set)
        return hook

    return attach_hook(args, "autopilot", autopilot, make_hook)


def __getattr__(name: str):
    """``AutopilotHook``, ``autopilot_tables``, ``layout``: imported on first use."""
    import importlib

    if name == "layout":
        return importlib.import_module("autopilot.telemetry.layout")
    if name in ("AutopilotHook", "autopilot_tables"):
        return getattr(importlib.import_module("autopilot.telemetry.hooks"), name)
    raise AttributeError(f"module 'autopilot.telemetry' has no attribute {name!r}")


__all__ = ["AutopilotHook", "attach", "autopilot_tables", "layout"]
