"""The design printout and parameter values of a square MIMO plant (``python -m tools.pfc design``, m > 1).  No I/O.

Each line says what was chosen and how (``tools.design.mimo``, ``tools.design.mimo_baseline``).  The parameters:
channel 1 (the roll on the aileron) keeps the SISO names (``CLSAC_PFC_NUM``, ``_DEN1``, ``_DEN0``, ``PID_KP``,
``_KI``, ``_KD``), channel 2 (the sideslip on the rudder) has them with a 2 (``CLSAC_PFC2_NUM``, ... ``PID2_KD``,
at most 16 characters: PARAM_VALUE's param_id); the six adaptation weights are one Gamma = gamma I for both.
"""

from __future__ import annotations

import math

import numpy as np


def _bands(bands) -> str:
    if not bands:
        return "none"
    return ", ".join(f"[{lo:.4g}, {'inf' if math.isinf(hi) else f'{hi:.4g}'}]" for lo, hi in bands)


def _z(zs) -> str:
    return ", ".join(f"{z.real:.4g}{'' if abs(z.imag) < 1e-12 else f'{z.imag:+.4g}j'}" for z in zs)


def _mismatch(a, b) -> float:
    """The largest distance from a point of ``a`` to the nearest of ``b`` and back (0 when the sets agree)."""
    if not len(a) and not len(b):
        return 0.0
    if len(a) != len(b):
        return math.inf
    return max(max(float(np.min(np.abs(b - z))) for z in a), max(float(np.min(np.abs(a - z))) for z in b))


def channel_names(lp) -> list[str]:
    """ "phi on aileron", ... one per channel."""
    return [f"{y} on the {s}" for y, s in zip(lp.output_names, lp.surfaces)]


def design_text_mimo(lp, plant_text: str, rate_hz: float, margin: float, lv: float) -> tuple[list[str], dict]:
    """The report lines and parameter values of the MIMO design of the plant file ``lp``."""
    from tools.design.mimo import GAMMAS, choose_gamma_mimo, design_pfc_mimo
    from tools.design.mimo_baseline import design_baseline_mimo
    from tools.design.tuning import GAMMA_NAMES

    mats = (lp.a_p, lp.b_p, lp.c_p)
    limits = [v if v is not None else math.radians(30.0) for v in lp.limits_rad]
    names = channel_names(lp)
    pfc = design_pfc_mimo(mats, rate_hz=rate_hz, margin=margin)
    gamma, rows = choose_gamma_mimo(mats, pfc.pfcs, limits, lv=lv, rate_hz=rate_hz)
    base = design_baseline_mimo(mats, rate_hz=rate_hz)
    lines = [
        f"plant {lp.name} ({plant_text}): {lp.m} x {lp.m}, channels "
        + "; ".join(names)
        + ", poles "
        + _z(np.linalg.eigvals(lp.a_p)),
    ]
    for i, (d, (k, a)) in enumerate(zip(pfc.designs, pfc.pfcs)):
        how = d.explain() if i == 0 else d.explain(margin)
        lines.append(f"PFC D_{i + 1}(s) = {k:.6g}/(s + {a:.6g}) ({names[i]}): {how}")
    lines += [
        f"PFC D(s) = diag({', '.join(f'D_{i + 1}' for i in range(lp.m))}); F = T + D: transmission zeros "
        f"{_z(pfc.zeros)} (Rosenbrock pencil; the "
        f"closed loop of C = D^-1 on T gives the same, largest difference "
        f"{_mismatch(pfc.zeros, pfc.zeros_barkana):.2g}); minimum phase "
        f"{'yes' if pfc.minimum_phase else 'NO'}",
        f"C_F B_F = {np.array2string(pfc.cb, precision=5, separator=', ').replace(chr(10), '')}: symmetric positive "
        f"definite {'yes' if pfc.cb_spd else 'NO'} (eigenvalues {_z(np.linalg.eigvals(pfc.cb))}), so relative degree 1 "
        f"in every channel; W-ASPR {'yes' if pfc.waspr else 'NO'}",
        f"the coupled loop C = D^-1 on T stays stable up to {pfc.coupled_margin:.4g} times C (C's own gain margin on "
        "the coupled plant)",
        "unstable K_e bands of u = -K_e y_a on F, along the rays checked (eigenvalues of A_F - k B_F K C_F, and of the "
        f"ZOH loop at {rate_hz:g} Hz, on a log grid of k in [1e-4, 1e5], edges bisected): "
        + "; ".join(f"K_e = {ray}: continuous {_bands(c)}, sampled {_bands(d)}" for ray, (c, d) in pfc.bands.items()),
        f"CL-SAC L_v = {lv:g} I, A_m = -5 I, B_m = 5 I, C_m = I (the paper's reference model per channel)",
        f"adaptation weights Gamma = {gamma:g} I (all six): the smallest of {', '.join(f'{g:g}' for g in GAMMAS)} "
        "whose roll ise_ref (+-10 deg square wave, sideslip command 0, in-process on the linear plant) is within 1.5x "
        "of the best without saturating a surface: "
        + ", ".join(
            f"{r['gamma']:g}: {r['ise_ref']:.4g}, max |beta| {math.degrees(r['max_abs_beta']):.3g} deg"
            f"{' (saturated)' if r['saturated'] else ''}"
            for r in rows
        ),
    ]
    for i, (g, mm) in enumerate(zip(base.gains, base.margins["loops"])):
        how = "the SISO design of its own element" if i == 0 else "the grid's largest crossover with channel 1 closed"
        lines.append(
            f"baseline PID {i + 1} ({names[i]}) K_p {g[0]:.4g}, K_i {g[1]:.4g} 1/s, K_d {g[2]:.4g} s ({how}): with "
            f"the other loop closed gain margin {mm['gain_margin_db']:.1f} dB, phase margin "
            f"{mm['phase_margin_deg']:.1f} deg at {mm['gain_crossover_rad_s']:.3g} rad/s, disk margin "
            f"{mm['disk_margin']:.3g} (+-{mm['disk_gain_db']:.1f} dB, +-{mm['disk_phase_deg']:.1f} deg)"
        )
    dm = base.margins
    lines.append(
        f"baseline multivariable disk margin at the plant input >= {dm['disk_margin']:.3g} (+-{dm['disk_gain_db']:.1f} "
        f"dB, +-{dm['disk_phase_deg']:.1f} deg in every channel at once; 1/max sigma_max(S - I/2)); closed loop "
        f"{'stable' if dm['closed_loop_stable'] else 'UNSTABLE'}"
    )
    values = {}
    for i, (k, a) in enumerate(pfc.pfcs):
        tag = "" if i == 0 else str(i + 1)
        values.update({f"CLSAC_PFC{tag}_NUM": k, f"CLSAC_PFC{tag}_DEN1": 1.0, f"CLSAC_PFC{tag}_DEN0": a})
    values.update({f"CLSAC_GAM_{n.upper()}": gamma for n in GAMMA_NAMES})
    for i, g in enumerate(base.gains):
        tag = "" if i == 0 else str(i + 1)
        values.update(zip((f"PID{tag}_KP", f"PID{tag}_KI", f"PID{tag}_KD"), g))
    return lines, values
