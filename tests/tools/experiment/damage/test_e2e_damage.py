"""The damage study end to end (issue 29, item 3): the must-show command as a user runs it, its numbers the same on
one process, two and a real Dask cluster, and an in-process faulted flight equal to the lockstep MAVLink flight with
``--fault`` (three real processes over UDP)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time
from dataclasses import replace

import numpy as np
import pytest

from tests._mavlink_procs import run_cli

pytestmark = pytest.mark.e2e

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def test_the_must_show_damage_study(tmp_path):
    # the must-show's command with the three laws it names (the suite's longest test with the default eight); the
    # retuned PID's designs on the same grid are checked below, without flying it
    out = tmp_path / "damage"
    t0 = time.perf_counter()
    r = subprocess.run(
        [sys.executable, "-m", "tools.experiment", "damage", "--plant", "kh2013a,jsbsim:c172x", "--runs", "2",
         "--seed", "1", "--controllers", "baseline,sac,clsac", "--out", str(out), "--quiet"],
        capture_output=True,
        text=True,
        timeout=1800,
    )  # fmt: skip
    wall = time.perf_counter() - t0
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads((out / "summary.json").read_text())
    assert doc["controllers"] == ["baseline", "sac", "clsac"]
    assert {"effectiveness", "stuck", "rate", "delay"} <= set(doc["kinds"])
    assert doc["plants"] == ["kh2013a", "jsbsim:c172x"] and doc["seeds"] == [1, 2]
    png = (out / "damage.png").read_bytes()
    assert png[:8] == PNG_SIGNATURE and png[12:16] == b"IHDR"
    cells = doc["cells"]
    kinds = {(c["plant"], c["kind"]) for c in cells}
    assert {(p, k) for p in doc["plants"] for k in ("none", "effectiveness", "stuck", "rate", "delay")} <= kinds
    for c in cells:
        assert c["flights"] == 2 and 0.0 <= c["share_controlled"] <= 1.0
        lo, hi = c["wilson95"]
        assert lo <= c["share_controlled"] <= hi
    # what must hold whatever the controllers: a surface jammed 5 deg off keeps rolling the aircraft away
    jammed = [c for c in cells if c["kind"] == "stuck" and c["severity"] == 5.0]
    assert jammed and all(c["share_controlled"] == 0.0 for c in jammed)
    # each law is paired with CL-SAC on the common seeds, with an interval (2 seeds: the range, at 50 %)
    pairs = [p for p in doc["paired"] if p["b"] == "baseline" and p["kind"] == "effectiveness"]
    assert pairs and all(p["a"] == "clsac" and len(p["ise_ref_after_diff"]["interval"]) == 2 for p in pairs)
    assert all(p["ise_ref_after_diff"]["verdict"].startswith("no difference shown") for p in pairs)
    assert "flights" in r.stdout and "wrote" in r.stdout
    print(f"must-show damage study: {doc['flights']} flights, {wall:.0f} s wall")


def test_every_retuned_pid_of_the_must_show_grid_meets_the_rule_that_designed_it():
    """The retuned PID on the must-show's grid (both plants, every linear fault): each design the study makes for it
    (``grid.designs_needed``, ``flight.design``: the study's own tasks) meets the rule that designed the c172x's
    PID (``tools.design.tuning``), the fault's delay included."""
    from tools.experiment.damage import grid
    from tools.experiment.damage.cli import build_parser, study_of
    from tools.experiment.damage.flight import design

    flags = ["--plant", "kh2013a,jsbsim:c172x", "--runs", "2", "--seed", "1", "--controllers", "pid-retuned"]
    needed = grid.designs_needed(study_of(build_parser().parse_args(flags)).flights())
    linear = {(d.plant, d.kind) for d in needed}
    assert {(p, k) for p in ("kh2013a", "jsbsim:c172x") for k in ("none", "effectiveness", "delay")} == linear
    for d in needed:
        m = design(d)["margins"]
        assert m["closed_loop_stable"] and m["phase_margin_deg"] >= 60 and m["gain_margin_db"] >= 10, (d, m)
        assert m["gain_crossover_rad_s"] <= 5.0, (d, m)


def test_the_study_is_the_same_on_one_two_workers_and_a_dask_cluster():
    from tools.experiment.damage.runner import Study, run

    study = Study(
        plants=("kh2013a",),
        controllers=("clsac", "pid-retuned", "pid-energy"),
        kinds=("effectiveness", "rate"),
        severities={"effectiveness": (0.3,), "rate": (5.0,)},
        runs=1,
        duration=20.0,
    )
    quiet = dict(progress=False, log=lambda *_: None)
    one = run(study, workers=1, **quiet)
    two = run(study, workers=2, **quiet)
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c:
        dask = run(study, scheduler=c.scheduler_address, **quiet)
    for key in ("cells", "designs"):
        assert one[key] == two[key] == dask[key], key
    energy = next(d for d in one["designs"] if d["task"] == "calibration")
    assert energy["energy"] == pytest.approx(energy["energy_clsac"], rel=1e-3)  # matched to CL-SAC's effort
    sched = {c["controller"]: c for c in one["cells"] if c["kind"] == "effectiveness"}
    assert sched["pid-retuned"]["share_controlled"] == 1.0


def test_an_in_process_faulted_flight_is_the_lockstep_flight_with_the_fault(tmp_path):
    from autopilot.shared.pwm import PwmMap
    from tools.experiment.scenario import PAPER, PAPER_RUNS, run_inprocess

    r = run_cli(
        "tools.launch", "--lockstep", "--quiet", "--duration", "20", "--fault", "effectiveness=0.3@10",
        "--out", str(tmp_path), timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    with np.load(tmp_path / "autopilot_series.npz") as a:
        t, phi = a["t"], a["phi"]
    summary = json.loads((tmp_path / "summary.json").read_text())
    res = run_inprocess(replace(PAPER, duration_s=20.0, faults=("effectiveness=0.3@10",)), PAPER_RUNS[1], wire=PwmMap())
    assert np.array_equal(t, res.series["t"])
    # as tests/tools/flight/test_e2e_lockstep.py: the same ControlStep on both sides, float32 on the wire, 1 us PWM:
    # the roll series and the metrics are equal to the last bit, before and after the fault
    assert np.array_equal(phi, res.series["phi"])
    assert summary["runs"][0]["metrics"] == res.metrics
    free = run_inprocess(replace(PAPER, duration_s=20.0), PAPER_RUNS[1], wire=PwmMap()).series["phi"]
    assert np.abs(free - phi)[t > 10.5].max() > math.radians(0.5)  # and the fault did change the flight


def test_ctrl_c_keeps_the_flights_flown_in_a_partial_summary(tmp_path):
    """SIGINT to a real damage study once some flights are done (issue 35, item 7): exit 130, one line saying what
    was kept, and a summary.json that says it is partial with the flights flown: as many as its cells hold."""
    import re
    import signal

    out = tmp_path / "d"
    p = subprocess.Popen(
        [sys.executable, "-m", "tools.experiment", "damage", "--plant", "kh2013a", "--kinds", "effectiveness,rate",
         "--controllers", "clsac,baseline", "--runs", "3", "--duration", "20", "--workers", "1", "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    seen = ""
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline:  # the progress bar: "damage [###...] N/42 ..."
        ch = p.stderr.read(1)
        if not ch:
            break
        seen += ch
        m = re.findall(r"\] (\d+)/(\d+) ", seen)
        if m and int(m[-1][0]) >= 3:
            break
    p.send_signal(signal.SIGINT)
    rest_out, rest_err = p.communicate(timeout=120)
    err = seen + rest_err
    assert p.returncode == 130 and "Traceback" not in err, err[-2000:]
    assert "interrupted: kept " in err and "(partial)" in err
    doc = json.loads((out / "summary.json").read_text())
    total = 2 * 3 * (1 + 3 + 3)  # controllers x seeds x (the fault-free flight + 3 effectiveness + 3 rate severities)
    assert doc["partial"] is True and doc["done"]["of"] == total and 3 <= doc["done"]["flights"] < total
    assert doc["flights"] == doc["done"]["flights"] == sum(c["flights"] for c in doc["cells"])
    assert f"kept {doc['flights']} of {total} flights" in err


def test_a_full_disk_keeps_the_summary_and_names_the_picture(tmp_path):
    """A real tmpfs with 48 kB free: the summary (about 27 kB, the paired statistics included) is written, damage.png
    (about 37 kB) does not fit: one line naming it, exit 1, no half picture and no temporary file."""
    from tests._small_disk import fill, leftovers, small_disk

    with small_disk(tmp_path / "disk", 300) as disk:
        fill(disk, leave_kb=48)
        out = disk / "d"
        r = subprocess.run(
            [sys.executable, "-m", "tools.experiment", "damage", "--plant", "kh2013a", "--kinds", "effectiveness",
             "--controllers", "clsac,baseline", "--runs", "1", "--duration", "20", "--out", str(out), "--quiet"],
            capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        assert r.returncode == 1 and "Traceback" not in r.stdout + r.stderr, r.stdout + r.stderr
        assert r.stderr.strip().splitlines() == [
            f"python -m tools.experiment damage: error: could not write {out / 'damage.png'}: No space left on device"
        ]
        doc = json.loads((out / "summary.json").read_text())
        assert doc["flights"] == 2 * 1 * (1 + 3) and doc["partial"] is False
        assert not (out / "damage.png").exists() and leftovers(disk) == []
