"""A real small disk for the full-disk tests: a tmpfs of a few hundred kB mounted on a test's folder (root only:
skipped with the reason otherwise), filled to a chosen number of free bytes, and the leftovers a command must not
leave (temporary files, space reserves)."""

from __future__ import annotations

import contextlib
import os
import subprocess
from pathlib import Path

import pytest


@contextlib.contextmanager
def small_disk(where: Path, size_kb: int = 200):
    """A tmpfs of ``size_kb`` kB mounted on ``where`` (made if missing), unmounted at the end."""
    where.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", str(where)], capture_output=True, text=True
    )
    if r.returncode != 0:
        pytest.skip(f"cannot mount a {size_kb} kB tmpfs here: {(r.stderr or r.stdout).strip() or r.returncode}")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], capture_output=True)


def free_bytes(disk: Path) -> int:
    st = os.statvfs(disk)
    return st.f_bavail * st.f_frsize


def fill(disk: Path, leave_kb: int = 0) -> Path:
    """Fill ``disk`` with one file until ``leave_kb`` kB are free (0: until a write fails for want of space)."""
    filler = disk / "filler"
    with open(filler, "wb", buffering=0) as f:  # unbuffered: every failed write fails here
        n = max(free_bytes(disk) - leave_kb * 1024, 0)
        try:
            f.write(b"\0" * n)
            if not leave_kb:
                while True:
                    f.write(b"\0" * 4096)
                    f.flush()
        except OSError:
            pass
    assert leave_kb or free_bytes(disk) == 0
    return filler


def leftovers(folder: Path) -> list[str]:
    """Files a command must not leave: temporary files (``*.tmp``) and space reserves (``*.reserve``)."""
    return sorted(str(p) for p in folder.rglob("*") if p.name.endswith((".tmp", ".reserve")))
