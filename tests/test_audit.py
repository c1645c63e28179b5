"""Classes of planted bugs an audit found no test for (issue 17, part 5); fast, no processes.

The bumpless transfer's clamp near the rudder limit, ``tv`` with a non-zero first command, the study's bounded
share, the vehicle's mode numbers and the fault injector's loss independent of its duplicate draw.  Every
expected value is computed here independently (numpy sums, the documented definitions), not read back.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from autopilot.config import ClSacConfig
from autopilot.metrics import MetricsAccumulator
from autopilot.step import TRANSFER_TAU_S, ControlStep, ProfileSetpoints

ROOT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------------------- bumpless transfer clamp
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_bumpless_transfer_is_clamped_at_the_rudder_limit(sign):
    """MANUAL at full rudder, then the law: the command starts at the limit and joins the law's own command
    exponentially (offset * exp(-dt / TRANSFER_TAU_S) per step), never beyond +-u_limit, while the law's command
    plus the offset would pass the limit (the clamp is exercised, not only allowed)."""
    step = ControlStep(ClSacConfig(), setpoints=ProfileSetpoints(lambda t: sign * 0.4))
    lim = step.config.u_limit_rad
    step.manual = sign * lim
    for k in range(20):  # the ground station's full rudder
        assert step(k * 0.01, 0.0).u == sign * lim
    step.manual = None
    step.transfer()
    decay = math.exp(-0.01 / TRANSFER_TAU_S)
    offset = None
    clamped = 0
    for j in range(60):
        r = step((20 + j) * 0.01, 0.0)
        law_u = step.law.u  # the law's own command this step (what flew is r.u)
        if offset is None:
            offset = sign * lim - law_u  # the first command is the last one flown
        unclamped = law_u + offset * decay**j
        clamped += abs(unclamped) > lim
        assert r.u == pytest.approx(max(-lim, min(lim, unclamped)), abs=1e-12), j
        assert abs(r.u) <= lim
    assert clamped >= 1  # the law's command plus the offset went past the limit at least once
    assert abs(r.u - step.law.u) < 0.1 * lim  # and the transfer has nearly joined the law


# ------------------------------------------------------------------------------------------------------ tv
def test_tv_does_not_count_a_step_from_zero_to_the_first_command():
    us = np.array([0.3, 0.1, -0.2, 0.25, 0.25, -0.4])
    acc = MetricsAccumulator(0.01)
    for u in us:
        acc.add(0.0, 0.0, 0.0, float(u))
    assert acc.result()["tv"] == pytest.approx(float(np.sum(np.abs(np.diff(us)))), rel=1e-15)  # 2.05, not 2.35
    assert acc.result()["max_abs_u"] == 0.4


def test_tv_of_a_flight_whose_first_command_is_not_zero():
    step = ControlStep(ClSacConfig(), setpoints=ProfileSetpoints(lambda t: 0.2))
    us = [step(k * 0.01, 0.1 + 0.05 * math.sin(k / 7)).u for k in range(300)]
    assert abs(us[0]) > 1e-3  # the first command is not zero
    tv = float(np.sum(np.abs(np.diff(us))))
    assert step.metrics.result()["tv"] == pytest.approx(tv, rel=1e-12)
    assert step.metrics.result()["energy"] == pytest.approx(float(np.sum(np.square(us))) * 0.01, rel=1e-12)


# ------------------------------------------------------------------------------------ the study's bounded share
def test_study_bounded_is_roll_below_60_deg_and_saturation_below_20_percent():
    """README "Robustness": a run is bounded when |roll| < 60 deg over the whole flight, the rudder is saturated
    less than 20 % of the steps and no 20 s window oscillates or fails to follow (autopilot.envelope; the flags
    themselves against the monitor in tests/test_tracking.py); the share is the bounded runs over all."""
    from tools.experiment.study import Task, aggregate, merge, simulate

    task = Task("clsac", tuple(("severe", i) for i in range(16)), 5)
    runs = simulate(task)
    roll, sat = runs["max_abs_roll"], runs["sat_fraction"]
    inside = (roll < math.radians(60.0)) & (sat < 0.2)
    bounded = inside & ~runs["oscillating"] & ~runs["not_following"]
    assert runs["bounded"].tolist() == bounded.tolist()
    assert 0 < bounded.sum() < 16  # both kinds among these runs
    assert np.any((roll >= math.radians(60.0)) & (sat < 0.2))  # one fails on the roll alone
    assert np.any(inside & runs["oscillating"])  # and one on its limit cycle alone
    share = aggregate(merge([task], [runs])["clsac"], "severe", "clsac", 5)["bounded_share"]
    assert share == pytest.approx(bounded.sum() / 16, abs=1e-15)


def test_study_saturated_share_is_the_share_of_steps_at_the_limit():
    from tools.experiment.study import Task, simulate

    r = simulate(Task("clsac", (("severe", 9),), 5, 30.0, True))
    u = np.array(r["series"]["u"])[:, 0]
    at_limit = float(np.mean(np.abs(u) >= math.radians(30.0) - 1e-12))
    assert float(r["sat_fraction"][0]) == pytest.approx(at_limit, abs=1e-12) and at_limit > 0


# -------------------------------------------------------------------------------------------- mode numbers
def test_mode_numbers_are_the_documented_ones():
    """HEARTBEAT.custom_mode: MANUAL = 0 (ArduPlane's MANUAL too), SAC 100, CLSAC 101, FAILSAFE 102, BASELINE 103,
    as docs/spec.md and the manual (docs/ground-stations.md) say; none of 100..103 has a name in ArduPlane's table."""
    from pymavlink import mavutil

    from autopilot.vehicle import Mode

    documented = {}
    for doc in ("docs/spec.md", "docs/ground-stations.md"):
        text = (ROOT / doc).read_text()
        found = dict(re.findall(r"`?\b(MANUAL|SAC|CLSAC|FAILSAFE|BASELINE|MRAC|CRM_MRAC|L1|INDI|LAW)`? = (\d+)", text))
        documented[doc] = {k: int(v) for k, v in found.items()}
    assert documented["docs/spec.md"] == {
        "MANUAL": 0,
        "SAC": 100,
        "CLSAC": 101,
        "FAILSAFE": 102,
        "BASELINE": 103,
        "MRAC": 104,
        "CRM_MRAC": 105,
        "L1": 106,
        "INDI": 107,
        "LAW": 108,
    }
    assert {m.name: m.value for m in Mode} == documented["docs/spec.md"]
    assert documented["docs/ground-stations.md"]  # the manual names the modes it lets a user select
    assert documented["docs/ground-stations.md"].items() <= documented["docs/spec.md"].items()
    plane = mavutil.mode_mapping_apm  # ArduPlane: number -> name
    assert plane[Mode.MANUAL] == "MANUAL" and not {100, 101, 102, 103} & set(plane)


# ------------------------------------------------------------------------------------ fault injector: loss
def _lost_indices(loss: float, duplicate: float, n: int, seed: int = 7) -> tuple[set[int], int]:
    """Push packets 0..n-1 through one channel; the indices that never arrive (from what is delivered, not the
    channel's counters) and the number of copies delivered."""
    from sitl.faults import FaultChannel, FaultConfig

    ch = FaultChannel(FaultConfig(loss=loss, duplicate=duplicate), np.random.default_rng(seed), delay=0)
    delivered = []
    for k in range(n):
        ch.push(k, k)
        delivered += ch.due(k)
    return set(range(n)) - set(delivered), len(delivered)


def test_loss_is_independent_of_the_duplicate_draw():
    n, p = 20_000, 0.2
    bound = 4.0 * math.sqrt(p * (1 - p) / n)  # 4 sigma of a binomial share: fails by chance ~6e-5 of the time
    lost_0, copies_0 = _lost_indices(p, 0.0, n)
    lost_5, copies_5 = _lost_indices(p, 0.5, n)
    assert abs(len(lost_0) / n - p) < bound and abs(len(lost_5) / n - p) < bound
    # the same packets are lost whatever the duplicate probability: each packet's loss draw is its own
    assert lost_0 == lost_5
    # among the packets that arrive, half arrive twice (duplication does not depend on the loss draw either)
    arrived = n - len(lost_5)
    assert abs((copies_5 - arrived) / arrived - 0.5) < 4.0 * math.sqrt(0.25 / arrived)
    assert copies_0 == n - len(lost_0)
