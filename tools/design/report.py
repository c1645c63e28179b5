"""The W-ASPR report: everything ``python -m tools.pfc`` prints about a PFC, computed by :func:`analyse`.

Paper secs. 2 and 5: T(s), D(s) and F(s) = T(s) + D(s) with their zeros and poles, the W-ASPR conditions
of F, the unstable bands of constant K_e (continuous and sampled at the control rate), how far C = 1/D is
from destabilising T, the CL-SAC K_x loop and the steady-state error the PFC adds, with notes in words.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from tools.design._common import AnalysisError, fmt_complex
from tools.design.aspr import (
    PAPER_PFC,
    augmented_realisation,
    augmented_tf,
    damping_ratio,
    dc_gain,
    hf_gain,
    is_minimum_phase,
    is_waspr,
    pfc_tf,
    plant_tf,
    relative_degree,
    steady_state_offset,
    tf_coefficients,
)
from tools.design.bands import (
    GainBand,
    clsac_kx_bands,
    compensator_gain_margin,
    discrete_bands,
    unstable_gain_bands,
)


@dataclass
class WasprReport:
    """Everything ``python -m tools.pfc`` prints.  Gains are dimensionless (rad of rudder per rad of roll)."""

    pfc_name: str
    plant_num: np.ndarray
    plant_den: np.ndarray
    pfc_num: np.ndarray
    pfc_den: np.ndarray
    f_num: np.ndarray
    f_den: np.ndarray
    zeros: np.ndarray
    poles: np.ndarray
    plant_zeros: np.ndarray
    plant_poles: np.ndarray
    minimum_phase: bool
    relative_degree: int
    hf_gain: float
    waspr: bool
    bands: list[GainBand]
    rate_hz: float | None
    bands_discrete: list[GainBand] | None
    plant_dc_gain: float
    pfc_dc_gain: float
    steady_state: dict[str, float]
    compensator_gain_margin: float | None
    lv: float = 20.0
    kx_bands: dict[str, list[GainBand]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def band_span(self) -> tuple[float, float] | None:
        """[lowest low, highest high] over all bands, or None."""
        return (self.bands[0].low, self.bands[-1].high) if self.bands else None

    def to_dict(self) -> dict:
        """JSON-ready dict, the keys docs/spec.md ("Command lines") promises first.  An unbounded edge
        (K -> inf) is null."""

        def inf_none(x: float):
            return None if math.isinf(x) else float(x)

        def bands_list(bands):
            return [
                {"low": inf_none(b.low), "high": inf_none(b.high), "omega_low": b.omega_low, "omega_high": b.omega_high}
                for b in bands
            ]

        def cplx(zs):
            return [[float(z.real), float(z.imag)] for z in zs]

        span = self.band_span
        d = {
            "minimum_phase": self.minimum_phase,
            "relative_degree": self.relative_degree,
            "hf_gain": self.hf_gain,
            # The list of bands is the answer (the paper's PFC has a stable window between two of them); the
            # hull [first low, last high] is kept only under a name that says it covers those windows too.
            "unstable_gain_bands": bands_list(self.bands),
            "unstable_gain_bands_hull": None if span is None else [inf_none(span[0]), inf_none(span[1])],
            "waspr": self.waspr,
            "pfc": self.pfc_name,
            "pfc_num": self.pfc_num.tolist(),
            "pfc_den": self.pfc_den.tolist(),
            "plant_num": self.plant_num.tolist(),
            "plant_den": self.plant_den.tolist(),
            "f_num": self.f_num.tolist(),
            "f_den": self.f_den.tolist(),
            "zeros": cplx(self.zeros),
            "poles": cplx(self.poles),
            "plant_zeros": cplx(self.plant_zeros),
            "plant_poles": cplx(self.plant_poles),
            "plant_dc_gain": self.plant_dc_gain,
            "pfc_dc_gain": self.pfc_dc_gain,
            "steady_state": {k: float(v) for k, v in self.steady_state.items()},
            "steady_state_error_deg": math.degrees(self.steady_state["offset"]),
            "compensator_gain_margin": (
                None if self.compensator_gain_margin is None else inf_none(self.compensator_gain_margin)
            ),
            "clsac_kx": {
                "lv": self.lv,
                "unstable_minus_kx_bands": bands_list(self.kx_bands.get("minus_kx", [])),
                "unstable_kx_bands": bands_list(self.kx_bands.get("kx", [])),
            },
            "notes": list(self.notes),
        }
        if self.rate_hz is not None:
            span_d = (self.bands_discrete[0].low, self.bands_discrete[-1].high) if self.bands_discrete else None
            d["discrete"] = {
                "rate_hz": self.rate_hz,
                "unstable_gain_bands": bands_list(self.bands_discrete),
                "unstable_gain_bands_hull": None if span_d is None else [inf_none(span_d[0]), inf_none(span_d[1])],
            }
        return d


def analyse(
    pfc_num: Sequence[float] = PAPER_PFC[0],
    pfc_den: Sequence[float] = PAPER_PFC[1],
    *,
    command_rad: float = math.radians(10.0),
    rate_hz: float | None = 100.0,
    lv: float = 20.0,
    pfc_name: str = "custom",
    plant=None,
) -> WasprReport:
    """The W-ASPR analysis of F = T + D for a PFC D = pfc_num/pfc_den (paper secs. 2 and 5).

    ``command_rad``: the steady roll command for the steady-state offset (paper scenario: 10 deg).
    ``rate_hz``: also analyse the ZOH-discretised loop at this control rate (None to skip).
    ``lv``: the CL-SAC L_v for ``clsac_kx_bands`` (paper: 20).
    ``plant``: another plant's (A_p, B_p, C_p) (``sitl.linear_plant``); default the KH2013A's.
    Raises ``PfcError`` for an unusable PFC, ``AnalysisError`` for other bad input.
    """
    if not math.isfinite(command_rad):
        raise AnalysisError(f"command must be finite, got {command_rad!r}")
    t = plant_tf(plant)
    d = pfc_tf(pfc_num, pfc_den)
    f = augmented_tf(t, d)
    tn, td = tf_coefficients(t)
    dn, dd = tf_coefficients(d)
    fn, fd = tf_coefficients(f)
    zeros = np.roots(fn) if fn.size > 1 else np.array([], dtype=complex)
    poles = np.roots(fd)
    real = augmented_realisation(pfc_num, pfc_den, plant)
    bands = unstable_gain_bands(fn, fd, realisation=real)
    bands_d = None if rate_hz is None else discrete_bands(real, rate_hz)
    t_dc, d_dc = dc_gain(tn, td), dc_gain(dn, dd)
    rep = WasprReport(
        pfc_name=pfc_name,
        plant_num=tn,
        plant_den=td,
        pfc_num=dn,
        pfc_den=dd,
        f_num=fn,
        f_den=fd,
        zeros=_sort_roots(zeros),
        poles=_sort_roots(poles),
        plant_zeros=_sort_roots(np.roots(tn) if tn.size > 1 else np.array([], dtype=complex)),
        plant_poles=_sort_roots(np.roots(td)),
        minimum_phase=is_minimum_phase(fn),
        relative_degree=relative_degree(fn, fd),
        hf_gain=hf_gain(fn, fd),
        waspr=is_waspr(fn, fd),
        bands=bands,
        rate_hz=rate_hz,
        bands_discrete=bands_d,
        plant_dc_gain=t_dc,
        pfc_dc_gain=d_dc,
        steady_state=steady_state_offset(t_dc, d_dc, command_rad),
        compensator_gain_margin=compensator_gain_margin(tn, td, dn, dd),
        lv=float(lv),
        kx_bands=clsac_kx_bands(fn, fd, lv),
    )
    rep.notes = _notes(rep)
    return rep


def _sort_roots(r: np.ndarray) -> np.ndarray:
    return np.array(sorted(np.asarray(r, dtype=complex), key=lambda z: (-z.real, z.imag)))


def _notes(rep: WasprReport) -> list[str]:
    notes = []
    g = rep.compensator_gain_margin
    if g is None:
        notes.append("C = 1/D does not stabilise T in feedback (1 + C T unstable): F is not minimum phase")
    elif math.isfinite(g):
        notes.append(
            f"C = 1/D stabilises T with gain margin {g:.4g} ({20 * math.log10(g):.2f} dB): "
            "F loses minimum phase if the gain of C rises by that factor"
        )
    if rep.zeros.size:
        z = min(rep.zeros, key=damping_ratio)
        notes.append(
            f"least damped zero of F at {fmt_complex(z)} (damping ratio {damping_ratio(z):.4f}): "
            "the closed-loop roots of 1 + K F tend to the zeros of F as K -> inf"
        )
    if rep.bands:
        spans = ", ".join(f"[{b.low:.6g}, {b.high:.6g}]" for b in rep.bands)
        notes.append(
            f"1 + Ke F(s) is unstable for constant Ke in {spans} although F is "
            f"{'W-ASPR' if rep.waspr else 'not W-ASPR'}; SAC's Ke(t) >= 0 grows with e^2 and can enter this band"
        )
    else:
        notes.append("1 + Ke F(s) is stable for every constant Ke > 0 (continuous time)")
    mk = rep.kx_bands.get("minus_kx", [])
    if mk:
        notes.append(
            f"CL-SAC (Lv = {rep.lv:g}) feeds y_a back through its reference model: with Ke = 0 the loop is "
            f"unstable for -Kx in " + ", ".join(f"[{b.low:.6g}, {b.high:.6g}]" for b in mk)
        )
    if rep.bands_discrete is not None:
        if rep.bands_discrete:
            spans = ", ".join(
                f"[{b.low:.6g}, {'inf' if math.isinf(b.high) else f'{b.high:.6g}'}]" for b in rep.bands_discrete
            )
            notes.append(
                f"sampled at {rep.rate_hz:g} Hz with a zero-order hold (the controller's own loop), "
                f"1 + Ke F_zoh(z) is unstable for Ke in {spans}"
            )
        else:
            notes.append(f"sampled at {rep.rate_hz:g} Hz (ZOH), 1 + Ke F_zoh(z) is stable for every Ke > 0")
    return notes
