"""The telemetry command-line flags of every process, and building a writer from them.

No rerun import at module level: a process started without telemetry flags, or with ``--telemetry-spool``, never
loads rerun.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

from autopilot.shared.cli import viewer_url


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--rrd PATH``, ``--telemetry-spool PATH``, ``--recording-id ID``, ``--connect URL``, ``--viewer``,
    ``--live-rate HZ``."""
    g = parser.add_argument_group("telemetry (Rerun)")
    g.add_argument("--rrd", metavar="PATH", default=None, help="write telemetry to this .rrd file (default: no file)")
    g.add_argument(
        "--telemetry-spool",
        metavar="PATH",
        default=None,
        help="write the telemetry rows to this spool file, for another process to record into a .rrd "
        "(autopilot.shared.telemetry.record_spools; without a viewer rerun is not imported); not with --rrd",
    )
    g.add_argument(
        "--recording-id",
        metavar="ID",
        default=None,
        help="Rerun recording id shared by every process of one flight (default: a new one)",
    )
    g.add_argument(
        "--connect",
        type=viewer_url,
        metavar="URL",
        default=None,
        help="stream live to a running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy",
    )
    g.add_argument(
        "--viewer", action="store_true", help="spawn a Rerun viewer (or reuse the one on port 9876) and stream to it"
    )
    g.add_argument(
        "--live-rate",
        type=_live_rate,
        metavar="HZ",
        default=None,
        help="a viewer (--connect, --viewer) gets at most HZ rows per second of sim time of each table of lines; "
        "the --rrd file or the spool keeps every row (default: every row; autopilot.shared.telemetry.thinning)",
    )


def _live_rate(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected rows per second (a number >= 0), got {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected rows per second >= 0 (0: every row), got {text!r}")
    return value


def requested(args: argparse.Namespace) -> bool:
    """True if any telemetry flag was given (only then is a writer built; rerun only without a spool)."""
    return bool(
        getattr(args, "rrd", None)
        or getattr(args, "connect", None)
        or getattr(args, "viewer", False)
        or getattr(args, "telemetry_spool", None)
    )


def check_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """A usage error (``parser.error``) for flags that cannot go together: a spool and a file are two recordings."""
    if getattr(args, "telemetry_spool", None) and getattr(args, "rrd", None):
        parser.error("--telemetry-spool writes the rows for another process to record: not with --rrd")


def from_args(args: argparse.Namespace, process: str, **kwargs):
    """A ``Telemetry`` writer from the flags of ``add_arguments`` (disabled when none is given)."""
    from autopilot.shared.telemetry.writer import Telemetry  # a live writer imports rerun (~0.45 CPU s), a spool not

    return Telemetry(
        process,
        getattr(args, "recording_id", None),
        getattr(args, "rrd", None),
        connect_url=getattr(args, "connect", None),
        spawn_viewer=bool(getattr(args, "viewer", False)),
        spool_path=getattr(args, "telemetry_spool", None),
        live_rate_hz=getattr(args, "live_rate", None),
        **kwargs,
    )


def attach(args: argparse.Namespace, process: str, target, make_hook: Callable):
    """If a telemetry flag was given, build the writer and register ``make_hook(writer)`` on ``target``.

    ``target`` is a process's loop: the hook goes to ``target.hooks`` (called once per step / frame,
    after the servo command went out) and its ``event`` method to ``target.event_hooks`` (status events).
    Returns the writer, which the caller closes (its stop handlers end the loop first), or None.
    """
    if not requested(args):
        return None
    tel = from_args(args, process)
    hook = make_hook(tel)
    target.hooks.append(hook)
    target.event_hooks.append(hook.event)
    return tel
