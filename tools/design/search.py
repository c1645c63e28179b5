"""The robust PFC search: first-order compensators D = k/(s + a) on a grid, each with its W-ASPR margin.

The paper's D(s) = 10/(4s + 40) = 2.5/(s + 10) (sec. 5) leaves F's zeros almost undamped, so 1 + K_e F is
unstable for two bands of K_e; the manual's ``ROBUST_PFC`` (10/(s + 10)) was chosen from this table.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from tools.design.aspr import (
    augmented_realisation,
    augmented_tf,
    damping_ratio,
    dc_gain,
    is_waspr,
    pfc_tf,
    plant_tf,
    steady_state_offset,
    tf_coefficients,
)
from tools.design.bands import discrete_bands, unstable_gain_bands


def first_order_pfc(k: float, a: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """D(s) = k/(s + a), i.e. C(s) = (s + a)/k (paper sec. 2: D = 1/C, C stabilising T)."""
    return (float(k),), (1.0, float(a))


def robust_pfc_search(
    ks: Sequence[float], as_: Sequence[float], *, rate_hz: float | None = 100.0, command_rad: float = math.radians(10.0)
) -> list[dict]:
    """Evaluate D = k/(s + a) over a grid (the family of the paper's D = 2.5/(s + 10)): W-ASPR, the
    continuous and discrete unstable bands, the least zero damping of F and the steady-state offset.
    Pure computation; the manual's choice of ``ROBUST_PFC`` came from this table."""
    t = plant_tf()
    tn, td = tf_coefficients(t)
    t_dc = dc_gain(tn, td)
    rows = []
    for k in ks:
        for a in as_:
            num, den = first_order_pfc(k, a)
            f = augmented_tf(t, pfc_tf(num, den))
            fn, fd = tf_coefficients(f)
            real = augmented_realisation(num, den)
            zeros = np.roots(fn)
            row = {
                "k": float(k),
                "a": float(a),
                "waspr": is_waspr(fn, fd),
                "min_zero_damping": float(min(damping_ratio(z) for z in zeros)),
                "bands": [(b.low, b.high) for b in unstable_gain_bands(fn, fd, realisation=real)],
                "offset_deg": math.degrees(steady_state_offset(t_dc, k / a, command_rad)["offset"]),
            }
            if rate_hz is not None:
                row["bands_discrete"] = [(b.low, b.high) for b in discrete_bands(real, rate_hz)]
            rows.append(row)
    return rows
