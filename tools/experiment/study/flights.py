"""The robustness study on a scalar plant, a JSBSim aircraft or a plant file: one in-process flight at a time.

Each flight is the reference scenario (the paper's +-10 deg square wave, 30 s) flown in-process
(``tools.experiment.scenario.run_inprocess``) with the plant's designed parameters
(``tools.design.linearise.designed_params``: designed at one airspeed, flown at all) and one of the controllers
of ``autopilot.controllers``.  A condition is a turbulence level (``--turbulence``) and, on a JSBSim aircraft, an
airspeed (``--airspeeds``: ``jsbsim:MODEL:airspeed_kt=V``); each condition is flown ``--seeds`` times, flight i
with the seed ``S * SEED_STRIDE + i`` of ``--seed S`` (the SITL's ``--seed`` of the same flight over MAVLink, as
the KH2013A study's ``replay_mavlink``).  A JSBSim aircraft flies its own MIL-F-8785C turbulence, seeded so; a
plant file flies the SITL's Dryden turbulence (``sitl.disturbances.Injector``, per physics step) when its states
carry the atmosphere ([v, p, r, phi], ``sitl.plant.check_disturbances``), else still air only.  In still air the
seeds fly the same flight.  A flight depends on (plant, controller, condition, seed) only, so the results are the
same whatever the execution (``tools.experiment.study.execution.stream``).  Bounded: inside the default envelope
(``autopilot.envelope``), as the KH2013A study.
"""

from __future__ import annotations

import os
import statistics
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from autopilot import controllers
from autopilot.envelope import saturated, verdict
from sitl import plant as plants
from tools.experiment.outdir import one_line
from tools.experiment.study.accumulate import wilson
from tools.experiment.study.execution import Progress, stream
from tools.experiment.study.sampling import BOUND_ROLL_RAD, BOUND_SAT_FRACTION, DEG, StudyError

TURBULENCE = ("none", "light", "moderate", "severe")
# The default controllers: every --controller of autopilot.controllers but the adaptive-law bench's (generic: the
# published tables fly these); --controllers names any registered law, or a user's own (FILE.py:Class)
CONTROLLERS = tuple(n for n in controllers.NAMES if not controllers.get(n).kind.generic)
SEED_STRIDE = 1_000_000
MAX_SEEDS = 10_000  # flights per controller and condition
RECORD_BYTES = 2000  # a flight's record in summary.json's table, about


@dataclass(frozen=True)
class StudyFlight:
    """One flight: ``runs`` (one) is what ``Progress`` counts; ``condition`` its cell's key."""

    controller: str
    plant: str  # the --plant text flown (a JSBSim spec with the condition's airspeed_kt)
    turbulence: str
    seed: int
    airspeed_kt: float | None = None  # a JSBSim aircraft's airspeed (its condition), None for a plant file

    @property
    def runs(self) -> tuple[int]:
        return (self.seed,)

    @property
    def condition(self) -> str:
        return self.turbulence if self.airspeed_kt is None else f"{self.airspeed_kt:g}kt_{self.turbulence}"


def fly_study_flight(task: StudyFlight) -> dict:
    """The flight's metrics, max |roll| (rad), saturated fraction and ``bounded`` (picklable: runs in a worker)."""
    from sitl import plant as plants
    from tools.experiment.scenario import PAPER, run_inprocess, run_of

    dist = (("seed", task.seed),) + ((("turbulence", task.turbulence),) if task.turbulence != "none" else ())
    limit = min(PAPER.u_limit_rad, plants.surface_limit_rad(task.plant) or float("inf"))
    if plants.spec(task.plant).mimo:
        return _simulate_mimo(task, dist, limit)
    scenario = replace(PAPER, plant=task.plant, u_limit_rad=limit, disturbances=dist)
    res = run_inprocess(scenario, run_of(task.controller), atmosphere=True)
    u, phi = res.series["u"], res.series["phi"]
    out = dict(res.metrics)
    out["max_abs_roll"] = float(np.max(np.abs(phi)))
    out["sat_fraction"] = float(np.mean(saturated(u, limit)))
    # inside the envelope (autopilot.envelope, the launcher's "controlled"): |roll|, saturation and tracking
    return _judged(out, verdict(res.series["t"], phi, u, limit, ref=res.series["ym_ol"]))


def _judged(out: dict, c: dict) -> dict:
    """``out`` with the verdict's ``bounded``, ``oscillating`` and ``not_following`` (``c``: the launcher's
    ``controlled``, ``autopilot.envelope.verdict``)."""
    tr = c.get("tracking")
    out["bounded"] = bool(c["ok"])
    out["oscillating"] = bool(tr is not None and tr["oscillating_windows"])
    out["not_following"] = bool(tr is not None and tr["not_following_windows"])
    return out


MIMO_CONTROLLERS = controllers.MIMO  # the controllers a square MIMO plant flies (autopilot.controllers)


def _simulate_mimo(task: StudyFlight, dist, limit: float) -> dict:
    """``fly_study_flight`` on a square MIMO plant: ``tools.experiment.mimo_inprocess.run_mimo`` (bit for bit its
    lockstep flight), judged as the launcher judges it (the roll channel, the rudder's saturation, the sideslip), the
    sideslip's max |beta| (rad) beside."""
    from tools.experiment.mimo_inprocess import run_mimo

    r = run_mimo(task.plant, task.controller, disturbances=dist)
    s = r["series"]
    out = dict(r["metrics"])
    out["max_abs_roll"] = float(np.max(np.abs(s["phi"])))
    out["sat_fraction"] = float(np.mean(saturated(s["u"], limit)))
    out["max_abs_sideslip"] = float(np.max(np.abs(s["beta"])))
    out["rudder_sat_fraction"] = r["sideslip"]["saturated_fraction"]["rudder"]
    # judged as the launcher judges it: the roll channel, the rudder's saturation and the sideslip
    return _judged(out, verdict(s["t"], s["phi"], s["u"], limit, ref=s["ym_ol"], sideslip=r["sideslip"]))


def with_airspeed(plant: str, airspeed_kt: float) -> str:
    """``jsbsim:MODEL[:KEYS]`` flown at ``airspeed_kt``."""
    return f"{plant}{',' if plant.count(':') > 1 else ':'}airspeed_kt={airspeed_kt!r}"


@dataclass(frozen=True)
class FlightOptions:
    """A scalar plant's study.  ``airspeeds_kt``: a JSBSim aircraft's conditions (None: its spec's airspeed)."""

    plant: str
    controllers: tuple[str, ...] = CONTROLLERS
    turbulence: tuple[str, ...] = ("none", "moderate")
    seeds: int = 3
    seed: int = 0
    airspeeds_kt: tuple[float, ...] | None = None
    workers: int = 1
    scheduler: str | None = None

    @property
    def jsbsim(self) -> bool:
        """A JSBSim aircraft (its own atmosphere, flown at airspeeds), else a plant file."""
        return plants.spec(self.plant).jsbsim is not None

    def conditions(self) -> list[tuple[str, float | None, str]]:
        """(plant text flown, airspeed or None, turbulence) of each condition, airspeed by airspeed."""
        if not self.jsbsim:
            return [(self.plant, None, t) for t in self.turbulence]
        if self.airspeeds_kt is None:
            from sitl.jsbsim_plant import parse_spec

            speeds = [(self.plant, parse_spec(self.plant).airspeed_kt)]
        else:
            speeds = [(with_airspeed(self.plant, v), float(v)) for v in self.airspeeds_kt]
        return [(text, v, t) for text, v in speeds for t in self.turbulence]

    def flights(self) -> list[StudyFlight]:
        """Every flight, controller by controller, condition by condition, seed by seed (a square MIMO plant: the
        controllers it flies, ``MIMO_CONTROLLERS``)."""
        mimo = plants.spec(self.plant).mimo
        names = [c for c in self.controllers if not mimo or c in MIMO_CONTROLLERS]
        return [
            StudyFlight(c, text, t, self.seed * SEED_STRIDE + i, v)
            for c in names
            for text, v, t in self.conditions()
            for i in range(self.seeds)
        ]


def make_flights(model: str, controllers, airspeeds, turbulence, seeds: int) -> list[StudyFlight]:
    """The flights of ``jsbsim:MODEL`` at ``airspeeds`` (kt) in ``turbulence``, ``seeds`` each."""
    opts = FlightOptions(f"jsbsim:{model}", tuple(controllers), tuple(turbulence), seeds, 0, tuple(airspeeds))
    return opts.flights()


def summarise(flights: Sequence[StudyFlight], results: Sequence[dict]) -> dict:
    """Per controller and condition: median ise_ref and energy, the share bounded with its Wilson 95 % interval,
    and every flight's record."""
    table: dict[str, dict[str, dict]] = {}
    for f, r in zip(flights, results):
        cell = table.setdefault(f.controller, {}).setdefault(f.condition, {"flights": []})
        cell["flights"].append({"seed": f.seed, **r})
    for per in table.values():
        for cell in per.values():
            fl = cell["flights"]
            k = sum(x["bounded"] for x in fl)
            cell["runs"] = len(fl)
            cell["ise_ref_p50"] = statistics.median(x["ise_ref"] for x in fl)
            cell["energy_p50"] = statistics.median(x["energy"] for x in fl)
            cell["bounded_share"] = k / len(fl)
            cell["bounded_ci95"] = wilson(k, len(fl))
    return table


def _label(controller: str) -> str:
    return controllers.get(controller).label


def _condition_label(cond: str) -> str:
    speed, sep, turb = cond.partition("kt_")
    return f"{speed} kt, {turb}" if sep else cond


def _conditions(table: dict) -> list[str]:
    conds = list(dict.fromkeys(c for per in table.values() for c in per))
    return sorted(
        conds, key=lambda c: (float(c.split("kt_")[0]) if "kt_" in c else 0.0, TURBULENCE.index(c.split("_")[-1]))
    )


def format_table(table: dict) -> str:
    """Markdown: per condition, each controller's median ise_ref and energy (rad^2 s; docs/jsbsim.md)."""
    head = "| condition | " + " | ".join(f"{_label(c)} ise_ref | {_label(c)} energy" for c in table) + " |"
    lines = [head, "|---|" + "---|---|" * len(table)]
    for cond in _conditions(table):
        cells = []
        for per in table.values():
            cell = per.get(cond)
            cells.append(f"{cell['ise_ref_p50']:.4g} | {cell['energy_p50']:.4g}" if cell else " | ")
        lines.append(f"| {_condition_label(cond)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def format_bounded(table: dict) -> str:
    """Markdown: per condition, each controller's bounded flights and the Wilson 95 % interval of the share."""
    lines = ["| condition | " + " | ".join(f"{_label(c)} bounded (95 % CI)" for c in table) + " |"]
    lines.append("|---|" + "---|" * len(table))
    for cond in _conditions(table):
        cells = []
        for per in table.values():
            cell = per.get(cond)
            if not cell:
                cells.append("")
                continue
            lo, hi = cell["bounded_ci95"]
            n = cell["runs"]
            cells.append(f"{round(cell['bounded_share'] * n)}/{n} ({100 * lo:.0f}-{100 * hi:.0f} %)")
        lines.append(f"| {_condition_label(cond)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def fly(opts: FlightOptions, *, log=print, progress: bool = True, stop: threading.Event | None = None, client=None):
    """Fly the study: (its summary section, wall time of the flights).  The first flight is flown alone and timed
    for the estimate; ``stop`` set: the flights done, ``partial`` True."""
    flights = opts.flights()
    where = opts.scheduler or ("this process" if opts.workers == 1 else f"{opts.workers} local processes")
    n_ctrl = len({f.controller for f in flights}) or 1  # a square MIMO plant flies MIMO_CONTROLLERS only
    log(
        f"study of {opts.plant}: {n_ctrl} controllers x {len(flights) // n_ctrl} "
        f"flights = {len(flights)} in-process flights of 30 s on {where}"
    )
    bar = Progress(len(flights), "30 s flights", enabled=progress, unit="flights")
    done: list[tuple[StudyFlight, dict]] = []
    t0 = time.perf_counter()
    error = None
    try:  # an error after the first flight keeps the flights flown (partial, with the error's line)
        for f, r in stream(flights[:1], simulate=fly_study_flight, stop=stop):
            done.append((f, r))
            bar.add(1)
        if done:
            first = time.perf_counter() - t0
            parallel = min(opts.workers, os.cpu_count() or 1)
            if client is not None:
                from tools.experiment.study.scheduler import threads

                parallel = threads(client)
            from tools.experiment.study.runner import _mb, _rss_bytes

            log(
                f"estimate: {len(flights):,} flights, about {first * len(flights) / parallel:,.0f} s on {where} "
                f"({first:.2f} s for the first flight); memory about "
                f"{_mb(_rss_bytes() + RECORD_BYTES * len(flights))} here; Ctrl-C stops and keeps what is done"
            )
            for f, r in stream(flights[1:], opts.scheduler, opts.workers, fly_study_flight, stop=stop, client=client):
                done.append((f, r))
                bar.add(1)
    except Exception as exc:
        if not done:
            raise
        error = one_line(exc)
    bar.close()
    wall = time.perf_counter() - t0
    table = summarise([f for f, _ in done], [r for _, r in done])
    section = {
        "study": "robustness",
        "plant": opts.plant,
        "kind": plants.spec(opts.plant).kind.name,
        "one_by_one": True,  # flown flight by flight (this module), not in the batched study: its tables are these
        "flights": "the reference scenario flown in-process (tools.experiment.scenario.run_inprocess)",
        "seed": opts.seed,
        "seeds": opts.seeds,
        "seed_of_flight": f"seed * {SEED_STRIDE} + i",
        "airspeeds_kt": None if opts.airspeeds_kt is None else list(opts.airspeeds_kt),
        "turbulence": list(opts.turbulence),
        "scheduler": opts.scheduler or "local",
        "where": where,
        "bounds": {
            "max_abs_roll_deg": BOUND_ROLL_RAD / DEG,
            "sat_fraction": BOUND_SAT_FRACTION,
            "tracking": "no 20 s window oscillating or not following (autopilot.envelope)",
        },
        "units": {"ise_ref": "rad^2 s", "ise_crm": "rad^2 s", "energy": "rad^2 s", "tv": "rad"},
        "controllers": {c: {"label": _label(c)} for c in opts.controllers},
        "results": table,
        "partial": len(done) < len(flights),
    }
    section["units"].update(max_abs_u="rad", max_abs_roll="rad", sat_fraction="1")
    if section["partial"]:
        section["done"] = {"runs": len(done), "of": len(flights)}
    if error:
        section["error"] = error
    section["timing"] = {"wall_s": wall, "runs": len(done), "runs_per_s": len(done) / wall if wall > 0 else None}
    return section


def check(opts: FlightOptions) -> None:
    """Refuse, in one line, what this plant cannot fly: a controller, a turbulence level, an airspeed."""
    from sitl import plant as plants

    for c in opts.controllers:
        from autopilot.law import LawSpecError

        try:  # a registered controller, or a user's law (FILE.py:Class, module:Class: autopilot.law)
            controllers.get(c)
        except LawSpecError as exc:
            raise StudyError(f"--controllers: {exc}") from None
        except ValueError:
            raise StudyError(
                f"--controllers {c!r} does not fly on --plant {opts.plant} (a JSBSim aircraft or plant file flies "
                f"{', '.join(controllers.NAMES)}, or a law of your own, FILE.py:Class)"
            ) from None
        law = controllers.get(c).kind
        if law.generic and law.design and not plants.spec(opts.plant).paper and not plants.spec(opts.plant).mimo:
            from tools.design.linearise import designed_law_params

            if designed_law_params(opts.plant, law.design) is None:
                raise StudyError(f"--controllers {c}: {opts.plant} has no design of it (python -m tools.design.laws)")
    for t in opts.turbulence:
        if t not in TURBULENCE:
            raise StudyError(f"unknown turbulence {t!r} (known: {', '.join(TURBULENCE)})")
        if t != "none":
            try:
                plants.check_disturbances(opts.plant, {"turbulence": t})
            except plants.PlantError as exc:
                raise StudyError(str(exc)) from None
    if not 1 <= opts.seeds <= MAX_SEEDS:
        raise StudyError(f"--seeds must be in [1, {MAX_SEEDS}], got {opts.seeds}")
    if opts.airspeeds_kt is not None and not opts.jsbsim:
        raise StudyError(f"--airspeeds applies to a JSBSim aircraft (jsbsim:MODEL), not to --plant {opts.plant}")
    if opts.jsbsim:
        from sitl.jsbsim_plant import parse_spec

        if opts.airspeeds_kt is not None and "airspeed_kt=" in opts.plant:
            raise StudyError(f"--airspeeds and --plant {opts.plant} both give the airspeed: give one")
        for text, _v, _t in opts.conditions()[:: len(opts.turbulence)]:
            try:
                parse_spec(text)
                plants.build(text, 1000.0)  # it trims (a few tens of ms)
            except (ValueError, plants.PlantError) as exc:
                raise StudyError(str(exc).strip().splitlines()[0]) from None
