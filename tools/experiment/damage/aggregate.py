"""The damage study's numbers per cell (plant x controller x fault kind x severity x onset, over the seeds), its
``summary.json`` and its printed tables.  No I/O.

Per cell: the flights, the share still controlled (``autopilot.envelope``) with its 95 % Wilson score interval, the
median tracking error after the onset (ise_ref over t >= onset, rad^2 s) and of the energy after it, the share
recovered and the median recovery time of those that did, the median error per period of the square wave, and the
median over the whole flight of the five metrics of ``autopilot.metrics``.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence

from tools.experiment.damage.grid import NONE, label

Z95 = 1.959963984540054  # the standard normal's 97.5 % quantile


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval of a share k/n (Wilson 1927): (p + z^2/2n -+ z sqrt(p(1-p)/n + z^2/4n^2)) /
    (1 + z^2/n); (0, 1) for n = 0."""
    if n <= 0:
        return 0.0, 1.0
    p = k / n
    d = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / d
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, centre - half), min(1.0, centre + half)


def _median(values) -> float | None:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    return statistics.median(vals) if vals else None


def cell_of(records: Sequence[dict]) -> dict:
    """The cell's numbers from its flights' records (``tools.experiment.damage.flight.record``)."""
    n = len(records)
    k = sum(r["controlled"] for r in records)
    lo, hi = wilson(k, n)
    measured = [r for r in records if r["recovered"] is not None]
    rec = [r for r in measured if r["recovered"]]
    n_periods = max(len(r["ise_ref_periods"]) for r in records)
    return {
        "flights": n,
        "controlled": k,
        "share_controlled": k / n if n else None,
        "wilson95": [lo, hi],
        "ise_ref_after_p50": _median(r["ise_ref_after"] for r in records),
        "energy_after_p50": _median(r["energy_after"] for r in records),
        "ise_ref_p50": _median(r["ise_ref"] for r in records),
        "energy_p50": _median(r["energy"] for r in records),
        "max_abs_roll_deg_p50": _median(r["max_abs_roll_deg"] for r in records),
        "oscillating_share": sum(r.get("oscillating", False) for r in records) / n if n else None,
        "recovered_share": len(rec) / len(measured) if measured else None,
        "recovery_s_p50": _median(r["recovery_s"] for r in rec),
        "ise_ref_periods_p50": [
            _median(r["ise_ref_periods"][i] for r in records if i < len(r["ise_ref_periods"])) for i in range(n_periods)
        ],
    } | _sideslip_of(records)


def _sideslip_of(records: Sequence[dict]) -> dict:
    """A square MIMO plant's cell: the median and the largest max |sideslip| (deg) of its flights and the median
    share of steps the rudder is saturated; nothing for a SISO plant's."""
    if not records or "max_abs_sideslip_deg" not in records[0]:
        return {}
    return {
        "max_abs_sideslip_deg_p50": _median(r["max_abs_sideslip_deg"] for r in records),
        "max_abs_sideslip_deg_max": max(r["max_abs_sideslip_deg"] for r in records),
        "rudder_saturated_share_p50": _median(r["rudder_saturated_share"] for r in records),
    }


def summarise(flights, results) -> list[dict]:
    """One entry per cell, in the flights' order: plant, controller, kind, severity, onset, fault spec, the seeds,
    the cell's numbers and every flight's record."""
    cells: dict[tuple, dict] = {}
    for f, r in zip(flights, results):
        c = cells.setdefault(
            f.cell,
            {
                "plant": f.plant,
                "controller": f.controller,
                "kind": f.kind,
                "severity": f.value,
                "onset_s": f.onset if f.kind != NONE else None,
                "fault": f.spec,
                "seeds": [],
                "records": [],
            },
        )
        c["seeds"].append(f.seed)
        c["records"].append({"seed": f.seed, **r})
    out = []
    for c in cells.values():
        records = c.pop("records")
        out.append({**c, **cell_of(records), "runs": records})
    return out


def _fmt(v, spec: str = ".3g") -> str:
    return "-" if v is None else format(v, spec)


def _fault_table(cells, plant: str, controllers, onset, title: str, entry) -> str:
    """A plant's printed table: a row per fault (kind and severity, at ``onset``: the first one by default), per
    controller ``entry(cell)`` (22 characters) or "-" where the cell is missing."""
    mine = [c for c in cells if c["plant"] == plant]
    onsets = sorted({c["onset_s"] for c in mine if c["onset_s"] is not None})
    onset = onsets[0] if onset is None and onsets else onset
    rows: dict[tuple, dict] = {}
    for c in mine:
        if c["kind"] == NONE or c["onset_s"] == onset:
            rows.setdefault((c["kind"], c["severity"]), {})[c["controller"]] = c
    width = 22
    head = f"{'fault':<22}" + "".join(f"{label(n)[: width - 1]:>{width}}" for n in controllers)
    lines = [f"{plant}: {title}, onset {_fmt(onset, 'g')} s", head]
    for (kind, sev), per in rows.items():
        name = kind if kind == NONE else f"{kind}={'here' if sev is None else format(sev, 'g')}"
        lines.append(
            f"{name:<22}" + "".join(f"{'-':>{width}}" if (e := entry(per.get(n))) is None else e for n in controllers)
        )
    return "\n".join(lines)


def sideslip_table(cells: Sequence[dict], plant: str, controllers: Sequence[str], onset: float | None = None) -> str:
    """A square MIMO plant's coordination: a row per fault (at ``onset``, the first by default), per controller the
    median max |sideslip| (deg) of the cell's flights and the largest."""

    def entry(c):
        if c is None or "max_abs_sideslip_deg_p50" not in c:
            return None
        return f"{_fmt(c['max_abs_sideslip_deg_p50'], '.2f'):>10} / {_fmt(c['max_abs_sideslip_deg_max'], '.2f'):>8}"

    title = "max |sideslip| (deg), median / largest over the seeds"
    return _fault_table(cells, plant, controllers, onset, title, entry)


def table(cells: Sequence[dict], plant: str, controllers: Sequence[str], onset: float | None = None) -> str:
    """The printed table of one plant: a row per fault (kind and severity, at ``onset``: the first one by default),
    per controller the share controlled (%) and the median ise_ref after the onset."""

    def entry(c):
        return None if c is None else f"{100 * c['share_controlled']:>9.0f} % {_fmt(c['ise_ref_after_p50']):>10}"

    title = "% controlled / median ise_ref after the onset (rad^2 s)"
    return _fault_table(cells, plant, controllers, onset, title, entry)


def period_table(cells: Sequence[dict], plant: str, controllers: Sequence[str], period: float = 10.0) -> str:
    """The long flights' table of one plant: per fault (at its first onset) and controller, the median ise_ref of
    the first whole period after the onset and of the last period, and the controllers ranked by each (1: the
    least error); the ranking can change with the time flown."""
    mine = [c for c in cells if c["plant"] == plant]
    onsets = sorted({c["onset_s"] for c in mine if c["onset_s"] is not None})
    onset = onsets[0] if onsets else 0.0
    rows: dict[tuple, dict] = {}
    for c in mine:
        if c["kind"] == NONE or c["onset_s"] == onset:
            rows.setdefault((c["kind"], c["severity"]), {})[c["controller"]] = c
    first = int(math.ceil(round(onset / period, 9)))
    lines = [
        f"{plant}: median ise_ref per {period:g} s period (rad^2 s): first period from {first * period:g} s / last "
        "period, and the rank of each (1: least error)"
    ]
    width = 22
    lines.append(f"{'fault':<22}" + "".join(f"{label(n)[: width - 1]:>{width}}" for n in controllers))
    for (kind, sev), per in rows.items():
        vals = {}
        for n in controllers:
            p = per.get(n, {}).get("ise_ref_periods_p50") or []
            vals[n] = (p[first] if first < len(p) else None, p[-1] if p else None)
        rank = {}
        for i in (0, 1):
            ok = sorted((v[i], n) for n, v in vals.items() if v[i] is not None)
            for r, (_v, n) in enumerate(ok, 1):
                rank[(n, i)] = r
        name = kind if kind == NONE else f"{kind}={'here' if sev is None else format(sev, 'g')}"
        row = f"{name:<22}"
        for n in controllers:
            a, b = vals[n]
            row += f"{_fmt(a, '.2g')}({rank.get((n, 0), '-')})/{_fmt(b, '.2g')}({rank.get((n, 1), '-')})".rjust(width)
        lines.append(row)
    return "\n".join(lines)


def markdown_table(cells: Sequence[dict], plant: str, controllers: Sequence[str], energy: bool = False) -> str:
    """A docs table of one plant (docs/damage.md): a row per fault at the first onset, per controller "share
    controlled (%) / median ise_ref after the onset"; ``energy``: also the median energy after the onset."""
    mine = [c for c in cells if c["plant"] == plant]
    onsets = sorted({c["onset_s"] for c in mine if c["onset_s"] is not None})
    onset = onsets[0] if onsets else None
    rows: dict[tuple, dict] = {}
    for c in mine:
        if c["kind"] == NONE or c["onset_s"] == onset:
            rows.setdefault((c["kind"], c["severity"]), {})[c["controller"]] = c
    head = "| fault | " + " | ".join(label(n) for n in controllers) + " |"
    lines = [head, "|---|" + "---:|" * len(controllers)]
    for (kind, sev), per in rows.items():
        name = "none" if kind == NONE else f"`{kind}={'here' if sev is None else format(sev, 'g')}`"
        out = []
        for n in controllers:
            c = per.get(n)
            if c is None:
                out.append("-")
                continue
            text = f"{100 * c['share_controlled']:.0f} % / {_fmt(c['ise_ref_after_p50'])}"
            if energy:
                text += f" / {_fmt(c['energy_after_p50'])}"
            out.append(text)
        lines.append(f"| {name} | " + " | ".join(out) + " |")
    return "\n".join(lines)
