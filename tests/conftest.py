"""Shared fixtures, and how the suite runs in parallel (docs/tests.md, "Parallel").

Slow tests that start real processes carry the ``e2e`` marker: ``python -m pytest -m "not e2e"`` runs the fast ones
in seconds.  ``python -m pytest`` runs on pytest-xdist workers (``addopts`` in pyproject.toml); this file decides
how, in two phases:

* **Everything that does not fly in real time, in parallel.**  Every such module runs whole on one worker, so a
  module-scoped fixture (a flight, a study several tests only read) runs once; the longest modules start first
  (``LONGEST_FIRST``), so no worker is left with a long module when the others are done.
* **Then the real-time tests, alone, one after the other.**  The tests that fly in real time assert timing
  (deadlines, stalls, latencies, sim time against the wall clock), and they failed whenever other tests shared the
  two cores with them (in two lanes beside the rest, 7 of them on a quiet machine).  Their modules (``SERIAL_LAST``)
  are one unit that starts only when every other test is done, on one worker, with the machine to itself: as the
  serial suite ran them.  The browser module is among them: its live flight flies in real time, and its software
  rendering takes both cores.
"""

from __future__ import annotations

import pytest

from tools.experiment.scenario import PAPER, PAPER_RUNS, run_inprocess

# The modules whose tests fly in real time and assert its timing (or share the machine with such a flight, as the
# browser's software rendering does): one unit, run last, alone (``_assign``).
SERIAL_LAST = (
    "test_stalls.py",
    "test_clients.py",
    "test_hostile.py",
    "test_mavlink_badinput.py",
    "test_signing.py",
    "test_web.py",
    "test_sysid.py",
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
    "test_browser_viewer.py",
)
SERIAL = "real time, alone"  # the serial unit's name

# Started first, in this order (modules; measured with --durations=0), in the parallel phase.
LONGEST_FIRST = (
    "tests/test_e2e_damage.py",
    "tests/test_e2e_every_plant.py",
    "tests/test_readme_robustness.py",
    "tests/test_study.py",
    "tests/test_plants.py",
    "tests/test_e2e_lockstep.py",
    "tests/test_bad_input.py",
    "tests/test_pfc_design.py",
    "tests/test_mavlink_cli.py",
    "tests/test_docs_jsbsim.py",
    "tests/test_failure_clients.py",
)


@pytest.fixture(scope="session")
def paper_runs() -> dict:
    """The reference scenario's five runs in-process (no wire model), by run name: ``RunResult`` objects."""
    return {run.name: run_inprocess(PAPER, run) for run in PAPER_RUNS}


def _module(nodeid: str) -> str:
    return nodeid.split("::", 1)[0]


def _serial(nodeid: str) -> bool:
    return _module(nodeid).rsplit("/", 1)[-1] in SERIAL_LAST


def _unit(nodeid: str) -> str:
    """What one worker runs, one test after the other: the serial unit, or else a whole module."""
    return SERIAL if _serial(nodeid) else _module(nodeid)


def _rank(nodeid: str) -> int:
    if _serial(nodeid):
        return len(LONGEST_FIRST) + 1  # last
    listed = (i for i, prefix in enumerate(LONGEST_FIRST) if nodeid.startswith(prefix))
    return next(listed, len(LONGEST_FIRST))


def pytest_collection_modifyitems(config, items):
    """The longest modules first, the real-time ones last; a unit starts where its best-ranked test is (stable: file
    order)."""
    first = {}
    for item in items:
        first[_unit(item.nodeid)] = min(first.get(_unit(item.nodeid), _rank(item.nodeid)), _rank(item.nodeid))
    items.sort(key=lambda it: first[_unit(it.nodeid)])


@pytest.hookimpl(tryfirst=True, optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """xdist's scope scheduling (one unit of tests to a worker, in collection order) with ``_unit`` as the scope, and
    a barrier before the serial unit: a worker that finds only it left ends (after the test it holds), and the last
    worker takes it once every other worker is gone, so the serial unit runs alone.  (An xdist worker runs the last
    test it holds only when it gets more work or is told to end, so a worker cannot simply wait for the barrier.)
    (Not ``--dist loadgroup`` and xdist_group marks: pytest 9.2 builds node ids in a way xdist 3.8's loadgroup no
    longer renames, so every test was its own group.)"""
    from xdist.scheduler import LoadScopeScheduling

    class Phases(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return _unit(nodeid)

        def _assign_work_unit(self, node) -> None:
            scope = next((s for s in self.workqueue if s != SERIAL), None)
            if scope is None:  # only the serial unit is left
                others = [n for n in self.assigned_work if n is not node]
                if others:
                    if not all(n.shutting_down for n in others):
                        node.shutdown()  # another worker still runs its module: this one ends, that one goes on
                    return  # else wait for the ending workers to be gone (remove_node)
                scope = SERIAL
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
            crashed = super().remove_node(node)
            for other in list(self.assigned_work):  # a worker gone may release the barrier
                self._reschedule(other)
            return crashed

    return Phases(config, log)
