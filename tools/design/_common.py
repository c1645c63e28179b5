"""What every analysis module shares: the error types, lazy imports of python-control and scipy, and the
polynomial helpers.  Polynomials are 1-D coefficient arrays, highest power first (numpy's convention)."""

from __future__ import annotations

import numpy as np


class AnalysisError(ValueError):
    """The analysis could not be carried out (e.g. a numerically inconsistent stability boundary)."""


class PfcError(AnalysisError):
    """The PFC is unusable (empty, not finite, not strictly proper, unstable); the message names the value."""


class CoefficientError(PfcError):
    """A coefficient list could not be parsed; the message names the offending text."""


def ct():
    """python-control, imported on first use: importing it costs ~2.5 s (scipy.signal, matplotlib) and
    ``python -m tools.pfc`` should answer --help and bad input at once."""
    import control

    return control


def brentq(*args, **kwargs):
    """scipy.optimize.brentq, imported on first use (~0.7 s) for the same reason as ``ct``."""
    from scipy.optimize import brentq as _brentq

    return _brentq(*args, **kwargs)


def poly(coeffs, name: str = "polynomial") -> np.ndarray:
    """A 1-D float array of coefficients with leading zeros removed."""
    try:
        arr = np.atleast_1d(np.asarray(coeffs, dtype=float)).ravel()
    except (TypeError, ValueError):
        raise AnalysisError(f"{name} must be a sequence of numbers, got {coeffs!r}") from None
    if not np.all(np.isfinite(arr)):
        raise AnalysisError(f"{name} must be finite, got {list(arr)!r}")
    arr = np.trim_zeros(arr, "f")
    if arr.size == 0:
        raise AnalysisError(f"{name} is zero")
    return arr


def fmt_complex(z: complex) -> str:
    """``-0.28+58.9j``, or just the real part when the imaginary part is round-off."""
    z = complex(z)
    if abs(z.imag) < 1e-12 * max(1.0, abs(z.real)):
        return f"{z.real:.6g}"
    return f"{z.real:.6g}{z.imag:+.6g}j"
