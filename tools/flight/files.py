"""What a flight leaves in its folder: the recording joined (``flight.rrd``), ``flight.png``, ``summary.json``
(provisional while it flies, a refusal's, the verdict's) and the per-step series read back (``load_series``)."""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path

from autopilot import controllers
from autopilot.shared.process import (
    EXIT_FAILED,
    EXIT_OK,
    EXIT_OUT_OF_ENVELOPE,
    EXIT_USAGE,
    write_json_atomic,
)
from tools.flight.config import PROCESSES, FlightConfig
from tools.flight.outcome import outcome_of
from tools.view.flight_picture import PNG_MAX_POINTS, draw_flight_png  # noqa: F401  (PNG_MAX_POINTS: re-exported)
from tools.view.series_files import load_series  # noqa: F401  (re-exported: tools.flight.load_series)


def png_request(cfg: FlightConfig, out: Path, name: str, metrics: dict) -> dict:
    """The keywords of ``tools.view.flight_picture.draw_flight_png`` for a flight's picture (plain values: the helper
    process gets them as JSON)."""
    from sitl import plant as plants

    return {
        "out": str(out),
        "name": name,
        "lv": controllers.flown_lv(cfg.controller, cfg.lv_value),
        "controller": cfg.controller,
        # a law on autopilot.law's interface: its words (the picture's helper loads no law's code)
        "law_label": controllers.get(cfg.controller).label if controllers.get(cfg.controller).kind.generic else None,
        "lockstep": cfg.lockstep,
        "rate": cfg.rate,
        "u_limit_deg": cfg.u_limit_deg,
        "metrics": metrics,
        "plant": cfg.plant_name,
        "surface": cfg.surface,
        "surface2": plants.spec(cfg.plant).surfaces[1] if cfg.mimo else None,
    }


def write_flight_png(cfg: FlightConfig, out: Path, name: str, metrics: dict) -> Path | None:
    """DIR/flight.png from the flight's series, drawn in this process (``draw_flight_png``); None without series."""
    return draw_flight_png(**png_request(cfg, out, name, metrics))


class RecorderImport:
    """What recording the flight's spools needs, prepared in a thread while the flight starts and flies
    (``start_recorder_import``): rerun imported, and the viewer layout built for the flight's span as asked."""

    def __init__(self, span=None, rudder_limit_deg: float | None = None):
        self.key = (tuple(span), rudder_limit_deg) if span is not None else None
        self._layout = None
        self.thread = threading.Thread(target=self._run, name="import-recorder", daemon=True)

    def _run(self) -> None:
        try:
            import autopilot.shared.telemetry.rerun_sink  # noqa: F401  (rerun, pyarrow and the sink)

            if self.key is not None:
                from tools.view.views import flight_blueprint

                self._layout = flight_blueprint(self.key[0], rudder_limit_deg=self.key[1])
        except Exception:  # noqa: BLE001  (the join imports and builds again, and says what failed)
            pass

    def layout(self, span, rudder_limit_deg: float | None):
        """The layout built for ``span`` and ``rudder_limit_deg``, or None (another span: a flight that ended early;
        or the thread failed): the caller builds it."""
        self.thread.join()
        return self._layout if (tuple(span), rudder_limit_deg) == self.key else None


def start_recorder_import(
    parts: dict[str, Path], span=None, rudder_limit_deg: float | None = None
) -> RecorderImport | None:
    """For a flight whose processes spool their rows (the launcher records them after the flight): import what the
    recording needs (rerun, about 0.27 CPU s) in a thread, now, while the children start, instead of after the
    flight, where it was the longest part of what the user waited for; and build its layout (``span``,
    ``rudder_limit_deg``: ``tools.view.views.flight_blueprint``'s, for a flight flown to its end), which the
    recording then carries (``_join_telemetry``).  The children's start-up keeps both cores busy, so it delays the
    flight a little; measured (10 alternating lockstep launches against the code before): 0.88 -> 0.77 s, 1.7 %
    more CPU.  The caller starts it for lockstep flights only (a real-time loop is not to share a core with it).
    The thread's failure is ignored: the join imports again and reports it.  None for a flight without spools:
    nothing to import."""
    if not any(p.suffix == ".spool" for p in parts.values()):
        return None
    prepared = RecorderImport(span, rudder_limit_deg)
    prepared.thread.start()
    return prepared


def _join_telemetry(
    parts: dict[str, Path],
    out: Path,
    recording_id: str | None,
    merge_max_mb: float,
    span=None,
    rudder_limit_deg: float | None = None,
    prepared: RecorderImport | None = None,
) -> tuple[Path | None, bool, str | None]:
    """Join the processes' part files into DIR/flight.rrd (whatever ended the flight); (path, indexed, error).
    ``span``: the flight's (start, end) sim s, the plots' visible time range; ``rudder_limit_deg``: the surface's
    limit, the Rudder plot's fixed range (``tools.view.views.flight_blueprint``); ``prepared``: the
    ``start_recorder_import`` of this flight, whose layout is used when it was built for the same span.

    Spools only (the default), ``merge_max_mb`` or less of them in all: they are recorded straight into the flight's
    one file, the layout first and rerun's index (footer) last, in bounded memory; no ``rerun rrd merge`` (it took
    about 0.09 s of the 1.5 s lockstep launch, a second pass over the same rows).

    ``rerun rrd merge`` compacts the chunks and writes the footer (index) the viewer uses for random access, but
    holds the whole recording in memory (about twice the files' size).  So parts larger than ``merge_max_mb`` in
    all (a flight of more than about 15 minutes at 100 Hz by default) are concatenated instead: their messages
    are copied into the same one file without decoding, a buffer at a time (constant memory whatever the
    flight's length; no footer, so ``indexed`` is False).  Either way the flight has one recording, with the
    viewer layout."""
    existing = [p for p in parts.values() if p.exists() and p.stat().st_size > 0]
    if not existing:
        return None, False, ("no telemetry was written" if parts else None)
    from autopilot.shared import telemetry as tm

    target = out / "flight.rrd"
    spools = [p for p in existing if p.suffix == ".spool"]
    if spools:
        # The processes spooled their rows (the default): one recording from them, both processes side by side in
        # sim time, written here by the same code a live writer sends with (autopilot.shared.telemetry.rerun_sink),
        # then joined like a live part.
        part = out / ".parts" / "flight.rrd"
        direct = len(spools) == len(existing) and sum(p.stat().st_size for p in spools) <= merge_max_mb * 1e6
        try:
            layout = None
            if direct:
                tm.check_recording_target(target)
                layout = prepared.layout(span, rudder_limit_deg) if prepared is not None else None
                if layout is None:
                    from tools.view.views import flight_blueprint

                    layout = flight_blueprint(span, rudder_limit_deg=rudder_limit_deg)
            tm.record_spools(spools, part, write_footer=direct, blueprint=layout)
            if direct:
                tm.install_recording(part, target)
        except Exception as exc:  # noqa: BLE001  (a flight's other files stay valid; say what went wrong)
            part.unlink(missing_ok=True)
            what = target if direct else part
            why = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc  # the file is named before
            later = f"python -m tools.rrd record {target} {' '.join(str(p) for p in spools)}"
            return (
                None,
                False,
                f"recording the telemetry spools into {what} failed: {why} (the spools are kept: {later})",
            )
        for p in spools:
            p.unlink(missing_ok=True)
        if direct:
            try:
                (out / ".parts").rmdir()
            except OSError:
                pass
            return target, True, None
        existing = [p for p in existing if p.suffix != ".spool"] + [part]
    indexed = sum(p.stat().st_size for p in existing) <= merge_max_mb * 1e6
    try:
        if indexed:
            # The layout saved once for this code (tools.view.layout_cache): no rerun import in the launcher.
            from tools.view.layout_cache import flight_blueprint_file

            layout = flight_blueprint_file(span=span, rudder_limit_deg=rudder_limit_deg)
            if layout is not None:
                tm.merge_recordings(existing, target, blueprint_file=layout, remove_parts=True)
            else:
                from tools.view.views import flight_blueprint

                blueprint = flight_blueprint(span, rudder_limit_deg=rudder_limit_deg)
                tm.merge_recordings(existing, target, blueprint=blueprint, remove_parts=True)
        else:
            from tools.view.views import flight_blueprint

            blueprint = flight_blueprint(span, rudder_limit_deg=rudder_limit_deg)
            tm.concatenate_recordings(
                existing, target, blueprint=blueprint, recording_id=recording_id, remove_parts=True
            )
    except Exception as exc:  # noqa: BLE001  (a flight's other files stay valid; say what went wrong)
        return None, False, f"joining telemetry into {target} failed: {exc}"
    try:
        (out / ".parts").rmdir()
    except OSError:
        pass
    return target, indexed, None


# ---------------------------------------------------------------------------------------- summary
def _load(path: Path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def _flown_lv(cfg: FlightConfig, stats: dict, at: str = "start"):
    """The closed-loop reference gain the autopilot flew at the ``start`` or the ``end`` of the flight (its stats:
    CLSAC_LV as it started, the law's at the end), else the configured one (nothing flew); SAC flies 0."""
    ap = stats.get("autopilot") or {}
    lv = (ap.get("params_start") or {}).get("CLSAC_LV") if at == "start" else ap.get("Lv")
    if lv is None:
        lv = ap.get("Lv")
    return controllers.flown_lv(cfg.controller, cfg.lv_value if lv is None else lv)


def parameters(stats: dict) -> dict:
    """summary.json's ``parameters``: every value as the flight started (``start``), as it ended (``end``: the start
    with the changes), and each change a ground station made (``changes``: sim time, name, from, to)."""
    ap = stats.get("autopilot") or {}
    start = dict(ap.get("params_start") or {})
    changes = list(ap.get("param_changes") or [])
    end = dict(start)
    for c in changes:
        end[c["name"]] = c["to"]
    return {"start": start, "end": end, "changes": changes}


def failure_injection_in_force(cfg: FlightConfig, stats: dict) -> bool:
    """Whether SYS_FAILURE_EN was 1 at any time of the flight: as it started (the flag or a --params file, the
    autopilot's ``params_start``) or set by a ground station in flight (its ``param_changes``); the flag alone when
    the autopilot left no stats."""
    p = parameters(stats)
    if not p["start"]:
        return bool(cfg.failure_injection)
    return p["start"].get("SYS_FAILURE_EN") == 1.0 or any(
        c["name"] == "SYS_FAILURE_EN" and c["to"] == 1.0 for c in p["changes"]
    )


def build_summary(
    cfg: FlightConfig,
    out: Path,
    stats: dict,
    exit_codes: dict,
    failed: str | None,
    error: str | None,
    exit_code: int,
    wall: float,
    rrd_path: Path | None,
    rrd_indexed: bool = False,
) -> dict:
    """summary.json of a flight from the processes' stats files (``stats``: process name -> dict or None)."""
    ap, sitl, gcs = stats["autopilot"], stats["sitl"], stats["gcs"]
    runs = []
    if ap and ap.get("metric_samples"):
        runs.append(
            {
                "name": ap["name"],
                "Lv": ap["Lv"] if ap["Lv"] is None else _flown_lv(cfg, stats),  # as it started (None: a PID)
                "metrics": ap["metrics"],
                "steps": ap["steps"],
                "controlled": ap.get("controlled"),
            }
        )
    return {
        "scenario": cfg.scenario,
        "runs": runs,
        "transport": "mavlink",
        "mode": "lockstep" if cfg.lockstep else "realtime",
        "signing": cfg.signing,  # MAVLink 2 signing on every link (docs/spec.md, "Trust model")
        # MAV_CMD_INJECT_FAILURE taken from a ground station at any time of the flight: the flag, a --params file or
        # a PARAM_SET of SYS_FAILURE_EN (what was in force, not only what the launcher was told)
        "failure_injection": failure_injection_in_force(cfg, stats),
        "controller": cfg.controller,
        # the law flown: its name, label, parameters, telemetry fields and their values at the end
        "law": {**controllers.describe(cfg.controller), "telemetry_end": (ap or {}).get("law_telemetry")},
        # the Lv that flew, as the flight started and as it ended (a ground station may change CLSAC_LV: the
        # changes are in "parameters"); a --params file (CLSAC_LV) may set another than the flags; SAC flies 0
        "Lv": _flown_lv(cfg, stats),
        "Lv_end": _flown_lv(cfg, stats, "end"),
        # a parameter file (given, or the one designed for the plant) sets the PFC the autopilot flies
        "pfc": (cfg.pfc or "paper") if cfg.params_file is None else f"from {cfg.params_file}",
        "plant": cfg.plant,  # the SITL's plant (sitl.plant): kh2013a, FILE.toml or jsbsim:MODEL[:...]
        "plant_name": cfg.plant_name,  # as the header, flight.png and the run folder name it
        "surface": cfg.surface,  # the surface the command drives: rudder (KH2013A), aileron (a JSBSim aircraft), ...
        "params": cfg.params_file,  # the autopilot's --params file, None if none
        "parameters": parameters(stats),  # every value at the start and the end, and each change in flight
        "sigma_xu": cfg.sigma_xu,
        "dead_zone_deg": cfg.dead_zone_deg,
        "ki_max": cfg.ki_max,
        "freeze_when_saturated": cfg.freeze_when_saturated,
        "duration_s": cfg.duration,
        "rate_hz": cfg.rate,
        "physics_rate_hz": cfg.physics_rate,
        "start_time_s": cfg.start_time,
        "profile": {
            "kind": "csv" if cfg.csv else cfg.profile,
            "amplitude_deg": cfg.amplitude,
            "period_s": cfg.period,
            "csv": cfg.csv,
        },
        "ok": exit_code == 0,
        "outcome": outcome_of(exit_code),
        "exit_code": exit_code,
        # flown to the end with every process clean / inside the envelope (docs/flying.md; autopilot.envelope)
        "completed": exit_code in (EXIT_OK, EXIT_OUT_OF_ENVELOPE) and not (sitl or {}).get("diverged"),
        # the SITL stopped the flight because its plant diverged: flight time, why, the plant (sitl.plant.divergence)
        "diverged": {k: v for k, v in sitl["diverged"].items() if k != "mono"}
        if (sitl or {}).get("diverged")
        else None,
        "controlled": ap.get("controlled") if ap else None,
        # a square MIMO plant's sideslip channel (autopilot.mimo.ChannelMetrics): max |sideslip| and its envelope,
        # saturation per surface, the metrics per channel; None with one surface
        "sideslip": ap.get("sideslip") if ap else None,
        # the time a ground station disarmed the vehicle or flew it in MANUAL (autopilot.envelope), and the words
        # the verdict line adds for it
        "ground_station": (ap.get("controlled") or {}).get("ground_station") if ap else None,
        "failed": failed,
        "error": error,
        "exit_codes": exit_codes,
        "wall_s": wall,
        "rtf": sitl.get("rtf") if sitl else None,
        "sim_time_s": sitl.get("sim_time_s") if sitl else None,
        "timing": ap.get("timing") if ap else None,
        "events": {"autopilot": ap.get("events") if ap else None, "sitl": sitl.get("events") if sitl else None},
        "disturbances": sitl.get("disturbances") if sitl else None,  # what the SITL injected (sitl.disturbances)
        # mid-flight faults (sitl.damage): the SITL's record (command line and ground station), else those asked
        "faults": sitl.get("faults", []) if sitl else _asked_faults(cfg),
        "counters": {
            "autopilot": ap.get("links") if ap else None,
            "sitl": sitl.get("link") if sitl else None,
            "gcs": gcs.get("link") if gcs else None,
        },
        "files": {
            "tlog": str(out / "flight.tlog"),
            "rrd": str(rrd_path) if rrd_path else None,  # DIR/flight.rrd, one recording with the viewer layout
            # merged with rerun's footer (index); False: concatenated without one (a long flight, bounded memory)
            "rrd_indexed": bool(rrd_path) and rrd_indexed,
            "summary": str(out / "summary.json"),
            "logs": {n: str(out / f"{n}.log") for n in PROCESSES},
            "stats": {n: str(out / f"{n}.json") for n in PROCESSES},
        },
    }


def flight_recovery(out: Path, faults: list | None) -> list[dict]:
    """``summary.json`` ``recovery``: per fault that started, the roll's recovery after its onset
    (``tools.flight.outcome.fault_recoveries``) from DIR/autopilot_series.npz (the steps flown, sim time >= 0: a
    real-time autopilot's stand-by steps before the first attitude are not flight); [] without faults."""
    if not faults:
        return []
    import zipfile

    import numpy as np

    from tools.flight.outcome import fault_recoveries

    t = roll = ref = um = None
    try:
        with np.load(out / "autopilot_series.npz") as s:
            t, roll, ref = (np.asarray(s[k], dtype=float) for k in ("t", "phi", "ym_ol"))
            um = np.asarray(s["um"], dtype=float) if "um" in s else None  # every block judged without it
        flying = t >= 0.0
        t, roll, ref = t[flying], roll[flying], ref[flying]
        um = None if um is None else um[flying]
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        t = roll = ref = um = None
    return fault_recoveries(faults, t, roll, ref, um)


# ---------------------------------------------------------------------------------------- the verdict
# A previous flight's files in a reused folder: removed before a new flight starts, so none can pass for its own.
STALE_FILES = (
    "autopilot.json",
    "sitl.json",
    "gcs.json",
    "autopilot_series.npz",
    "sitl_series.npz",
    "flight.rrd",
    "flight.rrd.sha256",
    "flight.png",
)


# What a process killed in mid-write leaves (a temporary file, a space reserve): removed at a flight's start and end.
LEFTOVERS = (
    *(f"{n}.json.tmp" for n in (*PROCESSES, "summary")),
    *(f".{n}.json.reserve" for n in (*PROCESSES, "summary")),
    "autopilot_series.npz.tmp",
    "sitl_series.npz.tmp",
)
SUMMARY_RESERVE_BYTES = 32 * 1024  # held from the start for the verdict (a summary is about 9 kB)
# What summary.json keeps when the whole one does not fit on the disk: the verdict and what was flown.
VERDICT_KEYS = ("ok", "outcome", "exit_code", "completed", "diverged", "controlled", "failed", "error", "exit_codes")
VERDICT_KEYS += ("flown", "duration_s", "mode", "controller", "plant", "files")


def remove_leftovers(out: Path) -> None:
    for name in LEFTOVERS:
        (out / name).unlink(missing_ok=True)


def write_summary(out: Path, summary: dict, reserve=None) -> dict:
    """Write ``out``/summary.json, the most complete that fits: the whole summary (the space ``reserve`` holds
    released if the disk is full), else only its verdict (``VERDICT_KEYS``, ``"cut": reason``), else nothing (the
    provisional one stays).  A summary that could not be written whole is not OK: exit status 1, its ``error``
    says so (``output_errors`` has the line).  Returns the summary as the launcher reports it."""
    path = out / "summary.json"
    try:
        write_json_atomic(path, summary, reserve=reserve)
        return summary
    except OSError as exc:
        problem = f"{path}: {exc.strerror or exc}"
    if summary.get("exit_code") in (EXIT_OK, EXIT_OUT_OF_ENVELOPE):
        error = f"launch: could not write {problem} (the flight itself: {summary.get('outcome')})"
    else:  # failed already: that reason first
        error = f"{summary.get('error')}; launch: could not write {problem}"
    summary = {
        **summary,
        "ok": False,
        "exit_code": EXIT_FAILED,
        "outcome": outcome_of(EXIT_FAILED),
        "failed": summary.get("failed") or "launch",
        "error": error,
        "output_errors": [*summary.get("output_errors", []), problem],
    }
    cut = {k: summary[k] for k in (*VERDICT_KEYS, "output_errors") if k in summary}
    cut["cut"] = f"only the verdict: the whole summary did not fit ({problem})"
    try:
        write_json_atomic(path, cut)
    except OSError:
        pass  # nothing fits: the provisional summary stays (not OK), and the console says why
    return summary


def write_unstarted(out: Path, exit_code: int, error: str, reserve=None) -> None:
    """summary.json of a flight that ended before any process started (a folder the disk cannot take, Ctrl-C): not
    OK, nothing flown; if even that does not fit, the provisional one stays.  The reserve and leftovers go."""
    path = out / "summary.json"
    summary = {
        "ok": False,
        "exit_code": exit_code,
        "outcome": outcome_of(exit_code),
        "failed": "launch" if exit_code == EXIT_FAILED else None,
        "error": error,
        "flown": {"steps": 0, "steps_asked": None, "fraction": 0.0, "frames": 0, "sim_time_s": 0.0, "complete": False},
        "files": {"summary": str(path)},
    }
    try:
        write_json_atomic(path, summary, reserve=reserve)
    except OSError:
        pass
    finally:
        if reserve is not None:
            reserve.release()
        remove_leftovers(out)
        try:
            (out / ".parts").rmdir()  # made for the telemetry, empty: nothing flew
        except OSError:
            pass


def provisional_summary(pid: int) -> dict:
    """DIR/summary.json while a flight runs: not OK until the launcher writes the verdict."""
    return {
        "ok": False,
        "running": True,
        "exit_code": None,
        "failed": None,
        "error": f"the flight has not ended: it is still running, or its launcher (pid {pid}) was killed",
        "launcher_pid": pid,
    }


def write_refusal(out: str | os.PathLike, process: str, reason: str) -> Path | None:
    """DIR/summary.json of a flight refused before anything was started (a value that cannot be flown):
    ``ok: false``, exit status 2, the process the value belongs to, the reason and nothing flown.  So a caller that
    reads summary.json finds the verdict whatever ended the launch.  None if DIR cannot be made or written (the
    one-line error on stderr still says why)."""
    path = Path(out) / "summary.json"
    summary = {
        "ok": False,
        "refused": True,  # nothing was started
        "exit_code": EXIT_USAGE,
        "failed": process,
        "error": f"{process}: {reason} (refused before the flight: nothing was started)",
        "flown": {"steps": 0, "steps_asked": None, "fraction": 0.0, "frames": 0, "sim_time_s": 0.0, "complete": False},
        "files": {"summary": str(path)},
    }
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(path, summary)
    except OSError:
        return None
    return path


def _asked_faults(cfg) -> list[dict]:
    """The faults asked for (the SITL wrote no record): each named with the surface it would hit."""
    from sitl import damage
    from sitl import plant as plants

    sched = damage.Schedule((), 0.0, 1e-3, plants.surfaces_of(cfg.plant))
    return [f.record(None, sched.surface_name(f)) for f in cfg.fault]
