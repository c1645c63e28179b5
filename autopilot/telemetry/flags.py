"""The telemetry command-line flags, without importing rerun (so processes that log nothing start fast)."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--rrd PATH``, ``--recording-id ID``, ``--connect URL``, ``--viewer`` (telemetry group)."""
    g = parser.add_argument_group("telemetry (Rerun)")
    g.add_argument("--rrd", metavar="PATH", default=None,
                   help="write telemetry to this .rrd file (default: no file)")
    g.add_argument("--recording-id", metavar="ID", default=None,
                   help="Rerun recording id shared by every process of one flight (default: a new one)")
    g.add_argument("--connect", metavar="URL", default=None,
                   help="stream live to a running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy")
    g.add_argument("--viewer", action="store_true",
                   help="spawn a Rerun viewer (or reuse the one on port 9876) and stream to it")


def requested(args: argparse.Namespace) -> bool:
    """True if any telemetry flag was given (only then is rerun imported)."""
    return bool(getattr(args, "rrd", None) or getattr(args, "connect", None) or getattr(args, "viewer", False))


def attach(args: argparse.Namespace, process: str, target, **hook_kwargs):
    """If telemetry was asked for, build the writer and register its hook on ``target`` (an Autopilot or a Sitl).

    The hook runs after each step's servo command went out (``target.hooks``) and on every status event
    (``target.event_hooks``); the loop only hands over a row.  The processes' own stop handlers flush
    on SIGINT/SIGTERM and the writer also closes at exit.  Returns the writer (close it) or None.
    """
    if not requested(args):
        return None
    from autopilot import telemetry as tm  # imports rerun (~1 s): only when asked for

    tel = tm.from_args(args, process, handle_signals=False)  # only the autopilot sends the blueprint
    hook = tm.AutopilotHook(tel, **hook_kwargs) if process == "autopilot" else tm.SitlHook(tel, **hook_kwargs)
    target.hooks.append(hook)
    target.event_hooks.append(hook.event)
    return tel
