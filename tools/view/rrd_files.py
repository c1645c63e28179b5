"""Read flight and experiment recordings back (rerun-sdk 0.41 ``rerun.chunk.RrdReader``), for tests and notebooks.

Values are what the viewer shows: angles in degrees and angular rates in deg/s (the layouts' ``scale``), the rest SI.

    from tools.view import rrd_files as rrd
    data = rrd.load("runs/x/flight.rrd")              # {entity_path: Signal}
    roll = data["/autopilot/roll"]                     # roll.t (s), roll.values (n, k) in deg, roll.names
    rrd.load_poses("runs/x/flight.rrd")["/sitl/attitude"]   # (t, quaternions x y z w) of the 3D aircraft
    rrd.has_blueprint("runs/x/flight.rrd")

Command line (``tools.rrd``)::

    python -m tools.rrd summary FILE.rrd            entities, rows, time span, recording ids, blueprint
    python -m tools.rrd verify FILE.rrd...          the framing to the last byte, FILE.rrd.sha256 if present, then
                                                    rerun rrd verify (footers required; --no-footer-check for parts)
    python -m tools.rrd merge OUT.rrd PART.rrd...   merge the part files of one flight (+ flight blueprint);
                                                    --concatenate: constant memory, no footer (long flights)
    python -m tools.rrd record OUT.rrd SPOOL...     record the processes' telemetry spools (--telemetry-spool)
                                                    into one recording (+ flight blueprint, footer)
"""

from __future__ import annotations

import os
import warnings
from collections import defaultdict
from typing import NamedTuple

import numpy as np

from autopilot.shared.telemetry.layout import SIM_TIME


class Signal(NamedTuple):
    """One scalar entity: ``values[i, j]`` is series ``names[j]`` at ``t[i]`` seconds (sorted by time)."""

    t: np.ndarray  # float64 seconds on the chosen timeline
    values: np.ndarray  # (n, k) float64
    names: tuple[str, ...]  # SeriesLines names, if logged
    t_ns: np.ndarray  # int64 nanoseconds (exact; compare these across processes)


def _reader(path):
    from rerun.chunk import RrdReader

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # footer-less parts (SIGKILL) warn that they are "legacy"
        return RrdReader(str(path))


def recordings(path: str | os.PathLike) -> list[tuple[str, str]]:
    """(application_id, recording_id) of every recording store in the file."""
    return [(e.application_id, e.recording_id) for e in _reader(path).recordings()]


def has_blueprint(path: str | os.PathLike) -> bool:
    """True if the file carries a blueprint store with at least one chunk (a viewport layout)."""
    r = _reader(path)
    for entry in r.blueprints():
        for _ in r.stream(store=entry):
            return True
    return False


def blueprint_components(path: str | os.PathLike, component: str) -> list:
    """Every value of one blueprint component (e.g. ``"ViewBlueprint:display_name"``,
    ``"TimePanelBlueprint:timeline"``) in the file's blueprint store(s), in file order."""
    r = _reader(path)
    out: list = []
    for entry in r.blueprints():
        for chunk in r.stream(store=entry):
            rb = chunk.to_record_batch()
            if component in rb.schema.names:
                for v in _to_list(rb.column(component)):
                    out.extend(v if isinstance(v, list) else [v])
    return out


def visible_time_ranges(path: str | os.PathLike) -> dict[str, list[dict]]:
    """The visible time range (``VisibleTimeRanges``) of every view that sets one, by the view's display name:
    ``[{"timeline", "start": (kind, value), "end": (kind, value)}, ...]`` with kind ``Absolute``,
    ``CursorRelative`` (value ns) or ``Infinite`` (value None), in the file's blueprint store(s)."""
    r = _reader(path)
    names: dict[str, str] = {}
    ranges: dict[str, list[dict]] = {}
    for entry in r.blueprints():
        for chunk in r.stream(store=entry):
            rb = chunk.to_record_batch()
            view = chunk.entity_path.split("/VisibleTimeRanges")[0]
            if "ViewBlueprint:display_name" in rb.schema.names:
                for v in _to_list(rb.column("ViewBlueprint:display_name")):
                    names[chunk.entity_path] = v[0] if isinstance(v, list) else v
            if "VisibleTimeRanges:ranges" in rb.schema.names:
                items = rb.column("VisibleTimeRanges:ranges").flatten()  # one struct per range
                timelines = items.field("timeline").to_pylist()
                bounds = items.field("range")
                ranges[view] = [
                    {
                        "timeline": tl,
                        "start": _boundary(bounds.field("start"), i),
                        "end": _boundary(bounds.field("end"), i),
                    }
                    for i, tl in enumerate(timelines)
                ]
    return {names.get(view, view): rng for view, rng in ranges.items()}


def y_ranges(path: str | os.PathLike) -> dict[str, list[float]]:
    """The fixed y range (``ScalarAxis:range``, [low, high]) of every view that sets one, by the view's display name,
    in the file's blueprint store(s)."""
    r = _reader(path)
    names: dict[str, str] = {}
    ranges: dict[str, list[float]] = {}
    for entry in r.blueprints():
        for chunk in r.stream(store=entry):
            rb = chunk.to_record_batch()
            if "ViewBlueprint:display_name" in rb.schema.names:
                for v in _to_list(rb.column("ViewBlueprint:display_name")):
                    names[chunk.entity_path] = v[0] if isinstance(v, list) else v
            if "ScalarAxis:range" in rb.schema.names:
                for v in _to_list(rb.column("ScalarAxis:range")):
                    ranges[chunk.entity_path.split("/ScalarAxis")[0]] = [float(x) for x in (v[0] if len(v) == 1 else v)]
    return {names.get(view, view): rng for view, rng in ranges.items()}


def _boundary(union, i: int) -> tuple[str, int | None]:
    """(kind, value) of element ``i`` of a ``TimeRangeBoundary`` dense union."""
    code = union.type_codes[i].as_py()
    child = list(union.type.type_codes).index(code)
    value = union.field(child)[union.offsets[i].as_py()].as_py()
    return union.type.field(child).name, value


def chunk_order(
    path: str | os.PathLike, *, timeline: str = SIM_TIME, recording_id: str | None = None
) -> list[tuple[str, float, float]]:
    """The temporal chunks of one recording in file order, each as (entity path, first, last time in s on
    ``timeline``): the order in which a viewer that reads the file from its start receives the data."""
    r = _reader(path)
    out = []
    for chunk in r.stream(store=_store(r, recording_id)):
        rb = chunk.to_record_batch()
        if timeline in rb.schema.names and rb.num_rows:
            t = rb.column(timeline).cast("int64").to_numpy(zero_copy_only=False)
            out.append((chunk.entity_path, t.min() * 1e-9, t.max() * 1e-9))
    return out


def _store(r, recording_id: str | None):
    entries = r.recordings()
    if not entries:
        raise ValueError(f"{r.path}: no recording in the file")
    if recording_id is None:
        return entries[0]
    for e in entries:
        if e.recording_id == recording_id:
            return e
    raise ValueError(f"{r.path}: no recording {recording_id!r} (has {[e.recording_id for e in entries]})")


def _to_list(column) -> list:
    return column.to_pylist()


def load(
    path: str | os.PathLike, *, timeline: str = SIM_TIME, prefix: str | None = None, recording_id: str | None = None
) -> dict[str, Signal]:
    """Every ``Scalars`` entity of one recording (the first, or ``recording_id``) as a ``Signal``.

    Rows are ordered by ``timeline`` (stable); entities without that timeline are skipped.
    ``prefix`` keeps only entities under it (e.g. ``"/sitl"``).
    """
    r = _reader(path)
    store = _store(r, recording_id)
    times: dict[str, list[np.ndarray]] = defaultdict(list)
    values: dict[str, list[np.ndarray]] = defaultdict(list)
    names: dict[str, tuple[str, ...]] = {}
    for chunk in r.stream(store=store):
        ep = chunk.entity_path
        if prefix is not None and not (ep == prefix or ep.startswith(prefix.rstrip("/") + "/")):
            continue
        rb = chunk.to_record_batch()
        cols = rb.schema.names
        for style in ("SeriesLines:names", "SeriesPoints:names"):  # lines, or markers (events)
            if style in cols:
                for v in _to_list(rb.column(style)):
                    if v:
                        names[ep] = tuple(v)
        if "Scalars:scalars" not in cols or timeline not in cols:
            continue
        t = rb.column(timeline).cast("int64").to_numpy(zero_copy_only=False)
        col = rb.column("Scalars:scalars")
        flat = col.flatten().to_numpy(zero_copy_only=False).astype(np.float64)
        offsets = col.offsets.to_numpy()
        k = int(offsets[1] - offsets[0]) if len(offsets) > 1 else 1
        if not np.all(np.diff(offsets) == k):
            raise ValueError(f"{ep}: rows with different numbers of series are not supported")
        times[ep].append(t)
        values[ep].append(flat.reshape(-1, k) if k else flat.reshape(len(t), 0))
    out: dict[str, Signal] = {}
    for ep in times:
        t_ns = np.concatenate(times[ep])
        vals = np.concatenate(values[ep], axis=0)
        order = np.argsort(t_ns, kind="stable")
        t_ns = t_ns[order]
        out[ep] = Signal(t_ns.astype(np.float64) * 1e-9, vals[order], names.get(ep, ()), t_ns)
    return out


def load_poses(
    path: str | os.PathLike, *, timeline: str = SIM_TIME, recording_id: str | None = None
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``Transform3D`` quaternions (the 3D attitudes): {path: (t seconds (n,), quaternions (n, 4) as x, y, z, w)}."""
    r = _reader(path)
    times: dict[str, list] = defaultdict(list)
    quats: dict[str, list] = defaultdict(list)
    for chunk in r.stream(store=_store(r, recording_id)):
        rb = chunk.to_record_batch()
        if "Transform3D:quaternion" not in rb.schema.names or timeline not in rb.schema.names:
            continue
        times[chunk.entity_path].append(rb.column(timeline).cast("int64").to_numpy(zero_copy_only=False))
        q = rb.column("Transform3D:quaternion").flatten().flatten().to_numpy(zero_copy_only=False)
        quats[chunk.entity_path].append(q.astype(np.float64).reshape(-1, 4))
    out = {}
    for ep in times:
        t_ns = np.concatenate(times[ep])
        order = np.argsort(t_ns, kind="stable")
        out[ep] = (t_ns[order] * 1e-9, np.concatenate(quats[ep])[order])
    return out


def load_states(
    path: str | os.PathLike, *, timeline: str = SIM_TIME, recording_id: str | None = None
) -> dict[str, list[tuple[float, str]]]:
    """``StateChange`` entities: {path: [(t seconds, state), ...]} in time order."""
    r = _reader(path)
    out: dict[str, list[tuple[float, str]]] = defaultdict(list)
    for chunk in r.stream(store=_store(r, recording_id)):
        rb = chunk.to_record_batch()
        if "StateChange:state" not in rb.schema.names or timeline not in rb.schema.names:
            continue
        t = rb.column(timeline).cast("int64").to_numpy(zero_copy_only=False)
        for ti, st in zip(t, _to_list(rb.column("StateChange:state"))):
            out[chunk.entity_path].append((ti * 1e-9, st[0] if st else ""))
    return {k: sorted(v, key=lambda x: x[0]) for k, v in out.items()}


def load_texts(
    path: str | os.PathLike, *, timeline: str = SIM_TIME, recording_id: str | None = None
) -> dict[str, list[tuple[float, str]]]:
    """Every ``TextLog`` entity (the event logs): {path: [(t seconds, text), ...]} in time order."""
    r = _reader(path)
    out: dict[str, list[tuple[float, str]]] = defaultdict(list)
    for chunk in r.stream(store=_store(r, recording_id)):
        rb = chunk.to_record_batch()
        if "TextLog:text" not in rb.schema.names or timeline not in rb.schema.names:
            continue
        t = rb.column(timeline).cast("int64").to_numpy(zero_copy_only=False)
        for ti, txt in zip(t, _to_list(rb.column("TextLog:text"))):
            out[chunk.entity_path].append((ti * 1e-9, txt[0] if txt else ""))
    return {k: sorted(v, key=lambda x: x[0]) for k, v in out.items()}


def load_text(
    path: str | os.PathLike, entity: str, *, timeline: str = SIM_TIME, recording_id: str | None = None
) -> list[tuple[float, str]]:
    """``TextLog`` lines of one entity: [(t seconds, text), ...] in time order."""
    return load_texts(path, timeline=timeline, recording_id=recording_id).get(entity, [])


def entity_paths(path: str | os.PathLike, recording_id: str | None = None) -> list[str]:
    """Every entity path with data in one recording (static or temporal)."""
    r = _reader(path)
    return sorted({c.entity_path for c in r.stream(store=_store(r, recording_id))})


def unreadable(path: str | os.PathLike) -> str | None:
    """Why ``path`` is not a readable recording (one line), or None: missing, empty, cut off inside a message
    (``RrdReader`` decodes every frame header), or holding no recording.  ``rerun rrd verify`` of rerun-sdk 0.41
    passes an empty file and one cut after 7 or 100 bytes, so :func:`verify` asks this first."""
    if not os.path.isfile(path):
        return "no such file"
    if os.path.getsize(path) == 0:
        return "empty file"
    try:
        r = _reader(path)
        if not r.recordings() and not r.blueprints():
            return "no recording in the file"
    except (RuntimeError, OSError, ValueError) as exc:
        return str(exc).strip().splitlines()[0].replace(f"Failed to read RRD file at {path}: ", "")
    return None


def verify(path: str | os.PathLike, *, check_footers: bool = True) -> tuple[bool, str]:
    """(ok, output): :func:`unreadable` first, then the framing walked to the last byte (a file cut inside its
    footer's trailer, which ``rerun rrd verify`` of rerun-sdk 0.41 passes, fails here), then the content against
    ``FILE.sha256`` if there is one (the product writes it beside every recording it makes; rerun checksums only
    its footer, so a change inside a message that still decodes is seen only so), then ``rerun rrd verify`` (the
    CLI of the installed rerun-sdk: every message decoded).  ``check_footers``: rerun's footer (index) required.
    The output of a pass says whether a digest was checked."""
    from autopilot.shared.telemetry.files import verify_rrd
    from autopilot.shared.telemetry.integrity import digest_path, digest_problem, stream_problem

    problem = unreadable(path)
    if problem:
        return False, problem
    problem = stream_problem(path, footers=check_footers)
    if problem:
        return False, problem
    has_digest, problem = digest_problem(path)
    if problem:
        return False, problem
    ok, text = verify_rrd(path, check_footers=check_footers)
    if ok and has_digest:
        text = f"sha256 matches {digest_path(path).name}\n{text}"
    return ok, text


def checked(text: str) -> str:
    """What a passed :func:`verify` checked, for its one line: ``" (sha256 matches FILE.sha256)"`` or ``""``."""
    first = text.strip().splitlines()[0] if text.strip() else ""
    return f" ({first})" if first.startswith("sha256 matches") else ""


def merge(out: str | os.PathLike, parts: list, *, blueprint: bool = True, concatenate: bool = False):
    """Join the part files of one flight into ``out``; adds the flight blueprint unless a part carries one
    (a file never holds two competing layouts) or ``blueprint`` is False.  Returns the output path.

    ``concatenate``: copy the parts' messages in constant memory (no footer; for long flights) instead of
    ``rerun rrd merge`` (compacted, with a footer; memory about twice the parts' size)."""
    from autopilot.shared.telemetry.files import concatenate_recordings, merge_recordings

    layout = None
    if blueprint and not any(os.path.isfile(p) and has_blueprint(p) for p in parts):
        from tools.view.views import flight_blueprint

        layout = flight_blueprint()
    if not concatenate:
        return merge_recordings(parts, out, blueprint=layout)
    present = [p for p in parts if os.path.isfile(p) and os.path.getsize(p) > 0]
    rid = recordings(present[0])[0][1] if present and layout is not None else None
    return concatenate_recordings(parts, out, blueprint=layout, recording_id=rid)


def record(out: str | os.PathLike, spools: list, *, blueprint: bool = True):
    """Record the telemetry spools of one flight (``--telemetry-spool``) into ``out``: one recording (sent through
    the live writers' ``RerunSink``, ``autopilot.shared.telemetry.record_spools``) with the flight blueprint and
    rerun's footer, written in one pass as the launcher writes ``flight.rrd``.  Returns the output path."""
    import tempfile

    from autopilot.shared.telemetry import check_recording_target, install_recording, record_spools

    out = os.fspath(out)
    check_recording_target(out)
    layout = None
    if blueprint:
        from tools.view.views import flight_blueprint

        layout = flight_blueprint()
    with tempfile.TemporaryDirectory(prefix=".rrd-record-", dir=os.path.dirname(os.path.abspath(out))) as tmp:
        part = os.path.join(tmp, "part.rrd")
        record_spools(spools, part, write_footer=True, blueprint=layout)
        return install_recording(part, out)


def summary(path: str | os.PathLike) -> str:
    lines = [f"{path}: {os.path.getsize(path) / 1e6:.2f} MB"]
    for app, rid in recordings(path):
        lines.append(f"recording {rid} (application {app})")
        for ep, sig in sorted(load(path, recording_id=rid).items()):
            span = f"{sig.t[0]:.3f}..{sig.t[-1]:.3f} s" if len(sig.t) else "-"
            lines.append(f"  {ep:32s} {len(sig.t):8d} rows  {span:22s} {', '.join(sig.names)}")
        for ep, states in sorted(load_states(path, recording_id=rid).items()):
            lines.append(f"  {ep:32s} {len(states):8d} states: " + ", ".join(s for _, s in states[:8]))
        for ep, texts in sorted(load_texts(path, recording_id=rid).items()):
            lines.append(f"  {ep:32s} {len(texts):8d} events" + (":" if texts else ""))
            lines += [f"      {t:9.3f} s  {text}" for t, text in texts[:10]]
            if len(texts) > 10:
                lines.append(f"      ... {len(texts) - 10} more")
    lines.append(f"blueprint: {'yes' if has_blueprint(path) else 'no'}")
    return "\n".join(lines)


def _first_error(text: str) -> str:
    """The one line of a verification's output that says what is wrong (rerun prints the file, then why)."""
    lines = [ln.strip() for ln in text.strip().splitlines() if ln.strip()]
    why = [ln for ln in lines if not ln.startswith("Error: Verification failed")]
    return (why or lines or ["failed"])[0]
