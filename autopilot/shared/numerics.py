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


def _squarings(m: np.ndarray) -> int:
    """s with ||M / 2^s||_1 <= 1/2, from the exact 1-norm (math.fsum): the same s anywhere."""
    norm = max(math.fsum(abs(float(v)) for v in m[:, j]) for j in range(m.shape[0]))
    return max(0, math.frexp(norm)[1] + 1) if norm > 0 else 0


def expm(m: np.ndarray) -> np.ndarray:
    """e^M by scaling and squaring of its Taylor series (M / 2^s with ||M / 2^s||_1 <= 1/2, TAYLOR_TERMS terms,
    then s squarings), without BLAS: the same bits on every CPU.

    scipy.linalg.expm goes through BLAS, whose last bits depend on the kernel OpenBLAS picks for the CPU (29 of 66
    entries of the study's plant [Phi, Gamma] differ between its SkylakeX and Haswell kernels); a 600 s saturated
    limit cycle grows such a difference into degrees (docs/experiments.md, "Long flights").  Agrees with scipy's
    to ~1e-14 of ||e^M||.  For the small matrices of the law and the plant, computed once at construction."""
    m = np.atleast_2d(np.asarray(m, dtype=float))
    n = m.shape[0]
    s = _squarings(m)
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


def _matmul_many(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``_matmul`` of each pair of a stack (N, n, n): the same operations, in the same order, per matrix."""
    out = a[:, :, :1] * b[:, :1, :]
    for k in range(1, a.shape[2]):
        out = out + a[:, :, k : k + 1] * b[:, k : k + 1, :]
    return out


def expm_many(ms: np.ndarray) -> np.ndarray:
    """``expm`` of each matrix of a stack (N, n, n) at once, bit for bit ``expm`` of each (the same elementwise
    operations in the same order; each matrix its own s squarings).  For the study's per-run plants."""
    ms = np.asarray(ms, dtype=float)
    s = np.array([_squarings(m) for m in ms], dtype=int)
    a = ms / np.ldexp(1.0, s)[:, None, None]  # a power of two: exact, as in expm
    term = out = np.broadcast_to(np.eye(ms.shape[1]), ms.shape).copy()
    for k in range(1, TAYLOR_TERMS + 1):
        term = _matmul_many(term, a) / k
        out = out + term
    for j in range(int(s.max(initial=0))):
        sel = s > j  # the matrices that still square
        out[sel] = _matmul_many(out[sel], out[sel])
    return out


def zoh_many(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``zoh`` of each (A, B) of stacks (N, n, n) and (N, n, m), bit for bit ``zoh`` of each (Van Loan, 1978)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    count, n, m = b.shape
    block = np.zeros((count, n + m, n + m))
    block[:, :n, :n] = a
    block[:, :n, n:] = b
    phi = expm_many(block * dt)
    return phi[:, :n, :n].copy(), phi[:, :n, n:].copy()


def wrap_pi(angle: float) -> float:
    """``angle`` (rad) wrapped to (-pi, pi]: a roll angle as a sensor reports it (ATTITUDE.roll)."""
    a = math.remainder(angle, math.tau)  # in [-pi, pi]
    return math.pi if a == -math.pi else a
