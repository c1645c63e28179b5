"""The per-process telemetry writer: cheap buffered appends, a background thread that sends batches.

The control loop never calls rerun.  ``Table.append`` puts one tuple on a ``collections.deque``
(an atomic, lock-free operation under the GIL, ~0.2 us); a daemon thread wakes every
``flush_interval_s`` (0.5 s), drains every deque, turns the rows into numpy columns and hands them to its
sink: ``rerun_sink.RerunSink`` sends them with ``RecordingStream.send_columns`` (which bypasses rerun's own
batcher and reaches the file a few milliseconds later); ``spool.SpoolSink`` (``spool_path``: a process that only
writes a file) appends them to a spool that one process of the flight records afterwards through the same
``RerunSink`` (``rerun_sink.record_spools``), so a spooling process never imports rerun.  So a SIGKILL loses at
most one flush interval of rows plus a few ms.

Shutdown is the process's: its stop handlers (``autopilot.shared.process.install_stop_handlers``) end
the loop, then it calls ``close()`` (or leaves a ``with`` block), which flushes everything and closes the
file cleanly (a complete stream; with ``write_footer``/``finalize`` also a footer).  A writer still open
when the interpreter exits is closed by an ``atexit`` handler, so a script that forgot ``close()``
loses nothing either.

The sinks are opened once, in the constructor (a bad file path raises there, in the caller).  A
viewer URL with no viewer behind it is detected with a short TCP probe and skipped.  The writer
thread has a lower nice value than the loop and hands the GIL over between two sends (see ``_yield``).
The writer knows no process's tables: each process registers its own layouts (``table``,
``state_channel``).
"""

from __future__ import annotations

import atexit
import logging
import math
import os
import subprocess
import sys
import threading
import time
import weakref
from collections import deque
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from autopilot.shared.telemetry import viewer as _viewer
from autopilot.shared.telemetry.buffers import NullTable, StateChannel, Table
from autopilot.shared.telemetry.files import RrdError, merge_recordings, new_recording_id
from autopilot.shared.telemetry.layout import APPLICATION_ID, PALETTE, Plot, Rgb, TableLayout

log = logging.getLogger(__name__)

DEFAULT_FLUSH_INTERVAL_S = 0.5


# ------------------------------------------------------------------------------------------ writer
_LIVE: weakref.WeakSet = weakref.WeakSet()
_atexit_installed = False


def _close_all_at_exit() -> None:
    for tel in list(_LIVE):
        try:
            tel.close()
        except Exception:  # noqa: BLE001 - one writer failing must not keep the others' files open
            log.exception("telemetry close at exit failed")


class Telemetry:
    """One process's telemetry: a recording stream to a part file and/or a live viewer, or a spool.

    ``process`` names the events entity (``/<process>/events``); ``recording_id`` must be the same in
    every process of a flight.  ``rrd_path`` writes a file, ``connect_url`` streams to a viewer,
    ``spawn_viewer`` starts one first (or reuses the one on the default port); ``spool_path`` writes the rows to a
    spool file instead of a file, for another process to record (``spool``, ``rerun_sink.record_spools``): without a
    viewer rerun is then never imported here.  ``live_rate_hz`` thins what the viewer gets to that many rows per
    second of sim time of each table of lines (``thinning``; None or 0: every row); the file or the spool keeps every
    row (the viewer then has a stream of its own, ``live_rec``).  Without any of them the writer is disabled: its
    tables are ``NullTable`` and its channels accept appends and drop them.  Either way the queues, the thread and the
    drain are this class's; what becomes of a flush's arrays is the sink's (``rerun_sink.RerunSink``,
    ``spool.SpoolSink``, ``thinning.TeeSink`` of both).
    """

    def __init__(
        self,
        process: str,
        recording_id: str | None = None,
        rrd_path: str | os.PathLike | None = None,
        *,
        connect_url: str | None = None,
        spawn_viewer: bool = False,
        spool_path: str | os.PathLike | None = None,
        application_id: str = APPLICATION_ID,
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        switch_interval_s: float | None = None,
        writer_nice: int = 10,
        recording_name: str | None = None,
        write_footer: bool = False,
        finalize: bool = False,
        live_rate_hz: float | None = None,
    ):
        if not process or "/" in process:
            raise ValueError(f"process must be a non-empty name without '/', got {process!r}")
        if not (math.isfinite(flush_interval_s) and 0 < flush_interval_s <= 1.0):
            raise ValueError(f"flush_interval_s must be in (0, 1] s, got {flush_interval_s!r}")
        if spool_path is not None and rrd_path is not None:
            raise ValueError("a spool and a .rrd file are two recordings of the same rows: give one")
        if live_rate_hz is not None and not (math.isfinite(live_rate_hz) and live_rate_hz >= 0):
            raise ValueError(f"live_rate_hz must be >= 0 rows/s (0: every row), got {live_rate_hz!r}")
        if spool_path is not None and (recording_name or write_footer or finalize):
            raise ValueError("recording_name, write_footer and finalize are the recording's: not with a spool")
        self.process = process
        self.recording_id = recording_id or new_recording_id()
        self.application_id = application_id
        self.rrd_path = Path(rrd_path) if rrd_path is not None else None
        self.spool_path = Path(spool_path) if spool_path is not None else None
        self.flush_interval_s = float(flush_interval_s)
        self._recording_name = recording_name
        self._write_footer = bool(write_footer)
        self._finalize = bool(finalize)
        self.live_rate_hz = float(live_rate_hz) if live_rate_hz else None
        if spawn_viewer and connect_url is None:
            connect_url = _viewer.spawn_viewer(application_id=application_id)
        self.connect_url = connect_url
        self.enabled = self.rrd_path is not None or self.connect_url is not None or self.spool_path is not None
        self.events_path = f"/{process}/events"
        self.rows_sent: dict[str, int] = {}
        self.errors = 0
        self.last_error: str | None = None
        self._tables: list[Table] = []
        self._channels: list[StateChannel] = []
        self._pending: deque = deque()  # tables and channels the sink has not registered yet
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
        self.rec = None  # the rerun.RecordingStream of the file (and of the viewer, unless it has its own)
        self.live_rec = None  # the viewer's own stream: beside a spool, or thinned (live_rate_hz)
        self.thinning = None  # the thinning.ThinnedSink of the viewer's stream
        self._sink = None
        if switch_interval_s is not None:
            sys.setswitchinterval(float(switch_interval_s))
        if not self.enabled:
            return
        sinks = []
        if self.spool_path is not None:
            from autopilot.shared.telemetry.spool import SpoolSink

            sinks.append(SpoolSink(self.spool_path, process, self.recording_id, application_id))  # a bad path raises
        if self.rrd_path is not None or self.connect_url is not None:
            sinks += self._rerun_sinks()
        if not sinks:
            # Only a viewer URL was given and nobody listens: without any sink rerun would buffer everything in
            # memory, so this writer turns itself off.
            self.enabled = False
            return
        if len(sinks) == 1:
            self._sink = sinks[0]
        else:
            from autopilot.shared.telemetry.thinning import TeeSink

            self._sink = TeeSink(*sinks)
        global _atexit_installed
        if not _atexit_installed:
            atexit.register(_close_all_at_exit)
            _atexit_installed = True
        _LIVE.add(self)
        self._thread = threading.Thread(target=self._run, name=f"telemetry-{process}", daemon=True)
        self._thread.start()

    @property
    def chunks_sent(self) -> int:
        """Chunks handed to the sink so far (sent to Rerun, or spooled records of rows, states and events)."""
        return 0 if self._sink is None else self._sink.chunks_sent

    # -------------------------------------------------------------- registration (set-up time)
    def table(self, table_layout: TableLayout) -> Table | NullTable:
        """A buffer for rows of ``table_layout``; its plots' names and colours are sent once, statically."""
        if not self.enabled:
            return NullTable(table_layout)
        table = Table(table_layout)
        with self._lock:
            self._tables.append(table)
            self._pending.append(table)
            self.rows_sent.setdefault(table_layout.name, 0)
        return table

    def series(
        self,
        path: str,
        fields: Sequence[str],
        labels: Sequence[str] | None = None,
        colors: Sequence[Rgb] | None = None,
        *,
        step: bool = False,
    ) -> Table | NullTable:
        """A one-entity table: ``len(fields)`` series under ``path``."""
        fields = tuple(fields)
        labels = tuple(labels) if labels is not None else fields
        colors = tuple(colors) if colors is not None else tuple(PALETTE[i % len(PALETTE)] for i in range(len(fields)))
        plot = Plot(path, fields, labels, colors, step=step)
        return self.table(TableLayout(path.strip("/").replace("/", "."), fields, (plot,)))

    def state_channel(
        self, path: str, label: str | None = None, colors: dict[str, Rgb] | None = None, *, warn: Iterable[str] = ()
    ) -> StateChannel:
        """A discrete state at ``path`` (``StateChange``), also echoed as text to ``/<process>/events``."""
        channel = StateChannel(path, label or path.rsplit("/", 1)[-1], colors, warn)
        if not self.enabled:
            return channel
        with self._lock:
            self._channels.append(channel)
            self._pending.append(channel)
        return channel

    @property
    def write_error(self) -> str | None:
        """Why the spool stopped growing (a write that failed, e.g. a full disk: one line naming the path), or
        None.  What reached the file stays readable; the process reports this at its exit."""
        return getattr(self._sink, "failed", None)

    def log_event(self, sim_time_s: float, wall_time_s: float, text: str, level: str = "INFO") -> None:
        """A free-text line in ``/<process>/events`` (TextLog; level INFO, WARN, ERROR...).  Any thread."""
        if self.enabled:
            self._events.append((sim_time_s, wall_time_s, str(text), str(level)))

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

    def _rerun_sinks(self) -> list:
        """The ``RerunSink`` of the file and of the viewer (one stream for both, or one each when the viewer's is
        thinned or beside a spool).  Sinks are opened here, once (a second set_sinks would start the file again): a
        bad path raises now, in the caller, and a --connect URL with nothing behind it is dropped after a short
        probe."""
        import rerun as rr

        from autopilot.shared.telemetry.rerun_sink import RerunSink

        if self.connect_url is not None and not _viewer.viewer_reachable(self.connect_url):
            kept = self.rrd_path is not None or self.spool_path is not None
            log.warning(
                "no Rerun viewer at %s: %s", self.connect_url, "writing the file only" if kept else "telemetry is off"
            )
            self.connect_url = None
        own_stream = self.connect_url is not None and (self.live_rate_hz is not None or self.spool_path is not None)
        file_sinks = []
        if self.rrd_path is not None:
            self.rrd_path.parent.mkdir(parents=True, exist_ok=True)
            file_sinks.append(rr.FileSink(str(self.rrd_path), write_footer=self._write_footer))
        if self.connect_url is not None and not own_stream:
            file_sinks.append(rr.GrpcSink(self.connect_url))
        out = []
        if file_sinks:
            self.rec = self._stream(rr, file_sinks)
            out.append(RerunSink(self.rec, self.events_path, self._error, self._yield))
        if own_stream:
            self.live_rec = self._stream(rr, [rr.GrpcSink(self.connect_url)])
            live = RerunSink(self.live_rec, self.events_path, self._error, self._yield)
            if self.live_rate_hz is not None:
                from autopilot.shared.telemetry.thinning import ThinnedSink

                live = self.thinning = ThinnedSink(live, self.live_rate_hz)
            out.append(live)
        return out

    def _stream(self, rr, sinks: list):
        rec = rr.RecordingStream(self.application_id, recording_id=self.recording_id)
        rec.set_sinks(*sinks)
        if self._recording_name:
            rec.send_recording_name(self._recording_name)
        return rec

    def flush(self) -> None:
        """Hand everything queued so far to the sink (the writer thread does this every ``flush_interval_s``)."""
        if not self.enabled or self._sink is None:
            return
        with self._lock:
            self._segment_start = time.perf_counter()
            sink = self._sink
            while self._pending:
                item = self._pending.popleft()
                if isinstance(item, Table):
                    item.handle = sink.table(item.layout)
                else:
                    item.handle = sink.channel(item.path, item.label, item.colors, item.warn)
            for table in self._tables:
                self._flush_table(table)
            self._flush_channels()
            sink.flush()

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
        except (TypeError, ValueError) as exc:
            self._error(f"table {name}: dropped {n} rows: {exc}")
            return
        self._sink.rows(table.handle, sim, wall, vals)
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
            self._sink.states(ch.handle, sim, wall, [r[2] for r in rows])
            for t, w, state, prev, note in rows:
                text = f"{ch.label}: {prev or '-'} -> {state}" + (f" ({note})" if note else "")
                lines.append((t, w, text, "WARN" if state in ch.warn else "INFO"))
        while self._events:
            lines.append(self._events.popleft())
        if lines:
            lines.sort(key=lambda r: r[0])
            self._sink.events(
                np.array([r[0] for r in lines], dtype=np.float64),
                np.array([r[1] for r in lines], dtype=np.float64),
                [r[2] for r in lines],
                [r[3] for r in lines],
            )

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
        close = getattr(self._sink, "close", None)  # a spool is complete once closed; a thinned stream sends the rest
        if close is not None:
            with self._lock:
                close()
        for rec in (self.rec, self.live_rec):
            if rec is None:
                continue
            try:
                rec.flush(timeout_sec=timeout_s)
            except Exception as exc:  # noqa: BLE001 - e.g. a viewer that went away: the file is what matters
                log.warning("telemetry flush: %s", exc)
            try:
                rec.disconnect()
            except Exception as exc:  # noqa: BLE001
                log.warning("telemetry disconnect: %s", exc)
        if self._finalize and self.rrd_path is not None and self.rrd_path.is_file():
            try:
                merge_recordings([self.rrd_path], self.rrd_path)
            except (RrdError, OSError, subprocess.SubprocessError) as exc:  # the footer-less file is still complete
                log.warning("telemetry finalize (footer) failed, file kept as written: %s", exc)

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> Telemetry:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        where = [str(p) for p in (self.rrd_path, self.spool_path) if p]
        if self.connect_url:
            where.append(self.connect_url)
        return f"Telemetry({self.process!r}, recording_id={self.recording_id!r}, -> {', '.join(where) or 'disabled'})"
