"""One recording from several processes: recording ids, part files, ``rerun rrd merge`` and ``rrd verify``.

Each process of a flight writes its own part (``DIR/.parts/<process>.rrd``) with the same application id
and recording id.  At the end the launcher calls ``merge_recordings``, which runs ``rerun rrd merge``
(it recognises the shared store id and writes ONE recording, compacting the chunks and writing a
footer) and adds the viewer layout it is given.  A part left without footer by a SIGKILL is still
merged: rerun reads every complete message and stops at the torn tail.  No rerun import here: the
rerun CLI does the work.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import uuid
from collections.abc import Sequence
from pathlib import Path

from autopilot.shared.telemetry.layout import APPLICATION_ID
from autopilot.shared.telemetry.viewer import rerun_cli_path


class RrdError(RuntimeError):
    """A rerun CLI operation on .rrd files failed; the message carries rerun's own last lines."""


def new_recording_id() -> str:
    """A fresh recording id for one flight; give the same one to every process of that flight."""
    return str(uuid.uuid4())


def part_paths(out_dir: str | os.PathLike, processes: Sequence[str] = ("autopilot", "sitl")) -> dict[str, Path]:
    """Where each process of a flight writes its part: ``OUT/.parts/<process>.rrd``."""
    base = Path(out_dir) / ".parts"
    return {p: base / f"{p}.rrd" for p in processes}


def _cli_env() -> dict[str, str]:
    env = dict(os.environ)
    env.setdefault("RUST_LOG", "warn")  # rrd merge is chatty at INFO
    return env


def _tail(text: str, n: int = 6) -> str:
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    return "\n".join(lines[-n:])


def merge_recordings(
    parts: Sequence[str | os.PathLike],
    out_path: str | os.PathLike,
    *,
    blueprint=None,
    application_id: str = APPLICATION_ID,
    remove_parts: bool = False,
    timeout_s: float = 120.0,
) -> Path:
    """Merge part files into ``out_path`` with ``rerun rrd merge``; returns the output path.

    ``blueprint``: a ``rerun.blueprint.Blueprint`` to add (saved for ``application_id``), or None to keep
    whatever the parts carry.  Missing or empty parts are skipped (a process that never started); if no
    part is left, RrdError.  ``remove_parts`` deletes the parts after a successful merge.
    """
    out = Path(out_path)
    present = [Path(p) for p in parts if Path(p).is_file() and Path(p).stat().st_size > 0]
    if not present:
        raise RrdError(f"no recording to merge: none of {[str(p) for p in parts]} exists or has data")
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="rrd-merge-") as tmp:
        inputs = [str(p) for p in present]
        if blueprint is not None:
            rbl = Path(tmp) / "blueprint.rbl"
            blueprint.save(application_id, str(rbl))
            inputs.append(str(rbl))
        tmp_out = Path(tmp) / "merged.rrd"
        cmd = [rerun_cli_path(), "rrd", "merge", "--continue-on-error", "-o", str(tmp_out), *inputs]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, env=_cli_env())
        if proc.returncode != 0 or not tmp_out.is_file():
            raise RrdError(f"rerun rrd merge failed (exit {proc.returncode}): {_tail(proc.stderr)}")
        shutil.move(str(tmp_out), str(out))
    if remove_parts:
        for p in present:
            p.unlink(missing_ok=True)
    return out


def verify_rrd(path: str | os.PathLike, *, check_footers: bool = True, timeout_s: float = 120.0) -> tuple[bool, str]:
    """Run ``rerun rrd verify`` on ``path``: (ok, rerun's output).  Footers are required by default."""
    cmd = [rerun_cli_path(), "rrd", "verify", f"--check-footers={'true' if check_footers else 'false'}", str(path)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, env=_cli_env())
    return proc.returncode == 0, _tail(proc.stdout + "\n" + proc.stderr)
