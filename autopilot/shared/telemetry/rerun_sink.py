"""Rows into Rerun: ``RerunSink``, the one code that turns a writer's rows into ``send_columns`` calls, and
``record_spools``, which sends the spooled rows of a whole flight through it into one recording file.

A live writer (``writer.Telemetry`` with a file or a viewer) drains its queues and hands each flush's arrays to a
``RerunSink`` on its own stream; a spooling writer hands the same arrays to a ``spool.SpoolSink`` and, after the
flight, ``record_spools`` reads them back and hands them to a ``RerunSink`` in the same order.  Either way the
same arrays meet the same code, so the two recordings hold the same entities, rows and values (only the chunking
differs: a live writer's flushes against one flush per spooled flush).
"""

from __future__ import annotations

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
            cols = vals[:, idx] if plot.scale == 1.0 else vals[:, idx] * plot.scale
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


def record_spools(
    spools: Sequence[str | os.PathLike],
    rrd_path: str | os.PathLike,
    *,
    write_footer: bool = False,
) -> dict:
    """Send the spooled rows of one flight's processes (``spool.SpoolReader``) into one recording at ``rrd_path``.

    Every spool must hold the same recording id (one flight).  The file is written like a live writer's part
    (without a footer unless ``write_footer``), one stream for all processes, in bounded memory: the spools are
    read a record at a time and the stream is flushed to the file after every ``FLUSH_EVERY_BYTES`` sent.
    Returns ``{"recording_id", "chunks", "truncated": [spools cut short]}``; a send that failed, a spool that is
    not one, or spools of different flights raise ``SpoolError``.
    """
    readers = [SpoolReader(p) for p in spools]
    try:
        ids = {(r.application_id, r.recording_id) for r in readers}
        if len(ids) != 1:
            raise SpoolError(f"spools of {len(ids)} recordings, one flight has one: {sorted(ids)}")
        application_id, rid = ids.pop()
        errors: list[str] = []
        rec = rr.RecordingStream(application_id, recording_id=rid)
        path = Path(rrd_path)
        path.parent.mkdir(parents=True, exist_ok=True)
        rec.set_sinks(rr.FileSink(str(path), write_footer=write_footer))
        chunks = 0
        pending = 0  # bytes sent since the stream was last flushed to the file
        for reader in readers:
            sink = RerunSink(rec, f"/{reader.process}/events", errors.append)
            handles: dict[int, object] = {}
            for head, arrays in reader:
                pending += sum(a.nbytes for a in arrays)
                if pending > FLUSH_EVERY_BYTES:  # rerun queues what is sent: let the file catch up
                    rec.flush()
                    pending = 0
                try:
                    _dispatch(sink, handles, head, arrays)
                except (KeyError, TypeError, ValueError) as exc:
                    if isinstance(exc, SpoolError):
                        raise
                    raise SpoolError(
                        f"{reader.path}: a {head.get('k')!r} record: {type(exc).__name__}: {exc}"
                    ) from None
            chunks += sink.chunks_sent
        rec.flush()
        rec.disconnect()
        if errors:
            raise SpoolError(f"{len(errors)} sends failed, the first: {errors[0]}")
        return {"recording_id": rid, "chunks": chunks, "truncated": [str(r.path) for r in readers if r.truncated]}
    finally:
        for r in readers:
            r.close()
