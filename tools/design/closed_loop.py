"""Closed-loop summaries: the paper scenario's five runs flown in-process with a given PFC.

What the W-ASPR analysis predicts (an unstable K_e band, a steady-state offset) checked against the
closed loop it describes: metrics of docs/spec.md, "Metrics", and the largest error gain K_e reached.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np


def paper_scenario_runs(num: Sequence[float], den: Sequence[float]) -> list[dict]:
    """The paper scenario's runs (``tools.experiment.scenario.PAPER_RUNS``: SAC and CL-SAC at four L_v) in-process with
    the PFC D(s) = num/den: ``name``, ``Lv``, ``metrics`` and ``ke_max`` (dimensionless) per run."""
    from autopilot.config import ClSacConfig
    from tools.experiment.scenario import PAPER, PAPER_RUNS, run_inprocess

    base = ClSacConfig(pfc_num=tuple(num), pfc_den=tuple(den))
    out = []
    for run in PAPER_RUNS:
        res = run_inprocess(PAPER, run, base=base)
        ke = res.series["ke"]
        out.append({"name": run.name, "Lv": run.lv, "metrics": res.metrics, "ke_max": float(np.max(ke))})
    return out
