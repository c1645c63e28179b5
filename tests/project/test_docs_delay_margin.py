"""docs/delay-margin.md's table is what the search finds: a published margin "M ms [M, M+1)" means the reference
flight (still air, ``--fault delay=M ms@0``) is controlled at M ms and not at M + 1 ms, and "fails at 0" that it is
not controlled without extra delay.  A cell is re-flown here with those two flights
(``tools.experiment.delay_margin.fly``, the command's own flight and verdict), not the whole search, so it costs
seconds.  A flight depends on its task only: a stale table fails."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tools.experiment.delay_margin import fly

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "delay-margin.md"
CASES = {"as built": "nominal", "effectiveness 0.3 at 10 s": "loss"}


def _table() -> dict:
    """{(plant, case, controller): the cell's text} of the page's table of margins."""
    lines = [x for x in PAGE.read_text(encoding="utf-8").splitlines() if x.startswith("| ")]
    head = next(x for x in lines if x.startswith("| law |"))
    cols = [c.strip() for c in head.strip("|").split("|")][1:]
    out = {}
    for line in lines[lines.index(head) + 1 :]:
        cells = [c.strip() for c in line.strip("|").split("|")]
        m = re.search(r"\(`([^`]+)`\)", cells[0])
        if m is None:
            continue
        for col, text in zip(cols, cells[1:]):
            plant, case = col.split(": ", 1)
            out[plant, CASES[case], m.group(1)] = text
    return out


def _holds(plant: str, controller: str, case: str) -> None:
    text = _table()[plant, case, controller]
    if text == "fails at 0":
        assert not fly(plant, controller, 0, case)["controlled"]
        return
    m = re.fullmatch(r"(\d+) ms \[(\d+), (\d+)\)", text)
    assert m and int(m.group(1)) == int(m.group(2)) == int(m.group(3)) - 1, text
    ms = int(m.group(1))
    assert fly(plant, controller, ms, case)["controlled"], (plant, controller, case, ms)
    assert not fly(plant, controller, ms + 1, case)["controlled"], (plant, controller, case, ms + 1)


def test_the_table_has_every_law_on_both_plants():
    t = _table()
    for ctrl in ("baseline", "sac", "clsac", "mrac", "crm-mrac", "l1", "indi"):
        for plant in ("kh2013a", "jsbsim:c172x"):
            assert {(plant, "nominal", ctrl), (plant, "loss", ctrl)} <= set(t), (plant, ctrl)


@pytest.mark.parametrize(("controller", "case"), [("clsac", "nominal"), ("clsac", "loss"), ("mrac", "nominal")])
def test_a_kh2013a_margin_is_two_fresh_flights(controller, case):
    _holds("kh2013a", controller, case)


@pytest.mark.e2e  # two JSBSim flights
def test_a_c172x_margin_is_two_fresh_flights():
    _holds("jsbsim:c172x", "l1", "nominal")
