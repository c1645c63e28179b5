"""A flight's ``flight.png``: the roll against the command and the reference models, the rudder command and the
adaptive gains K_e, K_x, K_u (or the PID's gains, or a law's own telemetry), in three panels sharing the time axis,
mode switches, faults and parameter changes marked.  The roll is not joined across a wrap at +-180 deg, a gain's rare
spikes are clipped and marked, the labels of faults that fall together are merged (``tools.view.flight_scales``).

It is the figure ``tools.view.plots`` used to draw with matplotlib, in the same layout, colours and font, drawn by the
Pillow and numpy engine ``tools.view.plot_engine``: matplotlib's import (about 0.45 CPU s) and draw (about 0.3 CPU s)
were the largest cost of a launch, in the picture helper (``tools.view.flight_picture``).  Here the helper's imports
(numpy, PIL) cost about 0.09 CPU s and its draw, PNG included, about 0.07 s."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
from PIL import Image

from autopilot import controllers
from tools.view import flight_scales
from tools.view.plot_engine import DEG, Line, Panel, render

# tools.view.plots' colours (matplotlib's default cycle): the law, the command and the reference models, the gains
C_CLSAC = "#1f77b4"
C_SAC = "#d62728"
C_BASE = "#e377c2"  # the fixed-gain PID baseline (matplotlib's tab:pink)
C_CMD = "#000000"
C_OL = "#737373"  # matplotlib's "0.45"
C_CRM = "#2ca02c"
C_GAINS = {"ke": "#ff7f0e", "kx": "#9467bd", "ku": "#8c564b"}
C_PARAM = "#0072b2"  # a parameter changed in flight by a ground station, dashed, its name and values in the top panel


# ---------------------------------------------------------------------------------------- a flight's picture
def _column(series: dict, key: str) -> np.ndarray | None:
    """A series as floats, or None when the flight's files do not have it."""
    v = series.get(key)
    return None if v is None or len(v) == 0 else np.asarray(v, dtype=float)


def _deg(v: np.ndarray | None) -> np.ndarray | None:
    return None if v is None else v * DEG


def _max_roll_text(phi: np.ndarray) -> str:
    """The note's largest roll: whole degrees, three digits beyond 10,000 deg (a blown-up flight), n/a without a
    finite value."""
    if not np.isfinite(phi).any():
        return "n/a"
    deg = _finite_max_abs(phi) * DEG
    return f"{deg:.0f} deg" if deg < 1e4 else f"{deg:.3g} deg"


def _finite_max_abs(v: np.ndarray) -> float:
    v = v[np.isfinite(v)]
    return float(np.max(np.abs(v))) if v.size else 0.0


def mode_switches(t: np.ndarray, mode: np.ndarray | None) -> list[tuple[float, str]]:
    """(time, name) of each change of the ``mode`` series (HEARTBEAT.custom_mode: ``autopilot.vehicle.Mode``)."""
    if mode is None or len(mode) != len(t):
        return []
    ok = np.isfinite(mode[1:]) & np.isfinite(mode[:-1]) & (mode[1:] != mode[:-1])
    switches = np.flatnonzero(ok) + 1
    if not len(switches):
        return []
    from autopilot.vehicle import Mode  # imported only for a flight that changed modes

    names = {m.value: m.name for m in Mode}
    return [(float(t[k]), names.get(int(mode[k]), f"mode {int(mode[k])}")) for k in switches]


def flight_image(
    series: dict,
    *,
    name: str,
    lv: float,
    metrics: dict,
    u_limit_rad: float,
    title: str,
    controller: str | None = None,
    faults: list[tuple[float, str]] = (),
    surface: str = "rudder",
    gains: tuple[float, float, float] | None = None,
    changes: list[dict] = (),
    law_label: str | None = None,
) -> Image.Image:
    """The picture of one flight (``series``: ``tools.view.series_files.load_series``; ``t`` must be there): roll
    against the command and the reference models, the command of the ``surface``, the adaptive gains; mode switches
    marked.  ``controller``: "clsac", "sac" or "baseline" (the fixed-gain PID: its gains ``gains`` = K_p, K_i, K_d
    as flown from the start); None: CL-SAC if ``lv`` > 0, else SAC.  ``faults``: (time, text[, colour]) of each
    fault's start and end and each parameter change (``tools.view.flight_picture.marks``), marked; ``changes``: the
    parameters a ground station changed (``summary.json`` ``param_changes``), for the PID's gains.  ``law_label``: a
    law on autopilot.law's interface (its words): its own telemetry (the series' ``law_*`` columns) is drawn."""
    t = _column(series, "t")
    if t is None:
        raise ValueError("flight_image: no time series 't'")
    col = {k: _column(series, k) for k in ("um", "phi", "ym_ol", "ym", "u", "mode", *C_GAINS)}
    col = {k: None if v is None or len(v) != len(t) else v for k, v in col.items()}  # a torn column: not drawn
    generic = law_label is not None  # a law on autopilot.law's interface
    baseline = generic or (controller is not None and not controllers.get(controller).adaptive)
    color, law = (C_BASE, "baseline PID") if baseline else (C_CLSAC, "CL-SAC") if lv > 0 else (C_SAC, "SAC")
    if generic:
        law = law_label

    # Roll tracking.  When the roll goes far beyond the command (SAC oscillating), the references are drawn over
    # it so they stay visible; otherwise the roll goes on top.
    um, phi, ym_ol, ym = col["um"], col["phi"], col["ym_ol"], col["ym"]
    wild = um is not None and phi is not None and _finite_max_abs(phi) > 2.0 * max(_finite_max_abs(um), 1e-12)
    zref, zphi = (3, 2) if wild else (2, 3)
    lines = []
    if um is not None:
        lines.append(Line(_deg(um), C_CMD, 1.2, "--", steps=True, label="command u_{m}", z=zref + 1))
    if ym_ol is not None:
        lines.append(Line(_deg(ym_ol), C_OL, 2.0, label="open-loop ref. model y_{m,ol}", z=zref))
    if lv > 0 and ym is not None:
        lines.append(Line(_deg(ym), C_CRM, 1.2, label=f"closed-loop ref. model y_{{m}} (L_{{v}}={lv:g})", z=zref))
    elif lv == 0 and ym_ol is not None and not baseline:
        lines.append(Line(None, C_CRM, 1.2, label="closed-loop ref. model = open loop (L_{v}=0)"))
    if phi is not None:
        lines.append(Line(_deg(phi), color, 1.1, label="roll φ", z=zphi, wrap=180.0))  # ATTITUDE's, wrapped
    ise = metrics.get("ise_ref") if isinstance(metrics, dict) else None
    note = [
        (f"ise_ref={ise:.3g} rad²s" if isinstance(ise, (int, float)) else "ise_ref=n/a")
        + (f", max|φ|={_max_roll_text(phi)}" if phi is not None else "")
    ]
    u = col["u"]
    if u is not None:
        at_limit = float(np.mean(np.abs(u) >= u_limit_rad * (1.0 - 1e-9)))
        if at_limit:
            share = f"{100 * at_limit:.0f}%" if at_limit >= 0.005 else "<1%"  # never "0%" for a flight that touched it
            note.append(f"{surface} at the {u_limit_rad * DEG:.3g} deg limit {share} of the time")
    tracking = Panel(
        f"Roll tracking, {law} ({name})" if baseline else f"Roll tracking, {law} ({name}, L_{{v}}={lv:g})",
        "roll [deg]",
        lines,
        missing=[k for k in ("um", "phi", "ym_ol", "ym") if col[k] is None and not (k == "ym" and lv == 0)],
        note=note,
    )

    # The rudder command, with its limits when it comes near them (else they would squash it to a line)
    rudder = Panel(f"{surface.capitalize()} command u_{{p}}", f"{surface} [deg]")
    if u is None:
        rudder.missing = ["u"]
    else:
        rudder.lines.append(Line(u * DEG, color, 1.0, label=f"{surface} command (flown, after PWM)"))
        if _finite_max_abs(u) > 0.5 * u_limit_rad:
            rudder.hlines = [u_limit_rad * DEG, -u_limit_rad * DEG]
    mimo = {k: _column(series, k) for k in ("u2", "beta", "ke12", "ke21", "ke22")}
    mimo = {k: v for k, v in mimo.items() if v is not None and len(v) == len(t)}
    if "u2" in mimo and "beta" in mimo:  # a square MIMO flight (autopilot.mimo): the rudder on the sideslip
        rudder.title = f"Surface commands and sideslip (max |β| {_finite_max_abs(mimo['beta']) * DEG:.2f} deg)"
        rudder.ylabel = "[deg]"
        rudder.legend_cols = 3
        rudder.lines.append(Line(mimo["u2"] * DEG, C_GAINS["kx"], 1.0, label="rudder command u_{2}"))
        rudder.lines.append(Line(mimo["beta"] * DEG, C_GAINS["ku"], 1.2, label="sideslip β"))

    # The adaptive gains; the baseline adapts nothing (its telemetry records K_p as K_e, the rest NaN)
    if generic:
        return render(t, [tracking, rudder, law_panel(t, series, law)], mode_switches(t, col["mode"]), title, faults)
    if baseline:
        return render(t, [tracking, rudder, pid_panel(t, gains, changes)], mode_switches(t, col["mode"]), title, faults)
    gains = Panel("Adaptive gains K = K_{p} + K_{I}", "[-]", legend_cols=3)
    for key, label in (("ke", "K_{e}"), ("kx", "K_{x}"), ("ku", "K_{u}")):
        if col[key] is None:
            gains.missing.append(key)
        else:
            gains.lines.append(Line(col[key], C_GAINS[key], 1.0, label="K_{e,11}" if mimo and key == "ke" else label))
    for key, label, style in (("ke12", "K_{e,12}", "--"), ("ke21", "K_{e,21}", ":"), ("ke22", "K_{e,22}", "--")):
        if key in mimo:  # the matrix gain's other entries (MIMO)
            gains.lines.append(Line(mimo[key], C_GAINS["ke"] if key != "ke22" else C_CMD, 1.0, style, label=label))

    _clip_spikes(t, gains)
    return render(t, [tracking, rudder, gains], mode_switches(t, col["mode"]), title, faults)


def _clip_spikes(t: np.ndarray, panel: Panel) -> None:
    """A panel whose few spikes would flatten the rest (``flight_scales.robust_range``): scaled to the bulk of its
    values, each clipped sample marked by a triangle at the edge in its line's colour, the extremes in the note."""
    lim = flight_scales.robust_range([ln.y for ln in panel.lines if ln.y is not None])
    if lim is None:
        return
    panel.ylim = lim
    for ln in panel.lines:
        if ln.y is None:
            continue
        above, below = flight_scales.clipped_marks(t, ln.y, lim)
        panel.clipped += [(ts, up, ln.color) for ts, up in ((above, True), (below, False)) if len(ts)]
        if len(above) or len(below):
            v = ln.y[~np.isnan(ln.y)]
            name = re.sub(r"_\{([^}]*)\}", r"_\1", ln.label or "")
            panel.note.append(f"{name} clipped (▲▼): {v.min():.3g} to {v.max():.3g}")


def law_panel(t: np.ndarray, series: dict, label: str) -> Panel:
    """A law's own telemetry (``autopilot.law``: the series' ``law_<field>`` columns, in its own units), by name."""
    panel = Panel(f"{label}: its own telemetry", "[SI]", legend_cols=3)
    colors, keys = (*C_GAINS.values(), C_CMD, C_OL, C_CRM), [k for k in series if k.startswith("law_")]
    ys = [(k, _column(series, k)) for k in keys]
    panel.lines = [Line(y, colors[i % len(colors)], 1.0, label=k[4:]) for i, (k, y) in enumerate(ys) if y is not None]
    panel.missing = [] if keys else ["law telemetry"]
    _clip_spikes(t, panel)
    return panel


def pid_panel(t: np.ndarray, gains, changes) -> Panel:
    """The fixed-gain PID's K_p, K_i, K_d as flown (constant, stepping where a ground station changed one), on a
    range from 0 to above the largest: a gain of 0 or a changed one stays readable."""
    panel = Panel("Fixed-gain PID gains (not adaptive)", "[-], [1/s], [s]", legend_cols=3)
    if gains is None:
        panel.missing.append("gains")
        return panel
    top = 0.0
    # K_p wide and K_i dashed over it: the KH2013A's K_p and K_i are both 0.1 (in their units), one line otherwise
    for i, (key, label, lw, style) in enumerate(
        (("ke", "K_{p}", 2.6, "-"), ("kx", "K_{i} [1/s]", 1.3, "--"), ("ku", "K_{d} [s]", 1.3, "-"))
    ):
        y = np.full(len(t), float(gains[i]))
        for c in changes or ():
            if c.get("name") in (f"PID_K{'PID'[i]}", f"CLSAC_PID_K{'PID'[i]}") and c.get("t_s") is not None:
                y[t >= c["t_s"]] = float(c["to"])
        top = max(top, float(np.max(y)))
        panel.lines.append(Line(y, C_GAINS[key], lw, style, steps=True, label=label))
    panel.ylim = (-0.05 * (top or 1.0), 1.2 * (top or 1.0))
    return panel


def save_flight_png(path: str | os.PathLike, series: dict, **kw) -> Path:
    """:func:`flight_image` saved as a PNG at ``path``; returns the path."""
    path = Path(path)
    # zlib level 3: about 20 ms for a flight's picture, 80 kB; the default 6 takes 28 ms for 64 kB
    flight_image(series, **kw).save(path, format="PNG", compress_level=3)
    return path
