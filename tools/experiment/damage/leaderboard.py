"""The damage study's leaderboard per plant (docs/damage.md, "Leaderboard"): for every law, against each fault kind
and severity, the share of flights still controlled with its 95 % Wilson interval, the median recovery time, the
median tracking error after the onset and the median energy after it, each law as designed and beside the PID at
equal effort (``pid-energy``: the ratio of the law's median error, and of its median energy, to that PID's in the
same cell).  The winner of a fault is the law with the highest share controlled, ties broken by the least median
error after the onset; ``pid-retuned`` (the PID retuned knowing the fault, a bound) is shown, never ranked.

    python -m tools.experiment.damage.leaderboard OUT/summary.json [MORE.json ...] [--plant P]   (markdown)

Several summaries are read as one study (their cells together: runs of other laws on the same seeds).

No I/O but that command's.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence

from tools.experiment.damage.grid import ENERGY, LABELS, NONE, RETUNED

NOT_RANKED = (RETUNED,)  # a bound that knows the fault, not a law one can fly without knowing it


def _name(kind: str, sev) -> str:
    return "none" if kind == NONE else f"{kind}={'here' if sev is None else format(sev, 'g')}"


def _cells(cells: Sequence[dict], plant: str, onset: float | None) -> tuple[float | None, dict]:
    """(the onset, {fault name: {controller: cell}}) of ``plant`` at ``onset`` (None: the first), faults in the
    study's order."""
    mine = [c for c in cells if c["plant"] == plant]
    onsets = sorted({c["onset_s"] for c in mine if c["onset_s"] is not None})
    onset = onsets[0] if onset is None and onsets else onset
    out: dict[str, dict] = {}
    for c in mine:
        if c["kind"] == NONE or c["onset_s"] == onset:
            out.setdefault(_name(c["kind"], c["severity"]), {})[c["controller"]] = c
    return onset, out


def _ratio(a, b) -> float | None:
    return None if a is None or b is None or b <= 0 else a / b


def rows(cells: Sequence[dict], plant: str, onset: float | None = None) -> list[dict]:
    """A row per fault and law: ``fault``, ``controller``, ``flights``, ``controlled``, ``share``, ``wilson95``,
    ``recovery_s_p50``, ``ise_ref_after_p50``, ``energy_after_p50`` and, where the PID at equal effort flew the
    same cell, ``ise_vs_energy_pid`` and ``energy_vs_energy_pid`` (the law's median over that PID's)."""
    _, faults = _cells(cells, plant, onset)
    out = []
    for fault, per in faults.items():
        ref = per.get(ENERGY)
        for ctrl, c in per.items():
            out.append(
                {
                    "fault": fault,
                    "controller": ctrl,
                    "flights": c["flights"],
                    "controlled": c["controlled"],
                    "share": c["share_controlled"],
                    "wilson95": list(c["wilson95"]),
                    "recovery_s_p50": c.get("recovery_s_p50"),
                    "recovered": sum(bool(r.get("recovered")) for r in c.get("runs", ())),
                    "recovery_measured": sum(r.get("recovered") is not None for r in c.get("runs", ())),
                    "ise_ref_after_p50": c.get("ise_ref_after_p50"),
                    "energy_after_p50": c.get("energy_after_p50"),
                    "ise_vs_energy_pid": None
                    if ref is None or ctrl == ENERGY
                    else _ratio(c.get("ise_ref_after_p50"), ref.get("ise_ref_after_p50")),
                    "energy_vs_energy_pid": None
                    if ref is None or ctrl == ENERGY
                    else _ratio(c.get("energy_after_p50"), ref.get("energy_after_p50")),
                }
            )
    return out


def _key(r: dict) -> tuple:
    err = r["ise_ref_after_p50"]
    return (-(r["share"] or 0.0), float("inf") if err is None else err)


def winners(cells: Sequence[dict], plant: str, onset: float | None = None) -> dict[str, list[str]]:
    """{fault: [the laws that win it]}: the highest share controlled, then the least median error after the onset
    (several on an exact tie); ``NOT_RANKED`` never wins, and a fault no law keeps in any flight has no winner
    (an empty list: the least error of lost flights ranks nothing)."""
    out: dict[str, list[str]] = {}
    for r in rows(cells, plant, onset):
        if r["controller"] in NOT_RANKED:
            continue
        best = out.setdefault(r["fault"], [])
        if not best:
            best.append(r)
        elif _key(r) < _key(best[0]):
            best[:] = [r]
        elif _key(r) == _key(best[0]):
            best.append(r)
    return {f: [r["controller"] for r in rs] if rs and rs[0]["share"] else [] for f, rs in out.items()}


def _g(v, spec: str = ".3g") -> str:
    return "-" if v is None else format(v, spec)


def markdown(cells: Sequence[dict], plant: str, onset: float | None = None, labels: dict | None = None) -> str:
    """The plant's leaderboard as a markdown table (a row per fault and law, the fault's winner in bold), and a
    line per law: the faults it wins."""
    labels = {**LABELS, **(labels or {})}
    rs = rows(cells, plant, onset)
    wins = winners(cells, plant, onset)
    lines = [
        "| fault | law | controlled | 95 % Wilson | recovery, s (recovered) | error after onset, rad²s | "
        "energy after | error / PID at equal effort | energy / PID at equal effort |",
        "|---|---|---:|---|---:|---:|---:|---:|---:|",
    ]
    for r in rs:
        name = labels.get(r["controller"], r["controller"])
        if r["controller"] in wins.get(r["fault"], ()):
            name = f"**{name}**"
        elif r["controller"] in NOT_RANKED:
            name = f"{name} (bound)"
        lo, hi = r["wilson95"]
        lines.append(
            f"| `{r['fault']}` | {name} | {r['controlled']}/{r['flights']} | {lo:.2f}-{hi:.2f} | "
            f"{_g(r['recovery_s_p50'], '.1f')} ({r['recovered']}/{r['recovery_measured']}) | "
            f"{_g(r['ise_ref_after_p50'])} | {_g(r['energy_after_p50'])} | "
            f"{_g(r['ise_vs_energy_pid'])} | {_g(r['energy_vs_energy_pid'])} |"
        )
    by_law: dict[str, list[str]] = {}
    for fault, laws in wins.items():
        for c in laws:
            by_law.setdefault(c, []).append(fault)
    lines.append("")
    for c in dict.fromkeys(r["controller"] for r in rs):
        if c in NOT_RANKED:
            continue
        won = by_law.get(c, [])
        lines.append(f"- {labels.get(c, c)} wins {len(won)}: {', '.join(f'`{f}`' for f in won) or 'none'}")
    lost = [f for f, laws in wins.items() if not laws]
    if lost:
        lines.append(f"- no law keeps a flight: {', '.join(f'`{f}`' for f in lost)}")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    prog = "python -m tools.experiment.damage.leaderboard"
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n")[0])
    p.add_argument("summary", nargs="+", help="a damage study's summary.json (several: their cells as one study)")
    p.add_argument("--plant", default=None, help="one plant (default: each)")
    args = p.parse_args(argv)
    cells, labels, plants = [], {}, []
    for path in args.summary:
        try:
            with open(path, encoding="utf-8") as fh:
                doc = json.load(fh)
            cells += list(doc["cells"])
            labels.update(doc.get("labels", {}))
            plants += [x for x in doc["plants"] if x not in plants]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            print(f"{p.prog}: error: cannot read {path}: {exc}".splitlines()[0], file=sys.stderr)
            return 2
    plants = [args.plant] if args.plant else plants
    for plant in plants:
        print(f"### {plant}\n")
        print(markdown(cells, plant, labels=labels))
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
