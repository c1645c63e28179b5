"""``python -m tools.experiment delay-margin``: the largest extra actuator delay each law flies (docs/delay-margin.md).

Per plant and law, the reference flight (the paper's +-10 deg square wave of period 10 s, 30 s, still air) is
flown in-process by the damage study's flight function (``tools.experiment.damage.flight``: the same scenario, the
same ``--fault`` code, the same record) with ``--fault delay=X@0``, and judged by the product's one verdict
(``autopilot.envelope.verdict``, the record's ``controlled``).  The margin is the largest X (whole milliseconds: the
delay line holds whole physics steps of 1 ms) whose flight is controlled.  A second margin flies the same with the
surface's effectiveness falling to 0.3 at 10 s (``effectiveness=0.3@10``), the delay there from the start.

The search (``search``) assumes the verdict is monotone in the delay, and checks it first: it flies a coarse grid
0, STEP, 2 STEP, ... up to the cap until the first failure, then ``AFTER`` more grid points beyond it; a pass among
those marks the law non-monotone (reported, never hidden).  The margin is then bisected inside the first failure's
bracket (the last pass before the first failure, the first failure) to ``TOL_MS``.  A law not controlled at 0 has
no margin (None); one controlled at every grid point has a margin of at least the cap (``status`` says which).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

PROG = "python -m tools.experiment delay-margin"
STEP_MS = 10  # the coarse grid's step
CAP_MS = 300  # the coarse grid's last point: a larger margin is reported as ">= cap"
TOL_MS = 1  # the bisection's end: the bracket is (margin, margin + 1 ms)
AFTER = 3  # grid points flown past the first failure to check the verdict is monotone
DURATION_S = 30.0
LOSS = ("effectiveness", 0.3, 10.0)  # the mid-flight effectiveness loss of the second margin: kind, value, onset
CASES = ("nominal", "loss")
DESIGNED = "pid-retuned"  # retuned for each fault: a different PID at every delay, no margin of one controller


def label(controller: str) -> str:
    """The damage study's words for a controller (its tables' column names)."""
    from tools.experiment.damage import grid

    return grid.LABELS.get(controller, controller)


class MarginError(ValueError):
    """A flag the search cannot run with; the message is one line."""


def search(
    ok: Callable[[int], bool],
    *,
    step_ms: int = STEP_MS,
    cap_ms: int = CAP_MS,
    tol_ms: int = TOL_MS,
    after: int = AFTER,
    log: Callable[[int, bool], None] | None = None,
) -> dict:
    """The largest delay (integer ms) at which ``ok`` holds, assuming it is monotone (passes up to a point, fails
    beyond), checked on the coarse grid (module docstring).  Returns ``margin_ms`` (None: fails at 0),
    ``bracket_ms`` [last pass, first failure] (the failure None when none up to the cap), ``status``
    (``bracketed``, ``above_cap``, ``fails_at_zero``), ``monotone`` (False: a grid point past the first failure
    passed), ``passes_after_failure_ms``, ``grid`` and ``bisection`` ([[ms, ok], ...] in the order flown)."""
    if not (step_ms >= 1 and cap_ms >= 0 and tol_ms >= 1 and after >= 0):
        raise MarginError(f"step {step_ms} ms, cap {cap_ms} ms, tol {tol_ms} ms, after {after}: out of range")
    seen: dict[int, bool] = {}

    def fly(ms: int) -> bool:
        if ms not in seen:
            seen[ms] = bool(ok(ms))
            if log is not None:
                log(ms, seen[ms])
        return seen[ms]

    points = list(range(0, cap_ms + 1, step_ms))
    if points[-1] != cap_ms:
        points.append(cap_ms)
    grid, first_fail, extra = [], None, 0
    for ms in points:
        if first_fail is not None and extra >= after:
            break
        r = fly(ms)
        grid.append([ms, r])
        if first_fail is None and not r:
            first_fail = ms
        elif first_fail is not None:
            extra += 1
    passes_after = [ms for ms, r in grid if first_fail is not None and ms > first_fail and r]
    out = {
        "grid": grid,
        "bisection": [],
        "monotone": not passes_after,
        "passes_after_failure_ms": passes_after,
    }
    if first_fail is None:
        return {**out, "margin_ms": cap_ms, "bracket_ms": [cap_ms, None], "status": "above_cap"}
    if first_fail == 0:
        return {**out, "margin_ms": None, "bracket_ms": [None, 0], "status": "fails_at_zero"}
    lo, hi = max(ms for ms, r in grid if r and ms < first_fail), first_fail
    while hi - lo > tol_ms:
        mid = (lo + hi) // 2
        r = fly(mid)
        out["bisection"].append([mid, r])
        lo, hi = (mid, hi) if r else (lo, mid)
    return {**out, "margin_ms": lo, "bracket_ms": [lo, hi], "status": "bracketed"}


@dataclass(frozen=True)
class Case:
    """One margin to find: ``plant``, ``controller``, ``case`` (``nominal`` or ``loss``), the search's grid and
    ``gains`` (a PID's designed gains, ``pid-energy``'s)."""

    plant: str
    controller: str
    case: str = "nominal"
    step_ms: int = STEP_MS
    cap_ms: int = CAP_MS
    tol_ms: int = TOL_MS
    gains: tuple | None = None
    verbose: bool = False

    @property
    def runs(self) -> tuple[int]:
        return (0,)


def faults_of(delay_ms: int, case: str) -> tuple:
    """The flight's faults: ``delay=X@0`` (none at 0 ms), then in the ``loss`` case ``effectiveness=0.3@10``."""
    from tools.experiment.damage.grid import fault_of

    out = [fault_of("delay", delay_ms / 1000.0, 0.0)] if delay_ms > 0 else []
    if case == "loss":
        out.append(fault_of(*LOSS))
    return tuple(out)


def fly(plant: str, controller: str, delay_ms: int, case: str = "nominal", gains=None) -> dict:
    """The damage study's record (``tools.experiment.damage.flight.record``) of the reference flight, still air,
    with the case's faults; a square MIMO plant as ``fly_record_mimo`` flies it."""
    from sitl import plant as plants
    from tools.experiment.damage import flight
    from tools.experiment.scenario import PAPER, run_inprocess

    faults = faults_of(delay_ms, case)
    dist = flight.disturbances("none", 1)
    onset = LOSS[2] if case == "loss" else 0.0
    scen = flight._scenario(plant, DURATION_S, dist, faults=faults, baseline_gains=gains)
    dt = 1.0 / scen.control_rate_hz
    if plants.spec(plant).mimo:
        from tools.experiment.mimo_inprocess import run_mimo

        r = run_mimo(
            plant, controller, duration_s=DURATION_S, rate_hz=PAPER.control_rate_hz, faults=faults, disturbances=dist
        )
        return flight.record(
            r["series"], r["metrics"], onset, scen.period_s, scen.u_limit_rad, dt, flight._roll_surface(plant),
            r["sideslip"],
        )  # fmt: skip
    res = run_inprocess(scen, flight._run(controller), atmosphere=True)
    return flight.record(
        res.series, res.metrics, onset, scen.period_s, scen.u_limit_rad, dt, flight._roll_surface(plant)
    )


def measure_margin(case: Case) -> dict:
    """One margin (picklable, for ``tools.experiment.study.execution.stream``): ``search`` over ``fly``."""
    reasons: dict[int, str] = {}
    t0 = time.perf_counter()

    def ok(ms: int) -> bool:
        rec = fly(case.plant, case.controller, ms, case.case, case.gains)
        reasons[ms] = rec["reason"]
        return rec["controlled"]

    def log(ms: int, r: bool) -> None:
        if case.verbose:
            what = f"{case.plant} {case.controller} {case.case}"
            print(f"  {what}: {ms} ms {'controlled' if r else 'NOT controlled'}", file=sys.stderr, flush=True)

    s = search(ok, step_ms=case.step_ms, cap_ms=case.cap_ms, tol_ms=case.tol_ms, log=log)
    lo, hi = s["bracket_ms"]
    return {
        **s,
        "margin_s": None if s["margin_ms"] is None else s["margin_ms"] / 1000.0,
        "bracket_s": [None if lo is None else lo / 1000.0, None if hi is None else hi / 1000.0],
        "failure_reason": None if hi is None else reasons.get(hi),
        "flights": len(reasons),
        "wall_s": time.perf_counter() - t0,
    }


def controllers_for(plant: str, asked: Sequence[str] | None) -> tuple[list[str], dict[str, str]]:
    """The controllers flown on ``plant`` and {controller: why not} for those it does not fly.  ``asked`` None:
    every registered law (``autopilot.controllers``, the PID variants included) and the damage study's SAC and
    CL-SAC with the robust PFC, where the plant flies them."""
    from autopilot import controllers as registry
    from tools.experiment.damage import grid

    names = list(asked) if asked is not None else [*registry.NAMES, *grid.ROBUST]
    refused = dict(grid.controller_refusals(plant, names))
    if DESIGNED in names:
        refused[DESIGNED] = "retuned for each fault: a different PID at every delay, not one controller's margin"
    from sitl import plant as plants

    if grid.ENERGY in names and plants.spec(plant).mimo:
        refused.setdefault(grid.ENERGY, grid.MIMO_REFUSALS[grid.ENERGY])
    return [c for c in names if c not in refused], refused


def known_controllers() -> tuple[str, ...]:
    from autopilot import controllers as registry
    from tools.experiment.damage import grid

    return tuple(dict.fromkeys([*registry.NAMES, *grid.ROBUST, grid.ENERGY]))


def _ms(text: str) -> int:
    """A delay in seconds on the command line, as whole milliseconds (the delay line's resolution)."""
    from sitl import damage

    x = damage.number(text)
    if x is None or not (0 < x <= damage.MAX_DELAY_S):
        raise argparse.ArgumentTypeError(f"expected seconds in (0, {damage.MAX_DELAY_S:g}], got {text!r}")
    ms = round(x * 1000.0)
    if ms < 1 or abs(ms - x * 1000.0) > 1e-6:
        raise argparse.ArgumentTypeError(f"expected whole milliseconds (the delay line's step), got {text!r}")
    return ms


def build_parser() -> argparse.ArgumentParser:
    from autopilot.shared.cli import OneLineArgumentParser
    from sitl.plant_kinds import help_text as plant_help
    from tools.experiment import flags

    p = OneLineArgumentParser(
        prog=PROG,
        description="The delay margin of every law: the largest extra actuator delay (--fault delay=X@0) at which "
        "the reference flight (30 s, still air) stays controlled, bisected to 1 ms, and the same under an "
        "effectiveness loss to 0.3 at 10 s; writes OUT/summary.json (docs/delay-margin.md).",
    )
    p.add_argument(
        "--plant",
        default="kh2013a,jsbsim:c172x",
        metavar="P1,P2",
        help=f"plants: {plant_help(None)} (default kh2013a,jsbsim:c172x)",  # sitl.plant_kinds' records
    )
    p.add_argument(
        "--controllers",
        default=None,
        metavar="C1,C2",
        help="laws to fly (default: every registered law the plant flies, the PIDs included, and SAC and CL-SAC "
        "with the robust PFC; also pid-energy)",
    )
    flags.add_out(p, "delay-margin")
    p.add_argument("--step", type=_ms, default=STEP_MS, help=f"the coarse grid's step, s (default {STEP_MS / 1000:g})")
    p.add_argument("--cap", type=_ms, default=CAP_MS, help=f"the grid's last delay, s (default {CAP_MS / 1000:g})")
    p.add_argument("--no-loss", action="store_true", help="skip the margin under the effectiveness loss")
    flags.add_workers(p, scheduler=False)
    p.add_argument("--verbose", action="store_true", help="a line on stderr per flight, not only per margin")
    return p


def plan(args) -> tuple[list[str], list[Case], dict]:
    """The plants, the cases to search and {plant: {controller: why not}} (MarginError, PlantError: one line)."""
    from tools.experiment.damage import grid
    from tools.experiment.flags import plant_list as plants_of

    plant_list = plants_of(args.plant)
    asked = None
    if args.controllers is not None:
        asked = list(dict.fromkeys(grid.parse_list(args.controllers, "controllers")))
        known = known_controllers()
        bad = [c for c in asked if c not in known and c != DESIGNED]
        if bad:
            raise MarginError(f"--controllers: unknown controller {bad[0]!r} (known: {', '.join(known)})")
    if args.step > args.cap:
        raise MarginError(f"--step {args.step / 1000:g} s is larger than --cap {args.cap / 1000:g} s")
    cases, refused = [], {}
    for p in plant_list:
        flown, why = controllers_for(p, asked)
        if why:
            refused[p] = why
        for c in flown:
            for k in CASES[: 1 if args.no_loss else 2]:
                cases.append(Case(p, c, k, args.step, args.cap, TOL_MS, verbose=args.verbose))
    if not cases:
        raise MarginError("no plant flies any of the controllers asked for")
    return plant_list, cases, refused


def with_gains(cases: list[Case]) -> list[Case]:
    """``pid-energy``'s cases with its gains (the damage study's calibration, once per plant)."""
    from dataclasses import replace

    from tools.experiment.damage import grid
    from tools.experiment.damage.flight import calibrate

    gains = {}
    out = []
    for c in cases:
        if c.controller == grid.ENERGY:
            if c.plant not in gains:
                gains[c.plant] = tuple(calibrate(grid.Calibration(c.plant))["gains"])
            c = replace(c, gains=gains[c.plant])
        out.append(c)
    return out


def _fmt(r: dict | None) -> str:
    if r is None:
        return "-"
    lo, hi = r["bracket_ms"]
    if r["status"] == "fails_at_zero":
        text = "fails at 0"
    elif r["status"] == "above_cap":
        text = f">= {lo} ms"
    else:
        text = f"{lo} ms [{lo}, {hi})"
    return text + ("" if r["monotone"] else " non-monotone")


def table(results: Sequence[dict], plants: Sequence[str]) -> str:
    """Per plant: each law's margin as designed and under the effectiveness loss, with its bracket."""
    lines = []
    for p in plants:
        rows = [r for r in results if r["plant"] == p]
        if not rows:
            continue
        if lines:
            lines.append("")
        lines.append(f"{p}: largest extra actuator delay still controlled (bracket: last pass, first failure)")
        lines.append(f"{'law':<32}{'as built':>28}{'effectiveness 0.3 at 10 s':>32}")
        for c in dict.fromkeys(r["controller"] for r in rows):
            by = {r["case"]: r for r in rows if r["controller"] == c}
            lines.append(f"{label(c)[:31]:<32}{_fmt(by.get('nominal')):>28}{_fmt(by.get('loss')):>32}")
    return "\n".join(lines)


def markdown(results: Sequence[dict], plants: Sequence[str], labels: dict | None = None) -> str:
    """The margins as docs/delay-margin.md shows them: a row per law, a column pair per plant."""
    labels = labels or {}
    by = {(r["plant"], r["controller"], r["case"]): r for r in results}
    laws = list(dict.fromkeys(r["controller"] for r in results))
    head = "| law | " + " | ".join(f"{p}: as built | {p}: effectiveness 0.3 at 10 s" for p in plants) + " |"
    lines = [head, "|---|" + "---:|---:|" * len(plants)]
    for c in laws:
        cols = [_fmt(by.get((p, c, k))) if (p, c, k) in by else "not flown" for p in plants for k in CASES]
        lines.append(f"| {labels.get(c, label(c))} (`{c}`) | " + " | ".join(cols) + " |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    from autopilot.shared.process import write_json_atomic
    from sitl import plant as plants
    from tools.experiment.damage import grid
    from tools.experiment.outdir import OutDirError, check_out_dir, default_out_dir, prepare_out_dir, write_problem
    from tools.experiment.study.execution import interruptible, stream

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        plant_list, cases, refused = plan(args)
        out = Path(args.out) if args.out else default_out_dir("delay-margin")
        check_out_dir(out)
        out = prepare_out_dir(out)
    except (MarginError, grid.DamageError, plants.PlantError, OutDirError) as exc:
        parser.error(str(exc))
    workers = min(args.workers or os.cpu_count() or 1, len(cases))
    for p, why in refused.items():
        for c, reason in why.items():
            print(f"not flown on {p}: controller {c} ({reason})", file=sys.stderr)
    print(f"{len(cases)} margins to find on {workers} local process(es), output in {out.resolve()}", file=sys.stderr)
    t0 = time.perf_counter()
    results, error = [], None
    try:
        cases = with_gains(cases)
        with interruptible() as stop:
            for i, (c, r) in enumerate(stream(cases, None, workers, measure_margin, stop=stop), 1):
                results.append({"plant": c.plant, "controller": c.controller, "case": c.case, **r})
                print(
                    f"[{i}/{len(cases)}] {c.plant} {c.controller} {c.case}: {_fmt(results[-1])} "
                    f"({r['flights']} flights, {r['wall_s']:.1f} s)",
                    file=sys.stderr,
                    flush=True,
                )
    except KeyboardInterrupt:
        error = "interrupted"
    except Exception as exc:  # noqa: BLE001  (the margins found so far are kept)
        from tools.experiment.outdir import one_line

        if not results:
            print(f"{PROG}: error: {one_line(exc)}", file=sys.stderr)
            return 1
        error = one_line(exc)
    wall = time.perf_counter() - t0
    doc = summary(results, plant_list, refused, args, wall, len(cases))
    if error:
        doc["error"] = error
    try:
        write_json_atomic(out / "summary.json", doc)
    except OSError as exc:
        print(f"{PROG}: error: {write_problem(out / 'summary.json', exc)}", file=sys.stderr)
        return 1
    print(table(results, plant_list))
    print()
    nonmono = [f"{r['plant']} {r['controller']} {r['case']}" for r in results if not r["monotone"]]
    flights = sum(r["flights"] for r in results)
    print(
        f"{len(results)} of {len(cases)} margins, {flights} flights in {wall:.1f} s; "
        f"{'non-monotone: ' + ', '.join(nonmono) if nonmono else 'every verdict monotone on its grid'}; "
        f"wrote {out / 'summary.json'}"
    )
    if error:
        print(f"{PROG}: {error}; kept {len(results)} of {len(cases)} margins", file=sys.stderr)
        return 130 if error == "interrupted" else 1
    return 0


def summary(results, plant_list, refused, args, wall: float, of: int) -> dict:
    margin: dict = {p: {} for p in plant_list}
    loss: dict = {p: {} for p in plant_list}
    for r in results:
        (margin if r["case"] == "nominal" else loss)[r["plant"]][r["controller"]] = r["margin_s"]
    return {
        "study": "delay-margin",
        "flight": "the reference scenario's +-10 deg square wave, period 10 s, 30 s, still air, in-process "
        "(tools.experiment.damage.flight), --fault delay=X@0; judged by autopilot.envelope.verdict",
        "loss": f"{LOSS[0]}={LOSS[1]:g}@{LOSS[2]:g} beside the delay",
        "grid": {"step_s": args.step / 1000, "cap_s": args.cap / 1000, "tol_s": TOL_MS / 1000, "after": AFTER},
        "plants": plant_list,
        "labels": {r["controller"]: label(r["controller"]) for r in results},
        "not_flown": refused,
        "margin_s": margin,
        "margin_after_loss_s": loss,
        "margins": results,
        "partial": len(results) < of,
        "wall_s": wall,
        "margin_note": "None: not controlled without extra delay; status above_cap: controlled at every grid point "
        "(the margin is at least the cap)",
    }


if __name__ == "__main__":
    sys.exit(main())
