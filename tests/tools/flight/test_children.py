"""How the launcher starts a flight's processes (``tools.flight.children.Child``): each a process group of its own,
so the terminal's Ctrl-C reaches the launcher only, in the launcher's session, so the kernel weighs it with the
launcher (its autogroup) and the launcher's priority holds for its flight."""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

import pytest

from tools.flight.children import Child, stop_children

REPORT = (
    "import os, signal\n"
    "signal.signal(signal.SIGINT, signal.SIG_DFL)\n"  # taken even if inherited ignored, as the flight's processes do
    "from pathlib import Path\n"
    "group = Path('/proc/self/autogroup')\n"
    "print('ids', os.getpid(), os.getpgid(0), os.getsid(0), flush=True)\n"
    "words = group.read_text().split() if group.exists() else []\n"
    "print('autogroup', words[0] if words else '-', flush=True)\n"
    "import time\n"
    "time.sleep(60)\n"
)


def _own_autogroup() -> str | None:
    """This process's autogroup, or None: no autogroups in the kernel, or the file is empty (as on the CI machine):
    the process is in the root autogroup, which the kernel does not name, and there sessions are not weighed apart."""
    group = Path("/proc/self/autogroup")
    words = group.read_text().split() if group.exists() else []
    return words[0] if words else None


def _line(child: Child, word: str) -> list[str]:
    for line in child.tail:
        if line.startswith(word + " "):
            return line.split()[1:]
    raise AssertionError(f"{child.name} said no {word!r} line: {child.tail}")


@pytest.fixture
def child(tmp_path: Path):
    c = Child("report", [sys.executable, "-c", REPORT], tmp_path / "report.log", False, ready_marker="autogroup")
    try:
        assert c.ready.wait(60) and c.marker_seen, c.tail
        yield c
    finally:
        stop_children([c])


def test_a_child_is_a_process_group_of_its_own_in_the_launchers_session(child):
    pid, pgid, sid = (int(x) for x in _line(child, "ids"))
    assert pid == child.proc.pid
    assert pgid == pid != os.getpgid(0)  # not in the terminal's foreground group: Ctrl-C reaches the launcher only
    assert sid == os.getsid(0)  # not a session of its own


@pytest.mark.skipif(_own_autogroup() is None, reason="this process is in no autogroup")
def test_a_child_shares_the_launchers_autogroup(child):
    """A session of its own would be an autogroup of its own, weighed as a desktop session at full weight, whatever the
    launcher's nice or SCHED_IDLE (docs/tests.md, "Parallel"; ``python -m tools.bench isolation``)."""
    (group,) = _line(child, "autogroup")
    assert group == _own_autogroup()


def test_stop_children_ends_a_child_and_its_log_keeps_its_lines(tmp_path):
    """``stop_children`` ends a child that would run on, by SIGINT to its own process (not the SIGKILL after the
    grace), and what it printed is in its log."""
    c = Child("report", [sys.executable, "-c", REPORT], tmp_path / "report.log", False, ready_marker="autogroup")
    assert c.ready.wait(60) and c.marker_seen, c.tail
    stop_children([c])
    assert c.code == -signal.SIGINT  # not the 60 s sleep's end, nor the kill after the grace
    log = (tmp_path / "report.log").read_text()
    assert "ids " in log and "autogroup " in log
