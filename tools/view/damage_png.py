"""``damage.png`` of the damage study (``python -m tools.experiment damage``): per plant, against each fault's
severity, the share of flights still controlled (with its 95 % Wilson interval) and the median tracking error after
the onset with its interval over the seeds (the sign test's, ``tools.experiment.damage.stats``; under 6 seeds the
seeds' range), one line per controller.

matplotlib's Agg canvas directly (no pyplot), as ``tools.view.plots``.  The severities are categories on the x axis,
ordered from the fault-free flight ("none") to the worst: a lower factor or rate is worse, a longer delay is worse.
"""

from __future__ import annotations

from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from sitl import fault_kinds

COLOURS = {
    "baseline": "#7f7f7f",
    "sac": "#d62728",
    "clsac": "#1f77b4",
    "pid-ff": "#2ca02c",
    "pid-retuned": "#9467bd",
    "pid-energy": "#ff7f0e",
    "sac-robust": "#e377c2",
    "clsac-robust": "#17becf",
}
DODGE = 0.07  # x offset between controllers (categories are 1 apart)
WORSE_LOWER = fault_kinds.WORSE_LOWER  # the worst severity is the lowest value (sitl.fault_kinds.FaultKind.worse)


def _order(kind: str, values) -> list:
    vals = [v for v in values if v is not None]
    out = sorted(vals, reverse=kind in WORSE_LOWER)
    return ([None] if None in values else []) + out


def _label(kind: str, v) -> str:
    if v is None:
        # no value: where it is for a kind whose value is optional (stuck), the kind itself for one without (off)
        return "here" if kind in fault_kinds.KINDS and fault_kinds.KINDS[kind].value == "optional" else kind
    return f"{v:g}"


def draw(cells, plants, kinds, controllers, labels: dict, path, onset: float | None = None) -> Path:
    """Write the figure to ``path``; ``cells``: ``tools.experiment.damage.aggregate.summarise``'s entries."""
    from tools.experiment.damage.grid import NONE

    cols = max(1, len(kinds))
    fig = Figure(figsize=(3.6 * cols + 1.2, 5.4 * len(plants)), dpi=100)
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(2 * len(plants), cols, hspace=0.55, wspace=0.3)
    for pi, plant in enumerate(plants):
        mine = [c for c in cells if c["plant"] == plant]
        onsets = sorted({c["onset_s"] for c in mine if c["onset_s"] is not None})
        at = onsets[0] if onset is None and onsets else onset
        for ki, kind in enumerate(kinds):
            share_ax = fig.add_subplot(grid[2 * pi, ki])
            err_ax = fig.add_subplot(grid[2 * pi + 1, ki])
            sevs = _order(kind, {c["severity"] for c in mine if c["kind"] == kind})
            if not sevs:
                for ax in (share_ax, err_ax):
                    ax.text(0.5, 0.5, f"{kind}: not on {plant}", ha="center", va="center", transform=ax.transAxes)
                    ax.set_xticks([])
                    ax.set_yticks([])
                continue
            xs = list(range(len(sevs) + 1))
            ticks = ["none"] + [_label(kind, v) for v in sevs]
            for ci, name in enumerate(controllers):
                dx = DODGE * (ci - (len(controllers) - 1) / 2)  # side by side: equal shares stay visible
                by = {(c["kind"], c["severity"]): c for c in mine if c["controller"] == name}
                by = {k: c for k, c in by.items() if k[0] == NONE or c["onset_s"] == at}
                row = [by.get((NONE, None))] + [by.get((kind, v)) for v in sevs]
                pts = [(x, c) for x, c in zip(xs, row) if c is not None]
                if not pts:
                    continue
                colour = COLOURS.get(name)
                share = [100 * c["share_controlled"] for _, c in pts]
                # max(0, .): Wilson's bound of k = n (or 0) is the share itself up to rounding (1 - 1e-16)
                lo = [max(0.0, 100 * (c["share_controlled"] - c["wilson95"][0])) for _, c in pts]
                hi = [max(0.0, 100 * (c["wilson95"][1] - c["share_controlled"])) for _, c in pts]
                share_ax.errorbar(
                    [x + dx for x, _ in pts],
                    share,
                    yerr=[lo, hi],
                    color=colour,
                    marker="o",
                    ms=3,
                    lw=1.2,
                    capsize=2,
                    elinewidth=0.6,
                    label=labels.get(name, name),
                )
                err = [(x + dx, c) for x, c in pts if c["ise_ref_after_p50"] and c["ise_ref_after_p50"] > 0]
                if err:
                    mid = [c["ise_ref_after_p50"] for _, c in err]
                    band = [c.get("ise_ref_after_interval") or [m, m] for m, (_, c) in zip(mid, err)]
                    err_ax.errorbar(
                        [x for x, _ in err],
                        mid,
                        yerr=[
                            [max(0.0, m - b[0]) for m, b in zip(mid, band)],
                            [max(0.0, b[1] - m) for m, b in zip(mid, band)],
                        ],
                        color=colour,
                        marker="o",
                        ms=3,
                        lw=1.2,
                        capsize=2,
                        elinewidth=0.6,
                    )
            for ax in (share_ax, err_ax):
                ax.set_xticks(xs)
                ax.set_xticklabels(ticks, fontsize=8)
                ax.grid(True, alpha=0.3)
            share_ax.set_ylim(-5, 105)
            err_ax.set_yscale("log")
            unit = f" {fault_kinds.KINDS[kind].unit}" if fault_kinds.KINDS[kind].unit else ""  # the record's
            share_ax.set_title(f"{plant}: {kind}{unit}", fontsize=9)
            err_ax.set_xlabel(f"{kind}{unit}", fontsize=8)
            if ki == 0:
                share_ax.set_ylabel("% still controlled", fontsize=8)
                err_ax.set_ylabel("median ise_ref after onset (rad² s),\ninterval over the seeds", fontsize=8)
        if pi == 0:
            handles, names = fig.axes[0].get_legend_handles_labels()
            fig.legend(
                handles,
                names,
                loc="upper center",
                bbox_to_anchor=(0.5, 1.0 - 0.25 / fig.get_figheight()),
                ncol=min(6, len(names)),
                fontsize=8,
                frameon=False,
            )
    at_text = "" if onset is None else f", onset {onset:g} s"
    fig.suptitle(
        f"Faults in mid-flight: share still controlled and error after the onset{at_text}", y=0.999, fontsize=10
    )
    fig.subplots_adjust(
        top=1.0 - 0.85 / fig.get_figheight(),
        bottom=0.4 / fig.get_figheight(),
        left=0.6 / fig.get_figwidth(),
        right=0.99,
    )
    path = Path(path)
    fig.savefig(path, format="png")
    return path
