"""The damage study's leaderboard per plant (docs/damage.md, "Leaderboard"): for every law, against each fault kind
and severity, the share of flights still controlled with its 95 % Wilson interval, the median recovery time, the
median tracking error after the onset (with its sign-test interval) and the median energy after it, each law as
designed and beside the PID at equal effort (``pid-energy``: the ratio of the law's median error, and of its median
energy, to that PID's in the same cell).  The winner of a fault is the law with the highest share controlled, ties
broken by the least median error after the onset; ``pid-retuned`` (the PID retuned knowing the fault, a bound) is
shown, never ranked.  Each win is set against the next law (the runner-up) on the seeds both flew: the seeds only
one of the two keeps (McNemar's exact test) and the paired difference of the error (the sign test's interval),
``tools.experiment.damage.stats``.

    python -m tools.experiment.damage.leaderboard OUT/summary.json [MORE.json ...] [--plant P]   (markdown)
    python -m tools.experiment.damage.leaderboard OUT/summary.json --page docs/damage.md   (rewrite its block)
    python -m tools.experiment.damage.leaderboard --fly OUT [--page docs/damage.md]        (regenerate it)

Several summaries are read as one study (their cells together: runs of other laws on the same seeds).

The page's block sits between ``<!-- leaderboard-ars: ARGS -->``, ``<!-- leaderboard-damage: ARGS -->`` and
``<!-- /leaderboard -->``: ``--fly OUT`` trains the learned policy with the first line's flags
(``python -m tools.experiment.gym.ars --out OUT/ars ARGS``: deterministic for its ``--seed``), flies the damage
study with the second's (``{policy}`` there is ``OUT/ars/policy_law.py:Policy``) into ``OUT/damage``, and writes
the block from its ``summary.json``.  ``--policy FILE.py:Class`` flies a policy trained before instead.

No I/O but that command's.
"""

from __future__ import annotations

import argparse
import json
import re
import shlex
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

from tools.experiment.damage import stats
from tools.experiment.damage.grid import ENERGY, LABELS, NONE, RETUNED

NOT_RANKED = (RETUNED,)  # a bound that knows the fault, not a law one can fly without knowing it
PAGE = Path(__file__).resolve().parents[3] / "docs" / "damage.md"
BLOCK = re.compile(
    r"(<!-- leaderboard-ars: ([^\n]*?) -->\n<!-- leaderboard-damage: ([^\n]*?) -->\n)(.*?)(<!-- /leaderboard -->)",
    re.S,
)
POLICY = "{policy}"  # in the damage flags of the block: the trained policy's law
HEADER = (
    "| fault | law | controlled | 95 % Wilson | recovery, s (recovered) | error after onset, rad²s, median "
    "[95 % sign test] | energy after | error / PID at equal effort | energy / PID at equal effort |"
)


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
    ``recovery_s_p50``, ``ise_ref_after_p50`` (with ``ise_ref_after_interval``, its confidence and the digits it
    supports), ``energy_after_p50`` and, where the PID at equal effort flew the same cell, ``ise_vs_energy_pid``
    and ``energy_vs_energy_pid`` (the law's median over that PID's)."""
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
                    "ise_ref_after_interval": c.get("ise_ref_after_interval"),
                    "ise_ref_after_confidence": c.get("ise_ref_after_confidence"),
                    "ise_ref_after_digits": c.get("ise_ref_after_digits", 3),
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


def ranking(cells: Sequence[dict], plant: str, onset: float | None = None) -> dict[str, list[dict]]:
    """{fault: its ranked laws' rows, best first}: the highest share controlled, then the least median error after
    the onset (``NOT_RANKED`` left out; the sort is stable, so an exact tie keeps the study's order)."""
    out: dict[str, list[dict]] = {}
    for r in rows(cells, plant, onset):
        if r["controller"] not in NOT_RANKED:
            out.setdefault(r["fault"], []).append(r)
    return {f: sorted(rs, key=_key) for f, rs in out.items()}


def winners(cells: Sequence[dict], plant: str, onset: float | None = None) -> dict[str, list[str]]:
    """{fault: [the laws that win it]}: the highest share controlled, then the least median error after the onset
    (several on an exact tie); ``NOT_RANKED`` never wins, and a fault no law keeps in any flight has no winner
    (an empty list: the least error of lost flights ranks nothing)."""
    out = {}
    for f, rs in ranking(cells, plant, onset).items():
        out[f] = [r["controller"] for r in rs if _key(r) == _key(rs[0])] if rs and rs[0]["share"] else []
    return out


def _by_seed(cell: dict, key: str) -> dict:
    return {r["seed"]: r[key] for r in cell.get("runs", ())}


def margins(cells: Sequence[dict], plant: str, onset: float | None = None) -> dict[str, dict]:
    """{fault: the win against the runner-up}, for each fault with a winner: ``winner``, ``runner_up`` (the next
    ranked law not tied with it; None when there is none), ``controlled`` (``stats.paired_share`` runner-up ->
    winner: the seeds only the winner keeps, ``b_only``, only the runner-up, ``a_only``, McNemar's exact p) and
    ``ise_ref_after`` (``stats.paired``: winner - runner-up over the common seeds, the sign test's interval)."""
    _, faults = _cells(cells, plant, onset)
    out = {}
    for f, rs in ranking(cells, plant, onset).items():
        if not rs or not rs[0]["share"]:
            continue
        win = rs[0]["controller"]
        nxt = next((r["controller"] for r in rs[1:] if _key(r) != _key(rs[0])), None)
        m = {"winner": win, "runner_up": nxt, "controlled": None, "ise_ref_after": None}
        if nxt is not None:
            a, b = faults[f][nxt], faults[f][win]
            m["controlled"] = stats.paired_share(_by_seed(a, "controlled"), _by_seed(b, "controlled"))
            m["ise_ref_after"] = stats.paired(
                _by_seed(a, "ise_ref_after"), _by_seed(b, "ise_ref_after"), "ise_ref_after"
            )
        out[f] = m
    return out


def _g(v, spec: str = ".3g") -> str:
    return "-" if v is None else format(v, spec)


def _two(x: float) -> str:
    """``x`` to 2 significant digits, without an exponent below 1e5 (an interval's ends)."""
    text = format(x, ".2g")
    return format(float(text), ".0f") if "e+" in text and abs(x) < 1e5 else text


def _two_signed(x: float) -> str:
    return ("+" if x >= 0 else "") + _two(x)


def _error(r: dict) -> str:
    """The median error to the digits its interval supports, and the interval (``stats.digits``)."""
    v, iv = r["ise_ref_after_p50"], r["ise_ref_after_interval"]
    if v is None:
        return "-"
    text = stats.fmt(v, r["ise_ref_after_digits"])
    return text if not iv else f"{text} [{_two(iv[0])}, {_two(iv[1])}]"


def row_line(r: dict, labels: dict, wins: Sequence[str] = ()) -> str:
    """One row of the table (the fault's winner in bold, the bound marked)."""
    name = labels.get(r["controller"], r["controller"])
    if r["controller"] in wins:
        name = f"**{name}**"
    elif r["controller"] in NOT_RANKED:
        name = f"{name} (bound)"
    lo, hi = r["wilson95"]
    return (
        f"| `{r['fault']}` | {name} | {r['controlled']}/{r['flights']} | {lo:.2f}-{hi:.2f} | "
        f"{_g(r['recovery_s_p50'], '.1f')} ({r['recovered']}/{r['recovery_measured']}) | "
        f"{_error(r)} | {_g(r['energy_after_p50'])} | "
        f"{_g(r['ise_vs_energy_pid'])} | {_g(r['energy_vs_energy_pid'])} |"
    )


def table(cells: Sequence[dict], plant: str, onset: float | None = None, labels: dict | None = None) -> str:
    """The plant's table: a row per fault and law, the fault's winner in bold."""
    labels = {**LABELS, **(labels or {})}
    wins = winners(cells, plant, onset)
    body = [row_line(r, labels, wins.get(r["fault"], ())) for r in rows(cells, plant, onset)]
    return "\n".join([HEADER, "|---|---|---:|---|---:|---:|---:|---:|---:|", *body])


def wins_lines(cells: Sequence[dict], plant: str, onset: float | None = None, labels: dict | None = None) -> str:
    """A line per law: the faults it wins; then the faults no law keeps."""
    labels = {**LABELS, **(labels or {})}
    wins = winners(cells, plant, onset)
    by_law: dict[str, list[str]] = {}
    for fault, laws in wins.items():
        for c in laws:
            by_law.setdefault(c, []).append(fault)
    lines = []
    for c in dict.fromkeys(r["controller"] for r in rows(cells, plant, onset)):
        if c in NOT_RANKED:
            continue
        won = by_law.get(c, [])
        lines.append(f"- {labels.get(c, c)} wins {len(won)}: {', '.join(f'`{f}`' for f in won) or 'none'}")
    lost = [f for f, laws in wins.items() if not laws]
    if lost:
        lines.append(f"- no law keeps a flight: {', '.join(f'`{f}`' for f in lost)}")
    return "\n".join(lines)


def margin_line(fault: str, m: dict, labels: dict) -> str:
    """``- `fault`: WINNER over RUNNER-UP: ...``, the win's two paired tests in words."""
    lab = lambda c: labels.get(c, c)  # noqa: E731
    if m["runner_up"] is None:
        return f"- `{fault}`: {lab(m['winner'])}, no other law ranked"
    sh, d = m["controlled"], m["ise_ref_after"]
    if sh["b_only"] or sh["a_only"]:
        kept = (
            f"kept at {sh['b_only']} seed(s) the other lost, lost at {sh['a_only']} it kept "
            f"(exact p = {sh['p_value']:.2g}: {'shown' if sh['shown'] else 'not shown'})"
        )
    else:
        kept = f"the same seeds kept ({sh['n']} common)"
    if d is None:
        err = "no error to compare"
    else:
        lo, hi = d["interval"]
        what = "lower, shown" if d["shown"] and hi < 0 else ("higher, shown" if d["shown"] else d["verdict"])
        err = f"error {_two_signed(d['median_diff'])} [{_two_signed(lo)}, {_two_signed(hi)}] rad²s: {what}"
    return f"- `{fault}`: {lab(m['winner'])} over {lab(m['runner_up'])}: {kept}; {err}"


def markdown(cells: Sequence[dict], plant: str, onset: float | None = None, labels: dict | None = None) -> str:
    """The plant's leaderboard as a markdown table (a row per fault and law, the fault's winner in bold), a line
    per law (the faults it wins) and a line per won fault (the win against the runner-up)."""
    labels = {**LABELS, **(labels or {})}
    ms = margins(cells, plant, onset)
    out = [table(cells, plant, onset, labels), "", wins_lines(cells, plant, onset, labels)]
    if ms:
        out += ["", *(margin_line(f, m, labels) for f, m in ms.items())]
    return "\n".join(out)


def page_block(doc: dict) -> str:
    """The page's block for a study's ``summary.json`` document: per plant, the wins, each win against the
    runner-up, and the full table folded."""
    labels = {**LABELS, **doc.get("labels", {})}
    cells = doc["cells"]
    out = []
    for plant in doc["plants"]:
        ms = margins(cells, plant)
        out += [
            f"**{plant}**, the winner of each fault (the highest share controlled, then the least median error after "
            "the onset; the PID retuned for the fault is a bound and not ranked):",
            "",
            wins_lines(cells, plant, labels=labels),
            "",
            f"{plant}, each win against the next law on the seeds both flew (the seeds only one of them keeps, "
            "McNemar's exact p; the winner's error minus the runner-up's, median [95 % sign-test interval]):",
            "",
            *(margin_line(f, m, labels) for f, m in ms.items()),
            "",
            f"<details><summary>{plant}: every law against every fault</summary>",
            "",
            table(cells, plant, labels=labels),
            "",
            "</details>",
            "",
        ]
    return "\n".join(out)


def commands(text: str) -> tuple[list[str], list[str]]:
    """(the ARS flags, the damage study's flags) of the page's block."""
    m = BLOCK.search(text)
    if m is None:
        raise ValueError("the page has no <!-- leaderboard-ars: ... --> block")
    return shlex.split(m.group(2)), shlex.split(m.group(3))


def rewrite(text: str, doc: dict) -> str:
    """``text`` with its leaderboard block's content replaced by ``page_block(doc)``."""
    return BLOCK.sub(lambda m: m.group(1) + "\n" + page_block(doc) + m.group(5), text, count=1)


def merge(docs: Sequence[dict]) -> dict:
    """One document of several studies' (their cells together; plants and labels in order)."""
    out = {"plants": [], "cells": [], "labels": {}}
    for d in docs:
        out["plants"] += [p for p in d["plants"] if p not in out["plants"]]
        out["cells"] += list(d["cells"])
        out["labels"].update(d.get("labels", {}))
    return out


def fly(out: Path, page: Path, policy: str | None = None) -> dict:
    """Regenerate the page's leaderboard: train the policy (unless ``policy`` is given), fly the study, return its
    ``summary.json`` document (the block's commands, module docstring)."""
    ars, damage = commands(page.read_text(encoding="utf-8"))
    if policy is None:
        cmd = [sys.executable, "-m", "tools.experiment.gym.ars", "--out", str(out / "ars"), *ars]
        print("$ " + shlex.join(cmd[1:]), flush=True)
        subprocess.run(cmd, check=True)
        policy = f"{out / 'ars' / 'policy_law.py'}:Policy"
    damage = [a.replace(POLICY, policy) for a in damage]
    cmd = [sys.executable, "-m", "tools.experiment", "damage", *damage, "--no-plot", "--out", str(out / "damage")]
    print("$ " + shlex.join(cmd[1:]), flush=True)
    subprocess.run(cmd, check=True)
    return json.loads((out / "damage" / "summary.json").read_text(encoding="utf-8"))


def main(argv: Sequence[str] | None = None) -> int:
    prog = "python -m tools.experiment.damage.leaderboard"
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n")[0])
    p.add_argument("summary", nargs="*", help="a damage study's summary.json (several: their cells as one study)")
    p.add_argument("--plant", default=None, help="one plant (default: each)")
    p.add_argument("--page", type=Path, default=None, help="rewrite this page's leaderboard block (docs/damage.md)")
    p.add_argument("--fly", type=Path, metavar="OUT", help="train and fly the page's commands into OUT, then write")
    p.add_argument("--policy", metavar="FILE.py:Class", help="with --fly: this trained policy (no training)")
    args = p.parse_args(argv)
    if bool(args.summary) == bool(args.fly):
        p.error("give a summary.json or --fly OUT (one of the two)")
    if args.policy and not args.fly:
        p.error("--policy goes with --fly")
    docs = []
    try:
        if args.fly:
            docs.append(fly(args.fly, args.page or PAGE, args.policy))
        for path in args.summary:
            with open(path, encoding="utf-8") as fh:
                docs.append(json.load(fh))
        doc = merge(docs)
    except (OSError, ValueError, KeyError, TypeError, subprocess.CalledProcessError) as exc:
        print(f"{prog}: error: {exc}".splitlines()[0], file=sys.stderr)
        return 2
    if args.plant:
        doc["plants"] = [args.plant]
    page = args.page or (PAGE if args.fly else None)
    if page is not None:
        try:
            text = page.read_text(encoding="utf-8")
            commands(text)
        except (OSError, ValueError) as exc:
            print(f"{prog}: error: {page}: {exc}".splitlines()[0], file=sys.stderr)
            return 2
        page.write_text(rewrite(text, doc), encoding="utf-8")
        print(f"rewrote the leaderboard of {page}")
        return 0
    for plant in doc["plants"]:
        print(f"### {plant}\n")
        print(markdown(doc["cells"], plant, labels=doc["labels"]))
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
