"""A spool: the telemetry rows of one process in a file, for another process to record (no rerun here).

A process that writes a file need not import rerun for it (about 0.45 CPU s with numpy and pyarrow) nor encode
Arrow chunks while it flies (a live viewer, if any, gets a thinned stream of its own: ``thinning``).  Its writer
(``writer.Telemetry`` with ``spool_path``) hands each flush's rows to a ``SpoolSink`` instead of Rerun's streams,
and after the flight one process reads the spools of the whole flight back and sends them, through the same
``rerun_sink.RerunSink`` a live writer uses, into one recording (``rerun_sink.record_spools``).  So a recording
from spools and one written live are made by the same code from the same arrays: the same entities, rows and
values.

The format, all little-endian: the 12 bytes ``MAGIC``, then records, each a ``<II`` pair (header length, payload
length), a UTF-8 JSON header and a payload of float64 arrays.  The headers (``"k"``):

* ``start``   ``process``, ``recording_id``, ``application_id`` (the first record);
* ``table``   ``id``, ``layout`` (a ``TableLayout`` as plain data);
* ``channel`` ``id``, ``path``, ``label``, ``colors``, ``warn`` (a ``StateChannel``);
* ``rows``    ``id`` (a table), ``n`` rows; payload sim (n), wall (n), values (n x the table's fields, row-major);
* ``states``  ``id`` (a channel), ``states`` (n strings); payload sim (n), wall (n);
* ``events``  ``texts``, ``levels`` (n each); payload sim (n), wall (n).

One flush of the writer is one ``rows`` record per table with rows, one ``states`` per channel with changes and
one ``events``: what a live writer sends as one chunk each.  A file cut short (a process killed while it wrote)
is read up to its last whole record (``SpoolReader.truncated``); anything else malformed is a ``SpoolError``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import struct
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from autopilot.shared.telemetry.layout import Plot, Pose, TableLayout

MAGIC = b"CLSAC-SPOOL1"
_HEAD = struct.Struct("<II")
_F8 = np.dtype("<f8")
MAX_HEADER = 64 << 20  # a header is a few kB (a flush's state and event texts); more is a corrupt file


class SpoolError(ValueError):
    """A spool file that is not one, or a record that does not fit its header."""


def spool_paths(out_dir: str | os.PathLike, processes: Sequence[str] = ("autopilot", "sitl")) -> dict[str, Path]:
    """Where each process of a flight spools its rows: ``OUT/.parts/<process>.spool``."""
    base = Path(out_dir) / ".parts"
    return {p: base / f"{p}.spool" for p in processes}


def layout_to_data(layout: TableLayout) -> dict:
    """A ``TableLayout`` as JSON-able data (``layout_from_data`` gives it back, equal)."""
    return dataclasses.asdict(layout)


def layout_from_data(d: dict) -> TableLayout:
    """The ``TableLayout`` of ``layout_to_data`` (its checks run again)."""
    plots = tuple(
        Plot(
            p["path"],
            tuple(p["fields"]),
            tuple(p["labels"]),
            tuple(tuple(c) for c in p["colors"]),
            step=bool(p["step"]),
            scale=float(p["scale"]),
            points=bool(p["points"]),
            wrap=bool(p.get("wrap", False)),
        )
        for p in d["plots"]
    )
    poses = tuple(Pose(q["path"], q["roll"], q["label"], tuple(q["color"]), q["pitch"]) for q in d["poses"])
    return TableLayout(d["name"], tuple(d["fields"]), plots, poses)


class SpoolSink:
    """The sink of a ``Telemetry`` that spools: each call appends one record to ``path`` (opened, truncated, now)."""

    def __init__(self, path: str | os.PathLike, process: str, recording_id: str, application_id: str):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "wb")  # noqa: SIM115 - open for the writer's life, closed by close()
        self._f.write(MAGIC)
        self._ids = 0
        self.chunks_sent = 0
        self.failed: str | None = None  # a write that failed (a full disk): one line naming the path; then no more
        self._record({"k": "start", "process": process, "recording_id": recording_id, "application_id": application_id})

    def _record(self, header: dict, *arrays: np.ndarray) -> None:
        if self.failed is not None:
            return
        head = json.dumps(header, separators=(",", ":")).encode()
        payload = b"".join(np.ascontiguousarray(a, dtype=_F8).tobytes() for a in arrays)
        try:
            self._f.write(_HEAD.pack(len(head), len(payload)) + head + payload)
        except OSError as exc:
            self._fail(exc)

    def _fail(self, exc: OSError) -> None:
        """Keep what reached the file (a reader stops at a torn last record), write nothing more."""
        self.failed = f"{self.path}: {exc.strerror or exc}"
        try:
            self._f.close()
        except OSError:
            pass

    def _new_id(self) -> int:
        self._ids += 1
        return self._ids - 1

    def table(self, layout: TableLayout) -> int:
        i = self._new_id()
        self._record({"k": "table", "id": i, "layout": layout_to_data(layout)})
        return i

    def channel(self, path: str, label: str, colors: dict, warn: frozenset) -> int:
        i = self._new_id()
        colors = {k: list(v) for k, v in colors.items()}
        self._record({"k": "channel", "id": i, "path": path, "label": label, "colors": colors, "warn": sorted(warn)})
        return i

    def rows(self, handle: int, sim: np.ndarray, wall: np.ndarray, vals: np.ndarray) -> None:
        self._record({"k": "rows", "id": handle, "n": len(sim)}, sim, wall, vals)
        self.chunks_sent += 1

    def states(self, handle: int, sim: np.ndarray, wall: np.ndarray, states: list[str]) -> None:
        self._record({"k": "states", "id": handle, "states": states}, sim, wall)
        self.chunks_sent += 1

    def events(self, sim: np.ndarray, wall: np.ndarray, texts: list[str], levels: list[str]) -> None:
        self._record({"k": "events", "texts": texts, "levels": levels}, sim, wall)
        self.chunks_sent += 1

    def flush(self) -> None:
        """After each of the writer's flushes: in the file, so a process killed later loses nothing of it."""
        if self.failed is None:
            try:
                self._f.flush()
            except OSError as exc:
                self._fail(exc)

    def close(self) -> None:
        if self.failed is None:
            try:
                self._f.close()
            except OSError as exc:
                self._fail(exc)


class SpoolReader:
    """The records of a spool, in order, as (header, arrays); ``truncated`` once a cut-short tail was met.

    ``rows`` records come with (sim, wall, values (n, m)), ``states`` and ``events`` with (sim, wall), the others
    with none.  The ``start`` record is read at once (``process``, ``recording_id``, ``application_id``).
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._f = open(self.path, "rb")  # noqa: SIM115 - closed by close() / the with block
        self.truncated = False
        self._fields: dict[int, int] = {}  # table id -> its number of fields
        if self._f.read(len(MAGIC)) != MAGIC:
            self._f.close()
            raise SpoolError(f"{self.path}: not a telemetry spool (no {MAGIC.decode()} header)")
        first = next(self._records(), None)
        if first is None or first[0].get("k") != "start":
            self._f.close()
            raise SpoolError(f"{self.path}: the spool has no start record")
        head = first[0]
        try:
            self.process = str(head["process"])
            self.recording_id = str(head["recording_id"])
            self.application_id = str(head["application_id"])
        except KeyError as exc:
            self._f.close()
            raise SpoolError(f"{self.path}: the start record has no {exc}") from None

    def __enter__(self) -> SpoolReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._f.close()

    def __iter__(self) -> Iterator[tuple[dict, tuple[np.ndarray, ...]]]:
        return self._records()

    def _records(self) -> Iterator[tuple[dict, tuple[np.ndarray, ...]]]:
        n_record = 0
        while True:
            n_record += 1
            raw = self._f.read(_HEAD.size)
            if not raw:
                return
            if len(raw) < _HEAD.size:
                self.truncated = True
                return
            n_head, n_payload = _HEAD.unpack(raw)
            if n_head > MAX_HEADER or n_payload % _F8.itemsize:
                raise SpoolError(f"{self.path}: record {n_record}: impossible sizes ({n_head}, {n_payload} bytes)")
            data = self._f.read(n_head + n_payload)
            if len(data) < n_head + n_payload:
                self.truncated = True
                return
            try:
                head = json.loads(data[:n_head])
            except ValueError as exc:
                raise SpoolError(f"{self.path}: record {n_record}: unreadable header: {exc}") from None
            if not isinstance(head, dict):
                raise SpoolError(f"{self.path}: record {n_record}: the header is not an object")
            yield head, self._arrays(head, np.frombuffer(data, _F8, offset=n_head), n_record)

    def _arrays(self, head: dict, flat: np.ndarray, n_record: int) -> tuple[np.ndarray, ...]:
        kind = head.get("k")
        try:
            if kind == "table":
                self._fields[int(head["id"])] = len(head["layout"]["fields"])
                return ()
            if kind == "rows":
                n, m = int(head["n"]), self._fields[int(head["id"])]
                if flat.size != n * (2 + m):
                    raise SpoolError(f"{self.path}: record {n_record}: {flat.size} values for {n} rows of {m}")
                return flat[:n], flat[n : 2 * n], flat[2 * n :].reshape(n, m)
            if kind in ("states", "events"):
                n = len(head["states"] if kind == "states" else head["texts"])
                if flat.size != 2 * n:
                    raise SpoolError(f"{self.path}: record {n_record}: {flat.size} times for {n} {kind}")
                return flat[:n], flat[n:]
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, SpoolError):
                raise
            raise SpoolError(f"{self.path}: record {n_record} ({kind}): {type(exc).__name__}: {exc}") from None
        if flat.size:
            raise SpoolError(f"{self.path}: record {n_record} ({kind}): unexpected payload")
        return ()
