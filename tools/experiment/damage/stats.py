"""The damage study's statistics: intervals over seeds, paired differences between two laws, the digits a median
supports, and averages over many periods of a long flight.  No I/O, numpy only.

Why these (docs/damage.md, "Reading the numbers"):

* **Paired differences, by the sign test.** Every cell of a plant flies the same seeds (common random numbers), so
  law B's flight at seed s and law A's meet the same air: the difference d_s = x_B,s - x_A,s removes the seed's own
  luck.  The 95 % interval of the median of d is the sign test's (distribution-free, exact): with d sorted,
  [d_(k), d_(n+1-k)] covers the median with probability 1 - 2 P(Bin(n, 1/2) <= k - 1) (Hollander & Wolfe,
  Nonparametric Statistical Methods, sec. 3.6), k the largest that keeps it >= 95 %.  No distribution-free test
  reaches 95 % with fewer than 6 seeds (the two all-one-sign outcomes alone have probability 2^(1-n) = 6.25 % at
  n = 5): there the interval given is the seeds' range [min d, max d] with its own confidence 1 - 2^(1-n) (87.5 % at
  4 seeds) and the verdict is "no difference shown".
* **Shares.** Controlled or not, per seed: the seeds where one law keeps the aircraft and the other does not
  (discordant pairs) decide; their exact two-sided sign-test p-value (McNemar's exact test) < 0.05 shows a difference.
* **Digits.** A median is printed to the precision its interval supports: significant digits up to the place of the
  leading digit of the interval's half width (1 to 3), so digits a new seed would change are not printed.
* **Long flights.** The mean error per period over many periods (the last ``window`` s), with a 95 % percentile
  bootstrap interval over the (seed, period) units (``BOOT`` resamples, a fixed generator: the same numbers on every
  run); a paired difference there is taken per (seed, period) unit and bootstrapped the same way.  Periods of one
  flight are treated as independent draws: 10 s apart, the turbulence's correlation time (about 1 s) is long past.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

LEVEL = 0.95
MIN_SIGN_N = 6  # the least n whose sign-test interval reaches 95 %: 1 - 2^(1-6) = 96.9 %
BOOT = 2000  # bootstrap resamples
BOOT_SEED = 20170  # the bootstrap's generator seed (fixed: the interval is a function of the data only)
NO_DIFF = "no difference shown"


def _binom_cdf_half(k: int, n: int) -> float:
    """P(Bin(n, 1/2) <= k)."""
    if k < 0:
        return 0.0
    return sum(math.comb(n, i) for i in range(min(k, n) + 1)) / 2.0**n


def sign_interval(values: Sequence[float]) -> tuple[float, float, float] | None:
    """(lo, hi, confidence): the sign test's interval of the median of ``values`` (finite ones), at the largest
    order statistic k that keeps the confidence >= 95 %, or the range [min, max] with its confidence
    1 - 2^(1-n) when n < 6; None for no finite value."""
    d = sorted(float(v) for v in values if v is not None and math.isfinite(v))
    n = len(d)
    if n == 0:
        return None
    k = 1
    while 1.0 - 2.0 * _binom_cdf_half(k, n) >= LEVEL:  # order statistic k + 1 still keeps 95 %
        k += 1
    conf = 1.0 - 2.0 * _binom_cdf_half(k - 1, n)
    return d[k - 1], d[n - k], conf


def median(values) -> float | None:
    vals = [float(v) for v in values if v is not None and math.isfinite(v)]
    return float(np.median(vals)) if vals else None


def digits(value: float | None, interval) -> int:
    """Significant digits of ``value`` its interval supports: down to the place of the leading digit of the
    interval's half width, 1 to 3 (3 for a zero width or no interval)."""
    if value is None or not math.isfinite(value) or value == 0.0 or not interval:
        return 3
    half = (interval[1] - interval[0]) / 2.0
    if not half > 0.0:
        return 3
    return max(1, min(3, math.floor(math.log10(abs(value))) - math.floor(math.log10(half)) + 1))


def fmt(value: float | None, n: int = 3) -> str:
    """``value`` to ``n`` significant digits ("-" for None)."""
    return "-" if value is None else format(value, f".{n}g")


def paired(a: dict, b: dict, metric: str) -> dict | None:
    """The paired difference b - a of ``metric`` over the seeds both flew (``a``, ``b``: {seed: value}): n, the
    median difference, the sign test's interval and its confidence, and whether a difference is shown."""
    common = sorted(s for s in a if s in b and a[s] is not None and b[s] is not None)
    d = [b[s] - a[s] for s in common if math.isfinite(b[s] - a[s])]
    iv = sign_interval(d)
    if iv is None:
        return None
    lo, hi, conf = iv
    shown = conf >= LEVEL and (lo > 0.0 or hi < 0.0)
    return {
        "metric": metric,
        "n": len(d),
        "median_diff": median(d),
        "interval": [lo, hi],
        "confidence": conf,
        "method": "sign test",
        "shown": shown,
        "verdict": ("b higher" if lo > 0.0 else "b lower") if shown else NO_DIFF + _short(len(d), conf),
    }


def _short(n: int, conf: float) -> str:
    """Why an interval that excludes 0 still shows nothing: too few seeds for 95 %."""
    if conf >= LEVEL:
        return ""
    return f" ({n} seeds reach {100 * conf:.4g} %, 95 % needs {MIN_SIGN_N})"


def ratio(a: dict, b: dict) -> dict | None:
    """The paired ratio b / a over the common seeds (a's value > 0): its median and the sign test's interval."""
    r = [b[s] / a[s] for s in sorted(a) if s in b and a[s] and b[s] is not None and a[s] > 0]
    iv = sign_interval(r)
    if iv is None:
        return None
    lo, hi, conf = iv
    return {"n": len(r), "median": median(r), "interval": [lo, hi], "confidence": conf}


def paired_share(a: dict, b: dict) -> dict:
    """Controlled or not, per common seed: the seeds only b keeps, only a keeps, and the exact two-sided
    sign-test p-value on those discordant pairs (McNemar's exact test)."""
    common = [s for s in a if s in b]
    b_only = sum(1 for s in common if b[s] and not a[s])
    a_only = sum(1 for s in common if a[s] and not b[s])
    m = a_only + b_only
    p = min(1.0, 2.0 * _binom_cdf_half(min(a_only, b_only), m)) if m else 1.0
    return {"n": len(common), "b_only": b_only, "a_only": a_only, "p_value": p, "shown": p < 1.0 - LEVEL}


def bootstrap_mean(values: Sequence[float], boot: int = BOOT, seed: int = BOOT_SEED) -> tuple:
    """(mean, lo, hi): the mean of ``values`` and its 95 % percentile bootstrap interval; (None, None, None) for no
    finite value (``summary.json`` holds no NaN)."""
    x = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if x.size == 0:
        return None, None, None
    rng = np.random.default_rng(seed)
    means = x[rng.integers(0, x.size, size=(boot, x.size))].mean(axis=1)
    lo, hi = np.quantile(means, [(1 - LEVEL) / 2, (1 + LEVEL) / 2])
    return float(x.mean()), float(lo), float(hi)
