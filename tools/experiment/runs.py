"""Run a reference scenario for every controller variant and write its metrics and figure.

    python -m tools.experiment paper --out DIR [--transport inprocess|mavlink] [--runs sac,clsac,...] [--no-plot]
                                           [--no-rrd] [--pfc paper|robust] [--sigma-xu SIGMA]

writes ``DIR/summary.json`` (schema: docs/spec.md, "summary.json") and ``DIR/paper.png``, and prints a table of
the metrics of docs/spec.md, "Metrics".  From Python::

    from tools.experiment.runs import run_experiment, write_summary
    results = run_experiment("runs/x", transport="inprocess", runs=["sac", "clsac"], plot=False)

A transport is a function ``(scenario, run, workdir) -> RunResult``; ``workdir`` is ``OUT/<run.name>``, a
folder of that run's own (not created beforehand) for a transport that writes files (logs, tlog).
:data:`TRANSPORTS` maps each name to a loader returning that function, so a loader may import lazily and
fail with a clear reason.
Adding a transport is one line in :data:`TRANSPORTS`.
"""

from __future__ import annotations

import datetime as _dt
import math
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterable, Sequence

from autopilot.metrics import METRIC_NAMES
from autopilot.shared.process import write_json_atomic
from sitl import plant as plants
from tools.experiment import outdir
from tools.experiment.outdir import hold_space, prepare_out_dir, write_problem

if TYPE_CHECKING:
    from tools.experiment.scenario import RunResult, RunSpec, Scenario

# tools.experiment.scenario (and through it scipy) is imported only once a scenario is needed, so that --help and
# most bad command lines answer at once instead of after ~1.5 s of imports.

DEG = 180.0 / math.pi

Runner = Callable[["Scenario", "RunSpec", Path], "RunResult"]


class OutputError(RuntimeError):
    """An output file that could not be written (a full disk): one line naming each; summary.json is written if
    it fitted."""


class ExperimentError(ValueError):
    """Bad input or an unavailable transport; the message is one line and names the value."""


# ---------------------------------------------------------------------------------------- registry
def _paper() -> tuple[Scenario, tuple[RunSpec, ...]]:
    from tools.experiment.scenario import PAPER, PAPER_RUNS

    return PAPER, PAPER_RUNS


# scenario name -> loader of (scenario, its runs)
SCENARIOS: dict[str, Callable[[], tuple[Scenario, tuple[RunSpec, ...]]]] = {
    "paper": _paper,
}


def _inprocess(scenario: Scenario, run: RunSpec, workdir: Path) -> RunResult:  # noqa: ARG001  (transport signature)
    from tools.experiment.scenario import run_inprocess

    return run_inprocess(scenario, run)


def _load_inprocess() -> Runner:
    return _inprocess


def _load_mavlink() -> Runner:
    """SITL + autopilot processes in lockstep, one ``tools.flight.Flight`` per run."""
    try:
        from tools.flight import fly_run_over_mavlink  # noqa: PLC0415  (lazy: pulls in pymavlink and processes)
    except ImportError as exc:
        raise ExperimentError(f"transport 'mavlink' is not available: importing tools.flight failed: {exc}") from None
    return fly_run_over_mavlink


TRANSPORTS: dict[str, Callable[[], Runner]] = {
    "inprocess": _load_inprocess,
    "mavlink": _load_mavlink,
}


def get_transport(name: str) -> Runner:
    """The runner of transport ``name``; ExperimentError if unknown or unavailable."""
    try:
        loader = TRANSPORTS[name]
    except KeyError:
        raise ExperimentError(f"unknown transport {name!r} (known: {', '.join(TRANSPORTS)})") from None
    return loader()


def get_scenario(name: str) -> tuple[Scenario, tuple[RunSpec, ...]]:
    """(scenario, its runs) of scenario ``name``; ExperimentError if unknown."""
    try:
        loader = SCENARIOS[name]
    except KeyError:
        raise ExperimentError(f"unknown scenario {name!r} (known: {', '.join(SCENARIOS)})") from None
    return loader()


def select_runs(runs: Iterable[str | RunSpec] | None, available: Sequence[RunSpec] | None = None) -> list[RunSpec]:
    """Resolve run names (or RunSpecs) against ``available`` (default: the paper's runs); None means all,
    duplicates are dropped."""
    from tools.experiment.scenario import OPTIONAL_RUNS, PAPER_RUNS, RunSpec

    if available is None:
        available = PAPER_RUNS
    if runs is None:
        return list(available)
    by_name = {r.name: r for r in (*available, *OPTIONAL_RUNS)}
    out: list[RunSpec] = []
    for item in runs:
        spec = item if isinstance(item, RunSpec) else by_name.get(str(item).strip())
        if spec is None:
            raise ExperimentError(f"unknown run {str(item).strip()!r} (known: {', '.join(by_name)})")
        if spec not in out:
            out.append(spec)
    if not out:
        raise ExperimentError("no runs selected")
    return out


# ---------------------------------------------------------------------------------------- analysis
def _surface(scenario: Scenario) -> str:
    """The surface the scenario's plant's command drives, as the tables and verdicts name it (``sitl.plant``)."""
    from sitl.plant import surface_of

    return surface_of(scenario.plant)


def saturation(result: RunResult, u_limit_rad: float) -> dict:
    """Whether the rudder command reached its limit, and for which fraction of the control samples."""
    u = result.series.get("u") if result.series else None
    if u is not None and len(u):
        import numpy as np

        frac = float(np.mean(np.abs(np.asarray(u, dtype=float)) >= u_limit_rad * (1.0 - 1e-9)))
        return {"saturated": frac > 0.0, "fraction": frac}
    sat = result.metrics.get("max_abs_u", 0.0) >= u_limit_rad * (1.0 - 1e-9)
    return {"saturated": bool(sat), "fraction": None}


def controlled(result: RunResult, u_limit_rad: float, surface: str = "rudder") -> dict | None:
    """Whether the run stayed inside the default envelope (``autopilot.envelope``, the launcher's "controlled"), from
    its series: roll, the law's limited command (``u_cmd`` over MAVLink, where ``u`` is after the PWM map) and the
    commanded response ``ym_ol`` (tracking: no sustained oscillation, the roll following the command).  None
    without series."""
    s = result.series or {}
    if s.get("t") is None or not len(s["t"]):
        return None
    from autopilot.envelope import Envelope, verdict

    u = s["u_cmd"] if s.get("u_cmd") is not None else s["u"]
    return verdict(s["t"], s["phi"], u, u_limit_rad, Envelope(surface=surface), ref=s.get("ym_ol"))


def paper_checks(results: Sequence[RunResult]) -> dict[str, dict]:
    """The paper's section 5 claims, checked against these metrics (only those the runs allow)."""
    by = {r.name: r for r in results}
    checks: dict[str, dict] = {}
    if "sac" in by and "clsac" in by:
        s, c = by["sac"].metrics, by["clsac"].metrics
        checks["clsac_tracks_better_than_sac"] = {
            "holds": c["ise_ref"] < s["ise_ref"],
            "detail": f"ise_ref clsac {c['ise_ref']:.3g} vs sac {s['ise_ref']:.3g}",
        }
        checks["clsac_no_more_effort_than_sac"] = {
            "holds": c["energy"] <= s["energy"],
            "detail": f"energy clsac {c['energy']:.3g} vs sac {s['energy']:.3g}",
        }
    sweep = sorted((r for r in results if r.lv > 0), key=lambda r: r.lv)
    if len(sweep) >= 2:
        lvs = ", ".join(f"{r.lv:g}" for r in sweep)
        en = [r.metrics["energy"] for r in sweep]
        ise = [r.metrics["ise_ref"] for r in sweep]
        checks["effort_falls_as_lv_grows"] = {
            "holds": all(b < a for a, b in zip(en, en[1:])),
            "detail": f"energy at Lv {lvs}: " + ", ".join(f"{v:.3g}" for v in en),
        }
        checks["ref_tracking_worsens_as_lv_grows"] = {
            "holds": all(b > a for a, b in zip(ise, ise[1:])),
            "detail": f"ise_ref at Lv {lvs}: " + ", ".join(f"{v:.3g}" for v in ise),
        }
    return checks


_CHECK_LABELS = {
    "clsac_tracks_better_than_sac": "CL-SAC tracks better than SAC",
    "clsac_no_more_effort_than_sac": "CL-SAC needs no more effort than SAC",
    "effort_falls_as_lv_grows": "effort falls as Lv grows",
    "ref_tracking_worsens_as_lv_grows": "open-loop model tracking worsens as Lv grows",
}


def _check_lines(checks: dict[str, dict]) -> list[str]:
    return [
        f"{_CHECK_LABELS.get(name, name)}: {'yes' if c['holds'] else 'NO'} ({c['detail']})"
        for name, c in checks.items()
    ]


# ---------------------------------------------------------------------------------------- output
def _finite_or_none(x: float):
    x = float(x)
    return x if math.isfinite(x) else None


def _versions() -> dict[str, str]:
    import platform
    from importlib import metadata

    import numpy

    out = {"python": platform.python_version(), "numpy": numpy.__version__}
    try:
        out["clsac-autopilot"] = metadata.version("clsac-autopilot")
    except metadata.PackageNotFoundError:
        pass
    return out


def write_summary(
    results: Sequence[RunResult],
    path: str | os.PathLike,
    *,
    scenario: Scenario | None = None,
    transport: str | None = None,
    extra: dict | None = None,
    reserve=None,
) -> Path:
    """Write ``summary.json`` (:func:`summary_doc`); on a full disk the space ``reserve`` holds
    (``tools.experiment.outdir.hold_space``) is released and the write tried again.  The file is replaced
    atomically."""
    path = Path(path)
    doc = summary_doc(results, scenario=scenario, transport=transport, extra=extra)
    write_json_atomic(path, doc, indent=2, reserve=reserve)
    return path


def summary_doc(
    results: Sequence[RunResult],
    *,
    scenario: Scenario | None = None,
    transport: str | None = None,
    extra: dict | None = None,
) -> dict:
    """``summary.json``'s document: ``{"scenario": ..., "runs": [{"name", "Lv", "metrics": {...}}, ...]}``.

    Extra top-level keys (never inside ``runs``): ``units``, ``settings``, ``transport``, ``saturation``,
    ``paper_checks``, ``versions``, ``created`` and whatever ``extra`` holds.  Non-finite metrics are
    written as null (strict JSON).
    """
    if scenario is None:
        from tools.experiment.scenario import PAPER as scenario
    doc: dict = {
        "scenario": scenario.name,
        "runs": [
            {
                "name": r.name,
                "Lv": float(r.lv),
                "metrics": {k: _finite_or_none(r.metrics[k]) for k in METRIC_NAMES},
                # inside the envelope (autopilot.envelope), its reason naming the plant's surface
                "controlled": controlled(r, scenario.u_limit_rad, _surface(scenario)),
            }
            for r in results
        ],
        "units": {"ise_ref": "rad^2 s", "ise_crm": "rad^2 s", "energy": "rad^2 s", "tv": "rad", "max_abs_u": "rad"},
        "settings": {
            "amplitude_rad": scenario.amplitude_rad,
            "period_s": scenario.period_s,
            "duration_s": scenario.duration_s,
            "control_rate_hz": scenario.control_rate_hz,
            "physics_rate_hz": scenario.physics_rate_hz,
            "u_limit_rad": scenario.u_limit_rad,
        },
        "saturation": {r.name: saturation(r, scenario.u_limit_rad) for r in results},
        "paper_checks": paper_checks(results),
        "versions": _versions(),
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }
    if transport is not None:
        doc["transport"] = transport
    if extra:
        for key in extra:
            if key in ("scenario", "runs"):
                raise ValueError(f"extra must not override {key!r}")
        doc.update(extra)
    return doc


def format_table(results: Sequence[RunResult], scenario: Scenario | None = None) -> str:
    """The metrics table, a saturation line and the paper's claims, as printed by the CLI."""
    if scenario is None:
        from tools.experiment.scenario import PAPER as scenario
    head = f"{'run':<12} {'Lv':>6} {'ise_ref':>11} {'ise_crm':>11} {'energy':>11} {'tv':>10} {'max|u|':>8}"
    unit = f"{'':<12} {'':>6} {'[rad^2 s]':>11} {'[rad^2 s]':>11} {'[rad^2 s]':>11} {'[rad]':>10} {'[deg]':>8}"
    lines = [head, unit, "-" * len(head)]
    for r in results:
        m = r.metrics
        lines.append(
            f"{r.name:<12} {r.lv:>6g} {m['ise_ref']:>11.4g} {m['ise_crm']:>11.4g} {m['energy']:>11.4g} "
            f"{m['tv']:>10.4g} {m['max_abs_u'] * DEG:>8.2f}"
        )
    parts = []
    for r in results:
        s = saturation(r, scenario.u_limit_rad)
        if not s["saturated"]:
            parts.append(f"{r.name} no")
        elif s["fraction"] is None:
            parts.append(f"{r.name} yes")
        else:
            parts.append(f"{r.name} yes ({100 * s['fraction']:.1f}% of samples)")
    surface = _surface(scenario)
    lines.append(f"{surface} saturated (|u| at the {scenario.u_limit_rad * DEG:g} deg limit): " + "; ".join(parts))
    verdicts = [(r.name, controlled(r, scenario.u_limit_rad, surface)) for r in results]
    lines.append(
        f"controlled (|roll| < 60 deg, {surface} saturated < 20 % of the flight, tracking in every 20 s window): "
        + "; ".join(f"{n} {'yes' if c['ok'] else 'NO: ' + c['reason']}" for n, c in verdicts if c is not None)
    )
    checks = _check_lines(paper_checks(results))
    if checks:
        lines.append("paper's claims (section 5) against these numbers:")
        lines += [f"  {c}" for c in checks]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------- run
def with_plant(scenario: Scenario, plant: str) -> Scenario:
    """The scenario on another plant (checked: ExperimentError), its command limit clipped to the plant's surface."""
    from dataclasses import replace

    from sitl import plant as plants

    try:
        plants.check(plant)
    except plants.PlantError as exc:
        raise ExperimentError(f"--plant: {exc}") from None
    limit = min(scenario.u_limit_rad, plants.surface_limit_rad(plant) or math.inf)
    return replace(scenario, plant=plant, u_limit_rad=limit)


def require_design(scenario: Scenario, pfc: str | None = None) -> None:
    """ExperimentError when the scenario's plant (other than the KH2013A) has no design (``tools.pfc design``) and
    neither a parameter file nor a PFC was given: its runs would fly another plant's values (as the launcher)."""
    from sitl import plant as plants
    from tools.design.linearise import design_advice, design_path, designed_params, shown_path

    if plants.spec(scenario.plant).paper or scenario.params is not None or pfc is not None:
        return
    if designed_params(scenario.plant) is None:
        raise ExperimentError(
            f"--plant: {scenario.plant} has no design (no {shown_path(design_path(scenario.plant))}): "
            f"{design_advice(scenario.plant)}, or give --pfc paper|robust to fly the KH2013A's"
        )


def with_disturbances(scenario: Scenario, values: dict, transport: str) -> Scenario:
    """The scenario with the SITL's disturbances (checked: ExperimentError); they need the mavlink transport."""
    from dataclasses import replace

    from sitl import disturbances
    from sitl import plant as plants

    given = {k: v for k, v in values.items() if v is not None}
    if not given:
        return scenario
    try:
        dist = disturbances.from_values(given)
        plants.check_disturbances(scenario.plant, given)
    except (*disturbances.ERRORS, disturbances.DisturbanceValueError, plants.PlantError) as exc:
        raise ExperimentError(str(exc)) from None
    rest = plants.injected(scenario.plant, dist)  # what only the SITL's injector can apply
    if transport != "mavlink" and (rest.atmosphere.active or rest.sensors.active or rest.faults.active):
        raise ExperimentError(
            f"--{next(iter(given)).replace('_', '-')} needs --transport mavlink on --plant {scenario.plant} "
            "(the SITL flies it; in-process only a JSBSim plant's own turbulence)"
        )
    return replace(scenario, disturbances=tuple(sorted(given.items())))


def run_experiment(
    out_dir: str | os.PathLike,
    transport: str = "inprocess",
    runs: Iterable[str | RunSpec] | None = None,
    plot: bool = True,
    *,
    scenario: str | Scenario = "paper",
    log: Callable[[str], None] | None = None,
    pfc: str | None = None,
    sigma_xu: float | None = None,
    rrd: bool = True,
    plant: str | None = None,
    disturbances: dict | None = None,
) -> list[RunResult]:
    """Fly the scenario's runs with ``transport``; write ``out_dir/summary.json`` and (``plot``) ``paper.png``.

    ``runs``: names (or RunSpecs) of the scenario's runs, None for all.  ``log``: called with progress
    lines (the CLI passes ``print``).  Raises ExperimentError on bad input (OutDirError for a folder that cannot
    be written), before flying anything.
    ``pfc`` (a PFC preset name) and ``sigma_xu`` (K_Ix/K_Iu leakage) apply to every run; None keeps the paper's.
    ``disturbances``: the SITL's (``{dest: value}`` of ``sitl.disturbances.FLAGS``), mavlink transport only.
    ``plant``: the SITL's plant (``sitl.plant``: kh2013a, FILE.toml, jsbsim:MODEL[:...]); None keeps the scenario's.
    On another plant the runs fly the PFC designed for it (``tools.design.linearise.designed_params``) unless ``pfc``
    is given.
    Returns the RunResults (metrics and series) in run order.
    """
    from dataclasses import replace

    from autopilot.config import PFC_PRESETS
    from tools.experiment.scenario import PAPER_RUNS, Scenario

    say = log or (lambda _msg: None)
    if transport not in TRANSPORTS:
        raise ExperimentError(f"unknown transport {transport!r} (known: {', '.join(TRANSPORTS)})")
    if isinstance(scenario, Scenario):
        scen, available = scenario, PAPER_RUNS
    else:
        scen, available = get_scenario(scenario)
    specs = select_runs(runs, available)
    if pfc is not None and pfc not in PFC_PRESETS:
        raise ExperimentError(f"unknown PFC {pfc!r} (known: {', '.join(PFC_PRESETS)})")
    if sigma_xu is not None and not (sigma_xu >= 0 and sigma_xu < float("inf")):
        raise ExperimentError(f"--sigma-xu must be finite and >= 0, got {sigma_xu!r}")
    specs = [
        replace(s, pfc=pfc if pfc is not None else s.pfc, sigma_xu=sigma_xu if sigma_xu is not None else s.sigma_xu)
        for s in specs
    ]
    if plant is not None:
        scen = with_plant(scen, plant)
    require_design(scen, pfc)
    if disturbances:
        scen = with_disturbances(scen, disturbances, transport)
    runner = get_transport(transport)
    out = prepare_out_dir(out_dir)
    reserve = hold_space(out, 256 * 1024)  # summary.json fits a disk that fills while the runs fly (~10 kB)
    results: list[RunResult] = []
    for i, spec in enumerate(specs, start=1):
        t0 = time.perf_counter()
        say(f"[{i}/{len(specs)}] {spec.name} (Lv={spec.lv:g}) via {transport} ...")
        try:
            res = runner(scen, spec, out / spec.name)
        except BaseException:
            reserve.release()
            raise
        results.append(res)
        sat = saturation(res, scen.u_limit_rad)
        say(
            f"[{i}/{len(specs)}] {spec.name} done in {time.perf_counter() - t0:.2f} s: "
            f"ise_ref={res.metrics['ise_ref']:.4g}"
            f" energy={res.metrics['energy']:.4g}" + (f" ({_surface(scen)} saturated)" if sat["saturated"] else "")
        )
    controller = {"pfc": pfc or "paper", "pfc_num_den": PFC_PRESETS[pfc or "paper"], "sigma_xu": sigma_xu or 0.0}
    if not plants.spec(scen.plant).paper:
        from tools.design.linearise import designed_params

        designed = None if pfc is not None else designed_params(scen.plant)
        controller.update(plant=scen.plant, params=None if designed is None else str(designed))
    problems: list[str] = []
    extra = {"controller": controller, "disturbances": dict(scen.disturbances)}
    try:
        doc = summary_doc(results, scenario=scen, transport=transport, extra=extra)
        summary = outdir.write_summary(out, doc, problems, reserve)
    finally:
        reserve.release()
    if summary is not None:
        say(f"wrote {summary.resolve()}")
    if rrd:
        t0 = time.perf_counter()
        from tools.view.recording import log_experiment  # lazy: rerun costs ~1 s to import

        target = out / f"{scen.name}.rrd"
        try:
            path = log_experiment(results, target)
            say(
                f"wrote {Path(path).resolve()} ({time.perf_counter() - t0:.1f} s; "
                f"open it with: rerun {Path(path).resolve()})"
            )
        except (OSError, RuntimeError) as exc:  # a full disk (rerun's writer says RuntimeError): no half file left
            for p in (target, target.with_name(target.name + ".sha256")):
                p.unlink(missing_ok=True)
            problems.append(write_problem(target, exc))
    if plot:
        t0 = time.perf_counter()
        from tools.view.plots import save_paper_figure  # lazy: matplotlib costs ~1 s to import

        target = out / f"{scen.name}.png"

        def draw():
            return save_paper_figure(results, target, scen, notes=_check_lines(paper_checks(results)))

        png = outdir.write_figure(target, draw, problems, say)
        if png is not None:
            say(f"wrote {png.resolve()} ({time.perf_counter() - t0:.1f} s)")
    if problems:
        raise OutputError("; ".join(problems))
    return results
