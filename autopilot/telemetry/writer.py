"""The per-process telemetry writer: cheap buffered appends, a background thread that sends batches.

The control loop never calls rerun.  ``Table.append`` puts one tuple on a ``collections.deque``
(an atomic, lock-free operation under the GIL, ~0.2 us); a daemon thread wakes every
``flush_interval_s`` (0.5 s), drains every deque, turns the rows into numpy columns and sends them
with ``RecordingStream.send_columns`` (which bypasses rerun's own batcher and reaches the file a few
milliseconds later).  So a SIGKILL loses at most one flush interval of rows plus a few ms, and a
clean exit (``close()``, a ``with`` block, SIGINT, SIGTERM or interpreter exit) flushes everything
and closes the file cleanly (a complete stream; with ``write_footer``/``finalize`` also a footer).

The sinks are opened once, in the constructor (a bad file path raises there, in the caller).  A
viewer URL with no viewer behind it is detected with a short TCP probe and skipped: rerun's own gRPC
client would otherwise block ``set_sinks`` for 5 s and ``disconnect`` for 5 s more.  The writer thread
has a lower nice value than the loop and hands the GIL over between two sends (see ``_yield``).
"""

from __future__ import annotations

import atexit
import logging
import math
import os
import signal
import socket
import sys
import threading
import time
import uuid
import weakref
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from urllib.parse import urlparse

import numpy as np
import pyarrow as pa
import rerun as rr

from autopilot.telemetry import layout as L

log = logging.getLogger(__name__)

DEFAULT_VIEWER_PORT = 9876
DEFAULT_FLUSH_INTERVAL_S = 0.5


def new_recording_id() -> str:
    """A fresh recording id for one flight; give the same one to every process of that flight."""
    return str(uuid.uuid4())


def viewer_url(port: int = DEFAULT_VIEWER_PORT, host: str = "127.0.0.1") -> str:
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
    import shutil

    found = shutil.which("rerun")
    if found:
        return found
    raise FileNotFoundError("cannot find the rerun executable (rerun-sdk installed without its CLI?)")


def viewer_reachable(url: str, timeout_s: float = 0.3) -> bool:
    """True if something accepts TCP connections at the host:port of a ``rerun+http://host:port/proxy`` URL."""
    parsed = urlparse(url.replace("rerun+http", "http", 1).replace("rerun+https", "https", 1)
                      .replace("rerun://", "http://", 1))
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


def spawn_viewer(port: int = DEFAULT_VIEWER_PORT, *, memory_limit: str = "75%") -> str | None:
    """Start a native Rerun viewer listening on ``port`` (or reuse one already there); returns its URL.

    Returns None, with a warning, on a machine without a display: spawning there would only make
    rerun wait ~6 s for a viewer that cannot start.  Call this once per flight (the launcher), then
    give the URL to every process as ``connect_url``.
    """
    url = viewer_url(port)
    if viewer_reachable(url):
        return url
    if not has_display():
        log.warning("no display (DISPLAY/WAYLAND_DISPLAY unset): not spawning a viewer; "
                    "open the saved .rrd later or pass a --connect URL")
        return None
    rec = rr.RecordingStream(L.APPLICATION_ID, recording_id=new_recording_id(), send_properties=False)
    try:
        rr.spawn(port=port, connect=False, memory_limit=memory_limit, hide_welcome_screen=True,
                 executable_path=rerun_cli_path(), recording=rec)
    except Exception as exc:  # noqa: BLE001 - a viewer is a convenience, never a reason to fail a flight
        log.warning("could not spawn the Rerun viewer: %s", exc)
        return None
    return url


_spawn_viewer = spawn_viewer


# ------------------------------------------------------------------------------------------ arrow helpers
class _ArrowBatch:
    """Minimal ComponentBatchLike around a ready pyarrow array (avoids rerun's per-call converters)."""

    __slots__ = ("_array",)

    def __init__(self, array: pa.Array):
        self._array = array

    def as_arrow_array(self) -> pa.Array:
        return self._array


_SCALARS = rr.Scalars.descriptor_scalars()


def scalar_column(values: np.ndarray) -> rr.ComponentColumn:
    """A ``Scalars`` column from an (n,) or (n, k) float array: k series per row (one per instance)."""
    v = np.ascontiguousarray(values, dtype=np.float64)
    n = v.shape[0]
    k = 1 if v.ndim == 1 else v.shape[1]
    offsets = np.arange(0, n * k + 1, k, dtype=np.int32)
    return rr.ComponentColumn(_SCALARS, _ArrowBatch(pa.array(v.reshape(-1), pa.float64())), offsets=offsets)


def sim_time_column(seconds: np.ndarray, timeline: str = L.SIM_TIME) -> rr.TimeColumn:
    """Duration column rounded to the nanosecond.

    rerun's own float path truncates (``(t * 1e9).astype(int)``), which maps 0.0075 s to 7499999 ns:
    two processes computing the same instant differently would then land on different indices.
    """
    ns = np.rint(np.asarray(seconds, dtype=np.float64) * 1e9).astype(np.int64)
    return rr.TimeColumn(timeline, duration=ns.astype("timedelta64[ns]"))


def wall_time_column(epoch_seconds: np.ndarray, timeline: str = L.WALL_TIME) -> rr.TimeColumn:
    ns = np.rint(np.asarray(epoch_seconds, dtype=np.float64) * 1e9).astype(np.int64)
    return rr.TimeColumn(timeline, timestamp=ns.astype("datetime64[ns]"))


def series_style(plot: L.Plot) -> rr.SeriesLines:
    return rr.SeriesLines(
        names=list(plot.labels),
        colors=[list(c) for c in plot.colors],
        interpolation_mode="StepAfter" if plot.step else None,
    )


# ------------------------------------------------------------------------------------------ buffers
class Table:
    """The rows of one ``TableLayout``.  ``append`` is the only method the control loop calls."""

    __slots__ = ("layout", "_queue", "_push", "push", "_plots", "__weakref__")

    def __init__(self, table_layout: L.TableLayout):
        self.layout = table_layout
        self._queue: deque = deque()
        self._push = self._queue.append
        #: Fastest form, no Python frame: ``push((sim_time_s, wall_time_s, values))`` (one tuple).
        self.push = self._queue.append
        self._plots = tuple((p, np.array([table_layout.index(f) for f in p.fields])) for p in table_layout.plots)

    def append(self, sim_time_s: float, wall_time_s: float, values: Sequence[float]) -> None:
        """Queue one row: sim time (s), wall clock (``time.time()``, s), values in ``layout.fields`` order.

        ``values`` must not be mutated afterwards (pass a tuple).  Never blocks, never calls rerun.
        """
        self._push((sim_time_s, wall_time_s, values))

    def __len__(self) -> int:
        return len(self._queue)


class NullTable:
    """What a disabled ``Telemetry`` hands out: appends cost a function call and do nothing."""

    __slots__ = ("layout",)

    def __init__(self, table_layout: L.TableLayout):
        self.layout = table_layout

    def append(self, sim_time_s: float, wall_time_s: float, values: Sequence[float]) -> None:
        return None

    def push(self, row: tuple) -> None:
        return None

    def __len__(self) -> int:
        return 0


class StateChannel:
    """A discrete state (mode, failsafe) logged as ``StateChange`` plus a readable ``TextLog`` line."""

    __slots__ = ("path", "label", "colors", "_queue", "last", "__weakref__")

    def __init__(self, path: str, label: str, colors: dict[str, L.Rgb] | None):
        self.path = path
        self.label = label
        self.colors = dict(colors or {})
        self._queue: deque = deque()
        self.last: str | None = None

    def set(self, sim_time_s: float, wall_time_s: float, state: str, note: str = "") -> bool:
        """Record a transition; repeated identical states are ignored.  Returns True if it was a change."""
        state = str(state)
        if state == self.last:
            return False
        self._queue.append((sim_time_s, wall_time_s, state, self.last, note))
        self.last = state
        return True


# ------------------------------------------------------------------------------------------ writer
_LIVE: weakref.WeakSet = weakref.WeakSet()
_atexit_installed = False
_closing = False


def _close_all_at_exit() -> None:
    global _closing
    _closing = True
    for tel in list(_LIVE):
        try:
            tel.close()
        except Exception:  # noqa: BLE001
            log.exception("telemetry close at exit failed")


def _on_sigterm(signum, frame):  # noqa: ARG001
    if _closing:
        return  # already shutting down: let close() finish
    raise SystemExit(128 + signum)


def install_signal_handlers() -> bool:
    """Make SIGTERM unwind like Ctrl-C does (SystemExit), so ``with``/``finally``/atexit close the files.

    Only from the main thread and only if SIGTERM still has its default action; returns whether it
    installed the handler.  SIGINT already raises KeyboardInterrupt and needs nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        return False
    if signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        return False
    signal.signal(signal.SIGTERM, _on_sigterm)
    return True


class Telemetry:
    """One process's writer into a flight recording.

    Parameters
    ----------
    process:
        ``"autopilot"``, ``"sitl"`` or another short name; events go to ``/<process>/events``.
    recording_id:
        The flight's recording id (``new_recording_id()``): the same for every process of a flight.
    rrd_path:
        File to write (a part file when several processes record one flight, see ``merge_recordings``).
    connect_url:
        A running viewer (``rerun+http://host:9876/proxy``) to stream to as well.  Skipped with a
        warning if nothing listens there.
    spawn_viewer:
        Start a native viewer (or reuse the one on the default port) and stream to it.
    send_blueprint:
        Send the flight blueprint with the data (default: True for ``process="autopilot"``).
    flush_interval_s:
        How often the background thread sends batches; bounds what a SIGKILL loses.
    handle_signals:
        Install the SIGTERM -> SystemExit handler (``install_signal_handlers``) when possible.
    switch_interval_s:
        If set, ``sys.setswitchinterval``: bounds how long the writer thread can keep a waking control
        loop waiting for the GIL (the default 5 ms is two 400 Hz periods).
    writer_nice:
        Nice increment of the writer thread (Linux, per thread): the control loop wins CPU contention.
    write_footer:
        Finish the file with rerun's footer (chunk manifest) on close.  Off by default: rerun keeps the
        manifest in memory while writing (~0.5 kB per chunk, ~1 MB per flight-minute here), which is
        the only thing that made the writer's memory grow.  A file without footer is a complete,
        valid RRD stream (the viewer and ``tools.rrd`` read it); ``merge_recordings`` (what the
        launcher does for ``flight.rrd``) writes one, and a SIGKILLed writer leaves none either way.
    finalize:
        On close, rewrite ``rrd_path`` through ``rerun rrd merge`` so that it has a footer (for a
        process that writes its own final file rather than a part of a flight).

    With neither ``rrd_path`` nor a viewer, the object is disabled: tables accept appends and drop them.
    """

    def __init__(
        self,
        process: str,
        recording_id: str | None = None,
        rrd_path: str | os.PathLike | None = None,
        *,
        connect_url: str | None = None,
        spawn_viewer: bool = False,
        send_blueprint: bool | None = None,
        blueprint: object | None = None,
        application_id: str = L.APPLICATION_ID,
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        handle_signals: bool = True,
        switch_interval_s: float | None = None,
        writer_nice: int = 10,
        recording_name: str | None = None,
        write_footer: bool = False,
        finalize: bool = False,
    ):
        if not process or "/" in process:
            raise ValueError(f"process must be a non-empty name without '/', got {process!r}")
        if not (math.isfinite(flush_interval_s) and 0 < flush_interval_s <= 1.0):
            raise ValueError(f"flush_interval_s must be in (0, 1] s, got {flush_interval_s!r}")
        self.process = process
        self.recording_id = recording_id or new_recording_id()
        self.application_id = application_id
        self.rrd_path = Path(rrd_path) if rrd_path is not None else None
        self.flush_interval_s = float(flush_interval_s)
        self.send_blueprint = (process == "autopilot") if send_blueprint is None else bool(send_blueprint)
        self._blueprint = blueprint
        self._recording_name = recording_name
        self._write_footer = bool(write_footer)
        self._finalize = bool(finalize)
        if spawn_viewer and connect_url is None:
            connect_url = _spawn_viewer()
        self.connect_url = connect_url
        self.enabled = self.rrd_path is not None or self.connect_url is not None
        self.events_path = f"/{process}/events"
        self.rows_sent: dict[str, int] = {}
        self.chunks_sent = 0
        self.errors = 0
        self.last_error: str | None = None
        self._tables: list[Table] = []
        self._channels: list[StateChannel] = []
        self._statics: deque = deque()
        self._events: deque = deque()
        self._lock = threading.RLock()  # serialises flushes (writer thread vs. explicit flush() / close())
        self._stop = threading.Event()
        self._closed = False
        self._thread: threading.Thread | None = None
        self._in_writer = False
        self._nice = int(writer_nice)
        self._yield_s = 5e-5
        self._segment_start = 0.0
        self.stretches: deque = deque(maxlen=8192)  # writer stretches between GIL hand-overs, s (diagnostic)
        self.rec: rr.RecordingStream | None = None
        if switch_interval_s is not None:
            sys.setswitchinterval(float(switch_interval_s))
        if handle_signals:
            install_signal_handlers()
        if not self.enabled:
            return
        if self.rrd_path is not None:
            self.rrd_path.parent.mkdir(parents=True, exist_ok=True)
        self.rec = rr.RecordingStream(self.application_id, recording_id=self.recording_id)
        # Sinks are opened here, once (a second set_sinks would start the file again): a bad path raises
        # now, in the caller, and a --connect URL with nothing behind it is dropped after a short probe.
        if not self._open_sinks():
            # Only a viewer URL was given and nobody listens: without any sink rerun would buffer
            # everything in memory, so this writer turns itself off.
            self.enabled = False
            self.rec = None
            return
        global _atexit_installed
        if not _atexit_installed:
            atexit.register(_close_all_at_exit)
            _atexit_installed = True
        _LIVE.add(self)
        self._thread = threading.Thread(target=self._run, name=f"telemetry-{process}", daemon=True)
        self._thread.start()

    # -------------------------------------------------------------- registration (set-up time)
    def table(self, table_layout: L.TableLayout) -> Table | NullTable:
        """A buffer for rows of ``table_layout``; its plots' names and colours are sent once, statically."""
        if not self.enabled:
            return NullTable(table_layout)
        table = Table(table_layout)
        with self._lock:
            self._tables.append(table)
            self.rows_sent.setdefault(table_layout.name, 0)
        for plot in table_layout.plots:
            self._statics.append((plot.path, series_style(plot)))
        return table

    def series(self, path: str, fields: Sequence[str], labels: Sequence[str] | None = None,
               colors: Sequence[L.Rgb] | None = None, *, step: bool = False) -> Table | NullTable:
        """A one-entity table: ``len(fields)`` series under ``path``."""
        fields = tuple(fields)
        labels = tuple(labels) if labels is not None else fields
        colors = tuple(colors) if colors is not None else tuple(L.RUN_PALETTE[i % len(L.RUN_PALETTE)]
                                                               for i in range(len(fields)))
        plot = L.Plot(path, fields, labels, colors, step=step)
        return self.table(L.TableLayout(path.strip("/").replace("/", "."), fields, (plot,)))

    def state_channel(self, path: str, label: str | None = None,
                      colors: dict[str, L.Rgb] | None = None) -> StateChannel:
        """A discrete state at ``path`` (``StateChange``), also echoed as text to ``/<process>/events``."""
        channel = StateChannel(path, label or path.rsplit("/", 1)[-1], colors)
        if not self.enabled:
            return channel
        with self._lock:
            self._channels.append(channel)
        if channel.colors:
            values = list(channel.colors)
            self._statics.append((path, rr.StateConfiguration(
                values=values, labels=values, colors=[list(channel.colors[v]) for v in values])))
        return channel

    def log_event(self, sim_time_s: float, wall_time_s: float, text: str, level: str = "INFO") -> None:
        """A free-text line in ``/<process>/events`` (TextLog; level INFO, WARN, ERROR...).  Any thread."""
        if self.enabled:
            self._events.append((sim_time_s, wall_time_s, str(text), str(level)))

    def autopilot_tables(self, links: Sequence[str] = ("sitl", "gcs")):
        """The autopilot's standard set: (main table, {link: table}, mode channel, failsafe channel)."""
        return (
            self.table(L.AUTOPILOT),
            {name: self.table(L.link_layout(name, i)) for i, name in enumerate(links)},
            self.state_channel(L.AP_MODE, "mode", L.MODE_COLORS),
            self.state_channel(L.AP_FAILSAFE, "failsafe", L.FAILSAFE_COLORS),
        )

    # -------------------------------------------------------------- background thread
    def _run(self) -> None:
        if self._nice and hasattr(os, "setpriority") and sys.platform.startswith("linux"):
            try:  # Linux nice values are per thread: let the control loop win any CPU contention
                os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), self._nice)
            except OSError:
                pass
        self._in_writer = True
        while True:
            stopping = self._stop.wait(self.flush_interval_s)
            self.flush()
            if stopping:
                return

    def _open_sinks(self) -> int:
        sinks = []
        if self.rrd_path is not None:
            sinks.append(rr.FileSink(str(self.rrd_path), write_footer=self._write_footer))
        if self.connect_url is not None:
            if viewer_reachable(self.connect_url):
                sinks.append(rr.GrpcSink(self.connect_url))
            else:
                log.warning("no Rerun viewer at %s: %s", self.connect_url,
                            "writing the file only" if sinks else "telemetry is off")
                self.connect_url = None
        if not sinks:
            return 0
        self.rec.set_sinks(*sinks)
        if self._recording_name:
            self.rec.send_recording_name(self._recording_name)
        if self.send_blueprint:
            from autopilot.telemetry.blueprints import flight_blueprint

            self.rec.send_blueprint(self._blueprint if self._blueprint is not None else flight_blueprint())
        return len(sinks)

    def flush(self) -> None:
        """Send everything queued so far (the writer thread does this every ``flush_interval_s``)."""
        if not self.enabled or self.rec is None:
            return
        with self._lock:
            self._segment_start = time.perf_counter()
            while self._statics:
                path, arch = self._statics.popleft()
                try:
                    self.rec.log(path, arch, static=True, strict=True)
                except Exception as exc:  # noqa: BLE001
                    self._error(f"static {path}: {exc}")
            for table in self._tables:
                self._flush_table(table)
            self._flush_channels()

    def _flush_table(self, table: Table) -> None:
        q = table._queue
        n = len(q)
        if n == 0:
            return
        pop = q.popleft
        rows = [pop() for _ in range(n)]
        name = table.layout.name
        try:
            sim = np.fromiter((r[0] for r in rows), np.float64, n)
            wall = np.fromiter((r[1] for r in rows), np.float64, n)
            vals = np.array([r[2] for r in rows], dtype=np.float64)
            if vals.shape != (n, len(table.layout.fields)):
                raise ValueError(f"rows must have {len(table.layout.fields)} values, got shape {vals.shape}")
        except Exception as exc:  # noqa: BLE001
            self._error(f"table {name}: dropped {n} rows: {exc}")
            return
        indexes = [sim_time_column(sim), wall_time_column(wall)]
        self._yield()
        for plot, idx in table._plots:
            try:
                self.rec.send_columns(plot.path, indexes=indexes, columns=[scalar_column(vals[:, idx])], strict=True)
                self.chunks_sent += 1
            except Exception as exc:  # noqa: BLE001
                self._error(f"{plot.path}: {exc}")
            self._yield()
        self.rows_sent[name] = self.rows_sent.get(name, 0) + n

    def _flush_channels(self) -> None:
        lines: list[tuple[float, float, str, str]] = []
        for ch in self._channels:
            q = ch._queue
            n = len(q)
            if n == 0:
                continue
            rows = [q.popleft() for _ in range(n)]
            sim = np.array([r[0] for r in rows], dtype=np.float64)
            wall = np.array([r[1] for r in rows], dtype=np.float64)
            try:
                self.rec.send_columns(ch.path, indexes=[sim_time_column(sim), wall_time_column(wall)],
                                      columns=rr.StateChange.columns(state=[r[2] for r in rows]), strict=True)
                self.chunks_sent += 1
            except Exception as exc:  # noqa: BLE001
                self._error(f"{ch.path}: {exc}")
            for t, w, state, prev, note in rows:
                text = f"{ch.label}: {prev or '-'} -> {state}" + (f" ({note})" if note else "")
                lines.append((t, w, text, "WARN" if ch.colors.get(state) == L.VERMILLION else "INFO"))
        while self._events:
            lines.append(self._events.popleft())
        if lines:
            lines.sort(key=lambda r: r[0])
            try:
                self.rec.send_columns(
                    self.events_path,
                    indexes=[sim_time_column(np.array([r[0] for r in lines])),
                             wall_time_column(np.array([r[1] for r in lines]))],
                    columns=rr.TextLog.columns(text=[r[2] for r in lines], level=[r[3] for r in lines]),
                    strict=True)
                self.chunks_sent += 1
            except Exception as exc:  # noqa: BLE001
                self._error(f"{self.events_path}: {exc}")

    def _yield(self) -> None:
        """Between two sends, let go of the GIL long enough for a waiting control loop to take it.

        Without this the writer would keep the GIL for a whole flush (~0.5-2 ms) or until the
        interpreter's switch interval (5 ms, two 400 Hz periods) expires.  ``sleep(0)`` is not
        enough: the writer usually takes the GIL back before the woken thread is scheduled; a real
        nap of ``yield_s`` hands it over, so a control loop waits for at most one send.
        """
        if self._in_writer and threading.current_thread() is self._thread:
            now = time.perf_counter()
            self.stretches.append(now - self._segment_start)
            time.sleep(self._yield_s)
            self._segment_start = time.perf_counter()

    def _error(self, message: str) -> None:
        self.errors += 1
        if self.last_error != message:
            log.warning("telemetry: %s", message)
        self.last_error = message

    # -------------------------------------------------------------- shutdown
    def close(self, timeout_s: float = 5.0) -> None:
        """Flush everything, finalise the file (footer) and close the viewer connection.  Idempotent."""
        if self._closed:
            return
        self._closed = True
        _LIVE.discard(self)
        if not self.enabled:
            return
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                log.warning("telemetry writer thread did not stop within %.1f s", timeout_s)
        self.flush()  # whatever the writer thread had not sent yet (it flushed once more on its way out)
        try:
            self.rec.flush(timeout_sec=timeout_s)
        except Exception as exc:  # noqa: BLE001 - e.g. a viewer that went away: the file is what matters
            log.warning("telemetry flush: %s", exc)
        try:
            self.rec.disconnect()
        except Exception as exc:  # noqa: BLE001
            log.warning("telemetry disconnect: %s", exc)
        if self._finalize and self.rrd_path is not None and self.rrd_path.is_file():
            from autopilot.telemetry.files import merge_recordings

            try:
                merge_recordings([self.rrd_path], self.rrd_path, blueprint=False)
            except Exception as exc:  # noqa: BLE001 - the footer-less file is still complete
                log.warning("telemetry finalize (footer) failed, file kept as written: %s", exc)

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> Telemetry:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        where = [str(self.rrd_path)] if self.rrd_path else []
        if self.connect_url:
            where.append(self.connect_url)
        return f"Telemetry({self.process!r}, recording_id={self.recording_id!r}, -> {', '.join(where) or 'disabled'})"
