"""The damage study's numbers per cell (plant x controller x fault kind x severity x onset, over the seeds), its
``summary.json`` and its printed tables.  No I/O.

Per cell: the flights, the share still controlled (``autopilot.envelope``) with its 95 % Wilson score interval, the
median tracking error after the onset (ise_ref over t >= onset, rad^2 s) and of the energy after it, the share
recovered and the median recovery time of those that did, the median error per period of the square wave, and the
median over the whole flight of the five metrics of ``autopilot.metrics``.  Beside the median error after the onset,
its sign-test interval over the seeds and the digits that interval supports; against the reference law (CL-SAC when
flown, else the first), each cell's paired difference over the common seeds, its energy ratio and the paired
shares; over the last ``window`` s of a long flight, the mean error per period with its bootstrap interval
(``tools.experiment.damage.stats``: the methods and why).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence

from tools.experiment.damage import stats
from tools.experiment.damage.grid import NONE, label

REFERENCE = "clsac"  # the law every other is paired with, when flown
PERIOD_S = 10.0  # the square wave's period: the error per period
WINDOW_S = 100.0  # a long flight's last window, averaged over its periods

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
    # k = 0 and k = n: the bound is the share itself (the formula's exact value, not its rounding: 2.8e-17 at 0/6)
    return (0.0 if k == 0 else max(0.0, centre - half)), (1.0 if k == n else min(1.0, centre + half))


def _median(values) -> float | None:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    return statistics.median(vals) if vals else None


def cell_of(records: Sequence[dict]) -> dict:
    """The cell's numbers from its flights' records (``tools.experiment.damage.flight.record``).  The recovered share
    is over the flights whose recovery was measured (``recovered`` not None), the recovery time's median over those
    that recovered."""
    n = len(records)
    k = sum(r["controlled"] for r in records)
    lo, hi = wilson(k, n)
    measured = [r for r in records if r["recovered"] is not None]
    rec = [r for r in measured if r["recovered"]]
    n_periods = max(len(r["ise_ref_periods"]) for r in records)
    after = _median(r["ise_ref_after"] for r in records)
    iv = stats.sign_interval(r["ise_ref_after"] for r in records)
    return {
        "flights": n,
        "controlled": k,
        "share_controlled": k / n if n else None,
        "wilson95": [lo, hi],
        "ise_ref_after_p50": after,
        "ise_ref_after_interval": None if iv is None else [iv[0], iv[1]],
        "ise_ref_after_confidence": None if iv is None else iv[2],
        "ise_ref_after_digits": stats.digits(after, iv),
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


def first_period(onset: float | None, period: float = PERIOD_S) -> int:
    """The index of the first whole period after the onset (an onset inside a period starts the next one)."""
    return int(math.ceil(round((onset or 0.0) / period, 9)))


def _last_units(records, window: float, period: float, onset: float | None) -> dict:
    """{(seed, period index): ise_ref} of the last ``window`` s of each flight (whole periods after the onset)."""
    out = {}
    start = first_period(onset, period)
    for r in records:
        p = r["ise_ref_periods"]
        take = max(1, min(len(p) - start, int(round(window / period))))
        for i in range(max(start, len(p) - take), len(p)):
            out[(r["seed"], i)] = p[i]
    return out


def long_of(records, onset: float | None, window: float = WINDOW_S, period: float = PERIOD_S) -> dict:
    """A long flight's cell: the mean error of the first period after the onset (over the seeds) and the mean per
    period over the last ``window`` s (over every seed's periods there), each with its 95 % bootstrap interval."""
    i = first_period(onset, period)
    first = [r["ise_ref_periods"][i] for r in records if i < len(r["ise_ref_periods"])]
    last = _last_units(records, window, period, onset)
    m1, lo1, hi1 = stats.bootstrap_mean(first)
    m2, lo2, hi2 = stats.bootstrap_mean(list(last.values()))
    periods = sorted({j for _, j in last})
    return {
        "first_period": {"start_s": i * period, "mean": m1, "interval": [lo1, hi1], "units": len(first)},
        "last_window": {
            "from_s": periods[0] * period if periods else None,
            "to_s": (periods[-1] + 1) * period if periods else None,
            "mean": m2,
            "interval": [lo2, hi2],
            "units": len(last),
        },
    }


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


def summarise(flights, results, window: float = WINDOW_S, period: float = PERIOD_S) -> list[dict]:
    """One entry per cell, in the flights' order: plant, controller, kind, severity, onset, fault spec, the seeds,
    the cell's numbers, its long-flight averages (``long_of``), its comparison with the reference law (``vs``,
    ``pair``) and every flight's record."""
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
    for key, c in cells.items():
        records = c.pop("records")
        onset = key[4]
        out.append({**c, **cell_of(records), "long": long_of(records, onset, window, period), "runs": records})
    controllers = list(dict.fromkeys(c["controller"] for c in out))
    ref = REFERENCE if REFERENCE in controllers else controllers[0] if controllers else None
    refs = {_row(c): c for c in out if c["controller"] == ref}
    for c in out:
        other = refs.get(_row(c))
        c["reference"] = ref
        c |= pair(other, c, window, period) if other is not None and other is not c else {}
    return out


def _row(c: dict) -> tuple:
    """A cell's row of a table: plant, fault kind, severity and onset (every controller's cell of it)."""
    return (c["plant"], c["kind"], c["severity"], c["onset_s"])


def _by_seed(cell: dict, key: str) -> dict:
    return {r["seed"]: r[key] for r in cell["runs"]}


def pair(a: dict, b: dict, window: float = WINDOW_S, period: float = PERIOD_S) -> dict:
    """Cell ``b`` against cell ``a`` (the reference law's of the same row) over their common seeds
    (``tools.experiment.damage.stats``): ``vs``: the paired difference b - a of ise_ref after the onset (sign test),
    the paired shares controlled (exact McNemar) and, over the last ``window`` s, the paired difference of the
    error per period (bootstrap over the (seed, period) units); ``energy_ratio``: b's energy after the onset over
    a's, its median over the seeds and interval (1: equal effort)."""
    vs = {
        "law": a["controller"],
        "ise_ref_after": stats.paired(_by_seed(a, "ise_ref_after"), _by_seed(b, "ise_ref_after"), "ise_ref_after"),
        "controlled": stats.paired_share(_by_seed(a, "controlled"), _by_seed(b, "controlled")),
    }
    ua = _last_units(a["runs"], window, period, a["onset_s"])
    ub = _last_units(b["runs"], window, period, b["onset_s"])
    d = [ub[u] - ua[u] for u in ua if u in ub]
    if any(v is not None and math.isfinite(v) for v in d):
        m, lo, hi = stats.bootstrap_mean(d)
        shown = lo > 0.0 or hi < 0.0
        vs["last_window"] = {
            "units": len(d),
            "mean_diff": m,
            "interval": [lo, hi],
            "method": "bootstrap",
            "shown": bool(shown),
            "verdict": ("b higher" if lo > 0.0 else "b lower") if shown else stats.NO_DIFF,
        }
    return {"vs": vs, "energy_ratio": stats.ratio(_by_seed(a, "energy_after"), _by_seed(b, "energy_after"))}


def paired_list(cells: Sequence[dict]) -> list[dict]:
    """Every paired comparison of the study (``summary.json``'s ``paired``): per plant, fault and law, the law
    against the reference law on the common seeds."""
    out = []
    for c in cells:
        if "vs" not in c:
            continue
        out.append(
            {
                "plant": c["plant"],
                "fault": c["fault"],
                "kind": c["kind"],
                "severity": c["severity"],
                "a": c["vs"]["law"],
                "b": c["controller"],
                "ise_ref_after_diff": c["vs"]["ise_ref_after"],
                "controlled": c["vs"]["controlled"],
                "energy_ratio": c["energy_ratio"],
                **({"last_window_diff": c["vs"]["last_window"]} if "last_window" in c["vs"] else {}),
            }
        )
    return out


def _fmt(v, spec: str = ".3g") -> str:
    return "-" if v is None else format(v, spec)


def _rows(cells, plant: str, onset) -> tuple[float | None, dict]:
    """(the onset, {(kind, severity): {controller: cell}}) of a plant's table at ``onset`` (None: the first one,
    never the last)."""
    mine = [c for c in cells if c["plant"] == plant]
    onsets = sorted({c["onset_s"] for c in mine if c["onset_s"] is not None})
    onset = onsets[0] if onset is None and onsets else onset
    rows: dict[tuple, dict] = {}
    for c in mine:
        if c["kind"] == NONE or c["onset_s"] == onset:
            rows.setdefault((c["kind"], c["severity"]), {})[c["controller"]] = c
    return onset, rows


def _name(kind: str, sev, code: bool = False) -> str:
    if kind == NONE:
        return "none"
    text = f"{kind}={'here' if sev is None else format(sev, 'g')}"
    return f"`{text}`" if code else text


def _fault_table(cells, plant: str, controllers, onset, title: str, entry, width: int = 22) -> str:
    """A plant's printed table: a row per fault (kind and severity, at ``onset``: the first one by default), per
    controller ``entry(cell)`` (``width`` characters) or "-" where the cell is missing."""
    onset, rows = _rows(cells, plant, onset)
    head = f"{'fault':<22}" + "".join(f" {n:>{width - 1}}" for n in controllers)  # whole names (legend: cli.legend)
    lines = [f"{plant}: {title}, onset {_fmt(onset, 'g')} s", head]
    for (kind, sev), per in rows.items():
        lines.append(
            f"{_name(kind, sev):<22}"
            + "".join(f"{'-':>{width}}" if (e := entry(per.get(n))) is None else e.rjust(width) for n in controllers)
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


def _after(c: dict) -> str:
    """The median ise_ref after the onset to the digits its interval over the seeds supports."""
    return stats.fmt(c["ise_ref_after_p50"], c.get("ise_ref_after_digits", 3))


def table(cells: Sequence[dict], plant: str, controllers: Sequence[str], onset: float | None = None) -> str:
    """The printed table of one plant: a row per fault (kind and severity, at ``onset``: the first one by default),
    per controller the share controlled (%) and the median ise_ref after the onset (to the digits its interval
    over the seeds supports)."""

    def entry(c):
        return None if c is None else f"{100 * c['share_controlled']:>9.0f} % {_after(c):>10}"

    title = "% controlled / median ise_ref after the onset (rad^2 s)"
    return _fault_table(cells, plant, controllers, onset, title, entry)


def _diff(c: dict | None) -> str | None:
    """A cell's paired difference to the reference law: median [interval], "=" where no difference is shown."""
    d = (c or {}).get("vs", {}).get("ise_ref_after")
    if d is None:
        return None
    lo, hi = d["interval"]
    return f"{d['median_diff']:+.2g} [{lo:+.2g}, {hi:+.2g}]{'' if d['shown'] else ' ='}"


def _ratio(c: dict | None) -> str | None:
    r = (c or {}).get("energy_ratio")
    return None if r is None else f"{r['median']:.2g}x"


def paired_table(cells: Sequence[dict], plant: str, controllers: Sequence[str], onset: float | None = None) -> str:
    """Each law against the reference law (CL-SAC when flown) on the common seeds: the median paired difference of
    ise_ref after the onset (law - reference, rad^2 s) with its 95 % sign-test interval ("=": no difference shown),
    and the law's energy after the onset over the reference's (median of the paired ratios)."""
    ref = next((c["reference"] for c in cells if c["plant"] == plant and "reference" in c), None)
    others = [n for n in controllers if n != ref]

    def entry(c):
        d, r = _diff(c), _ratio(c)
        return None if d is None else f"{d} E {r}"

    title = (
        f"paired difference to {label(ref)} of ise_ref after the onset (rad^2 s), median [95 % sign-test "
        "interval] ('=': no difference shown) and energy ratio E"
    )
    return _fault_table(cells, plant, others, onset, title, entry, width=36)


def period_table(cells: Sequence[dict], plant: str, controllers: Sequence[str], period: float = PERIOD_S) -> str:
    """The long flights' table of one plant: per fault (at its first onset) and controller, the mean ise_ref of the
    first whole period after the onset over the seeds, and the mean per period over the last window (every seed's
    periods there) with its 95 % bootstrap interval; the controllers ranked by each (1: the least error); the
    ranking can change with the time flown."""
    _onset, rows = _rows(cells, plant, None)
    any_long = next((c["long"] for per in rows.values() for c in per.values() if "long" in c), None)
    first = any_long["first_period"]["start_s"] if any_long else 0.0
    last = any_long["last_window"] if any_long else {"from_s": None, "to_s": None}
    lines = [
        f"{plant}: mean ise_ref per {period:g} s period (rad^2 s): the first period from {_fmt(first, 'g')} s / the "
        f"periods {_fmt(last['from_s'], 'g')}-{_fmt(last['to_s'], 'g')} s [95 % bootstrap interval], and the rank "
        "of each (1: least error)"
    ]
    width = 34
    lines.append(f"{'fault':<22}" + "".join(f" {n:>{width - 1}}" for n in controllers))
    for (kind, sev), per in rows.items():
        vals = {}
        for n in controllers:
            lg = per.get(n, {}).get("long")
            vals[n] = None if lg is None else (lg["first_period"], lg["last_window"])
        rank = {}
        for i in (0, 1):
            ok = sorted((v[i]["mean"], n) for n, v in vals.items() if v is not None and v[i]["mean"] is not None)
            for r, (_v, n) in enumerate(ok, 1):
                rank[(n, i)] = r
        row = f"{_name(kind, sev):<22}"
        for n in controllers:
            if vals[n] is None:
                row += "-".rjust(width)
                continue
            a, b = vals[n]
            lo, hi = b["interval"]
            r1, r2 = rank.get((n, 0), "-"), rank.get((n, 1), "-")
            m1, m2, lo, hi = (_fmt(v, ".2g") for v in (a["mean"], b["mean"], lo, hi))
            text = f"{m1}({r1})/{m2} [{lo}, {hi}]({r2})"
            row += text.rjust(width)
        lines.append(row)
    return "\n".join(lines)


def markdown_table(cells: Sequence[dict], plant: str, controllers: Sequence[str], energy: bool = False) -> str:
    """A docs table of one plant (docs/damage.md): a row per fault at the first onset, per controller "share
    controlled (%) / median ise_ref after the onset" (to the digits its interval supports); ``energy``: also the
    median energy after the onset and its paired ratio to the reference law's."""
    _onset, rows = _rows(cells, plant, None)
    head = "| fault | " + " | ".join(label(n) for n in controllers) + " |"
    lines = [head, "|---|" + "---:|" * len(controllers)]
    for (kind, sev), per in rows.items():
        out = []
        for n in controllers:
            c = per.get(n)
            if c is None:
                out.append("-")
                continue
            text = f"{100 * c['share_controlled']:.0f} % / {_after(c)}"
            if energy:
                text += f" / {_fmt(c['energy_after_p50'])}"
                text += f" ({_ratio(c)})" if c.get("energy_ratio") else ""
            out.append(text)
        lines.append(f"| {_name(kind, sev, True)} | " + " | ".join(out) + " |")
    return "\n".join(lines)


def markdown_paired_table(cells: Sequence[dict], plant: str, controllers: Sequence[str]) -> str:
    """A docs table of one plant: per fault and law, the paired difference to the reference law of ise_ref after
    the onset, median [95 % interval], "no difference shown" where the interval holds 0 (or reaches less than
    95 %), and the energy ratio."""
    _onset, rows = _rows(cells, plant, None)
    ref = next((c["reference"] for c in cells if c["plant"] == plant and "reference" in c), None)
    others = [n for n in controllers if n != ref]
    head = "| fault | " + " | ".join(f"{label(n)} - {label(ref)}" for n in others) + " |"
    lines = [head, "|---|" + "---:|" * len(others)]
    for (kind, sev), per in rows.items():
        out = []
        for n in others:
            d = (per.get(n) or {}).get("vs", {}).get("ise_ref_after")
            if d is None:
                out.append("-")
                continue
            lo, hi = d["interval"]
            text = f"{d['median_diff']:+.2g} [{lo:+.2g}, {hi:+.2g}]"
            why = "" if d["confidence"] >= stats.LEVEL else f" ({100 * d['confidence']:.4g} %)"
            out.append(text + ("" if d["shown"] else f" no difference shown{why}") + f", E {_ratio(per.get(n))}")
        lines.append(f"| {_name(kind, sev, True)} | " + " | ".join(out) + " |")
    return "\n".join(lines)


def markdown_period_table(cells: Sequence[dict], plants: Sequence[str], controllers: Sequence[str]) -> str:
    """A docs table of the long flights: a row per plant and fault, per controller "% controlled / mean ise_ref of
    the first period after the onset → mean per period over the last window [95 % bootstrap interval]"."""
    head = "| plant | fault | " + " | ".join(label(n) for n in controllers) + " |"
    lines = [head, "|---|---|" + "---:|" * len(controllers)]
    for plant in plants:
        _onset, rows = _rows(cells, plant, None)
        for (kind, sev), per in rows.items():
            out = []
            for n in controllers:
                c = per.get(n)
                if c is None or "long" not in c:
                    out.append("-")
                    continue
                a, b = c["long"]["first_period"], c["long"]["last_window"]
                lo, hi = b["interval"]
                share = 100 * c["share_controlled"]
                m1, m2, lo, hi = (_fmt(v, ".2g") for v in (a["mean"], b["mean"], lo, hi))
                out.append(f"{share:.0f} % / {m1} → {m2} [{lo}, {hi}]")
            name = "none" if kind == NONE else f"`{_name(kind, sev)}@{_fmt(_onset, 'g')}`"
            lines.append(f"| {plant} | {name} | " + " | ".join(out) + " |")
    return "\n".join(lines)


def markdown_tables(doc: dict, energy: Sequence[str] = ("clsac", "pid-energy", "baseline")) -> str:
    """Every docs table of a ``summary.json`` document, as docs/damage.md publishes them: per plant the table as
    designed, the paired differences to CL-SAC and (when flown) the table at equal effort; the long flights' table
    when the flights are >= 60 s."""
    cells = doc["cells"]
    out = []
    for plant in doc["plants"]:
        refused = doc.get("not_flown", {}).get(plant, {}).get("controllers", {})
        flown = [c for c in doc["controllers"] if c not in refused]
        out += [f"{plant}:", "", markdown_table(cells, plant, flown), ""]
        if len(flown) > 1 and doc.get("runs", 2) > 1:  # one seed pairs nothing
            out += [markdown_paired_table(cells, plant, flown), ""]
        eq = [c for c in energy if c in flown]
        if len(eq) == len(energy):
            out += [markdown_table(cells, plant, eq, energy=True), ""]
    if doc.get("duration_s", 0) >= 60:
        flown = list(doc["controllers"])
        out += [markdown_period_table(cells, doc["plants"], flown), ""]
    return "\n".join(out)
