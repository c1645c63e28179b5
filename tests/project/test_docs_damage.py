"""docs/damage.md's tables are what the damage study prints for their commands: each block of tables on the page
sits between ``<!-- damage-tables: ARGS -->`` and ``<!-- /damage-tables -->``, ARGS its command's flags; a row of
each is flown again with the block's seeds, turbulence and length, for two of its laws (the PID as designed and
CL-SAC, whose cells do not depend on the other laws flown), and every printed digit compared with the page
(``tools.experiment.damage.aggregate.markdown_tables``).  A flight depends on its task only, so the tolerance is
none: a stale table fails."""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "damage.md"
BLOCK = re.compile(r"<!-- damage-tables: ([^\n]*?) -->\n(.*?)<!-- /damage-tables -->", re.S)
COLUMNS = ("PID (as designed)", "CL-SAC", "PID (as designed) - CL-SAC")


def _blocks() -> list[tuple[list[str], str]]:
    return [(shlex.split(m.group(1)), m.group(2)) for m in BLOCK.finditer(PAGE.read_text(encoding="utf-8"))]


def _flag(args: list[str], name: str, default: str) -> str:
    return args[args.index(name) + 1] if name in args else default


def _tables(text: str) -> dict:
    """Every entry of the markdown tables of ``text``: {(plant, fault, column): entry}; a table's plant is the
    ``PLANT:`` line above it, or its own "plant" column (the long flights'); the fault without its ``@onset``."""
    out, rows, plant = {}, [], None
    for line in [*text.splitlines(), ""]:
        if line.startswith("|"):
            rows.append([c.strip() for c in line.strip().strip("|").split("|")])
            continue
        if rows:
            head, body = rows[0], rows[2:]
            own = head[:2] == ["plant", "fault"]
            for r in body:
                where, fault, cells = (r[0], r[1], r[2:]) if own else (plant, r[0], r[1:])
                for h, v in zip(head[2:] if own else head[1:], cells):
                    out.setdefault((where, re.sub(r"@[\d.]+`$", "`", fault), h), []).append(v)
            rows = []
        if re.fullmatch(r"\S+:", line.strip()):
            plant = line.strip()[:-1]
    return out


def _fresh(tmp_path: Path, args: list[str], plant: str, kind: str, value: str) -> str:
    from tools.experiment.damage.aggregate import markdown_tables

    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "tools.experiment", "damage", "--plant", plant, "--controllers", "baseline,clsac"]
    cmd += ["--kinds", kind, "--severity", f"{kind}={value}", "--quiet", "--no-plot", "--out", str(out)]
    for flag, default in (("--runs", "6"), ("--seed", "1"), ("--turbulence", "light"), ("--duration", "30")):
        cmd += [flag, _flag(args, flag, default)]
    r = subprocess.run(
        cmd, capture_output=True, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=900
    )
    assert r.returncode == 0, r.stderr
    return markdown_tables(json.loads((out / "summary.json").read_text(encoding="utf-8")))


def _block(plant: str, turbulence: str = "light", long: bool = False) -> tuple[list[str], str]:
    """The page's block flown on ``plant`` in ``turbulence`` (30 s flights, or ``long``: >= 60 s)."""
    for args, text in _blocks():
        plants = _flag(args, "--plant", "kh2013a,jsbsim:c172x").split(",")
        if plant in plants and _flag(args, "--turbulence", "light") == turbulence:
            if (float(_flag(args, "--duration", "30")) >= 60) == long:
                return args, text
    raise AssertionError(f"docs/damage.md has no table block for {plant}, {turbulence}")


def _check(tmp_path: Path, block: tuple[list[str], str], plant: str, kind: str, value: str) -> None:
    args, page = block
    want, got = _tables(page), _tables(_fresh(tmp_path, args, plant, kind, value))
    compared = 0
    for (where, fault, col), entries in got.items():
        if col in COLUMNS and fault in ("none", f"`{kind}={value}`"):
            page = want.get((where, fault, col), [])
            assert all(e in page for e in entries), (where, fault, col, entries, page)
            compared += len(entries)
    assert compared >= 4, got


def test_every_table_block_names_its_command():
    blocks = _blocks()
    assert len(blocks) >= 2
    for args, text in blocks:
        assert "|---|" in text and all(not a.startswith("--out") for a in args)


def test_the_main_tables_kh2013a_row_is_a_fresh_run(tmp_path):
    """The KH2013A at effectiveness 0.3 (and fault-free), the page's 6 seeds in light turbulence: 24 flights."""
    _check(tmp_path, _block("kh2013a"), "kh2013a", "effectiveness", "0.3")


def test_the_still_air_tables_kh2013a_row_is_a_fresh_run(tmp_path):
    _check(tmp_path, _block("kh2013a", "none"), "kh2013a", "delay", "0.05")


@pytest.mark.e2e  # 12 JSBSim flights
def test_the_still_air_tables_c172x_row_is_a_fresh_run(tmp_path):
    _check(tmp_path, _block("jsbsim:c172x", "none"), "jsbsim:c172x", "damping", "0.3")


@pytest.mark.e2e  # 24 JSBSim flights
def test_the_main_tables_c172x_row_is_a_fresh_run(tmp_path):
    _check(tmp_path, _block("jsbsim:c172x"), "jsbsim:c172x", "effectiveness", "0.3")


@pytest.mark.e2e  # 8 KH2013A flights of 300 s
def test_the_long_flights_kh2013a_row_is_a_fresh_run(tmp_path):
    _check(tmp_path, _block("kh2013a", long=True), "kh2013a", "effectiveness", "0.3")
