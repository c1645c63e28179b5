"""Experiments in the viewer: every run of a scenario in one ``.rrd``, one entity subtree per run.

    /runs/command                 um (shared: every run gets the same command)                      deg
    /runs/reference_ol            ym_ol (shared: the open-loop model is driven by the command alone)  deg
    /runs/<name>/roll             phi                                                                 deg
    /runs/<name>/reference        ym (closed-loop reference: depends on the run through L_v)          deg
    /runs/<name>/error            e                                                                   deg
    /runs/<name>/rudder           u                                                                   deg
    /runs/<name>/gains/ke|kx|ku   total gains
    /runs/<name>/gains/parts      Kpe, KIe, Kpx, KIx, Kpu, KIu
    /runs/<name>/state            v [m/s], p [deg/s], r [deg/s], delta_r [deg]
    /runs/metrics                 table of the metrics (markdown, SI: rad^2 s, rad)

The series are SI (rad); angles are shown in degrees and rates in deg/s, as in a flight's recording.

Time is ``sim_time`` (the runs are simulations; there is no meaningful wall time).  The entity paths and
the layout are ``tools.view.views``; the column helpers ``autopilot.shared.telemetry.columns``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import rerun as rr

from autopilot.shared.telemetry.columns import scalar_column, series_style, sim_time_column
from autopilot.shared.telemetry.files import (
    RRD_FIXED_BYTES,
    RRD_PER_SPOOL_BYTE,
    check_room,
    has_footer,
    new_recording_id,
)
from autopilot.shared.telemetry.integrity import write_digest
from autopilot.shared.telemetry.layout import (
    BLUE,
    GREEN,
    GREY,
    ORANGE,
    PALETTE,
    PURPLE,
    SKY,
    VERMILLION,
    WHITE,
    YELLOW,
    Rgb,
)
from autopilot.shared.telemetry.layout import DEG_PER_RAD as DEG
from tools.view.views import RUN_COMMAND, RUN_METRICS, RUN_REFERENCE_OL, experiment_blueprint, run_path

EXPERIMENT_APPLICATION_ID = "clsac_experiment"  # paper.rrd: its own blueprint, never mixed with a flight's

RUN_COLORS: dict[str, Rgb] = {
    "sac": VERMILLION,
    "clsac": SKY,
    "clsac_lv10": GREEN,
    "clsac_lv50": ORANGE,
    "clsac_lv100": PURPLE,
}


def run_color(name: str, i: int) -> Rgb:
    """The colour of run ``name`` (the ``i``-th): the paper's runs keep theirs, others take the palette in turn."""
    return RUN_COLORS.get(name, PALETTE[i % len(PALETTE)])


def _shade(c: Rgb, f: float) -> Rgb:
    return tuple(int(min(255, max(0, round(v * f)))) for v in c)  # type: ignore[return-value]


def _metrics_markdown(results) -> str:
    keys: list[str] = []
    for r in results:
        for k in r.metrics:
            if k not in keys:
                keys.append(k)
    head = "| run | Lv | " + " | ".join(keys) + " |"
    sep = "|---|---:|" + "---:|" * len(keys)
    rows = [
        f"| {r.name} | {r.lv:g} | " + " | ".join(f"{r.metrics.get(k, float('nan')):.6g}" for k in keys) + " |"
        for r in results
    ]
    return "\n".join([head, sep, *rows])


def log_experiment(
    results: Sequence, path: str | os.PathLike, *, scenario: str = "paper", recording_id: str | None = None
) -> Path:
    """Write ``path`` (e.g. ``DIR/paper.rrd``) with every run of ``results`` side by side.

    ``results`` are ``tools.experiment.scenario.RunResult``-like objects: ``name``, ``lv``, ``metrics`` and
    ``series`` (numpy arrays ``t, um, phi, ym, ym_ol, e, u, ke, kx, ku, kpe, kie, ...``).  The blueprint
    overlays all runs; each run also gets its own tab; every plot shows the runs' span of sim time (the first to the
    last sample).  Its SHA-256 goes beside it (``path.sha256``, ``autopilot.shared.telemetry.integrity``).  Returns
    the path.  A disk without room for it raises OSError (ENOSPC) before a byte is written; a recording rerun could
    not end (the disk filled meanwhile) raises RuntimeError.
    """
    results = list(results)
    if not results:
        raise ValueError("log_experiment needs at least one run")
    names = [r.name for r in results]
    if len(set(names)) != len(names):
        raise ValueError(f"run names must be unique, got {names}")
    for n in names:
        if not n or "/" in n:
            raise ValueError(f"run names must be non-empty path components, got {n!r}")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    # never a FileSink on a disk that cannot hold the recording: rerun's can hang for good there
    # (autopilot.shared.telemetry.files); the runs' arrays stand for the spools there
    arrays = sum(np.asarray(v).nbytes for r in results for v in r.series.values())
    check_room(out, RRD_PER_SPOOL_BYTE * arrays + RRD_FIXED_BYTES)
    rec = rr.RecordingStream(EXPERIMENT_APPLICATION_ID, recording_id=recording_id or new_recording_id())
    rec.set_sinks(rr.FileSink(str(out)))
    try:
        rec.send_recording_name(f"{scenario}: " + ", ".join(names))
        times = [np.asarray(r.series["t"], dtype=float) for r in results if len(r.series["t"])]
        span = (min(float(t[0]) for t in times), max(float(t[-1]) for t in times)) if times else None
        rec.send_blueprint(experiment_blueprint(names, span if span and span[1] > span[0] else None))

        def send(entity: str, t: np.ndarray, values: np.ndarray) -> None:
            rec.send_columns(entity, indexes=[sim_time_column(t)], columns=[scalar_column(values)], strict=True)

        first = results[0].series
        rec.log(RUN_COMMAND, series_style(["roll command um"], [GREY]), static=True)
        send(RUN_COMMAND, first["t"], first["um"] * DEG)
        rec.log(RUN_REFERENCE_OL, series_style(["open-loop reference ym_ol"], [WHITE]), static=True)
        send(RUN_REFERENCE_OL, first["t"], first["ym_ol"] * DEG)

        for i, r in enumerate(results):
            s = r.series
            t = s["t"]
            c = run_color(r.name, i)
            label = f"{r.name} (Lv={r.lv:g})"
            plots = [
                ("roll", [f"phi {label}"], [c], [s["phi"] * DEG]),
                ("reference", [f"ym {label}"], [_shade(c, 0.7)], [s["ym"] * DEG]),
                ("error", [f"e {label}"], [c], [s["e"] * DEG]),
                ("rudder", [f"u {label}"], [c], [s["u"] * DEG]),
                ("gains/ke", [f"Ke {label}"], [c], [s["ke"]]),
                ("gains/kx", [f"Kx {label}"], [c], [s["kx"]]),
                ("gains/ku", [f"Ku {label}"], [c], [s["ku"]]),
                (
                    "gains/parts",
                    ["Kpe", "KIe", "Kpx", "KIx", "Kpu", "KIu"],
                    [SKY, ORANGE, GREEN, YELLOW, PURPLE, VERMILLION],
                    [s["kpe"], s["kie"], s["kpx"], s["kix"], s["kpu"], s["kiu"]],
                ),
                (
                    "state",
                    ["v [m/s]", "p [deg/s]", "r [deg/s]", "delta_r [deg]"],
                    [GREEN, YELLOW, PURPLE, BLUE],
                    [s["v"], s["p"] * DEG, s["r"] * DEG, s["delta_r"] * DEG],
                ),
            ]
            for what, labels, colors, cols in plots:
                entity = run_path(r.name, what)
                rec.log(entity, series_style(labels, colors), static=True)
                send(entity, t, np.column_stack(cols))
        rec.log(RUN_METRICS, rr.TextDocument(_metrics_markdown(results), media_type="text/markdown"), static=True)
        rec.flush()
    finally:
        rec.disconnect()
    if not has_footer(out):  # rerun said nothing but could not end it (a disk that filled)
        raise RuntimeError(f"{out}: the recording has no end (rerun could not write its footer)")
    write_digest(out)  # out.sha256: what `python -m tools.rrd verify` checks the content against
    return out
