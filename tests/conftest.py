"""Shared fixtures, and how the suite runs in parallel (docs/tests.md, "Parallel").

Slow tests that start real processes carry the ``e2e`` marker: ``python -m pytest -m "not e2e"`` runs the fast ones
in seconds.  ``python -m pytest`` runs on four pytest-xdist workers (``addopts`` in pyproject.toml), also on two
cores; this file decides how:

* **The real-time tests, from the start, on two workers at normal priority** (``lane_workers``), one lane each
  (``LANES``, with the real-time tests of other modules, ``REAL_TIME_TESTS``; balanced by their measured durations).
  They assert timing (deadlines, stalls, latencies, sim time against the wall clock), but a real-time flight takes
  little CPU (0.4 of one core).  When both lanes are done, the last lane worker flies the tests that mount a small
  tmpfs and fill it (``SMALL_DISK_TESTS``, ``EXTRA_LANE``), then, once everything else is done, the browser
  (``ALONE``: a live flight, and software rendering on both cores that starves idle-priority tests); a lane worker
  done before it joins the parallel phase.
* **Everything else, on the other workers, at the lowest priority** (``_lower_priority``: ``SCHED_IDLE`` and the
  idle I/O class, nice 19 where refused; a worker lowers itself, and so every process it starts, before its first
  test of the parallel phase, and never raises itself again): a ``SCHED_IDLE`` task runs only on a CPU no other
  task in its scheduling group wants.  The launcher starts a flight's processes in its own session
  (``tools/flight/children.py``) so that the kernel's autogroups, one per session, do not give an idle-priority
  test's flight the weight of a session of its own (``python -m tools.bench isolation``).  Every such module runs
  whole on one worker, so a module-scoped fixture (a flight, a study several tests only read) runs once; the longest
  modules start first (``LONGEST_FIRST``).

**On two workers (``python -m pytest -n 2``) the schedule is in three phases instead:** everything that does not
fly in real time, in parallel; then the two lanes, with nothing else running (the tests of ``SMALL_DISK_TESTS`` run
with their modules, in the first phase); then the browser, alone.  A barrier keeps the lanes from starting while any
other test is still to run: a worker waiting at it is sent one test of ``test_process_hygiene.py`` (an xdist worker
runs the last test it holds only once it is given more work), so the test it held runs before the barrier opens.
On three workers, one lane worker flies the lanes one after the other.
"""

from __future__ import annotations

import os

import pytest

from tools.experiment.scenario import PAPER, PAPER_RUNS, run_inprocess

# The modules whose tests fly in real time and assert its timing: two lanes, side by side, balanced by their durations
# (seconds, each test's start and end logged in whole runs, 2026-12-07: 327 and 313 on 2 workers, where the split
# before had left 369 and 249; 334 and 307 on 4); on three workers, one lane after the other on the lane worker.
LANES = (
    (
        "tests/tools/flight/test_stalls.py",
        "tests/autopilot/test_vehicle.py",
        "tests/autopilot/test_hostile.py",
        "tests/autopilot/shared/test_mavlink_badinput.py",
        "tests/tools/flight/test_e2e_disturbances.py",
        "tests/autopilot/test_signed_gcs.py",
        "tests/autopilot/test_gcs_admission.py",
        "tests/autopilot/test_sysid.py",
        "tests/tools/flight/test_user_lines.py",
        "tests/autopilot/test_failure_injection.py",
    ),
    (
        "tests/tools/test_clients.py",
        "tests/tools/flight/test_launch_verdict.py",
        "tests/tools/flight/test_e2e_envelope.py",
        "tests/autopilot/test_telemetry_flight.py",
        "tests/autopilot/shared/test_signing.py",
        "tests/tools/flight/test_web.py",
        "tests/tools/view/test_e2e_telemetry.py",
    ),
)
# Tests that fly in real time in modules that otherwise do not: each joins a lane (REAL_TIME_TESTS[k] lane k + 1,
# split so that the two stay balanced), so that none runs at idle priority, where a real-time flight starved (a 30 s
# flight had flown 10 s after 75 s), or on 2 workers beside the CPU-bound tests; node ids, or their prefixes.
REAL_TIME_TESTS = (
    (
        "tests/autopilot/test_law.py::test_the_docs_law_flies_in_real_time_and_through_flight",
        "tests/autopilot/test_law.py::test_a_ground_station_sees_the_laws_mode_and_sets_its_parameters_live",
        "tests/tools/flight/test_startup.py::test_a_lockstep_launcher_imports_rerun_while_its_children_start_a_real_t",
        "tests/tools/flight/test_startup.py::test_only_a_lockstep_flight_has_the_picture_helper_beside_it",
    ),
    (
        "tests/tools/test_failure_clients.py::",
        "tests/tools/flight/test_e2e_tracking.py::test_a_flight_disarmed_by_a_ground_station_says_so_on_its_last_line",
        "tests/tools/flight/test_e2e_tracking.py::test_the_default_flight_tracks_and_stays_ok[",
        "tests/tools/flight/test_startup.py::test_an_adopted_helper_draws_the_picture_or_is_closed_when_not_wanted",
        "tests/tools/flight/test_e2e_failure_injection.py::test_real_time_",
        "tests/tools/flight/test_e2e_mimo_sensors.py::test_real_time_link_faults_carry_the_sideslip_with_the_attitude",
        "tests/tools/flight/test_startup.py::test_a_sitl_that_binds_after_the_first_heartbeat_is_found_at_once[realtime]",
        "tests/sitl/test_divergence.py::",
    ),
)
# On three workers or more, the tests that mount a small tmpfs and fill it (tests/_small_disk.py) are a lane of their
# own, after the others: a real-time flight beside them starved for 0.1-0.2 s twice in one run.  On two workers they
# run with their modules, in the parallel phase, where no real-time flight flies.
SMALL_DISK_TESTS = (
    "tests/tools/flight/test_output_paths.py::test_a_disk_full_",
    "tests/tools/flight/test_output_paths.py::test_a_full_disk_",
    "tests/tools/flight/test_output_paths.py::test_a_disk_that_holds_",
    "tests/tools/experiment/damage/test_e2e_damage.py::test_a_full_disk_keeps_the_summary_and_names_the_picture",
)
EXTRA_LANE = "real time, lane 3"  # SMALL_DISK_TESTS' unit on three workers or more
# Last, alone: real time with software rendering on both cores, and a flight pinned to a core it busy-waits on.
ALONE = ("tests/tools/view/test_browser_viewer.py", "tests/tools/flight/test_e2e_realtime.py")
SERIAL_LAST = tuple(m for lane in LANES for m in lane) + ALONE  # every module that flies in real time
BARRIER = "tests/project/test_process_hygiene.py"  # its tests are what a worker waiting at the barrier runs (one each)
SERIAL = "real time, alone"  # the last unit's name
CONCURRENT_FROM = 3  # the fewest workers on which the lanes overlap the parallel phase
LOWEST_PRIORITY = 19  # nice of a worker running the parallel phase beside the lanes, where SCHED_IDLE is not to be had

# Started first, in this order (modules, longest first: their time in a whole run on 2 workers, 2026-12-07), in the
# parallel phase: the last to start are then short, and neither worker waits long at the barrier for the other.
LONGEST_FIRST = (
    "tests/tools/experiment/damage/test_e2e_damage.py",
    "tests/tools/design/test_pfc_design.py",
    "tests/tools/flight/test_e2e_every_plant.py",
    "tests/tools/experiment/study/test_study_faults.py",
    "tests/tools/test_bad_input.py",
    "tests/tools/flight/test_startup.py",
    "tests/tools/experiment/study/test_study_flights.py",
    "tests/tools/flight/test_e2e_faults.py",
    "tests/tools/experiment/study/test_study_never_hangs.py",
    "tests/sitl/test_plants.py",
    "tests/project/test_docs_leaderboard.py",
    "tests/project/test_docs_damage.py",
    "tests/autopilot/test_law.py",
    "tests/tools/flight/test_e2e_tracking.py",
    "tests/tools/experiment/test_gym.py",
    "tests/autopilot/test_ground_station_bounds.py",
    "tests/tools/flight/test_output_paths.py",
    "tests/tools/experiment/study/test_study_kernel.py",
    "tests/tools/flight/test_e2e_lockstep.py",
    "tests/autopilot/shared/test_rrd_integrity.py",
    "tests/project/test_docs_jsbsim.py",
    "tests/tools/experiment/study/test_study.py",
    "tests/tools/flight/test_e2e_mimo.py",
    "tests/autopilot/test_telemetry_spool.py",
    "tests/tools/flight/test_e2e_mimo_sensors.py",
    "tests/tools/experiment/damage/test_e2e_damage_mimo.py",
    "tests/tools/experiment/test_mimo_inprocess.py",
    "tests/tools/design/test_mimo_design.py",
)


@pytest.fixture(scope="session")
def paper_runs() -> dict:
    """The reference scenario's five runs in-process (no wire model), by run name: ``RunResult`` objects."""
    return {run.name: run_inprocess(PAPER, run) for run in PAPER_RUNS}


def lane_workers(workers: int) -> int:
    """On ``CONCURRENT_FROM`` workers or more: how many fly the lanes from the start, one lane each (module
    docstring); the others, at least two, run the parallel phase."""
    return max(1, min(len(LANES), workers - 2))


def _module(nodeid: str) -> str:
    return nodeid.split("::", 1)[0]


def _unit(nodeid: str, concurrent: bool | None = None) -> str:
    """What one worker runs, one test after the other: a lane, the last unit, one barrier test, or a module.
    ``concurrent``: on the schedule of three workers or more (default: this worker's, ``_concurrent``), where the
    tests of ``SMALL_DISK_TESTS`` are a lane; on two workers they run with their modules."""
    name = _module(nodeid)
    if name in ALONE:
        return SERIAL
    for k, tests in enumerate(REAL_TIME_TESTS):
        if nodeid.startswith(tests):
            return f"real time, lane {k + 1}"
    if (_concurrent() if concurrent is None else concurrent) and nodeid.startswith(SMALL_DISK_TESTS):
        return EXTRA_LANE
    for k, lane in enumerate(LANES):
        if name in lane:
            return f"real time, lane {k + 1}"
    if name == BARRIER:
        return f"barrier {nodeid}"
    return _module(nodeid)


def _phase(unit: str) -> int:
    """0: in parallel; 1: a barrier test; 2: a real-time lane; 3: alone, last."""
    if unit == SERIAL:
        return 3
    if unit.startswith("real time, lane "):
        return 2
    if unit.startswith("barrier "):
        return 1
    return 0


def _rank(nodeid: str) -> int:
    phase = _phase(_unit(nodeid))
    if phase:
        return len(LONGEST_FIRST) + phase  # after every module of the parallel phase, in phase order
    listed = (i for i, prefix in enumerate(LONGEST_FIRST) if nodeid.startswith(prefix))
    return next(listed, len(LONGEST_FIRST))


def _concurrent() -> bool:
    """In an xdist worker of a run on ``CONCURRENT_FROM`` workers or more."""
    return int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0")) >= CONCURRENT_FROM


def _lower_priority() -> None:
    """This worker (its test thread, and every process and thread it starts from now on) to the lowest priority:
    ``SCHED_IDLE`` (it runs only on a CPU no other task wants, so a real-time flight never waits for it), and the
    idle I/O class; nice 19 where SCHED_IDLE is refused.  Irreversible without privileges: the scheduler never gives
    a real-time test to a worker that ran the parallel phase."""
    if getattr(os, "SCHED_IDLE", None) is not None and os.sched_getscheduler(0) != os.SCHED_IDLE:
        try:
            os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
        except OSError:
            pass
        _idle_io()
    if os.getpriority(os.PRIO_PROCESS, 0) < LOWEST_PRIORITY:
        os.setpriority(os.PRIO_PROCESS, 0, LOWEST_PRIORITY)


def _idle_io() -> None:
    """This thread's (and its children's) disk I/O to the idle class (``ioprio_set``, Linux x86-64 and arm64); best
    effort: the CPU is what the real-time flights need first."""
    import ctypes
    import platform

    number = {"x86_64": 251, "aarch64": 30}.get(platform.machine())
    if number is None:
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.syscall(number, 1, 0, 3 << 13)  # IOPRIO_WHO_PROCESS, this thread, IOPRIO_CLASS_IDLE << IOPRIO_CLASS_SHIFT
    except (OSError, AttributeError):
        pass


def pytest_runtest_setup(item):
    if _concurrent() and _phase(_unit(item.nodeid)) == 0:
        _lower_priority()


def pytest_collection_modifyitems(config, items):
    """The longest modules first, then the barrier, the real-time lanes and the browser; a unit starts where its
    best-ranked test is (stable: file order)."""
    first = {}
    for item in items:
        first[_unit(item.nodeid)] = min(first.get(_unit(item.nodeid), _rank(item.nodeid)), _rank(item.nodeid))
    items.sort(key=lambda it: first[_unit(it.nodeid)])


@pytest.hookimpl(tryfirst=True, optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """xdist's scope scheduling (one unit of tests to a worker, in collection order) with ``_unit`` as the scope, and
    two barriers (the module docstring).  (Not ``--dist loadgroup`` and xdist_group marks: pytest 9.2 builds node
    ids in a way xdist 3.8's loadgroup no longer renames, so every test was its own group.)"""
    from xdist.scheduler import LoadScopeScheduling

    class Phases(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return _unit(nodeid, self.numnodes >= CONCURRENT_FROM)

        def _give(self, node, scope: str) -> None:
            work_unit = self.workqueue.pop(scope)
            self.assigned_work.setdefault(node, {})[scope] = work_unit
            collection = self.registered_collections[node]
            node.send_runtest_some([collection.index(nodeid) for nodeid, done in work_unit.items() if not done])

        def _pending(self, node, phase: int) -> int:
            return sum(
                list(unit.values()).count(False)
                for scope, unit in self.assigned_work.get(node, {}).items()
                if _phase(scope) == phase
            )

        def _queued(self, phase: int) -> list:
            return [s for s in self.workqueue if _phase(s) == phase]

        def _parallel_left(self) -> bool:
            return bool(self._queued(0)) or any(self._pending(n, 0) for n in self.assigned_work)

        def _lane_worker(self, node) -> bool:
            """Whether ``node`` flies real time (never lowered); decided when it first asks for work."""
            roles = self.__dict__.setdefault("_roles", {})
            if node not in roles:
                real_time = bool(self._queued(2)) or SERIAL in self.workqueue
                roles[node] = real_time and sum(roles.values()) < lane_workers(self.numnodes)
            return roles[node]

        def _assign_concurrently(self, node) -> None:
            """On ``CONCURRENT_FROM`` workers or more: the lanes from the start on the lane workers, the parallel
            phase on the others (lowered); when the lanes are done, the last lane worker flies ``EXTRA_LANE``, and
            the browser once the parallel phase is done too; a lane worker done before it joins the parallel phase."""
            waiting = self.__dict__.setdefault("_waiting", set())
            waiting.discard(node)
            if self._lane_worker(node):
                lanes = [s for s in self._queued(2) if s != EXTRA_LANE]
                if lanes:
                    self._give(node, lanes[0])
                    return
                rest = [s for s in (EXTRA_LANE, SERIAL) if s in self.workqueue]
                flying = [n for n in self.assigned_work if n is not node and self._pending(n, 2)]
                if rest and any(self._roles.get(n) for n in flying):
                    self._roles[node] = False  # another lane worker still flies: it flies the rest
                elif rest and (flying or (rest[0] == SERIAL and self._parallel_left())):
                    # a lane worker turned parallel still flies its last lane tests, or the browser waits for the
                    # rest to be done: its rendering on both cores starves idle-priority tests
                    waiting.add(node)
                    return
                elif rest:
                    # EXTRA_LANE beside the parallel phase (its workers at SCHED_IDLE), or the browser after it
                    self._give(node, rest[0])
                    return
                else:
                    self._roles[node] = False  # no real time left to fly: it joins the parallel phase
                self._assign_concurrently(node)
                return
            parallel = self._queued(0)
            if parallel:
                self._give(node, parallel[0])
                return
            for barrier in self._queued(1):
                self._give(node, barrier)
            node.shutdown()

        def _assign_work_unit(self, node) -> None:
            if self.numnodes >= CONCURRENT_FROM:
                self._assign_concurrently(node)
                return
            parallel = self._queued(0)
            if parallel:
                self._give(node, parallel[0])
                return
            lanes = self._queued(2)
            if lanes:
                if self._pending(node, 0):  # it holds a test of the parallel phase: a barrier test runs that one
                    barriers = self._queued(1)
                    if barriers and not self._pending(node, 1):
                        self._give(node, barriers[0])
                        return
                    if barriers:
                        return  # its barrier test is on its way
                elif any(self._pending(n, 0) for n in self.assigned_work if n is not node):
                    return  # another worker still runs the parallel phase: wait at the barrier
                # the barrier opens: a lane to this worker and one to each other worker waiting at it
                for n in [node, *(n for n in self.assigned_work if n is not node and not n.shutting_down)]:
                    lanes = self._queued(2)
                    if not lanes:
                        break
                    if n is node or self._pending(n, 2) + self._pending(n, 3) == 0:
                        self._give(n, lanes[0])
                for barrier in self._queued(1):  # barrier tests no worker needed
                    self._give(node, barrier)
                return
            for barrier in self._queued(1):
                self._give(node, barrier)
            if SERIAL not in self.workqueue:
                return
            others = [n for n in self.assigned_work if n is not node]
            if others:
                if not all(n.shutting_down for n in others):
                    node.shutdown()  # another worker still runs: this one ends, that one goes on
                return  # else wait for the ending workers to be gone (remove_node)
            self._give(node, SERIAL)

        def _reschedule(self, node) -> None:
            if node.shutting_down:
                return
            if not self.workqueue:
                node.shutdown()
                return
            if self._pending_of(self.assigned_work[node]) > 2:
                return
            self._assign_work_unit(node)

        def mark_test_complete(self, node, item_index: int, duration: float = 0) -> None:
            super().mark_test_complete(node, item_index, duration)
            for other in list(self.__dict__.get("_waiting", ())):  # a lane worker waiting for lane tests or the rest
                if other is not node:
                    self._reschedule(other)

        def remove_node(self, node):
            crashed = super().remove_node(node)
            for other in list(self.assigned_work):  # a worker gone may release the barrier
                self._reschedule(other)
            return crashed

    return Phases(config, log)
