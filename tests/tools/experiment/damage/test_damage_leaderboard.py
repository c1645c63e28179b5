"""tools.experiment.damage.leaderboard against a hand count on a small grid: records made by hand, summarised by the
damage study's own cells (tools.experiment.damage.aggregate.summarise), read back as a leaderboard."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

from tools.experiment.damage.aggregate import summarise
from tools.experiment.damage.grid import DamageFlight
from tools.experiment.damage.leaderboard import markdown, rows, winners


def _rec(controlled, ise, energy, rec_s):
    return {
        "controlled": controlled,
        "reason": "",
        "first_exit_s": None,
        "oscillating": False,
        "not_following": False,
        "max_abs_roll_deg": 12.0,
        "saturated_share": 0.0,
        "ise_ref": ise * 2,
        "energy": energy * 2,
        "ise_ref_after": ise,
        "ise_ref_before": ise,
        "energy_after": energy,
        "ise_ref_periods": [ise / 2, ise / 2, ise / 2],
        "recovered": rec_s is not None,
        "recovery_s": rec_s,
        "recovery_band_deg": 1.0,
        "recovery_reason": "",
    }


# (controller): per seed 1, 2, 3 (controlled, ise_ref after the onset, energy after it, recovery s or None)
HAND = {
    "clsac": [(True, 0.1, 1.0, 2.0), (True, 0.3, 2.0, 4.0), (False, 0.2, 3.0, None)],
    "pid-energy": [(True, 0.4, 4.0, 1.0), (True, 0.5, 4.0, 1.0), (True, 0.6, 4.0, 1.0)],
    "baseline": [(True, 0.2, 5.0, 3.0), (True, 0.2, 6.0, 3.0), (True, 0.3, 7.0, 5.0)],
    "pid-retuned": [(True, 0.01, 1.0, 0.5)] * 3,
}


@pytest.fixture()
def cells():
    flights, results = [], []
    for c, per_seed in HAND.items():
        for seed, r in enumerate(per_seed, 1):
            flights.append(DamageFlight("kh2013a", c, "effectiveness", 0.3, 10.0, seed))
            results.append(_rec(*r))
    return summarise(flights, results)


def test_rows_are_the_hand_count(cells):
    rs = {r["controller"]: r for r in rows(cells, "kh2013a")}
    c = rs["clsac"]
    assert (c["fault"], c["controlled"], c["flights"]) == ("effectiveness=0.3", 2, 3)
    # Wilson 1927 for 2 of 3 at z = 1.96, written out here
    z, n, p = 1.959963984540054, 3, 2 / 3
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    assert c["wilson95"] == pytest.approx([centre - half, centre + half], abs=1e-12)
    assert c["wilson95"] == pytest.approx([0.2077, 0.9385], abs=1e-4)
    assert c["recovery_s_p50"] == pytest.approx(3.0)  # the median of the two that recovered (2, 4)
    assert c["ise_ref_after_p50"] == pytest.approx(0.2) and c["energy_after_p50"] == pytest.approx(2.0)
    assert c["ise_vs_energy_pid"] == pytest.approx(0.2 / 0.5) and c["energy_vs_energy_pid"] == pytest.approx(2 / 4)
    assert rs["pid-energy"]["ise_vs_energy_pid"] is None and rs["pid-energy"]["wilson95"][1] == 1.0
    assert rs["baseline"]["recovery_s_p50"] == pytest.approx(3.0)
    assert (c["recovered"], c["recovery_measured"]) == (2, 3)


def test_the_winner_is_the_highest_share_then_the_least_error_and_never_the_bound(cells):
    # baseline and pid-energy keep 3/3; baseline's median error 0.2 < 0.5; pid-retuned (0.01) is a bound
    assert winners(cells, "kh2013a") == {"effectiveness=0.3": ["baseline"]}
    md = markdown(cells, "kh2013a")
    assert "| `effectiveness=0.3` | **PID (as designed)** | 3/3 |" in md
    assert "PID retuned for the fault (bound)" in md
    assert "- CL-SAC wins 0: none" in md and "- PID (as designed) wins 1: `effectiveness=0.3`" in md


def test_a_fault_no_law_keeps_has_no_winner():
    flights, results = [], []
    for c, err in (("clsac", 5.0), ("baseline", 9.0)):
        for seed in (1, 2):
            flights.append(DamageFlight("kh2013a", c, "stuck", 5.0, 10.0, seed))
            results.append(_rec(False, err, 1.0, None))
    cells = summarise(flights, results)
    assert winners(cells, "kh2013a") == {"stuck=5": []}
    assert "- no law keeps a flight: `stuck=5`" in markdown(cells, "kh2013a")


def test_the_command_prints_a_summarys_leaderboard(cells, tmp_path):
    path = tmp_path / "summary.json"
    path.write_text(json.dumps({"plants": ["kh2013a"], "cells": cells, "labels": {}}))
    r = subprocess.run(
        [sys.executable, "-m", "tools.experiment.damage.leaderboard", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert "### kh2013a" in r.stdout and "**PID (as designed)**" in r.stdout
    r = subprocess.run(
        [sys.executable, "-m", "tools.experiment.damage.leaderboard", str(tmp_path / "nope.json")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1


def test_each_win_is_set_against_the_runner_up_by_hand(cells):
    """baseline wins (3/3, median 0.2); the runner-up is pid-energy (3/3, 0.5), pid-retuned being a bound.  Per seed
    baseline - pid-energy: 0.2 - 0.4, 0.2 - 0.5, 0.3 - 0.6 = -0.2, -0.3, -0.3: median -0.3; with 3 seeds the sign
    test's interval is their range at 1 - 2^(1-3) = 75 %, so no difference is shown; both keep every seed."""
    from tools.experiment.damage.leaderboard import margin_line, margins

    (m,) = margins(cells, "kh2013a").values()
    assert (m["winner"], m["runner_up"]) == ("baseline", "pid-energy")
    d = m["ise_ref_after"]
    assert d["median_diff"] == pytest.approx(-0.3) and d["interval"] == pytest.approx([-0.3, -0.2])
    assert d["confidence"] == pytest.approx(0.75) and not d["shown"]
    assert (m["controlled"]["b_only"], m["controlled"]["a_only"], m["controlled"]["p_value"]) == (0, 0, 1.0)
    line = margin_line("effectiveness=0.3", m, {"baseline": "PID", "pid-energy": "PID-E"})
    assert line.startswith(
        "- `effectiveness=0.3`: PID over PID-E: the same seeds kept (3 common); error -0.3 [-0.3, -0.2]"
    )  # noqa: E501
    assert "no difference shown (3 seeds reach 75 %, 95 % needs 6)" in line


def test_a_win_by_share_counts_the_seeds_only_the_winner_keeps():
    """6 seeds: A keeps all, B loses all: 6 discordant pairs one way, McNemar's exact p = 2 / 2^6 = 0.031."""
    from tools.experiment.damage.leaderboard import margin_line, margins

    flights, results = [], []
    for c, ok in (("clsac", True), ("baseline", False)):
        for seed in range(1, 7):
            flights.append(DamageFlight("kh2013a", c, "delay", 0.05, 10.0, seed))
            results.append(_rec(ok, (0.1, 0.2, 0.3, 0.5, 0.6, 0.7)[seed - 1] if ok else 5.0, 1.0, None))
    m = margins(summarise(flights, results), "kh2013a")["delay=0.05"]
    assert (m["winner"], m["runner_up"]) == ("clsac", "baseline")
    assert (m["controlled"]["b_only"], m["controlled"]["a_only"]) == (6, 0)
    assert m["controlled"]["p_value"] == pytest.approx(2 / 64) and m["controlled"]["shown"]
    # per seed -4.9, -4.8, -4.7, -4.5, -4.4, -4.3: median -4.6, all below 0 at 96.9 %: shown
    d = m["ise_ref_after"]
    assert d["shown"] and d["interval"] == pytest.approx([-4.9, -4.3]) and d["median_diff"] == pytest.approx(-4.6)
    line = margin_line("delay=0.05", m, {})
    assert "kept at 6 seed(s) the other lost, lost at 0 it kept (exact p = 0.031: shown)" in line
    assert line.endswith("error -4.6 [-4.9, -4.3] rad²s: lower, shown")


def test_the_error_column_prints_the_digits_its_interval_supports(cells):
    from tools.experiment.damage.leaderboard import row_line

    r = next(x for x in rows(cells, "kh2013a") if x["controller"] == "clsac")
    # seeds 0.1, 0.3, 0.2: median 0.2, interval (3 seeds: the range) [0.1, 0.3], half width 0.1: one digit
    assert r["ise_ref_after_interval"] == pytest.approx([0.1, 0.3]) and r["ise_ref_after_digits"] == 1
    assert "| 0.2 [0.1, 0.3] |" in row_line(r, {})


def test_the_page_block_is_rewritten_from_a_summary_and_names_its_commands(cells, tmp_path):
    from tools.experiment.damage.leaderboard import commands, main

    page = tmp_path / "page.md"
    page.write_text(
        "# t\n\nbefore\n\n<!-- leaderboard-ars: --seed 1 --iterations 2 -->\n"
        "<!-- leaderboard-damage: --plant kh2013a --controllers all,{policy} --runs 3 -->\nstale\n"
        "<!-- /leaderboard -->\n\nafter\n"
    )
    ars, damage = commands(page.read_text())
    assert ars == ["--seed", "1", "--iterations", "2"]
    assert damage == ["--plant", "kh2013a", "--controllers", "all,{policy}", "--runs", "3"]
    path = tmp_path / "summary.json"
    path.write_text(json.dumps({"plants": ["kh2013a"], "cells": cells, "labels": {}}))
    assert main([str(path), "--page", str(page)]) == 0
    text = page.read_text()
    assert "stale" not in text and text.startswith("# t\n\nbefore\n")
    assert text.endswith("<!-- /leaderboard -->\n\nafter\n")
    assert "<details><summary>kh2013a: every law against every fault</summary>" in text
    assert "- PID (as designed) wins 1: `effectiveness=0.3`" in text
    assert "- `effectiveness=0.3`: PID (as designed) over PID at CL-SAC's energy:" in text
    assert main([str(path), "--page", str(tmp_path / "none.md")]) == 2


@pytest.mark.e2e  # one ARS iteration of 2 directions, then 4 KH2013A flights
def test_fly_trains_the_policy_flies_the_blocks_command_and_writes_the_page(tmp_path):
    page = tmp_path / "page.md"
    page.write_text(
        "<!-- leaderboard-ars: --seed 1 --iterations 1 --directions 2 --top 1 -->\n"
        "<!-- leaderboard-damage: --plant kh2013a --controllers baseline,{policy} --kinds effectiveness "
        "--severity effectiveness=0.3 --runs 1 --seed 1 -->\nstale\n<!-- /leaderboard -->\n"
    )
    cmd = [sys.executable, "-m", "tools.experiment.damage.leaderboard", "--fly", str(tmp_path / "o")]
    r = subprocess.run(
        [*cmd, "--page", str(page)],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    assert json.loads((tmp_path / "o" / "ars" / "policy.json").read_text())["settings"]["seed"] == 1
    doc = json.loads((tmp_path / "o" / "damage" / "summary.json").read_text())
    assert doc["runs"] == 1 and any(c.endswith("policy_law.py:Policy") for c in doc["controllers"])
    text = page.read_text()
    assert "stale" not in text and "| `effectiveness=0.3` | ARS linear policy | " in text.replace("**", "")
