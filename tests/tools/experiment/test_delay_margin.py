"""tools.experiment.delay_margin: the search against hand-made verdicts, and one real margin checked by flights
flown separately through the damage study's own flight function."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tools.experiment.delay_margin import MarginError, search


def test_search_finds_a_monotone_threshold_to_one_ms():
    flown = []

    def ok(ms):
        flown.append(ms)
        return ms <= 137

    s = search(ok)
    assert s["margin_ms"] == 137 and s["bracket_ms"] == [137, 138] and s["status"] == "bracketed"
    assert s["monotone"] and s["passes_after_failure_ms"] == []
    # the coarse grid by hand: 0..140 step 10 (140 the first failure) and 3 points past it
    assert [g[0] for g in s["grid"]] == [*range(0, 150, 10), 150, 160, 170]
    # bisection of [130, 140] by hand: 135 ok, 137 ok, 138 fails
    assert s["bisection"] == [[135, True], [137, True], [138, False]]
    assert len(flown) == len(set(flown))  # no delay flown twice


def test_search_reports_a_non_monotone_verdict_and_keeps_the_first_failures_bracket():
    def ok(ms):  # passes to 42, fails 43..59, passes again from 60 (a window of failure)
        return ms <= 42 or ms >= 60

    s = search(ok)
    assert not s["monotone"] and s["passes_after_failure_ms"] == [60, 70, 80]
    assert s["margin_ms"] == 42 and s["bracket_ms"] == [42, 43]


def test_search_edges_fails_at_zero_and_above_the_cap():
    s = search(lambda ms: False)
    assert s["margin_ms"] is None and s["status"] == "fails_at_zero"
    assert s["grid"] == [[0, False], [10, False], [20, False], [30, False]]
    s = search(lambda ms: True, cap_ms=45)
    assert s["status"] == "above_cap" and s["margin_ms"] == 45 and [g[0] for g in s["grid"]] == [0, 10, 20, 30, 40, 45]
    with pytest.raises(MarginError):
        search(lambda ms: True, step_ms=0)


def test_bad_flags_exit_2_with_one_line(tmp_path):
    for argv in (["--controllers", "nope"], ["--cap", "nan"], ["--step", "0.0005"], ["--plant", "nope"]):
        r = subprocess.run(
            [sys.executable, "-m", "tools.experiment", "delay-margin", *argv, "--out", str(tmp_path / "o")],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert r.returncode == 2, (argv, r.stderr)
        assert len(r.stderr.strip().splitlines()) <= 2 and "error" in r.stderr  # usage line + the error
        assert not (tmp_path / "o").exists()


@pytest.mark.e2e
def test_the_baseline_margin_on_the_kh2013a_against_flights_flown_separately(tmp_path):
    """The command's margin for the PID on the KH2013A (a 50 ms grid to 300 ms, bisected to 1 ms); then the flights
    at margin - 1, margin and margin + 1 ms flown as the damage study flies them (its DamageFlight task, kind delay at
    0 s, still air): the first two controlled, the third not."""
    from tools.experiment.damage.flight import fly_record
    from tools.experiment.damage.grid import DamageFlight

    out = tmp_path / "m"
    r = subprocess.run(
        [sys.executable, "-m", "tools.experiment", "delay-margin", "--plant", "kh2013a", "--controllers", "baseline",
         "--step", "0.05", "--no-loss", "--workers", "1", "--out", str(out)],
        capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    doc = json.loads((out / "summary.json").read_text())
    m = doc["margin_s"]["kh2013a"]["baseline"]
    assert isinstance(m, float) and 0.05 <= m < 0.3
    (res,) = doc["margins"]
    assert res["bracket_s"] == [m, pytest.approx(m + 0.001)] and res["monotone"]
    ms = round(m * 1000)

    def controlled(d_ms):
        flight = DamageFlight("kh2013a", "baseline", "delay", d_ms / 1000.0, 0.0, 1, 30.0, "none")
        return fly_record(flight)["controlled"]

    assert controlled(ms - 1) and controlled(ms)
    assert not controlled(ms + 1)


def test_the_default_laws_are_every_registered_one_the_plant_flies():
    from autopilot import controllers as registry
    from tools.experiment.delay_margin import controllers_for

    flown, refused = controllers_for("kh2013a", None)
    assert set(registry.NAMES) <= set(flown)
    assert {"baseline", "pid-ff", "mrac", "crm-mrac", "l1", "indi"} <= set(flown) and not refused
    flown, refused = controllers_for("jsbsim:c172x", ["clsac", "clsac-robust", "pid-retuned"])
    assert flown == ["clsac"] and set(refused) == {"clsac-robust", "pid-retuned"}
