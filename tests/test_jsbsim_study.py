"""The JSBSim Monte Carlo (tools.experiment.jsbsim_study) on the study's executor: the same results whatever the
workers."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest

from tools.experiment.jsbsim_study import make_flights, simulate, summarise
from tools.experiment.study import execute

FLIGHTS = make_flights("c172x", ["clsac"], [63.0, 117.0], ["none", "moderate"], 1)


@pytest.mark.e2e
def test_the_monte_carlo_is_the_same_on_one_two_workers_and_a_dask_cluster():
    one = execute(FLIGHTS, None, None, 1, simulate=simulate)
    two = execute(FLIGHTS, None, None, 2, simulate=simulate)
    assert one == two
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c:
        dask = execute(FLIGHTS, c.scheduler_address, None, 1, simulate=simulate)
    assert dask == one
    table = summarise(FLIGHTS, one)["clsac"]
    # the slow end flies worse than the fast end, turbulence worse than still air, and all stay bounded
    assert table["63kt_none"]["ise_ref_p50"] > table["117kt_none"]["ise_ref_p50"]
    assert table["63kt_moderate"]["ise_ref_p50"] > table["63kt_none"]["ise_ref_p50"]
    assert all(cell["bounded_share"] == 1.0 for cell in table.values())


def test_a_flight_of_the_monte_carlo_is_the_in_process_scenario():
    r = simulate(FLIGHTS[0])
    assert r["bounded"] and r["max_abs_roll"] < math.radians(20.0) and r["sat_fraction"] == 0.0
    assert r == simulate(FLIGHTS[0])  # a flight depends on its task only


def test_bad_monte_carlo_flags_are_one_line_exit_2():
    for args, needle in (
        (["--turbulence", "gale"], "unknown turbulence or controller 'gale'"),
        (["--model", "c999"], "no model 'c999'"),
        (["--scheduler", "localhost:1"], "--scheduler must look like tcp://HOST:PORT"),
    ):
        r = subprocess.run(
            [sys.executable, "-m", "tools.experiment.jsbsim_study", *args], capture_output=True, text=True
        )
        assert r.returncode == 2 and needle in r.stderr and len(r.stderr.strip().splitlines()) == 1, args
