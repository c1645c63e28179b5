"""Real-time set-up of the control thread (``autopilot.shared.mavlink.apply_rt_priority``, ``move_other_threads``).

Run in a child interpreter so that pytest's own process is never put under SCHED_FIFO.  Needs the right
to use SCHED_FIFO (root or CAP_SYS_NICE); skipped where the kernel refuses it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

CHILD = r"""
import json, os, threading
from autopilot.shared.process import apply_rt_priority

def policy():
    return os.sched_getscheduler(0) & ~getattr(os, "SCHED_RESET_ON_FORK", 0)

out = {}
started = policy()  # what the process inherited: SCHED_OTHER, or SCHED_IDLE beside the suite's real-time lane
ready, done = threading.Event(), threading.Event()
def helper_before():
    ready.set(); done.wait(5); out["before"] = policy()
t = threading.Thread(target=helper_before); t.start(); ready.wait(5)
note = apply_rt_priority(int(os.environ["PRIO"]), "test")
out["note"] = note
out["main"] = policy()
out["main_prio"] = os.sched_getparam(0).sched_priority
def helper_after():
    out["after"] = policy()
t2 = threading.Thread(target=helper_after); t2.start(); t2.join()
done.set(); t.join()
out["fifo"], out["other"], out["started"] = os.SCHED_FIFO, os.SCHED_OTHER, started
print(json.dumps(out))
"""


def _run(prio: int) -> tuple[dict, str]:
    env = dict(os.environ, PRIO=str(prio))
    r = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout), r.stderr


@pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="no POSIX scheduling API")
def test_only_the_control_thread_runs_fifo():
    out, err = _run(10)
    if not out["note"]:
        pytest.skip(f"SCHED_FIFO not permitted here: {err.strip()}")
    assert out["main"] == out["fifo"] and out["main_prio"] == 10
    # A helper started before (telemetry writer, rerun's threads) keeps the policy the process started with (normal,
    # or idle in the suite's parallel phase) and one started after is a normal one (SCHED_RESET_ON_FORK), so neither
    # can hold the control thread off its CPU at equal FIFO priority.
    assert out["before"] == out["started"]
    assert out["after"] == out["other"]


def test_priority_zero_changes_nothing():
    out, _ = _run(0)
    assert out["note"] == ""
    assert out["main"] == out["before"] == out["after"] == out["started"]  # what the process started with


MOVE_CHILD = r"""
import json, os, threading
from autopilot.shared.process import move_other_threads

os.sched_setaffinity(0, {1})  # the whole process on CPU 1, as --cpu 1 does
ready, done = threading.Event(), threading.Event()
tid = {}
def helper():
    tid["id"] = threading.get_native_id(); ready.set(); done.wait(5)
t = threading.Thread(target=helper); t.start(); ready.wait(5)
moved = move_other_threads(1)
out = {"moved": moved, "main": sorted(os.sched_getaffinity(0)), "helper": sorted(os.sched_getaffinity(tid["id"]))}
done.set(); t.join()
print(json.dumps(out))
"""


@pytest.mark.skipif(
    not hasattr(os, "sched_setaffinity") or (os.cpu_count() or 1) < 2 or not {0, 1} <= os.sched_getaffinity(0),
    reason="needs CPUs 0 and 1 and per-thread affinity",
)
def test_busy_wait_moves_helper_threads_off_the_control_cpu():
    r = subprocess.run([sys.executable, "-c", MOVE_CHILD], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["moved"] >= 1
    assert out["main"] == [1]  # the control thread keeps its CPU
    assert 1 not in out["helper"] and 0 in out["helper"]
