"""Figures of the reference scenario ``paper``, laid out like the paper's section 5 figures.

Radians inside, degrees on the axes (converted here, once).  Uses matplotlib's Agg canvas directly
(no pyplot, no global backend switch), so it is safe to call from any process, with or without a display.

Cells (4 x 3):
    roll tracking SAC | roll tracking CL-SAC | rudder command SAC vs CL-SAC
    v                 | p                    | r                          (top SAC, bottom CL-SAC)
    Ke                | Kx                   | Ku                         (P, I and total; top SAC, bottom CL-SAC)
    Lv sweep tracking | Lv sweep control     | metrics table

SAC with the paper's PFC oscillates with the rudder at its limit while CL-SAC moves a few degrees, so
every SAC/CL-SAC comparison gets two axes with their own scales (the rudder cell also overlays CL-SAC on
SAC's scale so the difference in size is visible at a glance).
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from tools.experiment.scenario import PAPER, RunResult, Scenario

DEG = 180.0 / math.pi

C_SAC = "#d62728"
C_CLSAC = "#1f77b4"
C_CMD = "black"
C_OL = "0.45"
C_CRM = "#2ca02c"
METRIC_COLUMNS = ("ise_ref", "ise_crm", "energy", "tv", "max_abs_u")


def saturation_fraction(result: RunResult, u_limit_rad: float) -> float | None:
    """Fraction of control samples with the command at its limit, or None without a ``u`` series."""
    u = result.series.get("u") if result.series else None
    if u is None or len(u) == 0:
        return None
    return float(np.mean(np.abs(np.asarray(u)) >= u_limit_rad * (1.0 - 1e-9)))


def _pick(results: Iterable[RunResult], name: str) -> RunResult | None:
    for r in results:
        if r.name == name:
            return r
    return None


def _missing(ax, what: str) -> None:
    ax.text(0.5, 0.5, f"{what}: not in this experiment", ha="center", va="center", transform=ax.transAxes, color="0.4")
    ax.set_xticks([])
    ax.set_yticks([])


def _limit_lines(ax, u_limit_rad: float) -> None:
    for sgn in (1, -1):
        ax.axhline(sgn * u_limit_rad * DEG, color="0.3", lw=0.8, ls=":")


def _stacked(fig, spec, sharex=None):
    inner = spec.subgridspec(2, 1, hspace=0.0)
    top = fig.add_subplot(inner[0], sharex=sharex)
    bottom = fig.add_subplot(inner[1], sharex=top)
    top.tick_params(labelbottom=False)
    return top, bottom


def _tag(ax, text: str, color: str) -> None:
    ax.text(
        0.01,
        0.96,
        text,
        transform=ax.transAxes,
        ha="left",
        va="top",
        fontsize=9,
        color=color,
        fontweight="bold",
        bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.8),
    )


def _sig(res: RunResult, key: str) -> np.ndarray | None:
    """A series of the run, or None when its transport did not record it (e.g. mavlink: t, phi, u only)."""
    v = res.series.get(key) if res.series else None
    return None if v is None or len(v) == 0 else np.asarray(v, dtype=float)


def _command(res: RunResult, scenario: Scenario) -> np.ndarray | None:
    """u_m: recorded, or recomputed from the scenario (it is the scenario's definition)."""
    um = _sig(res, "um")
    t = _sig(res, "t")
    if um is None and t is not None:
        um = np.array([scenario.command(float(x)) for x in t])
    return um


def _not_recorded(ax, keys: Sequence[str]) -> None:
    where = (0.99, 0.5, "right") if ax.has_data() else (0.5, 0.5, "center")
    ax.text(
        where[0],
        where[1],
        "not recorded by this transport: " + ", ".join(keys),
        transform=ax.transAxes,
        ha=where[2],
        va="center",
        fontsize=8,
        color="0.4",
    )
    if not ax.has_data():
        ax.set_yticks([])


def _tracking(ax, res: RunResult | None, label: str, color: str, scenario: Scenario) -> None:
    if res is None:
        _missing(ax, label)
        return
    t, phi, um = _sig(res, "t"), _sig(res, "phi"), _command(res, scenario)
    ym_ol, ym = _sig(res, "ym_ol"), _sig(res, "ym")
    if t is None or phi is None:
        _missing(ax, f"{label} roll series")
        return
    # When the roll goes far beyond the command (SAC here), draw the references over it so they stay
    # visible; otherwise the roll goes on top.
    wild = um is not None and np.max(np.abs(phi)) > 2.0 * max(np.max(np.abs(um)), 1e-12)
    zref, zphi = (3, 2) if wild else (2, 3)
    if um is not None:
        ax.plot(
            t, um * DEG, color=C_CMD, lw=1.2, ls="--", drawstyle="steps-post", label="command $u_m$", zorder=zref + 1
        )
    if ym_ol is not None:
        ax.plot(t, ym_ol * DEG, color=C_OL, lw=2.0, label="open-loop ref. model $y_{m,ol}$", zorder=zref)
    if res.lv > 0 and ym is not None:
        ax.plot(t, ym * DEG, color=C_CRM, lw=1.2, label=f"closed-loop ref. model $y_m$ ($L_v$={res.lv:g})", zorder=zref)
    elif res.lv == 0 and ym_ol is not None:
        ax.plot([], [], color=C_CRM, lw=1.2, label="closed-loop ref. model = open loop ($L_v$=0)")
    ax.plot(t, phi * DEG, color=color, lw=1.1, label=r"roll $\phi$", zorder=zphi)
    missing = [k for k, v in (("ym_ol", ym_ol), ("ym", ym)) if v is None]
    if missing:
        _not_recorded(ax, missing)
    ax.set_ylabel("roll [deg]")
    ax.set_xlabel("t [s]")
    ax.set_title(f"Roll tracking, {label} ({res.name}, $L_v$={res.lv:g})", fontsize=10)
    frac = saturation_fraction(res, scenario.u_limit_rad)
    note = f"ise_ref={res.metrics['ise_ref']:.3g} rad$^2$s, max|$\\phi$|={np.max(np.abs(phi)) * DEG:.0f} deg" + (
        f"\nrudder at the {scenario.u_limit_rad * DEG:.0f} deg limit {100 * frac:.0f}% of the time" if frac else ""
    )
    ax.text(
        0.99,
        0.02,
        note,
        transform=ax.transAxes,
        ha="right",
        va="bottom",
        fontsize=8,
        bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="0.7", alpha=0.9),
    )
    ax.legend(loc="upper right", fontsize=7.5, framealpha=0.9)
    ax.grid(alpha=0.3)


def _rudder(fig, spec, sac: RunResult | None, cl: RunResult | None, scenario: Scenario):
    top, bottom = _stacked(fig, spec)
    top.set_title("Rudder command $u_p$: SAC vs CL-SAC", fontsize=10)
    lim = scenario.u_limit_rad
    su = None if sac is None else _sig(sac, "u")
    cu = None if cl is None else _sig(cl, "u")
    if su is not None:
        st = _sig(sac, "t")
        top.plot(st, su * DEG, color=C_SAC, lw=0.8, label=f"SAC ({sac.name})")
        sat = np.abs(su) >= lim * (1.0 - 1e-9)
        if sat.any():
            top.fill_between(st, -lim * DEG, lim * DEG, where=sat, color=C_SAC, alpha=0.08, lw=0, label="SAC saturated")
    if cu is not None:
        top.plot(_sig(cl, "t"), cu * DEG, color=C_CLSAC, lw=1.2, label=f"CL-SAC ({cl.name})")
    _limit_lines(top, lim)
    top.set_ylabel("[deg], SAC scale")
    if su is not None or cu is not None:
        top.legend(loc="upper right", fontsize=7.5, framealpha=0.9, ncol=3)
    top.grid(alpha=0.3)
    if cu is None:
        _missing(bottom, "CL-SAC rudder")
    else:
        bottom.plot(_sig(cl, "t"), cu * DEG, color=C_CLSAC, lw=1.2)
        _tag(bottom, "CL-SAC alone (own scale)", C_CLSAC)
        bottom.set_ylabel("[deg], CL-SAC scale")
        bottom.grid(alpha=0.3)
    bottom.set_xlabel("t [s]")


def _compare(fig, spec, sac, cl, key: str, scale: float, unit: str, title: str):
    top, bottom = _stacked(fig, spec)
    top.set_title(title, fontsize=10)
    for ax, res, label, color in ((top, sac, "SAC", C_SAC), (bottom, cl, "CL-SAC", C_CLSAC)):
        if res is None:
            _missing(ax, label)
            continue
        _tag(ax, f"{label} ({res.name})", color)
        y = _sig(res, key)
        if y is None:
            _not_recorded(ax, [key])
            continue
        ax.plot(_sig(res, "t"), y * scale, color=color, lw=1.0)
        ax.set_ylabel(unit)
        ax.grid(alpha=0.3)
    bottom.set_xlabel("t [s]")


def _gains(fig, spec, sac, cl, which: str):
    top, bottom = _stacked(fig, spec)
    top.set_title(f"Adaptive gain $K_{which}$ = $K_{{p{which}}}$ + $K_{{I{which}}}$", fontsize=10)
    for ax, res, label, color in ((top, sac, "SAC", C_SAC), (bottom, cl, "CL-SAC", C_CLSAC)):
        if res is None:
            _missing(ax, label)
            continue
        _tag(ax, f"{label} ({res.name})", color)
        t = _sig(res, "t")
        traces = (
            (f"kp{which}", "#ff7f0e", 0.9, "-", f"$K_{{p{which}}}$"),
            (f"ki{which}", "#9467bd", 1.2, "-", f"$K_{{I{which}}}$"),
            (f"k{which}", color, 1.0, "--", f"$K_{which}$"),
        )
        missing = []
        for key, c, lw, ls, lab in traces:
            y = _sig(res, key)
            if y is None:
                missing.append(key)
            else:
                ax.plot(t, y, color=c, lw=lw, ls=ls, label=lab)
        if missing:
            _not_recorded(ax, missing)
        if len(missing) < len(traces):
            ax.legend(loc="upper right", fontsize=7.5, framealpha=0.9, ncol=3)
        ax.set_ylabel("[-]")
        ax.grid(alpha=0.3)
    bottom.set_xlabel("t [s]")


def _sweep_runs(results: Sequence[RunResult]) -> list[RunResult]:
    return sorted((r for r in results if r.lv > 0), key=lambda r: r.lv)


def _sweep_colors(n: int):
    from matplotlib import colormaps

    cmap = colormaps["viridis"]
    return [cmap(0.1 + 0.75 * i / max(n - 1, 1)) for i in range(n)]


def _lv_tracking(fig, spec, sweep: list[RunResult], scenario: Scenario):
    top, bottom = _stacked(fig, spec)
    top.set_title("$L_v$ sweep: roll tracking (top), $\\phi - y_{m,ol}$ (bottom)", fontsize=10)
    if not sweep:
        _missing(top, "CL-SAC runs")
        _missing(bottom, "CL-SAC runs")
        return
    r0 = sweep[0]
    um, ym_ol = _command(r0, scenario), _sig(r0, "ym_ol")
    if um is not None:
        top.plot(_sig(r0, "t"), um * DEG, color=C_CMD, lw=1.0, ls="--", drawstyle="steps-post", label="$u_m$")
    if ym_ol is not None:
        top.plot(_sig(r0, "t"), ym_ol * DEG, color=C_OL, lw=2.0, label="$y_{m,ol}$")
    missing = set()
    for res, c in zip(sweep, _sweep_colors(len(sweep))):
        t, phi, ol = _sig(res, "t"), _sig(res, "phi"), _sig(res, "ym_ol")
        if phi is None:
            missing.add("phi")
            continue
        top.plot(t, phi * DEG, color=c, lw=1.0, label=f"$L_v$={res.lv:g}")
        if ol is None:
            missing.add("ym_ol")
            continue
        bottom.plot(
            t, (phi - ol) * DEG, color=c, lw=1.0, label=f"$L_v$={res.lv:g}: ise_ref={res.metrics['ise_ref']:.3g}"
        )
    if missing:
        _not_recorded(bottom, sorted(missing))
    top.set_ylabel("roll [deg]")
    bottom.set_ylabel("[deg]")
    for ax, ncol in ((top, 3), (bottom, 2)):
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper right", fontsize=7.5, ncol=ncol, framealpha=0.9)
        ax.grid(alpha=0.3)
    bottom.set_xlabel("t [s]")


def _lv_control(fig, spec, sweep: list[RunResult]):
    top, bottom = _stacked(fig, spec)
    top.set_title("$L_v$ sweep: rudder $u_p$ (top), error $e = y_m - y_a$ (bottom)", fontsize=10)
    if not sweep:
        _missing(top, "CL-SAC runs")
        _missing(bottom, "CL-SAC runs")
        return
    missing = set()
    for res, c in zip(sweep, _sweep_colors(len(sweep))):
        t, u, e = _sig(res, "t"), _sig(res, "u"), _sig(res, "e")
        if u is None:
            missing.add("u")
        else:
            top.plot(t, u * DEG, color=c, lw=1.0, label=f"$L_v$={res.lv:g}: energy={res.metrics['energy']:.3g}")
        if e is None:
            missing.add("e")
        else:
            bottom.plot(t, e * DEG, color=c, lw=1.0, label=f"$L_v$={res.lv:g}: ise_crm={res.metrics['ise_crm']:.3g}")
    if "u" in missing:
        _not_recorded(top, ["u"])
    if "e" in missing:
        _not_recorded(bottom, ["e"])
    top.set_ylabel("[deg]")
    bottom.set_ylabel("[deg]")
    for ax in (top, bottom):
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper right", fontsize=7.5, ncol=2, framealpha=0.9)
        ax.grid(alpha=0.3)
    bottom.set_xlabel("t [s]")


def _table(ax, results: Sequence[RunResult], scenario: Scenario, notes: Sequence[str] = ()):
    ax.axis("off")
    ax.set_title('Metrics (docs/spec.md, "Metrics"; SI: rad, s)', fontsize=10)
    header = ["run", "Lv", "ise_ref", "ise_crm", "energy", "tv", "max|u| deg", "saturated"]
    rows = []
    for r in results:
        frac = saturation_fraction(r, scenario.u_limit_rad)
        sat = "n/a" if frac is None else (f"{100 * frac:.0f}%" if frac > 0 else "no")
        m = r.metrics
        rows.append(
            [r.name, f"{r.lv:g}"] + [f"{m[k]:.3g}" for k in METRIC_COLUMNS[:4]] + [f"{m['max_abs_u'] * DEG:.2f}", sat]
        )
    if rows:
        widths = [0.17, 0.07, 0.12, 0.12, 0.12, 0.1, 0.14, 0.14]
        tab = ax.table(
            cellText=rows, colLabels=header, colWidths=widths, loc="upper center", cellLoc="right", colLoc="right"
        )
        tab.auto_set_font_size(False)
        tab.set_fontsize(9)
        tab.scale(1.0, 1.6)
        for i, r in enumerate(results, start=1):
            if saturation_fraction(r, scenario.u_limit_rad):
                for j in range(len(header)):
                    tab[i, j].set_facecolor("#fde0e0")
    lines = textwrap.wrap(
        f"Scenario '{scenario.name}': roll square wave +-{scenario.amplitude_rad * DEG:g} deg, period "
        f"{scenario.period_s:g} s, {scenario.duration_s:g} s; control {scenario.control_rate_hz:g} Hz, "
        f"physics {scenario.physics_rate_hz:g} Hz, rudder command limit +-{scenario.u_limit_rad * DEG:g} deg. "
        "Red rows: rudder saturated.",
        84,
    )
    if notes:
        lines += ["", "Paper's claims (section 5) against these numbers:"]
        for n in notes:
            lines += textwrap.wrap(n, 84, initial_indent="- ", subsequent_indent="    ")
    ax.text(
        0.0,
        0.5,
        "\n".join(lines),
        transform=ax.transAxes,
        fontsize=8.5,
        va="top",
        ha="left",
        color="0.15",
        family="monospace",
    )


def paper_figure(
    results: Sequence[RunResult], scenario: Scenario = PAPER, title: str | None = None, notes: Sequence[str] = ()
) -> Figure:
    """Build the figure (without saving).  Runs named ``sac`` and ``clsac`` fill the comparison cells;
    every run with L_v > 0 goes into the L_v sweep.  Missing runs leave a labelled empty panel.
    ``notes``: short text lines printed under the metrics table (e.g. the checks of the paper's claims)."""
    results = list(results)
    sac, cl = _pick(results, "sac"), _pick(results, "clsac")
    # Fixed margins rather than constrained layout: same look here, half the rendering time.
    fig = Figure(figsize=(21, 23), dpi=100)
    FigureCanvasAgg(fig)
    outer = fig.add_gridspec(4, 3, left=0.045, right=0.99, bottom=0.03, top=0.955, wspace=0.17, hspace=0.2)
    _tracking(fig.add_subplot(outer[0, 0]), sac, "SAC", C_SAC, scenario)
    _tracking(fig.add_subplot(outer[0, 1]), cl, "CL-SAC", C_CLSAC, scenario)
    _rudder(fig, outer[0, 2], sac, cl, scenario)
    _compare(fig, outer[1, 0], sac, cl, "v", 1.0, "v [m/s]", "Lateral velocity v")
    _compare(fig, outer[1, 1], sac, cl, "p", DEG, "p [deg/s]", "Roll rate p")
    _compare(fig, outer[1, 2], sac, cl, "r", DEG, "r [deg/s]", "Yaw rate r")
    for j, which in enumerate("exu"):
        _gains(fig, outer[2, j], sac, cl, which)
    sweep = _sweep_runs(results)
    _lv_tracking(fig, outer[3, 0], sweep, scenario)
    _lv_control(fig, outer[3, 1], sweep)
    _table(fig.add_subplot(outer[3, 2]), results, scenario, notes)
    from sitl.plant_kinds import kind_of

    plant = getattr(scenario, "plant", "kh2013a")
    plant = "KH2013A" if kind_of(plant).paper else plant
    default = f"CL-SAC roll autopilot, {plant}: scenario 'paper' (Jana & Bhat 2017, section 5)"
    fig.suptitle(title or default, fontsize=14)
    return fig


def save_paper_figure(
    results: Sequence[RunResult],
    path: str | Path,
    scenario: Scenario = PAPER,
    title: str | None = None,
    notes: Sequence[str] = (),
) -> Path:
    """Render :func:`paper_figure` to a PNG at ``path``; returns the path."""
    path = Path(path)
    fig = paper_figure(results, scenario, title, notes)
    fig.savefig(path, format="png")
    return path
