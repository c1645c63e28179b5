"""Numerical primitives the control law and the simulator share.  No I/O."""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm


def zoh(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation of x' = A x + B u over ``dt``: (e^{A dt}, int_0^dt e^{A s} ds B).

    Computed as the matrix exponential of the block matrix [[A, B], [0, 0]] dt (Van Loan, 1978), so it also
    holds for singular A (the servo and the roll integrator of the plant, paper section 5).
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
