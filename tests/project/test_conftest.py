"""The suite's schedule (tests/conftest.py; docs/tests.md, "Parallel") names modules by their paths: each must be a
test file that exists, or a moved or renamed file would silently lose its real-time lane, the barrier or its early
start and run beside the CPU-bound tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests import conftest as schedule

ROOT = Path(__file__).resolve().parents[2]
NAMED = (*schedule.SERIAL_LAST, schedule.BARRIER, *schedule.LONGEST_FIRST)


@pytest.mark.parametrize("module", NAMED)
def test_every_module_the_schedule_names_is_a_test_file(module):
    path = ROOT / module
    assert path.is_file() and path.name.startswith("test_") and module.startswith("tests/"), module


def test_no_module_is_named_twice():
    assert len(set(NAMED)) == len(NAMED)


def test_each_module_goes_to_its_unit():
    """A test of a lane's module goes to that lane, one of ALONE's to the last unit, each barrier test to a unit of
    its own, and any other test to its module's unit; the phases are 2, 3, 1 and 0."""
    lane2 = schedule.LANES[1][0]
    cases = {
        f"{schedule.LANES[0][-1]}::test_a": ("real time, lane 1", 2),
        f"{lane2}::test_a[x-1]": ("real time, lane 2", 2),
        f"{schedule.ALONE[0]}::test_a": (schedule.SERIAL, 3),
        f"{schedule.BARRIER}::test_a[3]": (f"barrier {schedule.BARRIER}::test_a[3]", 1),
        "tests/sitl/test_model.py::test_a": ("tests/sitl/test_model.py", 0),
    }
    for nodeid, (unit, phase) in cases.items():
        assert schedule._unit(nodeid) == unit, nodeid
        assert schedule._phase(unit) == phase, nodeid


def test_a_file_of_the_same_name_in_another_folder_is_not_scheduled_as_real_time():
    """Modules are matched by path, not by file name: a test_stalls.py of another package runs in parallel."""
    lane_file = Path(schedule.LANES[0][0]).name
    assert schedule._unit(f"tests/sitl/{lane_file}::test_a") == f"tests/sitl/{lane_file}"


@pytest.mark.parametrize(
    "prefix", [*(t for lane in schedule.REAL_TIME_TESTS for t in lane), *schedule.SMALL_DISK_TESTS]
)
def test_each_test_named_is_a_test_of_a_file_that_exists(prefix):
    """A prefix names a test file and, after ``::``, the start of a test function's name defined in it."""
    module, _, name = prefix.partition("::")
    path = ROOT / module
    assert path.is_file() and module.startswith("tests/") and "::" in prefix, prefix
    function = name.split("[", 1)[0]
    assert not function or f"def {function}" in path.read_text(), prefix


def test_a_real_time_test_of_another_module_joins_its_lane_on_every_schedule():
    for k, lane in enumerate(schedule.REAL_TIME_TESTS):
        for concurrent in (False, True):
            assert schedule._unit(f"{lane[0]}x", concurrent=concurrent) == f"real time, lane {k + 1}"


def test_the_small_disk_tests_are_a_lane_on_three_workers_only():
    nodeid = f"{schedule.SMALL_DISK_TESTS[0]}x"
    module = nodeid.split("::", 1)[0]
    assert schedule._unit(nodeid, concurrent=True) == schedule.EXTRA_LANE
    assert schedule._phase(schedule.EXTRA_LANE) == 2
    assert schedule._unit(nodeid, concurrent=False) == module


@pytest.mark.parametrize("workers,lanes", [(3, 1), (4, 2), (5, 2), (16, 2)])
def test_lane_workers_leave_two_workers_to_the_rest(workers, lanes):
    """On three workers one flies the lanes one after the other; from four on, one per lane, never more, and at
    least two workers run the parallel phase."""
    assert schedule.lane_workers(workers) == lanes
    assert workers - lanes >= 2
