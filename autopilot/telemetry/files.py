"""One recording per flight from several processes: part files merged with ``rerun rrd merge``.

Each process writes its own part (``DIR/.parts/autopilot.rrd``, ``DIR/.parts/sitl.rrd``) with the
same application id and recording id.  At the end the launcher calls ``merge_recordings`` which
runs ``rerun rrd merge`` (it recognises the shared store id and writes ONE recording, compacting the
chunks and writing a footer) and, if asked, adds the flight blueprint.  A part left without footer by
a SIGKILL is still merged: rerun reads every complete message and stops at the torn tail.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path

from autopilot.telemetry import layout as L
from autopilot.telemetry.writer import rerun_cli_path


class RrdError(RuntimeError):
    """A rerun CLI operation on .rrd files failed; the message carries rerun's own last lines."""


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
    blueprint: object | bool | str = "auto",
    application_id: str = L.APPLICATION_ID,
    remove_parts: bool = False,
    timeout_s: float = 120.0,
) -> Path:
    """Merge part files into ``out_path`` with ``rerun rrd merge``; returns the output path.

    ``blueprint``: ``"auto"`` (add the flight blueprint only if no part carries one, so the file never
    holds two competing layouts), False (keep whatever the parts carry), True (always add the flight
    blueprint) or a ``rerun.blueprint.Blueprint`` to add.  Missing or empty parts are skipped (a process that never
    started); if no part is left, RrdError.  ``remove_parts`` deletes the parts after a successful
    merge.
    """
    out = Path(out_path)
    present = [Path(p) for p in parts if Path(p).is_file() and Path(p).stat().st_size > 0]
    if not present:
        raise RrdError(f"no recording to merge: none of {[str(p) for p in parts]} exists or has data")
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="rrd-merge-") as tmp:
        inputs = [str(p) for p in present]
        if isinstance(blueprint, str) and blueprint == "auto":
            blueprint = not any(_has_blueprint_store(p) for p in present)
        if blueprint is not False and blueprint is not None:
            if blueprint is True:
                from autopilot.telemetry.blueprints import flight_blueprint

                blueprint = flight_blueprint()
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


def _has_blueprint_store(path: Path) -> bool:
    import warnings

    from rerun.chunk import RrdReader

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return bool(RrdReader(str(path)).blueprints())
    except Exception:  # noqa: BLE001 - unreadable part: rrd merge will say so
        return False


def verify_rrd(path: str | os.PathLike, *, check_footers: bool = True, timeout_s: float = 120.0) -> tuple[bool, str]:
    """Run ``rerun rrd verify`` on ``path``: (ok, rerun's output).  Footers are required by default."""
    cmd = [rerun_cli_path(), "rrd", "verify", f"--check-footers={'true' if check_footers else 'false'}", str(path)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, env=_cli_env())
    return proc.returncode == 0, _tail(proc.stdout + "\n" + proc.stderr)


def part_paths(out_dir: str | os.PathLike, processes: Sequence[str] = ("autopilot", "sitl")) -> dict[str, Path]:
    """Where each process of a flight writes its part: ``OUT/.parts/<process>.rrd``."""
    base = Path(out_dir) / ".parts"
    return {p: base / f"{p}.rrd" for p in processes}
