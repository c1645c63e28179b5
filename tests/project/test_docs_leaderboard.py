"""docs/damage.md's leaderboard is what the study flies for the block's command: one law's row at one fault,
flown again with the block's seeds, turbulence and length beside the PID at equal effort (its ratio columns), and
compared with the page's row character for character (``tools.experiment.damage.leaderboard.row_line``), the
winner's bold and the bound's mark aside: they depend on the other laws.  A flight depends on its task only, so the
tolerance is none: a stale table fails.  The learned policy's row is not re-flown here (its training takes
minutes): ``python -m tools.experiment.damage.leaderboard --fly`` regenerates it."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tools.experiment.damage.leaderboard import BLOCK, commands, row_line, rows

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "damage.md"


def _flag(args: list[str], name: str, default: str) -> str:
    return args[args.index(name) + 1] if name in args else default


def _plain(line: str) -> str:
    return line.replace("**", "").replace(" (bound)", "")


def _page_row(plant: str, fault: str, label: str) -> str:
    block = BLOCK.search(PAGE.read_text(encoding="utf-8")).group(4)
    table = block.split(f"<summary>{plant}: every law against every fault</summary>", 1)[1].split("</details>")[0]
    found = [_plain(x) for x in table.splitlines() if _plain(x).startswith(f"| `{fault}` | {label} |")]
    assert len(found) == 1, (plant, fault, label, found)
    return found[0]


def _check(tmp_path: Path, plant: str, controller: str, kind: str, value: str) -> None:
    _, args = commands(PAGE.read_text(encoding="utf-8"))
    assert plant in _flag(args, "--plant", "kh2013a,jsbsim:c172x").split(",")
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "tools.experiment", "damage", "--plant", plant]
    cmd += ["--controllers", f"pid-energy,{controller}", "--kinds", kind, "--severity", f"{kind}={value}"]
    for flag, default in (("--runs", "6"), ("--seed", "1"), ("--turbulence", "light"), ("--duration", "30")):
        cmd += [flag, _flag(args, flag, default)]
    cmd += ["--quiet", "--no-plot", "--workers", "1", "--out", str(out)]
    r = subprocess.run(
        cmd, capture_output=True, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=900
    )
    assert r.returncode == 0, r.stderr
    doc = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    fault = f"{kind}={value}"
    (mine,) = [x for x in rows(doc["cells"], plant) if x["controller"] == controller and x["fault"] == fault]
    assert mine["flights"] == int(_flag(args, "--runs", "6"))
    label = doc["labels"][controller]
    assert _plain(row_line(mine, doc["labels"])) == _page_row(plant, fault, label)


def test_the_block_names_both_commands_and_the_policy():
    ars, damage = commands(PAGE.read_text(encoding="utf-8"))
    assert "--seed" in ars and "--iterations" in ars
    ctrls = _flag(damage, "--controllers", "")
    assert ctrls.split(",")[0] == "all" and "{policy}" in ctrls and "--out" not in damage
    assert re.search(r"\| ARS linear policy \|", PAGE.read_text(encoding="utf-8"))


def test_the_kh2013a_indi_row_at_effectiveness_0_3_is_a_fresh_run(tmp_path):
    """24 KH2013A flights (INDI and the PID at equal effort, fault-free and at 0.3) and the PID's energy design."""
    _check(tmp_path, "kh2013a", "indi", "effectiveness", "0.3")


@pytest.mark.e2e  # 24 JSBSim flights and the PID's energy design on JSBSim
def test_the_c172x_l1_row_at_delay_0_05_is_a_fresh_run(tmp_path):
    _check(tmp_path, "jsbsim:c172x", "l1", "delay", "0.05")
