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

# Every public name, re-exported from the module that defines it, imported at its first use (PEP 562): a
# process that needs one submodule (the launcher's ``tools.design.linearise``) does not load them all.
_WHERE = {
    "PFC_PRESETS": "autopilot.config",
    "AnalysisError": "tools.design._common",
    "CoefficientError": "tools.design._common",
    "PfcError": "tools.design._common",
    "PAPER_PFC": "tools.design.aspr",
    "ROBUST_PFC": "tools.design.aspr",
    "augmented_realisation": "tools.design.aspr",
    "augmented_tf": "tools.design.aspr",
    "damping_ratio": "tools.design.aspr",
    "dc_gain": "tools.design.aspr",
    "hf_gain": "tools.design.aspr",
    "is_minimum_phase": "tools.design.aspr",
    "is_waspr": "tools.design.aspr",
    "parse_coefficients": "tools.design.aspr",
    "pfc_tf": "tools.design.aspr",
    "plant_tf": "tools.design.aspr",
    "relative_degree": "tools.design.aspr",
    "ss_to_tf": "tools.design.aspr",
    "steady_state_offset": "tools.design.aspr",
    "tf_coefficients": "tools.design.aspr",
    "validate_pfc": "tools.design.aspr",
    "GainBand": "tools.design.bands",
    "bilinear_realisation": "tools.design.bands",
    "clsac_kx_bands": "tools.design.bands",
    "compensator_gain_margin": "tools.design.bands",
    "discrete_bands": "tools.design.bands",
    "discretise": "tools.design.bands",
    "unstable_gain_bands": "tools.design.bands",
    "unstable_gain_bands_discrete": "tools.design.bands",
    "paper_scenario_runs": "tools.design.closed_loop",
    "WasprReport": "tools.design.report",
    "analyse": "tools.design.report",
    "first_order_pfc": "tools.design.search",
    "robust_pfc_search": "tools.design.search",
}


def __getattr__(name: str):
    where = _WHERE.get(name)
    if where is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(where), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_WHERE))


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
