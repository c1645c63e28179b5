"""What a batch of the study flies, the same bits on every CPU: the paper's command (``square_command``), each
run's plant discretised (``zoh_plant``, ``zoh_plants``), the Dryden filter (``dryden``, rounded by ``canonical``),
and per-run values packed for the steps (``per_run``)."""

from __future__ import annotations

import argparse
import functools
import math

import numpy as np

from tools.experiment.study.sampling import DEG


def _square(t: np.ndarray, amplitude: float = 10.0 * DEG, period: float = 10.0) -> np.ndarray:
    """The paper's command (tools.flight.profiles.square: +amplitude first, switching every period/2)."""
    from tools.flight.profiles import square

    return np.array([square(float(x), amplitude, period) for x in t])


@functools.lru_cache(maxsize=8)
def square_command(steps: int, dt: float) -> np.ndarray:
    """``_square`` at t = k dt, k < steps, computed once per process and length (a 600 s flight's 60,000 calls of
    ``square`` cost as much as its steps in C); read-only, shared by every batch of that length."""
    um = _square(np.arange(steps) * dt)
    um.flags.writeable = False
    return um


# The study's numbers must not depend on the CPU.  BLAS and LAPACK (scipy's expm, the Lyapunov solve) leave last
# bits that depend on the kernel OpenBLAS picks for the CPU (measured: 29 of 66 entries of a plant's [Phi, Gamma]
# differ between its SkylakeX and Haswell kernels, structural zeros coming out as +-1e-17), and over a 600 s
# saturated limit cycle such a difference grows into degrees: the long flight's clsac / moderate / robust median
# peak of 570-600 s read 63.1 deg on one kernel and 70.7 deg on the other.  So the plant and the law are discretised
# without BLAS (``autopilot.shared.numerics.expm``) and the one Dryden filter, which needs LAPACK (a Lyapunov solve,
# eigen-decompositions), is rounded to a grid (``canonical``) with its factors' column signs fixed.
CANONICAL_BITS = 32


def canonical(a) -> np.ndarray:
    """``a`` rounded to the grid 2**(e - CANONICAL_BITS), 2**e > max |a| (about 1e-10 of its largest entry),
    exactly.  A difference of a few ulp of max |a| changes an entry only if it straddles a grid point
    (probability about 1e-7 per entry); entries that should be zero and come out as +-1e-17 become 0."""
    a = np.asarray(a, dtype=float)
    top = float(np.max(np.abs(a))) if a.size else 0.0
    if top == 0.0:
        return a.copy()
    q = math.ldexp(1.0, math.frexp(top)[1] - CANONICAL_BITS)  # a power of two: a / q and its product are exact
    return np.round(a / q) * q + 0.0  # + 0.0: a -0.0 (rounded from -1e-17) becomes +0.0


def zoh_plant(scales: np.ndarray, dt: float):
    """Per-run ZOH matrices of the scaled plant with inputs [u, v_g, p_g, r_g] held over dt (the same bits on any
    CPU: ``autopilot.shared.numerics.expm``)."""
    from autopilot.shared.numerics import zoh

    return zoh(*_continuous(scales), dt)


def _continuous(scales: np.ndarray):
    """(A_p, [B_p, E]) of the scaled plant."""
    from sitl.atmosphere import disturbance_matrix
    from sitl.uncertainty import PlantScales

    a, b = PlantScales(*scales).matrices()
    return a, np.hstack([b, disturbance_matrix(a)])


def zoh_plants(scales: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``_plant`` of every run, (n, 6, 6) and (n, 6, 4): each distinct scale vector discretised once, all of them
    at once (``zoh_many``: bit for bit ``zoh`` of each)."""
    from autopilot.shared.numerics import zoh_many

    keys = [s.tobytes() for s in scales]
    first = {}
    for i, key in enumerate(keys):
        first.setdefault(key, i)
    pairs = [_continuous(scales[i]) for i in first.values()]
    phi, gam = zoh_many(np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs]), dt)
    where = {key: j for j, key in enumerate(first)}
    index = np.array([where[key] for key in keys])
    return phi[index], gam[index]


# The sign of each column's largest entry in the Dryden filter's square-root factors: LAPACK's choice on the machine
# the published numbers were computed on, now fixed for every machine (an eigen-decomposition may return either
# sign of each eigenvector, and LAPACK's choice depends on its kernel; both give the same covariance, but another
# turbulence sequence from the same draws).
DRYDEN_COLUMN_SIGNS = {"ld": (1.0, 1.0, 1.0, -1.0), "l0": (1.0, -1.0, 1.0, -1.0)}


def _signed_columns(a: np.ndarray, signs) -> np.ndarray:
    """The columns of a square-root factor (L L^T = Q, unique up to each column's sign) with the sign that gives
    each one's largest entry the sign in ``signs``."""
    top = a[np.argmax(np.abs(a), axis=0), np.arange(a.shape[1])]
    return a * np.where(np.sign(top) == np.asarray(signs), 1.0, -1.0) + 0.0  # + 0.0: no -0.0 from a flip


def dryden(dt: float):
    """The Dryden filter at the control period (MIL-HDBK-1797 "severe", scaled per run): its coefficients
    ``ad``, ``ld``, ``c``, ``l0`` rounded by ``canonical``, the factors' column signs fixed
    (``DRYDEN_COLUMN_SIGNS``)."""
    from sitl.atmosphere import DrydenConfig, DrydenFilter

    dry = DrydenFilter.build(DrydenConfig.intensity("severe"), dt)
    out = {k: canonical(getattr(dry, k)) for k in ("ad", "ld", "c", "l0")}
    for k, signs in DRYDEN_COLUMN_SIGNS.items():
        out[k] = _signed_columns(out[k], signs)
    return argparse.Namespace(**out)


def per_run(values: np.ndarray):
    """(k, ...) entries as Python floats when equal across runs (cheaper, and the same IEEE operation)."""
    first = values[0]
    if np.all(values == first):
        return float(first)
    return np.ascontiguousarray(values)


def airspeed() -> float:
    from sitl.atmosphere import AIRSPEED

    return AIRSPEED
