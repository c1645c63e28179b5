"""The flight layout (``tools.view.views.flight_blueprint``) saved once as a ``.rbl`` file and reused by every flight.

Building the layout needs ``rerun`` imported (about 0.3 s of the launcher's 2 s on the 2-core VM), for a file that
is the same for every flight of one version of the code.  So the launcher keeps the saved layout in a cache folder
and hands the file to ``rerun rrd merge`` as it is (``autopilot.shared.telemetry.merge_recordings``'s
``blueprint_file``); a flight's ``flight.rrd`` holds the same blueprint store (the same views, entities and
properties) as when it was built for that flight.

The file is valid while nothing it was built from changed: next to it a JSON file records the fingerprint of the
installed rerun (its native module and package files: path, size, modification time) and the SHA-256 of every
project source file that was loaded when the layout was built (``tools.view.views`` and what it imports, and, to be
safe,
every other project module the process had loaded).  Any difference, a missing or unreadable file: the layout is
built again and the cache rewritten (atomically: a concurrent launcher reads the old or the new file, never a torn
one).  A layout that cannot be cached (no writable folder) is built in the process, as before.

The folder: ``$CLSAC_CACHE_DIR``, else ``$XDG_CACHE_HOME/clsac-autopilot``, else ``~/.cache/clsac-autopilot``; one
slot per checkout (named by a hash of its root), flight span (the plots' visible time range, ``span``: a flight of
the same start clock and length reuses it) and rudder limit (the Rudder plot's fixed range, ``rudder_limit_deg``),
so two worktrees of different code do not evict each other.  At most
``MAX_LAYOUTS`` layouts are kept per checkout: the least recently used beyond are removed.
``CLSAC_CACHE_DIR=off`` turns the cache off.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import tempfile
from importlib.util import find_spec
from pathlib import Path

from autopilot.shared.process import standard_json

ROOT = Path(__file__).resolve().parents[2]  # the checkout: autopilot/, sitl/, tools/
_FORMAT = 3  # bump when the meaning of the JSON changes (2: the span; 3: the rudder's limit)
MAX_LAYOUTS = 16  # layouts kept per checkout (one per flight span)


def cache_dir() -> Path | None:
    """Where the layout is cached, or None when ``CLSAC_CACHE_DIR=off``."""
    given = os.environ.get("CLSAC_CACHE_DIR")
    if given:
        return None if given.lower() == "off" else Path(given)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "clsac-autopilot"


def _rerun_fingerprint() -> list:
    """The installed rerun, without importing it: (path, size, mtime_ns) of its native module and package file."""
    out = []
    for name in ("rerun_bindings", "rerun"):
        spec = find_spec(name)
        origin = spec.origin if spec is not None else None
        if origin and os.path.isfile(origin):
            st = os.stat(origin)
            out.append([origin, st.st_size, st.st_mtime_ns])
        else:
            out.append([name, None, None])
    return out


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _project_sources() -> dict[str, str]:
    """SHA-256 of the source file of every project module loaded in this process (relative path -> digest)."""
    out = {}
    for mod in list(sys.modules.values()):
        f = getattr(mod, "__file__", None)
        if not f or not f.endswith(".py"):
            continue
        p = Path(f).resolve()
        try:
            rel = p.relative_to(ROOT)
        except ValueError:
            continue
        if rel.parts[0] in ("autopilot", "sitl", "tools"):
            out[rel.as_posix()] = _sha256(p)
    return dict(sorted(out.items()))


def _span_key(span) -> list | None:
    """The span as exact integers (ns), or None (no span: the whole timeline)."""
    return None if span is None else [round(float(t) * 1e9) for t in span]


def _checkout() -> str:
    return hashlib.sha256(str(ROOT).encode()).hexdigest()[:12]


def _limit_key(rudder_limit_deg) -> str | None:
    return None if rudder_limit_deg is None else repr(float(rudder_limit_deg))


def _paths(application_id: str, span=None, rudder_limit_deg=None) -> tuple[Path, Path] | None:
    d = cache_dir()
    if d is None:
        return None
    key = f"{ROOT}\0{application_id}\0{_span_key(span)}\0{_limit_key(rudder_limit_deg)}"
    slot = hashlib.sha256(key.encode()).hexdigest()[:16]
    name = f"flight-blueprint-{_checkout()}-{slot}"
    return d / f"{name}.rbl", d / f"{name}.json"


def _prune(keep: Path) -> None:
    """Remove this checkout's layouts beyond the ``MAX_LAYOUTS`` most recently used (``keep`` stays)."""
    try:
        layouts = sorted(keep.parent.glob(f"flight-blueprint-{_checkout()}-*.rbl"), key=lambda p: p.stat().st_mtime_ns)
        for old in [p for p in layouts if p != keep][: max(0, len(layouts) - MAX_LAYOUTS)]:
            old.with_suffix(".json").unlink(missing_ok=True)
            old.unlink(missing_ok=True)
    except OSError:
        pass  # another launcher pruned them meanwhile


def _valid(rbl: Path, meta_path: Path, application_id: str, span=None, rudder_limit_deg=None) -> bool:
    try:
        meta = json.loads(meta_path.read_text())
        if (
            meta.get("format") != _FORMAT
            or meta.get("application_id") != application_id
            or meta.get("span_ns") != _span_key(span)
            or meta.get("rudder_limit_deg") != _limit_key(rudder_limit_deg)
            or meta.get("python") != list(sys.version_info[:2])
            or meta.get("rerun") != _rerun_fingerprint()
            or not rbl.is_file()
            or rbl.stat().st_size == 0
        ):
            return False
        deps = meta.get("sources")
        return bool(deps) and all(_sha256(ROOT / rel) == digest for rel, digest in deps.items())
    except (OSError, ValueError, TypeError, AttributeError):
        return False


def _write_atomic(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def flight_blueprint_file(application_id: str | None = None, span=None, rudder_limit_deg=None) -> Path | None:
    """The saved flight layout for the flight ``span`` (start, end sim s) and rudder limit (deg, the Rudder plot's
    range; ``tools.view.views.flight_blueprint``), built now if the cache has none for this code, this rerun, this
    span and this limit, or None if it cannot be cached (then the caller builds the layout itself)."""
    from autopilot.shared.telemetry.files import RRD_FIXED_BYTES, check_room
    from autopilot.shared.telemetry.layout import APPLICATION_ID

    application_id = application_id or APPLICATION_ID
    paths = _paths(application_id, span, rudder_limit_deg)
    if paths is None:
        return None
    rbl, meta_path = paths
    if _valid(rbl, meta_path, application_id, span, rudder_limit_deg):
        try:
            os.utime(rbl)  # used: the last to be pruned
        except OSError:
            pass
        return rbl
    try:
        rbl.parent.mkdir(parents=True, exist_ok=True)
        from tools.view.views import flight_blueprint

        with tempfile.TemporaryDirectory(prefix=".flight-blueprint-", dir=rbl.parent) as tmp:
            built = Path(tmp) / "flight.rbl"
            # blueprint.save writes with rerun's FileSink, which can hang for good on a full disk (telemetry.files)
            check_room(built, RRD_FIXED_BYTES, "the layout")
            flight_blueprint(span, rudder_limit_deg=rudder_limit_deg).save(application_id, str(built))
            data = built.read_bytes()
        meta = {
            "format": _FORMAT,
            "application_id": application_id,
            "span_ns": _span_key(span),
            "rudder_limit_deg": _limit_key(rudder_limit_deg),
            "python": list(sys.version_info[:2]),
            "rerun": _rerun_fingerprint(),
            "sources": _project_sources(),
        }
        _write_atomic(rbl, data)
        _write_atomic(meta_path, standard_json(meta, indent=1).encode())
    except OSError:
        return None
    _prune(rbl)
    return rbl
