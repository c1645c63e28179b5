"""The README's reference-scenario result tables equal a fresh in-process run, to the digits they print, so the
published numbers cannot drift unseen (issue 13, "The science, checked")."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from autopilot.shared.pwm import PwmMap
from tools.experiment.scenario import PAPER, PAPER_RUNS, RunSpec, run_inprocess

ROOT = Path(__file__).resolve().parents[2]
# The full tables are on the manual's experiments page; the front page repeats two rows of the first one.
README = (ROOT / "docs" / "experiments.md").read_text(encoding="utf-8")
FRONT_PAGE = (ROOT / "README.md").read_text(encoding="utf-8")
METRICS = ("ise_ref", "ise_crm", "energy", "tv", "max_abs_u")
NUMBER = re.compile(r"^-?\d+(\.\d+)?(e-?\d+)?")


def _rows(header_start: str, text: str = README) -> dict[str, list[str]]:
    """The body rows of the first markdown table of ``text`` whose header line starts with ``header_start``."""
    lines = text.splitlines()
    i = next(k for k, line in enumerate(lines) if line.startswith(header_start))
    rows = {}
    for line in lines[i + 2 :]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip("|").split("|")]
        rows[cells[0]] = cells[1:]
    return rows


def _agrees(printed: str, value: float) -> bool:
    """``value`` rounds to ``printed`` (half a unit of its last digit)."""
    m = NUMBER.match(printed.replace("**", ""))
    assert m, printed
    text = m.group(0)
    mant, _, exp = text.partition("e")
    decimals = len(mant.partition(".")[2])
    unit = 10.0 ** (-decimals + (int(exp) if exp else 0))
    return abs(value - float(text)) <= 0.5 * unit * (1 + 1e-9)


def test_paper_results_table():
    rows = _rows("| run | Lv | ise_ref")
    assert list(rows) == [r.name for r in PAPER_RUNS]
    for run in PAPER_RUNS:
        fresh = run_inprocess(PAPER, run).metrics
        cells = rows[run.name]
        assert float(cells[0]) == run.lv
        for metric, cell in zip(METRICS, cells[1:]):
            assert _agrees(cell, fresh[metric]), (run.name, metric, cell, fresh[metric])


def test_front_page_results_are_rows_of_the_manual_table():
    """The README's small table: SAC and CL-SAC, each row exactly as the manual prints it (checked fresh above)."""
    front, manual = _rows("| run | Lv | ise_ref", FRONT_PAGE), _rows("| run | Lv | ise_ref")
    assert list(front) == ["sac", "clsac"]
    for name, cells in front.items():
        assert cells == manual[name], name


def test_robust_pfc_results_table():
    rows = _rows("| run (robust PFC) |")
    for run in PAPER_RUNS:
        fresh = run_inprocess(PAPER, RunSpec(run.name, run.lv, pfc="robust")).metrics
        for metric, cell in zip(METRICS, rows[run.name]):
            assert _agrees(cell, fresh[metric]), (run.name, metric, cell, fresh[metric])


def test_over_mavlink_table_in_process_columns():
    """The in-process and wire-model columns (the lockstep column is the e2e tests' business)."""
    rows = _rows("| metric | in-process | lockstep over UDP |")
    clsac = PAPER_RUNS[1]
    plain = run_inprocess(PAPER, clsac).metrics
    wire = run_inprocess(PAPER, clsac, wire=PwmMap()).metrics
    for metric in METRICS:
        cells = rows[metric]
        assert _agrees(cells[0], plain[metric]), (metric, cells[0], plain[metric])
        assert _agrees(cells[3], wire[metric]), (metric, cells[3], wire[metric])


@pytest.mark.parametrize("printed, value, ok", [("0.001380", 0.0013804, True), ("27.51", 27.52, False)])
def test_agreement_rule(printed, value, ok):
    assert _agrees(printed, value) is ok
