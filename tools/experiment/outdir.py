"""The output folder of an experiment or a study: checked before anything runs, created, a default name.

Used by ``tools.experiment`` and ``tools.experiment.study`` alike (neither imports the other for it).
"""

from __future__ import annotations

import datetime as _dt
import os
import tempfile
from pathlib import Path

SUMMARY_RESERVE_BYTES = 1024 * 1024  # held while a study flies, for its summary.json on a full disk


class OutDirError(ValueError):
    """An output folder that cannot be created or written; the message is one line and names the path."""


def prepare_out_dir(out_dir: str | os.PathLike) -> Path:
    """Create ``out_dir`` if needed and check that files can be written in it."""
    path = Path(out_dir)
    if path.exists() and not path.is_dir():
        raise OutDirError(f"output directory {str(path)!r} exists and is not a directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-test-"):
            pass
    except OSError as exc:
        raise OutDirError(f"cannot write to output directory {str(path)!r}: {exc.strerror or exc}") from None
    return path


def check_out_dir(out_dir: str | os.PathLike) -> Path:
    """Reject an output path that cannot become a folder, without creating anything."""
    path = Path(out_dir)
    if path.exists():
        if not path.is_dir():
            raise OutDirError(f"output directory {str(path)!r} exists and is not a directory")
        probe = path
    else:
        probe = path.absolute().parent
        while not probe.exists():
            probe = probe.parent
        if not probe.is_dir():
            raise OutDirError(f"cannot create output directory {str(path)!r}: {str(probe)!r} is not a directory")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutDirError(f"cannot write to output directory {str(path)!r}: {str(probe)!r} is not writable")
    return path


def default_out_dir(scenario: str = "paper", root: str | os.PathLike = "runs") -> Path:
    """A new folder ``runs/<scenario>-YYYYmmdd-HHMMSS[-n]`` (relative to the working directory)."""
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    base = Path(root) / f"{scenario}-{stamp}"
    path, n = base, 1
    while path.exists():
        path = base.with_name(f"{base.name}-{n}")
        n += 1
    return path


def hold_space(out: Path, nbytes: int = SUMMARY_RESERVE_BYTES):
    """Disk space held in ``out`` for its summary.json (``autopilot.shared.process.SpaceReserve``, a hidden file):
    pass it to ``write_json_atomic(reserve=...)`` and ``release()`` it at the end, whatever happened."""
    from autopilot.shared.process import reserve_for

    return reserve_for(Path(out) / "summary.json", nbytes)


def write_summary(out: str | os.PathLike, doc: dict, problems: list[str], reserve=None, *, indent: int = 2):
    """``out``/summary.json, standard JSON replaced atomically (``autopilot.shared.process.write_json_atomic``: on a
    full disk the space ``reserve`` holds, :func:`hold_space`, is released and the write tried again): its path, or
    None and a line in ``problems`` (:func:`write_problem`) when it cannot be written."""
    from autopilot.shared.process import write_json_atomic

    path = Path(out) / "summary.json"
    try:
        write_json_atomic(path, doc, indent=indent, reserve=reserve)
    except OSError as exc:
        problems.append(write_problem(path, exc))
        return None
    return path


def write_figure(path: Path, draw, problems: list[str], log=print, not_drawn: str | None = None):
    """``draw()``'s value (it writes the figure ``path``), or None.  A file that cannot be written (a full disk) is
    a line in ``problems``; a figure that cannot be drawn (its own error) never fails what wrote the numbers: a line
    to ``log``, ``NOT_DRAWN: error`` (default ``NAME not drawn``).  Either way no half file is left."""
    try:
        return draw()
    except OSError as exc:  # a full disk: no half picture left
        path.unlink(missing_ok=True)
        problems.append(write_problem(path, exc))
    except Exception as exc:  # noqa: BLE001  (the figure's own error: the numbers are written)
        path.unlink(missing_ok=True)
        log(f"{not_drawn or f'{path.name} not drawn'}: {one_line(exc)}")
    return None


def write_problem(path: str | os.PathLike, exc: Exception) -> str:
    """The line for an output that could not be written: ``could not write PATH: reason``."""
    return f"could not write {os.fspath(path)}: {getattr(exc, 'strerror', None) or one_line(exc)}"


def one_line(exc: BaseException) -> str:
    """An error's first line, with its type: ``ValueError: ...``."""
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text.splitlines()[0]}" if text else type(exc).__name__
