"""The manual's promises that can be run: the ten-line closed loop with the two public imports (docs/python-api.md)."""

from __future__ import annotations

import re
from pathlib import Path

from tools.experiment.scenario import RunSpec, Scenario, run_inprocess
from tools.flight.profiles import Profile

API_PAGE = Path(__file__).resolve().parents[2] / "docs" / "python-api.md"


def _ten_line_loop() -> str:
    m = re.search(r"<!-- ten-line-loop -->\s*```python\n(.*?)```", API_PAGE.read_text(), re.S)
    assert m, "docs/python-api.md has no <!-- ten-line-loop --> python block"
    return m.group(1)


def test_the_manual_loop_is_ten_lines_with_two_imports():
    code = _ten_line_loop()
    lines = [ln for ln in code.splitlines() if ln.strip()]
    assert len(lines) <= 10, code
    imports = [ln for ln in lines if ln.startswith(("import ", "from "))]
    assert imports == ["from autopilot import ClSac, ClSacConfig", "from sitl import Aircraft, AircraftConfig"]


def test_the_manual_loop_flies_the_paper_law(capsys):
    """Run the manual's block as written: it tracks the square wave, and it is exactly the in-process runner
    (the runner's own numbers are checked against independent computations in tests/autopilot/test_closed_loop.py)."""
    ns: dict = {}
    exec(compile(_ten_line_loop(), "docs/python-api.md", "exec"), ns)  # noqa: S102
    ac = ns["ac"]
    assert "roll" in capsys.readouterr().out
    # After 3000 steps (30 s) the command has been -0.1745 rad for 5 s: the roll has settled on it.
    assert abs(ac.phi - (-0.1745)) < 0.005
    # The same law and aircraft stepped by tools.experiment.scenario: phi at step 3000 is the roll after the manual's
    # loop.
    ref = run_inprocess(Scenario(profile=Profile("square", 0.1745, 10.0), duration_s=30.01), RunSpec("clsac", 20.0))
    assert ac.phi == ref.series["phi"][-1]


def test_the_run_folders_the_manual_names_are_the_ones_the_launcher_makes(tmp_path):
    """Every ``runs/<timestamp>...`` in the README and docs/telemetry.md ("open a saved flight": it once lacked the
    plant) is the folder ``python -m tools.launch`` makes with its defaults: ``new_run_dir`` with the launcher's tag
    for the default flight, made here in a scratch folder, its time stamp replaced by ``<timestamp>``."""
    from tools.flight.children import new_run_dir
    from tools.flight.config import FlightConfig
    from tools.flight.supervision import run_folder_tag

    made = new_run_dir(str(tmp_path / "runs"), run_folder_tag(FlightConfig()))
    assert re.fullmatch(r"\d{8}-\d{6}-rt-clsac-KH2013A", made.name), made.name
    expected = "runs/<timestamp>" + made.name[len("20250101-120000") :]
    root = API_PAGE.parents[1]
    named = [
        m
        for page in ("README.md", "docs/telemetry.md")
        for m in re.findall(r"runs/<timestamp>[^/`\s]*", (root / page).read_text())
    ]
    assert len(named) >= 3 and set(named) == {expected}, named
