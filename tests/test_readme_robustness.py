"""The README's robustness tables are what a fresh run of the study prints, so published numbers cannot drift."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tools.study import StudyOptions, format_breaks, format_table, run_study

# The whole study (11,250 runs of 30 s, about 20 s): kept out of the fast suite with the end-to-end tests.
pytestmark = pytest.mark.e2e

README = Path(__file__).resolve().parents[1] / "README.md"
# The command the README gives, and the options it means (the long flight is not re-run here: 2 minutes).
COMMAND = (
    "python -m tools.experiment robustness --runs 100 --seed 1 --sweep-runs 50 --long-runs 10 --out runs/robustness"
)


def _block(text: str, name: str) -> str:
    m = re.search(rf"<!-- {name} -->\n(.*?)\n<!-- /{name} -->", text, re.S)
    assert m, f"README has no {name} block"
    return m.group(1).strip()


@pytest.fixture(scope="module")
def fresh():
    return run_study(
        StudyOptions(runs=100, seed=1, sweep_runs=50, long_runs=0), None, log=lambda _m: None, progress=False
    )


def test_readme_gives_the_command_it_publishes():
    assert COMMAND in README.read_text(encoding="utf-8")


def test_readme_results_table_equals_a_fresh_run(fresh):
    assert _block(README.read_text(encoding="utf-8"), "robustness-table") == format_table(fresh)


def test_readme_break_points_equal_a_fresh_run(fresh):
    assert _block(README.read_text(encoding="utf-8"), "robustness-breaks") == format_breaks(fresh)
