"""A live Rerun viewer: its URL, whether one listens, spawning one, showing a blueprint in it.

Nothing here runs unless asked for (``--viewer`` / ``--connect``): a headless machine never waits on a
viewer.  rerun itself is imported only by ``spawn_viewer`` and ``send_blueprint``.
"""

from __future__ import annotations

import logging
import os
import shutil
import socket
import sys
from pathlib import Path
from urllib.parse import urlparse

from autopilot.shared.telemetry.layout import APPLICATION_ID, new_recording_id

log = logging.getLogger(__name__)

DEFAULT_VIEWER_PORT = 9876


def viewer_url(port: int = DEFAULT_VIEWER_PORT, host: str = "127.0.0.1") -> str:
    """The gRPC URL of a viewer: ``rerun+http://HOST:PORT/proxy``."""
    return f"rerun+http://{host}:{port}/proxy"


def rerun_cli_path() -> str:
    """The ``rerun`` executable shipped with the installed rerun-sdk (PATH need not contain it)."""
    override = os.environ.get("RERUN_CLI_PATH")
    if override:
        return override
    import rerun_cli

    exe = Path(rerun_cli.__file__).parent / ("rerun.exe" if sys.platform.startswith("win") else "rerun")
    if exe.exists():
        return str(exe)
    found = shutil.which("rerun")
    if found:
        return found
    raise FileNotFoundError("cannot find the rerun executable (rerun-sdk installed without its CLI?)")


def viewer_reachable(url: str, timeout_s: float = 0.3) -> bool:
    """True if something accepts TCP connections at the host:port of a ``rerun+http://host:port/proxy`` URL.

    rerun's own gRPC client would block 5 s on connecting and 5 s more on disconnecting from nobody.
    """
    parsed = urlparse(
        url.replace("rerun+http", "http", 1).replace("rerun+https", "https", 1).replace("rerun://", "http://", 1)
    )
    host = parsed.hostname or "127.0.0.1"
    port = parsed.port or DEFAULT_VIEWER_PORT
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            return True
    except OSError:
        return False


def has_display() -> bool:
    """Whether a native viewer window could open here (always True off Linux)."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") or os.environ.get("WAYLAND_SOCKET"))


def spawn_viewer(
    port: int = DEFAULT_VIEWER_PORT, *, memory_limit: str = "75%", application_id: str = APPLICATION_ID
) -> str | None:
    """Start a native Rerun viewer listening on ``port`` (or reuse one already there); returns its URL.

    Returns None, with a warning, on a machine without a display: spawning there would only make
    rerun wait ~6 s for a viewer that cannot start.  Call this once per flight (the launcher), then
    give the URL to every process as ``connect_url``.
    """
    url = viewer_url(port)
    if viewer_reachable(url):
        return url
    if not has_display():
        log.warning(
            "no display (DISPLAY/WAYLAND_DISPLAY unset): not spawning a viewer; "
            "open the saved .rrd later or pass a --connect URL"
        )
        return None
    import rerun as rr

    rec = rr.RecordingStream(application_id, recording_id=new_recording_id(), send_properties=False)
    try:
        rr.spawn(
            port=port,
            connect=False,
            memory_limit=memory_limit,
            hide_welcome_screen=True,
            executable_path=rerun_cli_path(),
            recording=rec,
        )
    except Exception as exc:  # noqa: BLE001 - a viewer is a convenience, never a reason to fail a flight
        log.warning("could not spawn the Rerun viewer: %s", exc)
        return None
    return url


def send_blueprint(
    url: str, blueprint, recording_id: str, *, application_id: str = APPLICATION_ID, timeout_s: float = 5.0
) -> bool:
    """Show ``blueprint`` (a ``rerun.blueprint.Blueprint``) for a recording in the viewer at ``url``.

    A short-lived stream with the recording's application id and recording id sends it (no recording
    properties, no data): the processes that write the recording need not know the layout.  Returns
    False, with a warning, if no viewer listens there or sending failed.
    """
    if not viewer_reachable(url):
        log.warning("no Rerun viewer at %s: blueprint not sent", url)
        return False
    import rerun as rr

    rec = rr.RecordingStream(application_id, recording_id=recording_id, send_properties=False)
    try:
        rec.set_sinks(rr.GrpcSink(url))
        rec.send_blueprint(blueprint)
        rec.flush(timeout_sec=timeout_s)
    except Exception as exc:  # noqa: BLE001 - a viewer is a convenience, never a reason to fail a flight
        log.warning("could not send the blueprint to %s: %s", url, exc)
        return False
    finally:
        rec.disconnect()
    return True
