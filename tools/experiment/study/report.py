"""What a person reads: the Markdown tables (docs/experiments.md, table.md), the figure, the worst runs in Rerun."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from autopilot import controllers as registry
from tools.experiment.study.sampling import SWEEPS, StudyOptions
from tools.experiment.study.simulation import replay


def _adaptive(name: str) -> bool:
    """A study controller whose law has a PFC (the baseline's has none)."""
    return name not in registry.ROBUSTNESS or registry.studied(name).adaptive


def format_table(summary: dict, conditions: Sequence[str] = ("nominal", "moderate", "severe")) -> str:
    """Markdown: bounded share (and its Wilson 95 % interval) and p95 of ise_ref and energy per controller and
    condition (docs/experiments.md)."""
    conds = [c for c in conditions if any(c in v for v in summary["results"].values())]
    head = "| controller | " + " | ".join(f"{c}: bounded (95 % CI) / p95 ise_ref / p95 energy" for c in conds) + " |"
    lines = [head, "|---|" + "---|" * len(conds)]
    for ctrl, by_cond in summary["results"].items():
        cells = []
        for c in conds:
            a = by_cond.get(c) or {}
            if not a:
                cells.append("")
                continue
            ci = a.get("bounded_ci95")
            share = f"{100 * a['bounded_share']:.1f} %" + (f" ({100 * ci[0]:.1f}-{100 * ci[1]:.1f})" if ci else "")
            cells.append(f"{share} / {_fmt(a['p95']['ise_ref'])} / {_fmt(a['p95']['energy'])}")
        lines.append(f"| {ctrl} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def format_breaks(summary: dict) -> str:
    """Markdown: per controller, the loss probability, sensor delay (samples of 10 ms) and turbulence (x severe)
    at which it stops being bounded, with the paper's PFC / the robust PFC ("-": bounded at every value tried)."""
    head = "| controller | " + " | ".join(f"{k}: paper PFC / robust PFC" for k in SWEEPS) + " |"
    lines = [head, "|---|" + "---|" * len(SWEEPS)]
    for ctrl, b in summary["breaks"].items():
        cells = []
        for k in SWEEPS:
            if k not in b:  # a study stopped before this sweep
                cells.append("not flown")
                continue
            if not _adaptive(ctrl):
                v = b.get(k)
                cells.append(f"{'-' if v is None else f'{v:.3g}'} (no PFC)")
                continue
            pair = [b["by_pfc"][p].get(k) for p in ("paper", "robust")]
            cells.append(" / ".join("-" if v is None else f"{v:.3g}" for v in pair))
        lines.append(f"| {ctrl} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def format_long(summary: dict) -> str:
    """Markdown: the long flight's median peak |roll| (deg) in the first window, at 180-210 s and in the last
    window, per controller, condition and PFC."""
    lf = summary.get("long_flight")
    if not lf:
        return ""
    lines = [
        "| controller | condition | PFC | peak 0-30 s | peak 180-210 s | peak 570-600 s | bounded |",
        "|---|---|---|---|---|---|---|",
    ]
    for ctrl, by_cond in lf["controllers"].items():
        for cond, by_pfc in by_cond.items():
            for pfc, d in by_pfc.items():
                if not _adaptive(ctrl) and pfc == "robust":
                    continue
                cells = [d["peak_first_window_deg"], d["peak_180_210_s_deg"], d["peak_last_window_deg"]]
                lines.append(
                    f"| {ctrl} | {cond} | {pfc if _adaptive(ctrl) else '-'} | "
                    + " | ".join("diverged" if v is None else f"{v:.1f} deg" for v in cells)
                    + f" | {100 * d['bounded_share']:.0f} % |"
                )
    return "\n".join(lines)


def _fmt(v) -> str:
    return "diverged" if v is None else f"{v:.3g}"


def save_figure(tally, opts: StudyOptions, path: Path) -> Path:
    """Box plots of ise_ref and energy per controller, one column per condition (log scale): the quartiles and the
    p5-p95 whiskers of each cell's finite positive values (``tools.experiment.study.accumulate.Sample``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    conds = list(opts.conditions)
    fig, axes = plt.subplots(2, len(conds), figsize=(4.2 * len(conds), 7), squeeze=False, sharey="row")
    boxes = {}  # (row, column): a box per controller, from the finite positive values only
    for j, cond in enumerate(conds):
        for i, metric in enumerate(("ise_ref", "energy")):
            stats = []
            for ctrl in opts.controllers:
                cell = tally.cells.get(ctrl, {}).get(cond)
                q = cell.samples[metric].quantiles((5, 25, 50, 75, 95)) if cell else None
                q = [v if v is not None and math.isfinite(v) and v > 0 else math.nan for v in (q or [math.nan] * 5)]
                stats.append({"whislo": q[0], "q1": q[1], "med": q[2], "q3": q[3], "whishi": q[4], "fliers": []})
            boxes[i, j] = stats
    # a log scale needs a value above zero: a row without one (every run diverged) is drawn empty, on a linear scale
    log_rows = {i for (i, _), st in boxes.items() if any(b["med"] == b["med"] for b in st)}
    for j, cond in enumerate(conds):
        for i, metric in enumerate(("ise_ref", "energy")):
            ax = axes[i][j]
            ax.bxp(boxes[i, j], showfliers=False)
            ax.set_xticks(range(1, len(opts.controllers) + 1), opts.controllers, rotation=60, fontsize=7)
            if i in log_rows:
                ax.set_yscale("log")
            else:
                ax.text(0.5, 0.5, "no finite value", transform=ax.transAxes, ha="center")
            ax.grid(True, alpha=0.3)
            if i == 0:
                ax.set_title(cond)
            if j == 0:
                ax.set_ylabel(f"{metric} [rad^2 s]")
    fig.suptitle(f"Monte Carlo: {opts.runs} runs per condition, seed {opts.seed} (whiskers p5-p95)")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def save_worst_rrd(summary: dict, opts: StudyOptions, path: Path, condition: str = "severe") -> Path | None:
    """The worst run of each controller under ``condition`` (else the last condition), side by side in Rerun."""
    from tools.experiment.scenario import RunResult

    cond = condition if condition in opts.conditions else opts.conditions[-1]
    results = []
    for ctrl in opts.controllers:
        w = summary["results"][ctrl][cond].get("worst")
        if not w:
            continue
        r = replay(ctrl, cond, opts.seed, w["run"], faults=opts.faults)
        series = {k: v[:, 0] for k, v in r["series"].items()}
        metrics = {m: float(r[m][0]) for m in ("ise_ref", "ise_crm", "energy", "tv", "max_abs_u")}
        results.append(RunResult(f"{ctrl}_{cond}_run{w['run']}", registry.studied(ctrl).lv, metrics, series))
    if not results:
        return None
    try:
        from tools.view.recording import log_experiment
    except ImportError:
        return None
    return Path(log_experiment(results, path))
