"""The batch laws (autopilot.batch) against the scalar laws, bit for bit, on sampled runs of the study."""

from __future__ import annotations

import numpy as np
import pytest

from autopilot.baseline import Baseline
from autopilot.batch import BatchClSac
from autopilot.clsac import ClSac
from autopilot.config import ClSacConfig, ConfigError
from autopilot.controllers import studied
from tools.experiment.study import Task, replay, simulate

SAMPLED = [
    ("clsac", "severe", 3),
    ("clsac", "moderate", 11),
    ("sac", "moderate", 5),
    ("clsac_lv50", "severe", 8),
    ("clsac_leak", "severe", 2),
    ("clsac_deadzone", "moderate", 4),
    ("clsac_projection", "severe", 9),
    ("clsac_freeze", "severe", 1),
    ("baseline", "severe", 6),
]


@pytest.mark.parametrize("controller, condition, run", SAMPLED)
def test_batch_law_equals_the_scalar_law_bit_for_bit_on_study_runs(controller, condition, run):
    """Replay what the batch law was fed in a study run (measured roll, command) through the scalar law: every
    command and every integral gain is the same double."""
    r = replay(controller, condition, seed=4, run=run, duration_s=10.0, record=True)
    s = {k: v[:, 0] for k, v in r["series"].items()}
    ctrl = studied(controller)  # the registry's (autopilot.controllers)
    pfc = "paper" if r["pfc_paper"][0] else "robust"
    law = ClSac(ctrl.study_config(pfc, 100.0, np.radians(30.0))) if ctrl.law == "clsac" else Baseline()
    u = np.array([law(y, um) for y, um in zip(s["phi"].tolist(), s["um"].tolist())])
    assert np.array_equal(u, s["u"])
    assert np.array_equal(np.array([law.e]), s["e"][-1:])
    if ctrl.law == "clsac":
        # the gains used in the last step are those the batch exposed
        assert (law.kie, law.kix, law.kiu) == (s["kie"][-1], s["kix"][-1], s["kiu"][-1])


def test_batch_element_does_not_depend_on_the_rest_of_the_batch():
    """A run's numbers are the same alone, in a chunk, or with other conditions around it."""
    pairs = tuple(("severe", i) for i in range(7)) + tuple(("moderate", i) for i in range(5))
    whole = simulate(Task("clsac", pairs, 11, 10.0))
    parts = [simulate(Task("clsac", pairs[a:b], 11, 10.0)) for a, b in ((0, 3), (3, 4), (4, 12))]
    for key in ("ise_ref", "ise_crm", "energy", "tv", "max_abs_u", "max_abs_roll", "sat_fraction", "bounded"):
        assert np.array_equal(whole[key], np.concatenate([p[key] for p in parts])), key
    alone = simulate(Task("clsac", (pairs[9],), 11, 10.0))
    assert alone["ise_ref"][0] == whole["ise_ref"][9]


def test_batch_of_mixed_pfcs_and_switch_check():
    cfgs = [ClSacConfig(), ClSacConfig().with_pfc("robust"), ClSacConfig(lv=0.0)]
    law = BatchClSac(cfgs)
    scalar = [ClSac(c) for c in cfgs]
    rng = np.random.default_rng(0)
    for y, um in rng.normal(0, 0.2, (400, 2)):
        ys = np.full(3, y)
        assert np.array_equal(law(ys, np.full(3, um)), [c(y, um) for c in scalar])
    with pytest.raises(ConfigError, match="same"):
        BatchClSac([ClSacConfig(), ClSacConfig(ki_max=1.0)])


def test_batch_plant_matches_the_sitl_aircraft_to_rounding():
    """The study's plant (explicit sums over the 10 ms ZOH) and sitl.Aircraft (1 ms ZOH steps collapsed with BLAS
    products) are the same linear system computed in a different order: equal to ~1e-9 relative, not bit for bit."""
    from tools.experiment.scenario import PAPER, PAPER_RUNS, run_inprocess

    ref = run_inprocess(PAPER, PAPER_RUNS[1]).metrics
    pairs = tuple(("nominal", i) for i in range(8))
    r = simulate(Task("clsac", pairs, 0))
    i = int(np.flatnonzero(r["pfc_paper"])[0])  # a run with the paper's PFC, like run_inprocess
    for key in ("ise_ref", "ise_crm", "energy", "max_abs_u"):
        assert r[key][i] == pytest.approx(ref[key], rel=1e-8), key
