"""Shared fixtures, and how the suite runs in parallel (docs/tests.md, "Parallel").

Slow tests that start real processes carry the ``e2e`` marker: ``python -m pytest -m "not e2e"`` runs the fast ones
in seconds.  ``python -m pytest`` runs on pytest-xdist workers (``addopts`` in pyproject.toml, ``--dist loadgroup``);
this file decides how:

* **Real-time tests in two lanes.**  The tests that fly in real time assert timing (deadlines, stalls, latencies,
  sim time against the wall clock) and flaked when several real-time flights and lockstep flights shared the two
  cores.  Their modules run in two lanes (``REAL_TIME_LANES``, one scheduling unit each: one test after the other on
  one worker), so at most two real-time flights of the suite run at once.
* **Real time first in line for the CPU.**  On a worker, every test outside the lanes runs at ``nice`` +``NICE``
  (a study or a lockstep flight, which only needs CPU time, then yields to the real-time processes).  The processes
  a test starts inherit it.  Lowering the nice value back needs root (CI runs as root); elsewhere nothing changes.
* **A module on one worker.**  Every other module runs whole on one worker, so a module-scoped fixture (a flight, a
  study, a browser session that several tests only read) runs once (``pytest_xdist_make_scheduler``: xdist's scope
  scheduling with the lane or the module as the scope).
* **Longest first.**  The lanes, then the longest modules start first (``LONGEST_FIRST``), so no worker is left with
  a long module when the others are done.
"""

from __future__ import annotations

import os

import pytest

from tools.scenario import PAPER, PAPER_RUNS, run_inprocess

# The modules whose tests fly in real time and assert its timing, in two lanes: each lane is one scheduling unit, so its
# tests run one after the other on one worker, and at most two real-time flights of the suite share the machine
# (split by their serial durations: about 250 s a lane on a loaded 2-core machine).
REAL_TIME_LANES = {
    "real-time-a": (
        "test_stalls.py",
        "test_clients.py",
        "test_hostile.py",
        "test_mavlink_badinput.py",
        "test_signing.py",
        "test_web.py",
        "test_sysid.py",
    ),
    "real-time-b": (
        "test_launch_verdict.py",
        "test_e2e_envelope.py",
        "test_vehicle.py",
        "test_telemetry_flight.py",
        "test_e2e_realtime.py",
        "test_e2e_disturbances.py",
        "test_signed_gcs.py",
        "test_e2e_telemetry.py",
        "test_gcs_admission.py",
        "test_user_lines.py",
    ),
}
LANE = {module: lane for lane, modules in REAL_TIME_LANES.items() for module in modules}
NICE = 5  # every other test on a worker: about a third of the CPU weight of a real-time process when both want it
BASE_NICE = os.getpriority(os.PRIO_PROCESS, 0)  # the worker's own, as it was started

# Started first, in this order (modules; measured with --durations=0, about two minutes down to 10 s each), after the
# two real-time lanes.
LONGEST_FIRST = (
    "tests/test_readme_robustness.py",  # the study and its 120 long flights (about 75 s of CPU)
    "tests/test_browser_viewer.py",  # three Chromium sessions on SwiftShader (about 2 min)
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


def _lane(nodeid: str) -> str | None:
    return LANE.get(_module(nodeid).rsplit("/", 1)[-1])


def _unit(nodeid: str) -> str:
    """What one worker runs, one test after the other: a real-time lane, or else a whole module (so a module-scoped
    fixture, a flight or a study several tests only read, runs once)."""
    return _lane(nodeid) or _module(nodeid)


def _rank(nodeid: str) -> int:
    lanes = tuple(REAL_TIME_LANES)
    if _lane(nodeid):
        return lanes.index(_lane(nodeid))
    listed = (i for i, prefix in enumerate(LONGEST_FIRST) if nodeid.startswith(prefix))
    return len(lanes) + next(listed, len(LONGEST_FIRST))


def pytest_collection_modifyitems(config, items):
    """The lanes first, then the longest modules; a unit starts where its best-ranked test is (stable: file order)."""
    first = {}
    for item in items:
        first[_unit(item.nodeid)] = min(first.get(_unit(item.nodeid), _rank(item.nodeid)), _rank(item.nodeid))
    items.sort(key=lambda it: first[_unit(it.nodeid)])


@pytest.hookimpl(tryfirst=True, optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """xdist's scope scheduling (one unit of tests to a worker, in collection order), with ``_unit`` as the scope.
    (Not ``--dist loadgroup`` and xdist_group marks: pytest 9.2 builds node ids in a way xdist 3.8's loadgroup no
    longer renames, so every test was its own group.)"""
    from xdist.scheduler import LoadScopeScheduling

    class Units(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return _unit(nodeid)

    return Units(config, log)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """On an xdist worker: real-time tests at the worker's own priority, every other test at nice +NICE above it
    (fixtures and the processes a test starts inherit it).  Lowering it back needs root (CI runs as root)."""
    if os.environ.get("PYTEST_XDIST_WORKER") and os.geteuid() == 0:
        target = BASE_NICE if _lane(item.nodeid) else BASE_NICE + NICE
        if os.getpriority(os.PRIO_PROCESS, 0) != target:
            os.setpriority(os.PRIO_PROCESS, 0, target)
