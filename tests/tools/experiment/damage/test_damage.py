"""The damage study's parts (``tools.experiment.damage``): the task grid, the designs it asks for, a flight's record
and the cells' numbers against independent computations, the faulted linear plants, the in-process faults, and
its flags (one line, exit 2).  Fast: the end-to-end runs are in tests/tools/experiment/damage/test_e2e_damage.py."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from tools.experiment.damage import grid
from tools.experiment.damage.aggregate import cell_of, summarise, wilson
from tools.experiment.damage.flight import record


def test_the_grid_is_every_kind_severity_onset_seed_and_controller():
    cells = {"kh2013a": [("effectiveness", 0.3), ("stuck", None)], "jsbsim:c172x": [("rate", 20.0)]}
    flights = grid.make_flights(
        ["kh2013a", "jsbsim:c172x"], ["clsac", "pid-retuned"], cells, [5.0, 10.0], 7, 3, 30.0, "light"
    )
    # per plant x controller x seed: one fault-free flight and one per fault cell and onset
    assert len(flights) == 2 * 3 * (1 + 2 * 2) + 2 * 3 * (1 + 1 * 2)
    assert {f.seed for f in flights} == {7, 8, 9}
    assert len(set(flights)) == len(flights)
    f = next(f for f in flights if f.kind == "effectiveness" and f.onset == 5.0)
    assert f.spec == "effectiveness=0.3@5" and f.runs == (f.seed,)
    assert next(f for f in flights if f.kind == "stuck").spec == "stuck@5"
    assert next(f for f in flights if f.kind == grid.NONE).spec is None
    need = grid.designs_needed(flights)
    assert need == [
        grid.Design("kh2013a", grid.NONE, None),
        grid.Design("kh2013a", "effectiveness", 0.3),
        grid.Design("jsbsim:c172x", grid.NONE, None),
    ]  # stuck and rate are no linear plant: the retuned PID flies the design as built


def test_the_retuned_pid_switches_at_the_onset_and_the_energy_pid_flies_its_scaled_gains():
    flights = [
        grid.DamageFlight("kh2013a", grid.RETUNED, "effectiveness", 0.3, 10.0, 1),
        grid.DamageFlight("kh2013a", grid.RETUNED, "rate", 5.0, 10.0, 1),
        grid.DamageFlight("kh2013a", grid.ENERGY, "rate", 5.0, 10.0, 1),
        grid.DamageFlight("kh2013a", "clsac", "rate", 5.0, 10.0, 1),
    ]
    designed = {
        grid.Design("kh2013a", grid.NONE, None): (1.0, 0.1, 0.2),
        grid.Design("kh2013a", "effectiveness", 0.3): (3.0, 0.3, 0.6),
        grid.Calibration("kh2013a"): (0.5, 0.05, 0.1),
    }
    a, b, c, d = grid.with_designs(flights, designed)
    assert (a.gains, a.schedule) == ((1.0, 0.1, 0.2), ((10.0, (3.0, 0.3, 0.6)),))
    assert (b.gains, b.schedule) == ((1.0, 0.1, 0.2), ())
    assert (c.gains, c.schedule) == ((0.5, 0.05, 0.1), ())
    assert d == flights[3]


def test_severities_and_onsets_are_checked_as_faults():
    assert grid.parse_severity("rate=5,20") == ("rate", (5.0, 20.0))
    assert grid.parse_severity("stuck=here,-5") == ("stuck", (None, -5.0))
    for text, needle in (
        ("rate=0", "rate must be > 0"),
        ("effectiveness=abc", "not a finite number in ASCII digits"),
        ("effectiveness=\uff10.5", "not a finite number in ASCII digits"),
        ("delay=0_1", "not a finite number in ASCII digits"),
        ("bogus=1", "KIND=V1,V2"),
        ("off=1", "no severity"),
        ("delay=", "no values"),
    ):
        with pytest.raises(grid.DamageError, match=needle):
            grid.parse_severity(text)
    with pytest.raises(grid.DamageError, match="inside the flight"):
        grid.check_onsets([40.0], 30.0)


def test_wilson_interval_matches_the_formula_s_known_values():
    # Wilson (1927) at 95 %: 0/2 -> [0, 0.658], 1/2 -> [0.095, 0.905], 10/10 -> [0.722, 1]
    assert wilson(0, 2) == pytest.approx((0.0, 0.6576), abs=1e-4)
    assert wilson(1, 2) == pytest.approx((0.0945, 0.9055), abs=1e-4)
    assert wilson(10, 10) == pytest.approx((0.7225, 1.0), abs=1e-4)
    assert wilson(0, 0) == (0.0, 1.0)


def _series(n=3000, dt=0.01, onset=10.0, boost=3.0):
    t = np.arange(n) * dt
    ym = 0.17 * np.sign(np.sin(2 * np.pi * t / 10.0) + 1e-12)
    phi = ym + 0.01 * np.where(t >= onset, boost, 1.0) * np.sin(3.0 * t)
    return {"t": t, "phi": phi, "ym_ol": ym, "um": ym, "u": 0.05 * np.sin(t)}


def test_a_record_integrates_the_error_after_the_onset_and_per_period():
    s = _series()
    dt = 0.01
    r = record(s, {"ise_ref": 1.0, "energy": 2.0}, 10.0, 10.0, math.radians(30), dt)
    d2 = (s["phi"] - s["ym_ol"]) ** 2
    assert r["ise_ref_after"] == pytest.approx(d2[1000:].sum() * dt, rel=1e-12)
    assert r["ise_ref_before"] == pytest.approx(d2[:1000].sum() * dt, rel=1e-12)
    assert r["ise_ref_periods"] == pytest.approx(
        [d2[i * 1000 : (i + 1) * 1000].sum() * dt for i in range(3)], rel=1e-12
    )
    assert r["ise_ref_periods"][1] > 5 * r["ise_ref_periods"][0]  # the error grew 3x in amplitude after the onset
    assert r["energy_after"] == pytest.approx((s["u"][1000:] ** 2).sum() * dt, rel=1e-12)
    assert r["controlled"] and r["saturated_share"] == 0.0
    assert r["max_abs_roll_deg"] == pytest.approx(math.degrees(np.abs(s["phi"]).max()))
    assert "rudder saturated 0.0 %" in r["reason"]  # the KH2013A's surface, the default


def test_a_record_names_the_surface_that_rolls_the_plant():
    s = _series()
    s["u"] = np.full(3000, math.radians(30))  # on the stop the whole flight
    r = record(s, {"ise_ref": 1.0, "energy": 2.0}, 10.0, 10.0, math.radians(30), 0.01, "aileron")
    assert not r["controlled"] and "aileron saturated 100.0 % of the flight" in r["reason"], r["reason"]
    assert "rudder" not in r["reason"]


def test_a_record_counts_commands_exactly_on_the_stop_and_not_finite_ones_as_saturated():
    """The envelope's one definition (autopilot.envelope.saturated): |u| >= (1 - 1e-9) u_limit or not finite.
    A hand count: 300 samples clipped to exactly +-u_limit, 1 NaN, 200 a hair inside (1 - 2e-9): 301 of 3000."""
    lim = math.radians(30)
    s = _series()
    u = np.zeros(3000)
    u[:150], u[150:300], u[300] = lim, -lim, math.nan
    u[301:501] = lim * (1 - 2e-9)
    s["u"] = u
    r = record(s, {"ise_ref": 1.0, "energy": 2.0}, 10.0, 10.0, lim, 0.01)
    assert r["saturated_share"] == pytest.approx(301 / 3000, abs=1e-12)
    assert "rudder saturated 10.0 % of the flight" in r["reason"]


def test_a_records_recovery_is_judged_in_the_commands_band():
    """The record's recovery (autopilot.recovery): the band from the command (a +-10 deg square: 3 deg), printed in
    the record, and a NaN second after the onset never counted inside it."""
    t = np.arange(3000) * 0.01
    um = np.where(np.floor(t / 5.0) % 2 == 0, 1.0, -1.0) * math.radians(10.0)
    s = {"t": t, "phi": um.copy(), "ym_ol": um, "um": um, "u": np.zeros(3000)}
    r = record(s, {"ise_ref": 1.0, "energy": 2.0}, 10.0, 10.0, math.radians(30), 0.01)
    assert r["recovered"] is True and r["recovery_s"] == 0.0 and r["recovery_band_deg"] == pytest.approx(3.0)
    s["phi"] = np.where(t >= 28.5, math.nan, um)
    r = record(s, {"ise_ref": 1.0, "energy": 2.0}, 10.0, 10.0, math.radians(30), 0.01)
    assert r["recovered"] is False and r["recovery_s"] is None


def test_cells_aggregate_their_seeds():
    recs = [
        {
            "controlled": c,
            "oscillating": False,
            "ise_ref_after": e,
            "energy_after": 1.0,
            "ise_ref": e,
            "energy": 1.0,
            "max_abs_roll_deg": 10.0,
            "recovered": rec,
            "recovery_s": rs,
            "ise_ref_periods": [e, 2 * e],
        }
        for c, e, rec, rs in ((True, 0.1, True, 2.0), (True, 0.3, True, 4.0), (False, 5.0, False, None))
    ]
    cell = cell_of(recs)
    assert (cell["flights"], cell["controlled"]) == (3, 2)
    assert cell["share_controlled"] == pytest.approx(2 / 3)
    assert cell["wilson95"] == pytest.approx(list(wilson(2, 3)))
    assert cell["ise_ref_after_p50"] == 0.3 and cell["ise_ref_periods_p50"] == [0.3, 0.6]
    assert cell["recovered_share"] == pytest.approx(2 / 3) and cell["recovery_s_p50"] == 3.0
    flights = [grid.DamageFlight("kh2013a", "clsac", "rate", 5.0, 10.0, s) for s in (1, 2, 3)]
    (one,) = summarise(flights, recs)
    assert one["fault"] == "rate=5@10" and one["seeds"] == [1, 2, 3] and len(one["runs"]) == 3


def test_the_faulted_linear_plant_is_the_plant_the_sitl_flies():
    from sitl.damage import Effect
    from tools.design.aspr import plant_tf
    from tools.design.linearise import linear_model
    from tools.design.tuning import faulted_plant

    a, b, c, rr = linear_model("kh2013a")
    s = 2.0j
    base = plant_tf((a, b, c))(s)
    # effectiveness scales every control derivative: T(s) exactly times F
    assert plant_tf(faulted_plant((a, b, c), rr, Effect(effectiveness=0.3)))(s) == pytest.approx(0.3 * base)
    fa, _, _ = faulted_plant((a, b, c), rr, Effect(damping=0.5))
    assert fa[1, 1] == 0.5 * a[1, 1] and np.count_nonzero(fa != a) == 1
    with pytest.raises(ValueError, match="not a linear plant"):
        faulted_plant((a, b, c), rr, Effect(stuck=True))


def test_a_delay_costs_the_designed_loop_its_phase_at_crossover():
    # z^-d leaves |L| alone and takes w_c d T of phase at the crossover w_c
    from autopilot.baseline import BaselineConfig
    from tools.design.margins import baseline_margins

    m0 = baseline_margins(BaselineConfig())
    m5 = baseline_margins(BaselineConfig(), delay_steps=5)
    assert m5["gain_crossover_rad_s"] == pytest.approx(m0["gain_crossover_rad_s"], rel=1e-6)
    lost = math.degrees(m0["gain_crossover_rad_s"] * 5 * 0.01)
    assert m0["phase_margin_deg"] - m5["phase_margin_deg"] == pytest.approx(lost, abs=0.05)


def test_an_in_process_fault_starts_at_its_onset_and_not_before():
    from tools.experiment.scenario import PAPER, PAPER_RUNS, run_inprocess

    free = run_inprocess(replace(PAPER, duration_s=12.0), PAPER_RUNS[1]).series
    hit = run_inprocess(replace(PAPER, duration_s=12.0, faults=("stuck@10",)), PAPER_RUNS[1]).series
    t = free["t"]
    assert np.array_equal(free["phi"][t <= 10.0], hit["phi"][t <= 10.0])  # the roll at 10.0 is measured before
    assert np.abs(free["phi"] - hit["phi"])[t > 10.5].max() > math.radians(0.5)
    after = hit["delta_r"][t > 10.0]
    assert np.ptp(after) == 0.0  # the surface is stuck where it was


def test_a_mimo_plant_flies_the_mimo_laws_and_names_the_others_it_does_not():
    mimo = "jsbsim:c172x:surface=aileron+rudder"
    cells = {"kh2013a": [("effectiveness", 0.3)], mimo: [("effectiveness", 0.3)]}
    flights = grid.make_flights(["kh2013a", mimo], list(grid.CONTROLLERS), cells, [10.0], 1, 1, 30.0, "light")
    assert {f.controller for f in flights if f.plant == mimo} == {"baseline", "sac", "clsac"}
    assert {f.controller for f in flights if f.plant == "kh2013a"} == set(grid.CONTROLLERS)
    assert set(grid.controller_refusals(mimo, grid.CONTROLLERS)) == {"pid-ff", grid.RETUNED, grid.ENERGY, *grid.ROBUST}
    # the c172x's design file sets the PFC (and overrides --pfc): the robust preset is not what it flies
    assert set(grid.controller_refusals("jsbsim:c172x", grid.CONTROLLERS)) == set(grid.ROBUST)
    assert grid.controller_refusals("kh2013a", grid.CONTROLLERS) == {}
    assert grid.designs_needed([f for f in flights if f.plant == mimo]) == []  # nothing SISO designed for it
    from tools.experiment.damage.runner import Study, not_flown

    doc = not_flown(Study(plants=("kh2013a", mimo), kinds=("effectiveness", "inertia")))
    assert set(doc[mimo]) == {"controllers"} and "inertia" in doc["kh2013a"]
    assert "controllers" not in doc["kh2013a"]


def test_bad_damage_flags_are_one_line_exit_2(tmp_path):
    for args, needle in (
        (["--kinds", "bogus"], "unknown kind 'bogus'"),
        (["--controllers", "lqr"], "unknown controller 'lqr'"),
        (["--severity", "rate=-5"], "rate must be > 0"),
        (["--onsets", "50"], "inside the flight"),
        (["--plant", "jsbsim:c999"], "c999"),
        (["--scheduler", "localhost:1"], "--scheduler must look like tcp://HOST:PORT"),
        (["--runs", "0"], "--runs"),
        (["--kinds", "inertia", "--plant", "kh2013a"], "no plant flies"),
        (["--plant", "jsbsim:c172x:surface=aileron+rudder", "--controllers", "pid-ff"], "a square MIMO plant flies"),
        (["--out", str(tmp_path / "f"), "--runs", "1"], "not a directory"),
    ):
        if args[:1] == ["--out"]:
            (tmp_path / "f").write_text("")
        r = subprocess.run(
            [sys.executable, "-m", "tools.experiment", "damage", *args], capture_output=True, text=True, timeout=60
        )
        assert r.returncode == 2, (args, r.stderr)
        assert needle in r.stderr and len(r.stderr.strip().splitlines()) == 1, (args, r.stderr)
        assert "Traceback" not in r.stderr


def test_the_printed_tables_rank_and_show_each_cell():
    from tools.experiment.damage.aggregate import markdown_table, period_table, table

    def cell(ctrl, kind, sev, share, after, periods):
        return {
            "plant": "kh2013a",
            "controller": ctrl,
            "kind": kind,
            "severity": sev,
            "onset_s": None if kind == grid.NONE else 10.0,
            "share_controlled": share,
            "ise_ref_after_p50": after,
            "energy_after_p50": 0.5,
            "ise_ref_periods_p50": periods,
        }

    cells = [
        cell("clsac", grid.NONE, None, 1.0, 0.1, [0.05, 0.04, 0.03]),
        cell("baseline", grid.NONE, None, 1.0, 0.2, [0.05, 0.06, 0.07]),
        cell("clsac", "rate", 5.0, 0.5, 3.0, [0.05, 2.0, 0.01]),
        cell("baseline", "rate", 5.0, 1.0, 0.3, [0.05, 0.1, 0.2]),
    ]
    text = table(cells, "kh2013a", ["clsac", "baseline"])
    assert "rate=5" in text and "50 %" in text and "onset 10 s" in text
    # the first period after the onset (10-20 s): baseline first; the last window: CL-SAC first
    for c, first, last in zip(cells, (0.04, 0.06, 2.0, 0.1), (0.03, 0.07, 0.01, 0.2)):
        c["long"] = {
            "first_period": {"start_s": 10.0, "mean": first},
            "last_window": {"from_s": 20.0, "to_s": 30.0, "mean": last, "interval": [last, last]},
        }
    rows = period_table(cells, "kh2013a", ["clsac", "baseline"]).splitlines()
    rate = next(r for r in rows if r.startswith("rate=5"))
    assert "2(2)/0.01 [0.01, 0.01](1)" in rate and "0.1(1)/0.2 [0.2, 0.2](2)" in rate, rate
    md = markdown_table(cells, "kh2013a", ["clsac", "baseline"], energy=True).splitlines()
    assert (
        md[0] == "| fault | CL-SAC | PID (as designed) |"
        and md[3] == "| `rate=5` | 50 % / 3 / 0.5 | 100 % / 0.3 / 0.5 |"
    )


def _study(*flags):
    from tools.experiment.damage.cli import build_parser, study_of

    return study_of(build_parser().parse_args(list(flags)))


def test_the_grid_flies_each_value_once_and_counts_its_flights_by_hand():
    """5000 equal severities, a plant, a kind and a controller given twice are one each (issue 35, item 7): a plant
    and a controller fly per seed one fault-free flight and one per (severity, onset), so 1 plant x 2 controllers x
    2 seeds x (1 + 2 severities x 1 onset) = 12 flights, counted here by hand."""
    study = _study(
        "--plant", "kh2013a,kh2013a", "--kinds", "effectiveness,effectiveness", "--controllers", "clsac,baseline,clsac",
        "--severity", "effectiveness=" + ",".join(["0.3"] * 5000 + ["0.30", "0.6"]), "--runs", "2", "--onsets", "10,10",
    )  # fmt: skip
    assert study.plants == ("kh2013a",) and study.controllers == ("clsac", "baseline")
    assert study.severities["effectiveness"] == (0.3, 0.6) and study.onsets == (10.0,)
    assert study.count() == len(study.flights()) == 1 * 2 * 2 * (1 + 2 * 1)
    # a MIMO plant flies 3 of the 8 controllers: 3 x 1 seed x (1 + 3 default effectiveness severities) = 12 flights
    mimo = _study("--plant", "jsbsim:c172x:surface=aileron+rudder", "--kinds", "effectiveness", "--runs", "1")
    assert mimo.count() == len(mimo.flights()) == 3 * 1 * (1 + 3)


def test_a_grid_above_the_cap_is_refused_in_one_line_naming_the_cap():
    def damage(*flags):
        return subprocess.run(
            [sys.executable, "-m", "tools.experiment", "damage", "--plant", "kh2013a", *flags],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip

    # the defaults on one plant: 8 controllers x 1000 seeds x (1 + 4 kinds x 3 severities) = 104,000 > 20,000
    r = damage("--runs", "1000")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr
    assert "104,000 flights" in r.stderr and "cap of 20,000" in r.stderr and "--max-flights N" in r.stderr
    r = damage("--kinds", "rate", "--severity", "rate=5", "--controllers", "clsac", "--max-flights", "3")
    assert r.returncode == 2 and "the grid has 12 flights, more than the cap of 3" in r.stderr, (
        r.stderr
    )  # 6 seeds x (1 + 1)


def test_the_first_line_names_only_the_designs_asked_for():
    from tools.experiment.damage.runner import plan_line

    plain = _study("--plant", "kh2013a", "--kinds", "effectiveness,rate", "--controllers", "clsac,baseline")
    flights = plain.flights()
    assert plan_line(flights, grid.designs_needed(flights), "1 local process(es)") == (
        f"{len(flights)} flights on 1 local process(es)"
    )
    retuned = _study("--plant", "kh2013a", "--kinds", "effectiveness,rate", "--severity", "effectiveness=0.3",
                     "--controllers", "clsac,pid-retuned")  # fmt: skip
    flights = retuned.flights()
    line = plan_line(flights, grid.designs_needed(flights), "here")
    # the PID as built and retuned for effectiveness 0.3 (rate is no linear plant): 2 designs, no energy calibration
    assert line.startswith(f"{len(flights)} flights and 2 design(s) (2 for pid-retuned") and "energy" not in line


def test_column_headers_are_whole_names_with_a_legend():
    from tools.experiment.damage.aggregate import period_table, table
    from tools.experiment.damage.cli import legend

    names = list(grid.CONTROLLERS)
    cells = [
        {"plant": "kh2013a", "controller": c, "kind": grid.NONE, "severity": None, "onset_s": None,
         "share_controlled": 1.0, "ise_ref_after_p50": 0.1, "ise_ref_periods_p50": [0.1, 0.1]}
        for c in names
    ]  # fmt: skip
    for text in (table(cells, "kh2013a", names), period_table(cells, "kh2013a", names)):
        head = next(line for line in text.splitlines() if line.startswith("fault"))
        assert head.split() == ["fault", *names], head
    assert legend(names) == "columns: " + "; ".join(f"{c} = {grid.LABELS[c]}" for c in names)
    assert "pid-retuned = PID retuned for the fault" in legend(names)


def test_an_error_after_the_first_flight_keeps_the_flights_flown(tmp_path):
    """A study stopped by an error at its third flight: the two flights flown are kept, in a summary that says it is
    partial, how many of how many and why; an error before any flight is raised as it was."""
    from tools.experiment.damage.flight import run_damage_task
    from tools.experiment.damage.runner import run, write

    study = _study("--plant", "kh2013a", "--kinds", "effectiveness", "--severity", "effectiveness=0.3",
                   "--controllers", "clsac,baseline", "--runs", "1", "--duration", "12")  # fmt: skip
    calls = []

    def third_fails(task):
        calls.append(task)
        if len(calls) == 3:
            raise ValueError("the third flight failed")
        return run_damage_task(task)

    quiet = dict(workers=1, progress=False, log=lambda *_: None)
    doc = run(study, simulate=third_fails, **quiet)
    assert doc["partial"] and doc["done"] == {"flights": 2, "of": 4} and doc["flights"] == 2
    assert doc["error"] == "ValueError: the third flight failed"
    assert sum(c["flights"] for c in doc["cells"]) == 2
    assert [(c["controller"], c["kind"]) for c in doc["cells"]] == [(f.controller, f.kind) for f in calls[:2]]
    written, problems = write(doc, tmp_path, plot=False)
    assert problems == [] and json.loads((tmp_path / "summary.json").read_text())["done"] == {"flights": 2, "of": 4}

    def first_fails(task):
        raise ValueError("no flight flies")

    with pytest.raises(ValueError, match="no flight flies"):
        run(study, simulate=first_fails, **quiet)


def test_the_summary_is_standard_json_whatever_its_numbers(tmp_path):
    """A cell's recovery that never came was written as a bare Infinity: now null, which a strict parser reads."""
    from tools.experiment.damage.runner import write

    doc = {
        "cells": [],
        "plants": [],
        "kinds": [],
        "controllers": [],
        "labels": {},
        "x": [math.inf, -math.inf, math.nan],
    }
    write(doc, tmp_path, plot=True)
    text = (tmp_path / "summary.json").read_text()
    assert json.loads(text, parse_constant=lambda c: pytest.fail(c))["x"] == [None, None, None]


def test_sac_and_cl_sac_fly_the_robust_pfc_as_named_controllers():
    from autopilot.config import PFC_PRESETS
    from tools.experiment.damage.flight import _run, _scenario
    from tools.experiment.scenario import controller_config

    scen = _scenario("kh2013a")
    for name, lv in (("sac-robust", 0.0), ("clsac-robust", 20.0), ("sac", 0.0), ("clsac", 20.0)):
        cfg = controller_config(scen, _run(name))
        want = PFC_PRESETS["robust" if name.endswith("-robust") else "paper"]
        assert (tuple(cfg.pfc_num), tuple(cfg.pfc_den)) == want and cfg.lv == lv, name
    assert grid.LABELS["sac-robust"] == "SAC, robust PFC" and "clsac-robust" in grid.CONTROLLERS
