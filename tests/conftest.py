"""Shared fixtures, and how the suite runs in parallel (docs/tests.md, "Parallel").

Slow tests that start real processes carry the ``e2e`` marker: ``python -m pytest -m "not e2e"`` runs the fast ones
in seconds.  ``python -m pytest`` runs on pytest-xdist workers (``addopts`` in pyproject.toml: ``-n auto``, four on
2 cores), in two kinds of lane side by side (``pytest_xdist_make_scheduler``):

* **Two real-time lanes**, at the normal priority.  The modules whose tests fly in real time and assert its timing
  (``REAL_TIME``: deadlines, stalls, failsafe latencies, sim time against the wall clock) run on at most two
  workers, one module after the other on each.  They use little CPU, but need it on time: two side by side keep
  their timing.  A module that takes the whole machine (``ALONE``: two processes busy-waiting on both CPUs; floods
  of 10,000 datagrams a second) holds a lock that keeps the other real-time lane waiting meanwhile (``_lane``).
* **A CPU lane per CPU (at least two)**, at the lowest priority (nice 19, ``CPU_NICE``): every other module, whole
  on one worker (a module-scoped fixture, a flight or a study several tests only read, runs once), the longest
  first (``LONGEST_FIRST``).  They need only CPU time: a lockstep flight's numbers do not depend on how fast it
  flies.  The kernel gives a waking real-time process the CPU before them, so they cannot make a real-time step
  late (in two real-time lanes beside four workers at the same priority, 7 real-time tests failed on a quiet
  machine).  The browser's software rendering runs between the two (``_browser.BROWSER_NICE``).

A real-time lane with nothing left takes CPU modules (and lowers its priority); a CPU lane never takes a real-time
module (a process cannot raise its priority back without privilege).  ``-n 0`` runs everything in one process, one
test after the other, at the caller's priority.
"""

from __future__ import annotations

import os

import pytest

from tools.scenario import PAPER, PAPER_RUNS, run_inprocess

# The modules whose tests fly in real time and assert its timing: the real-time lanes' work (module docstring).
REAL_TIME = (
    "test_browser_viewer.py",
    "test_stalls.py",
    "test_launch_verdict.py",
    "test_clients.py",
    "test_e2e_envelope.py",
    "test_vehicle.py",
    "test_mavlink_badinput.py",
    "test_hostile.py",
    "test_e2e_realtime.py",
    "test_telemetry_flight.py",
    "test_signing.py",
    "test_e2e_disturbances.py",
    "test_signed_gcs.py",
    "test_web.py",
    "test_e2e_telemetry.py",
    "test_gcs_admission.py",
    "test_sysid.py",
    "test_user_lines.py",
    "test_e2e_busy_wait.py",
)  # in this order, the longest first (measured with --durations=0)
# Of those, the modules that take the whole machine: the other real-time lane waits while one runs.  (Not the
# browser's: its software rendering runs below the real-time flights, at ``_browser.BROWSER_NICE``.)
ALONE = ("test_e2e_busy_wait.py", "test_mavlink_badinput.py")  # both CPUs spinning; floods of 10,000 datagrams/s
REAL_TIME_LANES = 2
CPU_NICE = 19  # the CPU lanes' nice value (the lowest priority)

# Started first, in this order (modules; measured with --durations=0), in the parallel phase.
LONGEST_FIRST = (
    "tests/test_readme_robustness.py",
    "tests/test_study.py",
    "tests/test_plants.py",
    "tests/test_e2e_lockstep.py",
    "tests/test_bad_input.py",
    "tests/test_pfc_design.py",
    "tests/test_mavlink_cli.py",
)


@pytest.fixture(scope="session")
def paper_runs() -> dict:
    """The reference scenario's five runs in-process (no wire model), by run name: ``RunResult`` objects."""
    return {run.name: run_inprocess(PAPER, run) for run in PAPER_RUNS}


def _module(nodeid: str) -> str:
    return nodeid.split("::", 1)[0]


def _basename(nodeid: str) -> str:
    return _module(nodeid).rsplit("/", 1)[-1]


def _real_time(nodeid: str) -> bool:
    return _basename(nodeid) in REAL_TIME


def _rank(nodeid: str) -> int:
    """Where a module starts in the queue: the real-time ones in ``REAL_TIME`` order, then ``LONGEST_FIRST``, then the
    rest in file order."""
    name = _basename(nodeid)
    if name in REAL_TIME:
        return REAL_TIME.index(name)
    listed = (i for i, prefix in enumerate(LONGEST_FIRST) if nodeid.startswith(prefix))
    return len(REAL_TIME) + next(listed, len(LONGEST_FIRST))


def pytest_collection_modifyitems(config, items):
    """The modules in ``_rank`` order (stable: file order within a module and among the rest)."""
    items.sort(key=lambda it: _rank(it.nodeid))


# ------------------------------------------------------------------------------------------------------ the lanes
def _lock_path(config) -> str | None:
    """The lock file the real-time lanes share (one per test run), None outside xdist."""
    workerinput = getattr(config, "workerinput", None)
    if workerinput is None:
        return None
    import tempfile

    return os.path.join(tempfile.gettempdir(), f"clsac-tests-{workerinput['testrunuid']}.lock")


def _lower_priority(nice: int) -> None:
    """This worker's every thread (Linux's nice value is per thread: numpy's BLAS threads, started at import, too)
    to at least ``nice``; processes and threads started from now on inherit it."""
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = [0]
    for tid in tids:
        try:
            if os.getpriority(os.PRIO_PROCESS, tid) < nice:
                os.setpriority(os.PRIO_PROCESS, tid, nice)
        except OSError:  # a thread that ended meanwhile
            pass


@pytest.fixture(scope="module", autouse=True)
def _lane(request):
    """Under xdist: a real-time module holds the lanes' lock while it runs, shared (``ALONE``: exclusive); any other
    module lowers this worker to ``CPU_NICE`` first (its processes inherit it).  Module-scoped and autouse, so it is
    set up before the module's own fixtures (the browser module's live flight)."""
    path = _lock_path(request.config)
    nodeid = request.node.nodeid
    if path is None:
        yield
        return
    if not _real_time(nodeid):
        _lower_priority(CPU_NICE)
        yield
        return
    import fcntl

    with open(path, "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX if _basename(nodeid) in ALONE else fcntl.LOCK_SH)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


@pytest.hookimpl(tryfirst=True, optionalhook=True)
def pytest_xdist_auto_num_workers(config):
    """``-n auto`` (addopts): a CPU lane per CPU (at least two) and the real-time lanes (four workers on 2 cores)."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 2)
    return max(2, cpus) + REAL_TIME_LANES


@pytest.hookimpl(tryfirst=True, optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """xdist's scope scheduling (one module to a worker, in collection order) with two kinds of worker (module
    docstring): the first ``REAL_TIME_LANES`` workers take the real-time modules, then the others; the rest take the
    others only.  A worker with nothing it may take ends (after the test it holds: an xdist worker runs the last
    test it holds only when it gets more work or is told to end).  (Not ``--dist loadgroup`` and xdist_group marks:
    pytest 9.2 builds node ids in a way xdist 3.8's loadgroup no longer renames, so every test was its own group.)"""
    from xdist.scheduler import LoadScopeScheduling

    class Lanes(LoadScopeScheduling):
        def __init__(self, config, log=None):
            super().__init__(config, log)
            self.real_time_lanes: list = []  # the workers that may take a real-time module

        def _split_scope(self, nodeid: str) -> str:
            return _module(nodeid)

        def _next_scope(self, node) -> str | None:
            if node not in self.real_time_lanes and len(self.real_time_lanes) < REAL_TIME_LANES:
                if not self.assigned_work.get(node):  # a worker that has run nothing yet (its priority is normal)
                    self.real_time_lanes.append(node)
            real_time = node in self.real_time_lanes
            lanes_alive = any(not n.shutting_down for n in self.real_time_lanes)
            for scope in self.workqueue:
                if _real_time(scope):
                    if real_time or not lanes_alive:  # (no real-time lane left: any worker, rather than none)
                        return scope
                else:
                    if real_time and any(_real_time(s) for s in self.workqueue):
                        continue  # a real-time lane takes the real-time modules first
                    return scope
            return None

        def _assign_work_unit(self, node) -> None:
            scope = self._next_scope(node)
            if scope is None:
                node.shutdown()
                return
            if _real_time(scope) is False and node in self.real_time_lanes:
                self.real_time_lanes.remove(node)  # it runs CPU work now (at CPU_NICE): never real time again
            work_unit = self.workqueue.pop(scope)
            self.assigned_work.setdefault(node, {})[scope] = work_unit
            collection = self.registered_collections[node]
            node.send_runtest_some([collection.index(nodeid) for nodeid, done in work_unit.items() if not done])

        def _reschedule(self, node) -> None:
            if node.shutting_down:
                return
            if not self.workqueue:
                node.shutdown()
                return
            if self._pending_of(self.assigned_work[node]) > 2:
                return
            self._assign_work_unit(node)

        def remove_node(self, node):
            if node in self.real_time_lanes:
                self.real_time_lanes.remove(node)
            crashed = super().remove_node(node)
            for other in list(self.assigned_work):  # real-time work may now go to any worker
                self._reschedule(other)
            return crashed

    return Lanes(config, log)
