"""Numerical primitives the control law and the simulator share.  No I/O."""

from __future__ import annotations

import math

import numpy as np

TAYLOR_TERMS = 18  # of e^M after scaling ||M||_1 to <= 1/2: remainder below 1e-22


def _matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a @ b as elementwise products and sums in a fixed order: correctly rounded IEEE operations on any CPU."""
    out = a[:, :1] * b[:1, :]
    for k in range(1, a.shape[1]):
        out = out + a[:, k : k + 1] * b[k : k + 1, :]
    return out


def expm(m: np.ndarray) -> np.ndarray:
    """e^M by scaling and squaring of its Taylor series (M / 2^s with ||M / 2^s||_1 <= 1/2, TAYLOR_TERMS terms,
    then s squarings), without BLAS: the same bits on every CPU.

    scipy.linalg.expm goes through BLAS, whose last bits depend on the kernel OpenBLAS picks for the CPU (29 of 66
    entries of the study's plant [Phi, Gamma] differ between its SkylakeX and Haswell kernels); a 600 s saturated
    limit cycle grows such a difference into degrees (docs/experiments.md, "Long flights").  Agrees with scipy's
    to ~1e-14 of ||e^M||.  For the small matrices of the law and the plant, computed once at construction."""
    m = np.atleast_2d(np.asarray(m, dtype=float))
    n = m.shape[0]
    norm = max(math.fsum(abs(float(v)) for v in m[:, j]) for j in range(n))  # exact: s is the same anywhere
    s = max(0, math.frexp(norm)[1] + 1) if norm > 0 else 0
    a = m / 2.0**s  # a power of two: exact
    term = out = np.eye(n)
    for k in range(1, TAYLOR_TERMS + 1):
        term = _matmul(term, a) / k
        out = out + term
    for _ in range(s):
        out = _matmul(out, out)
    return out


def zoh(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation of x' = A x + B u over ``dt``: (e^{A dt}, int_0^dt e^{A s} ds B).

    Computed as the matrix exponential of the block matrix [[A, B], [0, 0]] dt (Van Loan, 1978), so it also
    holds for singular A (the servo and the roll integrator of the plant, paper section 5); ``expm`` makes it
    the same bits on every CPU.
    """
    a = np.atleast_2d(np.asarray(a, dtype=float))
    b = np.asarray(b, dtype=float).reshape(a.shape[0], -1)
    n, m = b.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n] = a
    block[:n, n:] = b
    phi = expm(block * dt)
    return phi[:n, :n].copy(), phi[:n, n:].copy()


def wrap_pi(angle: float) -> float:
    """``angle`` (rad) wrapped to (-pi, pi]: a roll angle as a sensor reports it (ATTITUDE.roll)."""
    a = math.remainder(angle, math.tau)  # in [-pi, pi]
    return math.pi if a == -math.pi else a
