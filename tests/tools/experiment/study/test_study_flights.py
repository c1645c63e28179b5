"""The robustness study on a JSBSim aircraft or a plant file (``python -m tools.experiment robustness --plant``,
tools.experiment.study.flights): the same results on one and two workers and a real Dask cluster, plant files
flying the SITL's own turbulence, a list of plants in one summary.json, and bad flags in one line."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from sitl.plant import shipped
from tools.experiment.study import StudyOptions, execute, replay, run_study
from tools.experiment.study.flights import StudyFlight, fly_study_flight, make_flights, summarise

ROOT = Path(__file__).resolve().parents[4]
FLIGHTS = make_flights("c172x", ["clsac"], [63.0, 117.0], ["none", "moderate"], 1)
KH_FILE = str(shipped("kh2013a.toml"))
C172_FILE = str(shipped("jsbsim-c172x.toml"))


def _robustness(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "tools.experiment", "robustness", "--no-progress", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=env,
        timeout=timeout,
    )


@pytest.mark.e2e
def test_the_command_gives_the_same_results_on_one_two_workers_and_a_dask_cluster(tmp_path):
    argv = ["--plant", "jsbsim:c172x", "--controllers", "clsac", "--airspeeds", "63,117"]
    argv += ["--turbulence", "none,moderate", "--seeds", "1"]

    def results(*extra: str) -> dict:
        out = tmp_path / f"run{len(list(tmp_path.iterdir()))}"
        r = _robustness(*argv, *extra, "--out", str(out))
        assert r.returncode == 0, r.stderr
        doc = json.loads((out / "summary.json").read_text())
        assert doc["plant"] == "jsbsim:c172x" and doc["kind"] == "jsbsim" and not doc["partial"]
        return doc["results"]

    one = results("--workers", "1")
    assert results("--workers", "2") == one
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, host="127.0.0.1"
    ) as c:
        assert results("--scheduler", c.scheduler_address) == one
    table = one["clsac"]
    # the slow end flies worse than the fast end, turbulence worse than still air, and all stay bounded
    assert table["63kt_none"]["ise_ref_p50"] > table["117kt_none"]["ise_ref_p50"]
    assert table["63kt_moderate"]["ise_ref_p50"] > table["63kt_none"]["ise_ref_p50"]
    assert all(cell["bounded_share"] == 1.0 and cell["runs"] == 1 for cell in table.values())
    # and the executor alone, as tools.bench and the damage study call it: each flight's record
    alone = execute(FLIGHTS, None, None, 2, simulate=fly_study_flight)
    assert [{"seed": f.seed, **r} for f, r in zip(FLIGHTS, alone)] == [
        table[f.condition]["flights"][0] for f in FLIGHTS
    ]


def test_a_flight_of_the_monte_carlo_is_the_in_process_scenario():
    r = fly_study_flight(FLIGHTS[0])
    assert r["bounded"] and r["max_abs_roll"] < math.radians(20.0) and r["sat_fraction"] == 0.0
    assert r == fly_study_flight(FLIGHTS[0])  # a flight depends on its task only


def test_a_plant_file_of_the_kh2013a_flies_the_studys_nominal_run():
    """In still air the KH2013A's plant file, flown in-process at 1 kHz, is the batched study's nominal run (its
    exact ZOH at 100 Hz; docs/spec.md: the same linear system, equal to ~1e-9): an independent solution."""
    flown = fly_study_flight(StudyFlight("clsac", KH_FILE, "none", 0))
    run = next(i for i in range(20) if replay("clsac", "nominal", 0, i, record=False)["pfc_paper"][0])  # paper PFC
    batch = replay("clsac", "nominal", 0, run, record=False)
    for m in ("ise_ref", "energy", "max_abs_roll"):
        assert flown[m] == pytest.approx(float(batch[m][0]), rel=1e-6), m


def test_a_plant_file_flies_seeded_turbulence():
    a, b = (fly_study_flight(StudyFlight("clsac", KH_FILE, "moderate", s)) for s in (7, 8))
    assert a == fly_study_flight(StudyFlight("clsac", KH_FILE, "moderate", 7))  # the seed decides
    assert abs(a["ise_ref"] - b["ise_ref"]) > 0.1 * a["ise_ref"]  # another seed, another gust sequence
    still = fly_study_flight(StudyFlight("clsac", KH_FILE, "none", 7))
    assert a["ise_ref"] > 3 * still["ise_ref"]


@pytest.mark.e2e
def test_a_plant_files_turbulence_is_the_sitls(tmp_path):
    """The in-process flight draws the SITL's own Dryden sequence (sitl.disturbances.Injector, the same seed
    streams): a lockstep flight over MAVLink of the same plant, turbulence and seed scores the same to 0.5 % (the
    float32 roll and the 1 us PWM of the wire apart), where two seeds differ by 50 %."""
    from tools.flight import Flight as Launch

    for seed in (7, 8):
        here = fly_study_flight(StudyFlight("clsac", KH_FILE, "moderate", seed))
        res = Launch(
            lockstep=True,
            plant=KH_FILE,
            turbulence="moderate",
            seed=seed,
            duration=30.0,
            out=tmp_path / f"f{seed}",
            quiet=True,
            png=False,
        ).run()
        assert res.ok, res.reason
        there = res.summary["runs"][0]["metrics"]
        assert here["ise_ref"] == pytest.approx(there["ise_ref"], rel=5e-3)
        assert here["energy"] == pytest.approx(there["energy"], rel=5e-3)


def test_a_list_of_plants_writes_one_summary_with_a_section_each(tmp_path):
    r = _robustness(
        "--plant",
        f"kh2013a,{KH_FILE}",
        "--controllers",
        "clsac,baseline",
        "--runs",
        "3",
        "--sweep-runs",
        "0",
        "--long-runs",
        "0",
        "--seeds",
        "2",
        "--turbulence",
        "none,light",
        "--out",
        str(tmp_path),
    )
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "summary.json").read_text())
    assert list(doc["plants"]) == ["kh2013a", KH_FILE] and doc["partial"] is False
    kh, f = doc["plants"]["kh2013a"], doc["plants"][KH_FILE]
    alone = run_study(
        StudyOptions(runs=3, controllers=("clsac", "baseline"), sweep_runs=0, long_runs=0), None, log=lambda _m: None
    )
    assert kh["results"] == json.loads(json.dumps(alone["results"]))
    assert set(f["results"]) == {"clsac", "baseline"} and set(f["results"]["clsac"]) == {"none", "light"}
    cell = f["results"]["baseline"]["light"]
    assert [x["seed"] for x in cell["flights"]] == [0, 1] and cell["runs"] == 2
    table = (tmp_path / "table.md").read_text()
    assert "## kh2013a\n" in table and f"## {KH_FILE}\n" in table and "| light |" in table


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--plant", "jsbsim:c172x", "--turbulence", "gale"], "unknown turbulence 'gale'"),
        (["--plant", "jsbsim:c999"], "no model 'c999'"),
        (["--plant", ""], "--plant is empty"),
        (["--plant", "kh2013a,"], "--plant has an empty name"),
        (["--conditions", ""], "--conditions is empty"),
        (["--conditions", "nominal,,severe"], "--conditions has an empty name"),
        (["--controllers", ""], "--controllers is empty"),
        (["--scheduler", "localhost:1"], "--scheduler must look like tcp://HOST:PORT"),
        (["--plant", "jsbsim:c172x", "--runs", "5"], "--runs applies to --plant kh2013a only"),
        (["--seeds", "2"], "--seeds applies to a JSBSim aircraft or plant file only"),
        (["--plant", KH_FILE, "--airspeeds", "90"], "--airspeeds applies to a JSBSim aircraft"),
        (["--plant", "jsbsim:c172x", "--controllers", "clsac_leak"], "'clsac_leak' does not fly on --plant"),
        (["--plant", "jsbsim:c172x", "--airspeeds", "nan"], "--airspeeds must be positive and finite"),
        (["--plant", "jsbsim:c172x", "--airspeeds", "150"], "does not trim in level flight at 150 kt"),
        (["--plant", "jsbsim:c172x:airspeed_kt=80", "--airspeeds", "90"], "both give the airspeed"),
        (["--plant", C172_FILE, "--turbulence", "moderate"], "the atmosphere needs the airframe states"),
        (["--plant", "kh2013a,kh2013a"], "--plant names kh2013a twice"),
        (["--plant", "jsbsim:c172x", "--seeds", "0"], "--seeds: must be in [1, 10000]"),
    ],
)
def test_bad_flags_are_one_line_exit_2(tmp_path, args, needle):
    r = _robustness(*args, "--out", str(tmp_path / "out"), timeout=60)
    assert r.returncode == 2 and needle in r.stderr and len(r.stderr.strip().splitlines()) == 1, (args, r.stderr)
    assert not (tmp_path / "out").exists()  # refused before anything started


def test_help_shows_every_default():
    r = _robustness("--help", timeout=60)
    text = " ".join(r.stdout.split())
    assert r.returncode == 0
    for default in (
        "default 1000",
        "default 100)",
        "default 10)",
        "default 2500",
        "default 3)",
        "default none,moderate",
    ):
        assert default in text, default


def test_summarise_gives_the_median_and_the_wilson_interval():
    flights = [StudyFlight("sac", "p.toml", "none", s) for s in range(4)]
    results = [{"ise_ref": v, "energy": 2 * v, "bounded": v < 3} for v in (1.0, 4.0, 2.0, 3.0)]
    cell = summarise(flights, results)["sac"]["none"]
    assert cell["ise_ref_p50"] == 2.5 and cell["energy_p50"] == 5.0 and cell["bounded_share"] == 0.5
    from scipy.stats import binomtest

    ci = binomtest(2, 4).proportion_ci(confidence_level=0.95, method="wilson")
    assert cell["bounded_ci95"] == pytest.approx([ci.low, ci.high], abs=1e-12)
