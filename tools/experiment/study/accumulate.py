"""The study's runs folded as they arrive (``Tally``), so that memory follows the cells, not the runs: per controller
and condition the counts, every metric's sample for its percentiles and the worst run so far (``Cell``); per long
flight and PFC the window peaks (``LongCell``).  And the Wilson score interval of a share (``wilson``).

A sample keeps every value (exact percentiles, 8 bytes a value) while the study's planned values fit in
``EXACT_BYTES``; a larger study counts them on a log grid of relative width ``BIN_WIDTH`` instead (``Sample``,
"binned": a percentile is then its bin's geometric centre, within 0.05 % of the exact one, and the memory is bounded by
the values' range, not their number).  Which one a study uses depends on its options only, never on the execution.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from tools.experiment.study.sampling import METRICS

EXACT_BYTES = 256 * 2**20  # the values a study keeps for exact percentiles, at most

BIN_WIDTH = 1e-3  # binned samples: bins [b^k, b^(k+1)) with b = 1 + BIN_WIDTH

Z95 = 1.959963984540054  # the standard normal's 97.5 % quantile, scipy.stats.norm.ppf(0.975)

PFCS = ("paper", "robust")


def wilson(successes: int, n: int, z: float = Z95) -> list[float] | None:
    """The Wilson score interval of a binomial proportion (Wilson 1927, J. Am. Stat. Assoc. 22: 209-212):
    (p + z^2/2n -+ z sqrt(p (1 - p)/n + z^2/4n^2)) / (1 + z^2/n), p = successes/n; 95 % for the default z.
    None for no trials."""
    if n <= 0:
        return None
    p = successes / n
    z2 = z * z
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z / (1 + z2 / n) * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n))
    return [max(0.0, centre - half), min(1.0, centre + half)]


def value_bytes(runs_30s: int, runs_long: int, windows: int) -> int:
    """The bytes an exact study keeps: every metric of every 30 s run, every window peak of every long run."""
    return 8 * (len(METRICS) * runs_30s + windows * runs_long)


class Sample:
    """The values of one quantity over a cell's runs (>= 0 or +inf), for percentiles: kept (``exact``) or binned."""

    def __init__(self, exact: bool):
        self.exact = exact
        self.n = 0
        self._parts: list[np.ndarray] = []  # exact: the values as they came
        self._zeros = 0  # binned: exact zeros, +inf, and the counts of the finite positive values per bin
        self._infs = 0
        self._lo = 0  # the bin index of _counts[0]
        self._counts = np.zeros(0, dtype=np.int64)

    def add(self, values: np.ndarray) -> None:
        v = np.asarray(values, dtype=float).ravel()
        self.n += v.size
        if self.exact:
            self._parts.append(v.copy())
            return
        if np.any(v < 0) or np.any(np.isnan(v)):
            raise ValueError("a binned sample takes values >= 0 or +inf")
        self._zeros += int(np.count_nonzero(v == 0))
        self._infs += int(np.count_nonzero(np.isinf(v)))
        pos = v[(v > 0) & np.isfinite(v)]
        if not pos.size:
            return
        k = np.floor(np.log(pos) / math.log1p(BIN_WIDTH)).astype(np.int64)
        lo, hi = int(k.min()), int(k.max())
        if not self._counts.size:
            self._lo, self._counts = lo, np.zeros(hi - lo + 1, dtype=np.int64)
        elif lo < self._lo or hi >= self._lo + self._counts.size:
            new_lo = min(lo, self._lo)
            grown = np.zeros(max(hi, self._lo + self._counts.size - 1) - new_lo + 1, dtype=np.int64)
            grown[self._lo - new_lo : self._lo - new_lo + self._counts.size] = self._counts
            self._lo, self._counts = new_lo, grown
        self._counts += np.bincount(k - self._lo, minlength=self._counts.size)

    def values(self) -> np.ndarray:
        """Every value (exact samples only), in the order they came."""
        if not self.exact:
            raise ValueError("a binned sample keeps no values")
        return np.concatenate(self._parts) if self._parts else np.zeros(0)

    def _ranked(self, rank: int) -> float:
        """The value of 1-based ``rank`` in ascending order (binned: its bin's geometric centre)."""
        if rank <= self._zeros:
            return 0.0
        rank -= self._zeros
        cum = np.cumsum(self._counts)
        if cum.size and rank <= cum[-1]:
            k = self._lo + int(np.searchsorted(cum, rank))
            return math.exp((k + 0.5) * math.log1p(BIN_WIDTH))
        return math.inf

    def percentile(self, q: float) -> float:
        """The nearest-rank percentile (numpy's ``inverted_cdf``: a diverged run's +inf stays +inf)."""
        if self.exact:
            return float(np.percentile(self.values(), q, method="inverted_cdf"))
        return self._ranked(max(1, math.ceil(self.n * (q / 100.0))))  # numpy's rank, n q

    def median(self) -> float:
        """numpy's median: the middle value, or the mean of the two middle ones."""
        if self.exact:
            return float(np.median(self.values()))
        lo, hi = self._ranked((self.n + 1) // 2), self._ranked(self.n // 2 + 1)
        return 0.5 * (lo + hi)

    def quantiles(self, qs: Sequence[float]) -> list[float]:
        """Linearly interpolated percentiles of the finite positive values (the figure's boxes), None if none."""
        if self.exact:
            v = self.values()
            v = v[np.isfinite(v) & (v > 0)]
            return [float(x) for x in np.percentile(v, qs)] if v.size else None
        n = int(self._counts.sum())
        if not n:
            return None
        cum = np.cumsum(self._counts)
        out = []
        for q in qs:
            k = self._lo + int(np.searchsorted(cum, max(1, math.ceil(n * (q / 100.0)))))
            out.append(math.exp((k + 0.5) * math.log1p(BIN_WIDTH)))
        return out


def _draws(r: dict, j: int) -> dict:
    return {k: (v[j].tolist() if np.ndim(v[j]) else float(v[j])) for k, v in r["draws"].items()}


class Cell:
    """One controller under one condition: runs, bounded runs (also per PFC), the metrics' samples, the worst run
    (the first, in run order, of the unbounded that rolled furthest, then the worst ise_ref)."""

    def __init__(self, exact: bool):
        self.runs = 0
        self.bounded = 0
        self.oscillating = self.not_following = 0  # runs out by tracking (autopilot.envelope.window_flags)
        self.by_pfc = {p: [0, 0] for p in PFCS}  # runs, bounded
        self.samples = {m: Sample(exact) for m in METRICS}
        self.worst: tuple | None = None  # (key, run index, record)

    def add(self, index: np.ndarray, r: dict, rows: np.ndarray) -> None:
        """The runs ``index`` (ascending), rows ``rows`` of the batch result ``r``."""
        bounded = np.asarray(r["bounded"])[rows].astype(bool)
        paper = np.asarray(r["pfc_paper"])[rows].astype(bool)
        self.runs += rows.size
        self.bounded += int(bounded.sum())
        for name in ("oscillating", "not_following"):
            if name in r:
                setattr(self, name, getattr(self, name) + int(np.asarray(r[name])[rows].astype(bool).sum()))
        for pfc, sel in (("paper", paper), ("robust", ~paper)):
            self.by_pfc[pfc][0] += int(sel.sum())
            self.by_pfc[pfc][1] += int(bounded[sel].sum())
        for m in METRICS:
            self.samples[m].add(np.asarray(r[m])[rows])
        roll, ise = np.asarray(r["max_abs_roll"])[rows], np.asarray(r["ise_ref"])[rows]
        j = int(np.lexsort((-ise, -roll, bounded))[0])  # stable: the first of equal keys
        key = (bool(bounded[j]), -float(roll[j]), -float(ise[j]))
        if self.worst is None or key < self.worst[0]:
            row = int(rows[j])
            rec = {m: float(r[m][row]) for m in METRICS}
            rec.update(bounded=bool(r["bounded"][row]), pfc="paper" if r["pfc_paper"][row] else "robust")
            rec["draws"] = _draws(r, row)
            self.worst = (key, int(index[j]), rec)


class LongCell:
    """One controller's long flights under one condition, per PFC: runs, bounded runs, the window peaks (deg)."""

    def __init__(self, exact: bool, windows: int):
        self.exact, self.windows = exact, windows
        self.by_pfc: dict[str, dict] = {}

    def add(self, r: dict, rows: np.ndarray) -> None:
        from tools.experiment.study.sampling import DEG

        peaks = np.asarray(r["window_peak_roll"])[rows] / DEG
        paper = np.asarray(r["pfc_paper"])[rows].astype(bool)
        bounded = np.asarray(r["bounded"])[rows].astype(bool)
        for pfc, sel in (("paper", paper), ("robust", ~paper)):
            if not sel.any():
                continue
            d = self.by_pfc.setdefault(pfc, {"runs": 0, "bounded": 0, "peaks": None})
            d["runs"] += int(sel.sum())
            d["bounded"] += int(bounded[sel].sum())
            if d["peaks"] is None:
                d["peaks"] = [Sample(self.exact) for _ in range(peaks.shape[1])]
            for w, s in enumerate(d["peaks"]):
                s.add(peaks[sel, w])

    def medians(self, pfc: str) -> np.ndarray:
        """The median of each window's peak (numpy's median of the runs' peaks, bit for bit when exact)."""
        d = self.by_pfc[pfc]
        if self.exact:
            return np.median(np.stack([s.values() for s in d["peaks"]], axis=1), axis=0)
        return np.array([s.median() for s in d["peaks"]])


class Tally:
    """Every cell of a study, fed batch by batch (``add``) in task order; ``runs``: the runs folded so far."""

    def __init__(self, exact: bool, windows: int = 0):
        self.exact, self.windows = exact, windows
        self.cells: dict[str, dict[str, Cell]] = {}
        self.long: dict[str, dict[str, LongCell]] = {}
        self.runs = 0

    def add(self, task, r: dict) -> None:
        """A task's batch result (``tools.experiment.study.simulate``): its runs grouped by condition."""
        groups: dict[str, list[int]] = {}
        for j, (cond, _i) in enumerate(task.runs):
            groups.setdefault(cond, []).append(j)
        for cond, js in groups.items():
            rows = np.array(js)
            if task.duration_s == 30.0:
                cell = self.cells.setdefault(task.controller, {}).get(cond)
                if cell is None:
                    cell = self.cells[task.controller][cond] = Cell(self.exact)
                cell.add(np.array([task.runs[j][1] for j in js]), r, rows)
            else:
                lc = self.long.setdefault(task.controller, {}).get(cond)
                if lc is None:
                    lc = self.long[task.controller][cond] = LongCell(self.exact, self.windows)
                lc.add(r, rows)
        self.runs += len(task.runs)


def records_batch(records: Sequence[dict]) -> dict:
    """Per-run records (``tools.experiment.study.merge``) back into a batch result, for ``Cell.add``."""
    out = {m: np.array([rec[m] for rec in records], dtype=float) for m in METRICS}
    out["bounded"] = np.array([rec["bounded"] for rec in records], dtype=bool)
    out["pfc_paper"] = np.array([rec["pfc"] == "paper" for rec in records], dtype=bool)
    for name in ("oscillating", "not_following"):
        if records and name in records[0]:
            out[name] = np.array([rec[name] for rec in records], dtype=bool)
    if records and "window_peak_roll" in records[0]:
        out["window_peak_roll"] = np.array([rec["window_peak_roll"] for rec in records], dtype=float)
    keys = records[0]["draws"] if records else {}
    out["draws"] = {k: np.array([rec["draws"][k] for rec in records]) for k in keys}
    return out
