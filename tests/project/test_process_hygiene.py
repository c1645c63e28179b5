"""No flight's process outlives the tests that started it: every SITL, autopilot, GCS script and launcher a test
started has ended by the time the next test runs.

These tests are also the suite's barrier (``tests/conftest.py``): a worker waiting for the real-time phase runs one
of them, so the last test it held runs first, and then they check that it left nothing behind.  Run on their own,
they check whatever ran before them on this process.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

# ``python -m MODULE`` of each process a flight runs (tools.launch starts the other three)
FLIGHT_MODULES = ("sitl", "autopilot", "tools.gcs", "tools.launch")
PROC = Path("/proc")


def _parents() -> dict[int, int]:
    """{pid: parent pid} of every process now (Linux's /proc; a process gone while read is left out)."""
    out = {}
    for d in PROC.iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            out[int(d.name)] = int(stat.rsplit(")", 1)[1].split()[1])  # the field after the state
    return out


def descendants(pid: int, parents: dict[int, int]) -> list[int]:
    children: dict[int, list[int]] = {}
    for child, parent in parents.items():
        children.setdefault(parent, []).append(child)
    out, todo = [], [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            out.append(c)
            todo.append(c)
    return out


def module_of(pid: int) -> str | None:
    """The MODULE of ``python -m MODULE``, or None (another program, a zombie, or a process gone)."""
    try:
        argv = (PROC / str(pid) / "cmdline").read_bytes().split(b"\0")
    except OSError:
        return None
    for a, b in zip(argv, argv[1:]):
        if a == b"-m":
            return b.decode(errors="replace")
    return None


def test_descendants_are_found_through_every_generation():
    parents = {2: 1, 3: 2, 4: 3, 5: 1, 6: 9}  # 1 -> 2 -> 3 -> 4, 1 -> 5; 6 is another tree's
    assert sorted(descendants(1, parents)) == [2, 3, 4, 5] and descendants(4, parents) == []


@pytest.mark.skipif(not (PROC / "self" / "stat").exists(), reason="needs Linux's /proc")
@pytest.mark.parametrize("k", range(4))
def test_no_flight_process_outlives_the_tests_before(k):
    left = [(pid, m) for pid in descendants(os.getpid(), _parents()) if (m := module_of(pid)) in FLIGHT_MODULES]
    assert not left, f"processes of earlier tests still running: {left}"
