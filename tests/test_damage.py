"""The damage study's parts (``tools.experiment.damage``): the task grid, the designs it asks for, a flight's record
and the cells' numbers against independent computations, the faulted linear plants, the in-process faults, and
its flags (one line, exit 2).  Fast: the end-to-end runs are in tests/test_e2e_damage.py."""

from __future__ import annotations

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
        grid.Flight("kh2013a", grid.RETUNED, "effectiveness", 0.3, 10.0, 1),
        grid.Flight("kh2013a", grid.RETUNED, "rate", 5.0, 10.0, 1),
        grid.Flight("kh2013a", grid.ENERGY, "rate", 5.0, 10.0, 1),
        grid.Flight("kh2013a", "clsac", "rate", 5.0, 10.0, 1),
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
        ("effectiveness=abc", "not a list of numbers"),
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
    flights = [grid.Flight("kh2013a", "clsac", "rate", 5.0, 10.0, s) for s in (1, 2, 3)]
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
