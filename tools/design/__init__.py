"""W-ASPR analysis of the KH2013A roll plant with a parallel feedforward compensator (PFC).  No I/O.

Jana & Bhat 2017, sec. 2 (W-ASPR conditions, PFC D(s) = 1/C(s)) and sec. 5 (the plant T(s), the PFC
D(s) = 10/(4s + 40) and the augmented plant F(s) = T(s) + D(s)).  One module per topic:

* ``plant``: T(s) = C_p (sI - A_p)^-1 B_p, D(s), F(s) = T(s) + D(s) and a realisation of F; the W-ASPR
  conditions of F (minimum phase, relative degree <= 1, positive high-frequency gain); parsing and
  validating a PFC; the steady-state error the PFC adds;
* ``bands``: the constant output-feedback gains K_e > 0 for which 1 + K_e F(s) is unstable, continuous
  and ZOH-sampled at the control rate; the compensator's gain margin; CL-SAC's K_x loop;
* ``report``: :func:`analyse` and :class:`WasprReport`, everything ``python -m tools.pfc`` prints;
* ``search``: the grid search over D = k/(s + a) that chose ``ROBUST_PFC``;
* ``closed_loop``: the paper scenario flown in-process with a PFC (metrics and the largest K_e).

``from tools import design; design.analyse(...)``: every public name is re-exported here.
python-control and scipy are imported on first use, so ``python -m tools.pfc --help`` answers at once.
"""

from __future__ import annotations

from autopilot.config import PFC_PRESETS
from tools.design._common import AnalysisError, CoefficientError, PfcError
from tools.design.aspr import (
    PAPER_PFC,
    ROBUST_PFC,
    augmented_realisation,
    augmented_tf,
    damping_ratio,
    dc_gain,
    hf_gain,
    is_minimum_phase,
    is_waspr,
    parse_coefficients,
    pfc_tf,
    plant_tf,
    relative_degree,
    ss_to_tf,
    steady_state_offset,
    tf_coefficients,
    validate_pfc,
)
from tools.design.bands import (
    GainBand,
    bilinear_realisation,
    clsac_kx_bands,
    compensator_gain_margin,
    discrete_bands,
    discretise,
    unstable_gain_bands,
    unstable_gain_bands_discrete,
)
from tools.design.closed_loop import paper_scenario_runs
from tools.design.report import WasprReport, analyse
from tools.design.search import first_order_pfc, robust_pfc_search

__all__ = [
    "PFC_PRESETS",
    "PAPER_PFC",
    "ROBUST_PFC",
    "AnalysisError",
    "PfcError",
    "CoefficientError",
    "parse_coefficients",
    "validate_pfc",
    "tf_coefficients",
    "ss_to_tf",
    "plant_tf",
    "pfc_tf",
    "augmented_tf",
    "augmented_realisation",
    "relative_degree",
    "hf_gain",
    "is_minimum_phase",
    "is_waspr",
    "damping_ratio",
    "dc_gain",
    "steady_state_offset",
    "GainBand",
    "unstable_gain_bands",
    "bilinear_realisation",
    "unstable_gain_bands_discrete",
    "discretise",
    "discrete_bands",
    "compensator_gain_margin",
    "clsac_kx_bands",
    "WasprReport",
    "analyse",
    "first_order_pfc",
    "robust_pfc_search",
    "paper_scenario_runs",
]
