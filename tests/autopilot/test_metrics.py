"""The flight's metrics (autopilot.metrics.MetricsAccumulator): ``tv``, the total variation of the command, counts
no step from zero to the first command, alone and in a flight whose first command is not zero; the energy is the sum
of the squared commands times the period.  Every expected value is a numpy sum computed here, not read back.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.config import ClSacConfig
from autopilot.metrics import MetricsAccumulator
from autopilot.step import ControlStep, ProfileSetpoints


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
