"""Whether work at idle priority, started as the launcher starts a flight's processes, leaves a real-time loop alone.

    python -m tools.bench isolation [--quick]      (or: python -m tools.bench.isolation [--periods N] [--per-cpu K])

A probe in this process (normal priority) sleeps to a 10 ms deadline ``--periods`` times (1200) and counts the
periods it woke more than ``LATE_MS`` (2 ms) late, with ``--per-cpu`` busy loops per CPU (2) beside it, in three
set-ups:

* ``quiet``: no busy loop (the machine's own noise);
* ``launcher``: each busy loop lowers itself to ``SCHED_IDLE`` (nice 19 where refused) and is started by
  ``tools.flight.children.Child``, as the launcher starts the SITL and the autopilot: a process group of its own in
  this session;
* ``own_session``: the same busy loops, each started in a session of its own (``start_new_session``, what the
  launcher did before).  With the kernel's autogroups on (``/proc/sys/kernel/sched_autogroup_enabled``), each session
  is a scheduling group of its own at full weight, whatever the priority of the tasks in it, so an idle-priority
  busy loop there competes with the probe as an equal.

This is what lets the suite fly its real-time tests beside CPU-bound tests on idle-priority workers (docs/tests.md,
"Parallel"): the target is on ``launcher`` (at most ``TARGET_LATE`` of the periods late); ``own_session`` is shown
for comparison only.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from tools.bench import figure, machine_load, percentile, report

QUICK_ARGV = ["--quick"]
PERIOD_S = 0.010  # the real-time flights' 100 Hz step
LATE_MS = 2.0  # a period counts as late when the probe wakes this much after its deadline
TARGET_LATE = 0.01  # at most 1 % of the periods late beside idle-priority work started as the launcher starts it
BUSY_LOOP = (
    "import os\n"
    "try:\n"
    "    os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))\n"
    "except (AttributeError, OSError):\n"
    "    os.setpriority(os.PRIO_PROCESS, 0, 19)\n"
    "print('spinning', flush=True)\n"
    "while True:\n"
    "    pass\n"
)


def probe(periods: int) -> list[float]:
    """How late (ms) this process woke for each of ``periods`` 10 ms deadlines (absolute deadlines, as the SITL's
    real-time loop keeps them: a late period does not shift the next)."""
    lateness = []
    deadline = time.monotonic() + PERIOD_S
    for _ in range(periods):
        time.sleep(max(0.0, deadline - time.monotonic()))
        lateness.append(max(0.0, (time.monotonic() - deadline) * 1000.0))
        deadline += PERIOD_S
    return lateness


def busy_loops(how: str, n: int, folder: Path) -> list:
    """``n`` busy loops started ``how`` (``launcher`` or ``own_session``), each spinning once this returns."""
    import subprocess

    from tools.flight.children import Child

    argv = [sys.executable, "-c", BUSY_LOOP]
    if how == "launcher":
        loops = [Child(f"busy{i}", argv, folder / f"busy{i}.log", False, ready_marker="spinning") for i in range(n)]
        if not all(loop.ready.wait(30) and loop.marker_seen for loop in loops):
            stop(loops)
            raise RuntimeError(f"a busy loop did not start (its log: {folder})")
        return loops
    loops = [
        subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, text=True, start_new_session=True)
        for _ in range(n)
    ]
    for loop in loops:
        loop.stdout.readline()
    return loops


def stop(loops: list) -> None:
    from tools.flight.children import Child, stop_children

    children = [p for p in loops if isinstance(p, Child)]
    stop_children(children)
    for p in loops:
        if not isinstance(p, Child):
            p.kill()
            p.wait()
            p.stdout.close()


def autogroups() -> str:
    try:
        return {"0": "off", "1": "on"}.get(Path("/proc/sys/kernel/sched_autogroup_enabled").read_text().strip(), "?")
    except OSError:
        return "n/a"


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m tools.bench.isolation", description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="400 periods per set-up instead of 1200")
    p.add_argument("--periods", type=int, default=None, help="10 ms periods per set-up (default 1200, quick 400)")
    p.add_argument("--per-cpu", type=int, default=2, help="busy loops per CPU (default 2)")
    args = p.parse_args(argv or [])
    periods = args.periods or (400 if args.quick else 1200)
    if periods < 1 or args.per_cpu < 1:
        p.error("--periods and --per-cpu must be at least 1")
    load = machine_load()
    cpus = os.cpu_count() or 1
    loops_n = args.per_cpu * cpus
    figs = {}
    with tempfile.TemporaryDirectory(prefix="bench-isolation-") as tmp:
        for how in ("quiet", "launcher", "own_session"):
            loops = [] if how == "quiet" else busy_loops(how, loops_n, Path(tmp))
            try:
                lateness = probe(periods)
            finally:
                stop(loops)
            late = sum(x > LATE_MS for x in lateness)
            p99, worst = round(percentile(lateness, 99.0), 2), round(max(lateness), 1)
            target = TARGET_LATE if how == "launcher" else None
            figs[f"isolation_{how}_late"] = figure(
                late / periods, "", target, late=late, of=periods, p99_ms=p99, max_ms=worst
            )
    report(
        f"a 10 ms loop beside {loops_n} idle-priority busy loop(s): periods > {LATE_MS:g} ms late, autogroups "
        f"{autogroups()}, load {load['load1']} on {load['cpus']} CPU(s)",
        figs,
    )
    return figs


if __name__ == "__main__":
    main(sys.argv[1:])
