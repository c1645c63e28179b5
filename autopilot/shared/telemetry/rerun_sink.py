"""Rows into Rerun: ``RerunSink``, the one code that turns a writer's rows into ``send_columns`` calls, and
``record_spools``, which sends the spooled rows of a whole flight through it into one recording file.

A live writer (``writer.Telemetry`` with a file or a viewer) drains its queues and hands each flush's arrays to a
``RerunSink`` on its own stream; a spooling writer hands the same arrays to a ``spool.SpoolSink`` and, after the
flight, ``record_spools`` reads them back and hands them to a ``RerunSink`` in the same order.  Either way the
same arrays meet the same code, so the two recordings hold the same entities, rows and values (only the chunking
differs: a live writer's flushes against one flush per spooled flush).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import rerun as rr

from autopilot.shared.telemetry.columns import (
    aircraft_shape,
    pose_columns,
    scalar_column,
    series_style,
    sim_time_column,
    wall_time_column,
)
from autopilot.shared.telemetry.files import RRD_FIXED_BYTES, RRD_PER_SPOOL_BYTE, check_room, has_footer
from autopilot.shared.telemetry.layout import TableLayout
from autopilot.shared.telemetry.spool import SpoolError, SpoolReader, layout_from_data


def _nothing() -> None:
    return None


class RerunSink:
    """A process's rows into a ``RecordingStream``: its tables' plots and poses, its state channels, its events.

    ``on_error(message)`` is told of a send that failed (telemetry never stops the process); ``pause()`` runs
    between two sends (the live writer hands the GIL to the control loop there).
    """

    def __init__(
        self,
        rec: rr.RecordingStream,
        events_path: str,
        on_error: Callable[[str], None],
        pause: Callable[[], None] = _nothing,
    ):
        self.rec = rec
        self.events_path = events_path
        self._on_error = on_error
        self._pause = pause
        self.chunks_sent = 0

    def _static(self, path: str, archetype) -> None:
        try:
            self.rec.log(path, archetype, static=True, strict=True)
        except Exception as exc:  # noqa: BLE001 - telemetry never stops the process
            self._on_error(f"static {path}: {exc}")

    def _send(self, path: str, sim: np.ndarray, wall: np.ndarray, columns, indexes=None) -> None:
        try:
            self.rec.send_columns(
                path,
                indexes=indexes or [sim_time_column(sim), wall_time_column(wall)],
                columns=columns,
                strict=True,
            )
            self.chunks_sent += 1
        except Exception as exc:  # noqa: BLE001 - telemetry never stops the process
            self._on_error(f"{path}: {exc}")

    # -------------------------------------------------------------- registration: the static parts
    def table(self, layout: TableLayout):
        """The plots' names and colours and the poses' aircraft, once; the handle of the table's rows."""
        for plot in layout.plots:
            self._static(plot.path, series_style(plot.labels, plot.colors, plot.step, plot.points))
        for pose in layout.poses:
            self._static(pose.path, aircraft_shape(pose.color))
        return layout, tuple((p, np.array([layout.index(f) for f in p.fields])) for p in layout.plots)

    def channel(self, path: str, label: str, colors: dict, warn: frozenset) -> str:  # noqa: ARG002 - SpoolSink's
        """A state channel's colours, once; its handle (its path)."""
        if colors:
            values = list(colors)
            self._static(
                path,
                rr.StateConfiguration(values=values, labels=values, colors=[list(colors[v]) for v in values]),
            )
        return path

    # -------------------------------------------------------------- rows
    def rows(self, handle, sim: np.ndarray, wall: np.ndarray, vals: np.ndarray) -> None:
        """n rows of a table (``vals`` n x its fields): one ``Scalars`` column per plot, one pose per row."""
        layout, plots = handle
        indexes = [sim_time_column(sim), wall_time_column(wall)]
        self._pause()
        for plot, idx in plots:
            cols = plot.shown(vals[:, idx])
            self._send(plot.path, sim, wall, [scalar_column(cols)], indexes)
            self._pause()
        for pose in layout.poses:
            pitch = None if pose.pitch is None else vals[:, layout.index(pose.pitch)]
            self._pose(pose, sim, wall, vals[:, layout.index(pose.roll)], pitch)

    def _pose(self, pose, sim: np.ndarray, wall: np.ndarray, roll: np.ndarray, pitch=None) -> None:
        """One ``Transform3D`` per row with a finite attitude (a step without one keeps the last attitude)."""
        ok = np.isfinite(roll) if pitch is None else np.isfinite(roll) & np.isfinite(pitch)
        if not ok.any():
            return
        if not ok.all():
            sim, wall, roll = sim[ok], wall[ok], roll[ok]
            pitch = None if pitch is None else pitch[ok]
        self._send(pose.path, sim, wall, pose_columns(roll, pitch))
        self._pause()

    def states(self, handle: str, sim: np.ndarray, wall: np.ndarray, states: list[str]) -> None:
        """A channel's transitions (``StateChange``)."""
        self._send(handle, sim, wall, rr.StateChange.columns(state=states))

    def events(self, sim: np.ndarray, wall: np.ndarray, texts: list[str], levels: list[str]) -> None:
        """Lines of the process's event log (``TextLog``), in sim-time order."""
        self._send(self.events_path, sim, wall, rr.TextLog.columns(text=texts, level=levels))

    def flush(self) -> None:
        return None


def _dispatch(sink: RerunSink, handles: dict, head: dict, arrays: tuple) -> None:
    """One spooled record into ``sink`` (``handles``: the spool's table and channel ids -> the sink's handles)."""
    kind = head.get("k")
    if kind == "table":
        handles[head["id"]] = sink.table(layout_from_data(head["layout"]))
    elif kind == "channel":
        colors = {k: tuple(v) for k, v in head["colors"].items()}
        handles[head["id"]] = sink.channel(head["path"], head["label"], colors, frozenset(head["warn"]))
    elif kind == "rows":
        sink.rows(handles[head["id"]], *arrays)
    elif kind == "states":
        sink.states(handles[head["id"]], *arrays, [str(s) for s in head["states"]])
    elif kind == "events":
        sink.events(*arrays, [str(t) for t in head["texts"]], [str(v) for v in head["levels"]])
    else:
        raise SpoolError(f"unknown record {kind!r}")


FLUSH_EVERY_BYTES = 4 << 20  # record_spools waits for the file after this much spooled data: bounded memory (measured:
# peak RSS 120 MB recording 1 h of a 100 Hz autopilot table, 126 MB for 3 h; 187 MB for 1 h without these flushes)
INTERLEAVE_S = 2.0  # record_spools sends every process's rows in slices of this many sim seconds, in sim-time order
_TIMED = ("rows", "states", "events")  # records with times (the others register a table or a channel)


def _slice(head: dict, arrays: tuple, keep: np.ndarray) -> tuple[dict, tuple]:
    """The part of a timed record whose rows ``keep`` selects (a boolean mask over its rows)."""
    kind = head["k"]
    out = tuple(a[keep] for a in arrays)
    if kind == "rows":
        return {**head, "n": int(keep.sum())}, out
    idx = np.flatnonzero(keep)
    if kind == "states":
        return {**head, "states": [head["states"][i] for i in idx]}, out
    return {**head, "texts": [head["texts"][i] for i in idx], "levels": [head["levels"][i] for i in idx]}, out


def _joined(parts: list[tuple[dict, tuple]]) -> tuple[dict, tuple]:
    """Timed records of one table, channel or event log as one (their rows in order)."""
    if len(parts) == 1:
        return parts[0]
    head = dict(parts[0][0])
    arrays = tuple(np.concatenate(columns) for columns in zip(*(a for _, a in parts)))
    if head["k"] == "rows":
        head["n"] = sum(h["n"] for h, _ in parts)
    for key in ("states", "texts", "levels"):
        if key in head:
            head[key] = [v for h, _ in parts for v in h[key]]
    return head, arrays


def _start_of(sim: np.ndarray) -> float:
    """The earliest finite-or-infinite sim time of a record's rows (NaN ignored; -inf when none is finite)."""
    return float(np.nanmin(sim)) if np.isfinite(sim).any() else -math.inf


class _Source:
    """One spool being recorded: its reader, its sink, and the timed records read but not all sent yet."""

    def __init__(self, reader: SpoolReader, rec: rr.RecordingStream, errors: list):
        self.reader = reader
        self.records = iter(reader)
        self.sink = RerunSink(rec, f"/{reader.process}/events", errors.append)
        self.handles: dict[int, object] = {}
        self.pending: list[tuple[dict, tuple]] = []
        self.starts: list[float] = []  # each pending record's earliest sim time (``_start_of``), computed once
        self.done = False
        self.span = [math.inf, -math.inf]  # the sim times of its rows

    def _dispatch(self, head: dict, arrays: tuple) -> None:
        try:
            _dispatch(self.sink, self.handles, head, arrays)
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, SpoolError):
                raise
            raise SpoolError(f"{self.reader.path}: a {head.get('k')!r} record: {type(exc).__name__}: {exc}") from None

    def fill(self, until: float, read: Callable[[tuple], None]) -> None:
        """Read records until one starts at or after ``until`` (or the spool ends); a record that registers a table
        or a channel is sent at once (it comes before that table's rows)."""
        while not self.done and not (self.pending and self.pending[-1][1][0].size and self.starts[-1] >= until):
            item = next(self.records, None)
            if item is None:
                self.done = True
                return
            head, arrays = item
            read(arrays)
            if head.get("k") in _TIMED:
                if head["k"] == "rows" and arrays[0].size:
                    ok = arrays[0][np.isfinite(arrays[0])]
                    if ok.size:
                        self.span = [min(self.span[0], float(ok.min())), max(self.span[1], float(ok.max()))]
                self.pending.append(item)
                self.starts.append(_start_of(arrays[0]))
            else:
                self._dispatch(head, arrays)

    def start(self) -> float:
        """The earliest sim time not sent yet (inf: nothing pending)."""
        return min((t for (_h, a), t in zip(self.pending, self.starts) if a[0].size), default=math.inf)

    def send_before(self, until: float | None) -> None:
        """Send what of the pending records lies before ``until``: one send per table, channel and event log (the
        slice's rows of each, in the spool's order: one chunk per entity per slice).  ``until=None``: every pending
        record as it is, one send each."""
        if until is None:
            for head, arrays in self.pending:
                self._dispatch(head, arrays)
            self.pending, self.starts = [], []
            return
        left, starts, due = [], [], {}
        for (head, arrays), start in zip(self.pending, self.starts):
            later = arrays[0] >= until
            if later.all():
                left.append((head, arrays))
                starts.append(start)
                continue
            if later.any():
                left.append(_slice(head, arrays, later))
                starts.append(_start_of(left[-1][1][0]))
                head, arrays = _slice(head, arrays, ~later)
            due.setdefault((head["k"], head.get("id")), []).append((head, arrays))
        self.pending, self.starts = left, starts
        for parts in due.values():
            self._dispatch(*_joined(parts))


def record_spools(
    spools: Sequence[str | os.PathLike],
    rrd_path: str | os.PathLike,
    *,
    write_footer: bool = False,
    interleave_s: float | None = INTERLEAVE_S,
    blueprint=None,
) -> dict:
    """Send the spooled rows of one flight's processes (``spool.SpoolReader``) into one recording at ``rrd_path``.

    Every spool must hold the same recording id (one flight).  The processes' rows go out together, in sim-time
    order: every ``interleave_s`` seconds of sim time, each spool's rows of that slice in turn (a record spanning
    more is cut at the slice's end), so the file holds both processes' data of one instant side by side: a viewer
    that reads the file in order (``rerun rrd merge`` keeps the order in which the chunks were made) shows the
    SITL's truth with the autopilot's signals, not after all of them.  ``interleave_s=None`` sends each spool whole,
    in turn (the order before).  The same rows either way: only the chunking and the order differ.

    The file is written like a live writer's part (without a footer unless ``write_footer``), one stream for all
    processes, in bounded memory: the spools are read a flush at a time and the stream is flushed to the file after
    every ``FLUSH_EVERY_BYTES`` sent.  ``blueprint``: a ``rerun.blueprint.Blueprint`` sent first, in the same stream
    (its own store, active and default), so that with ``write_footer`` the file is a whole flight's recording as
    ``rerun rrd merge`` of a part and the layout makes it, without that second pass.

    Returns ``{"recording_id", "chunks", "truncated": [spools cut short],
    "span": (first, last) sim s of the rows or None}``; a send that failed, a spool that is not one, spools of
    different flights, or a footer rerun could not write raise ``SpoolError``.  A disk without room for the recording
    (``files.check_room``: 4 bytes per spooled byte and 1 MB) raises OSError (ENOSPC) before rerun writes a byte.
    """
    if interleave_s is not None and not (math.isfinite(interleave_s) and interleave_s > 0):
        raise ValueError(f"interleave_s must be positive seconds or None, got {interleave_s!r}")
    readers = [SpoolReader(p) for p in spools]
    try:
        ids = {(r.application_id, r.recording_id) for r in readers}
        if len(ids) != 1:
            raise SpoolError(f"spools of {len(ids)} recordings, one flight has one: {sorted(ids)}")
        application_id, rid = ids.pop()
        errors: list[str] = []
        path = Path(rrd_path)
        path.parent.mkdir(parents=True, exist_ok=True)
        # never a FileSink on a disk that cannot hold the recording: rerun's can hang for good there (files.py)
        spooled = sum(r.path.stat().st_size for r in readers)
        check_room(path, RRD_PER_SPOOL_BYTE * spooled + RRD_FIXED_BYTES, "the recording of the spools")
        rec = rr.RecordingStream(application_id, recording_id=rid)
        rec.set_sinks(rr.FileSink(str(path), write_footer=write_footer))
        if blueprint is not None:
            rec.send_blueprint(blueprint)
        pending = [0]  # bytes read since the stream was last flushed to the file

        def read(arrays: tuple) -> None:
            pending[0] += sum(a.nbytes for a in arrays)
            if pending[0] > FLUSH_EVERY_BYTES:  # rerun queues what is sent: let the file catch up
                rec.flush()
                pending[0] = 0

        sources = [_Source(r, rec, errors) for r in readers]
        if interleave_s is None:
            for src in sources:
                src.fill(math.inf, read)
                src.send_before(None)
        else:
            until = -math.inf
            while True:
                for src in sources:
                    src.fill(until, read)
                    src.send_before(until)
                first = min(src.start() for src in sources)
                if first == math.inf and all(src.done for src in sources):
                    break
                until = first + interleave_s  # the next slice starts at the earliest row left (>= the last end)
        rec.flush()
        rec.disconnect()
        if errors:
            raise SpoolError(f"{len(errors)} sends failed, the first: {errors[0]}")
        if write_footer and not has_footer(path):  # rerun said nothing but could not end it (a disk that filled)
            raise SpoolError(f"{path}: the recording has no end (rerun could not write its footer)")
        t0, t1 = min(s.span[0] for s in sources), max(s.span[1] for s in sources)
        return {
            "recording_id": rid,
            "chunks": sum(s.sink.chunks_sent for s in sources),
            "truncated": [str(r.path) for r in readers if r.truncated],
            "span": (t0, t1) if t0 <= t1 else None,
        }
    finally:
        for r in readers:
            r.close()
