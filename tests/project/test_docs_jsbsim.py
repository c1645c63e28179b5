"""docs/jsbsim.md's Monte Carlo table is what the robustness command prints (``--plant jsbsim:c172x``): rows of it
flown again, every printed digit compared with the page, so its numbers cannot drift."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "jsbsim.md"
COMMAND = (
    "python -m tools.experiment robustness --plant jsbsim:c172x --airspeeds 63,77,90,104,117 "
    "--turbulence none,light,moderate --seeds 3 --workers 2 --out DIR"
)
HEADER = "| condition | SAC ise_ref | SAC energy | CL-SAC ise_ref | CL-SAC energy | fixed-gain PID ise_ref |"


def _page_table() -> list[str]:
    lines = PAGE.read_text(encoding="utf-8").splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(HEADER))
    rows = []
    for line in lines[start:]:
        if not line.startswith("|"):
            break
        rows.append(line)
    return rows


def _fresh(tmp_path: Path, *args: str) -> list[str]:
    """The medians table (table.md's first) of the page's command with ``args`` instead of its grid."""
    out = tmp_path / "out"
    r = subprocess.run(
        [sys.executable, "-m", "tools.experiment", "robustness", "--plant", "jsbsim:c172x", *args]
        + ["--no-progress", "--out", str(out)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=600,
    )
    assert r.returncode == 0, r.stderr
    return (out / "table.md").read_text(encoding="utf-8").split("\n\n")[0].splitlines()


def _check(fresh: list[str], conditions: list[str]) -> None:
    page = _page_table()
    assert fresh[:2] == page[:2]  # the same columns
    for cond in conditions:
        want = [row for row in page if row.startswith(f"| {cond} |")]
        got = [row for row in fresh if row.startswith(f"| {cond} |")]
        assert len(want) == 1 and got == want, (cond, got, want)


def test_the_page_gives_the_command_it_publishes():
    assert COMMAND in " ".join(PAGE.read_text(encoding="utf-8").split())
    assert len(_page_table()) == 2 + 11


def test_the_design_point_row_is_a_fresh_run(tmp_path):
    """90 kt in still air, where the page's seeds fly one flight: one seed gives their median (3 flights)."""
    _check(_fresh(tmp_path, "--airspeeds", "90", "--turbulence", "none", "--seeds", "1"), ["90 kt, none"])


@pytest.mark.e2e  # 27 JSBSim flights on 2 workers
def test_the_63_kt_rows_are_a_fresh_run_of_the_pages_seeds(tmp_path):
    """The slow end in still air, light and moderate turbulence: the page's 3 seeds, 2 workers, as printed."""
    fresh = _fresh(
        tmp_path, "--airspeeds", "63", "--turbulence", "none,light,moderate", "--seeds", "3", "--workers", "2"
    )
    _check(fresh, ["63 kt, none", "63 kt, light", "63 kt, moderate"])
    text = PAGE.read_text(encoding="utf-8")
    rows = {r.split(" | ")[0][2:]: r.strip("| ").split(" | ") for r in fresh[2:]}
    sac, base = float(rows["63 kt, light"][1]), float(rows["63 kt, light"][5])
    assert re.search(rf"light {sac:.3f} vs {base:.3f}", text)  # the sentence under the table
