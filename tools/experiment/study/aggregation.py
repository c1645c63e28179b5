"""From the runs to summary.json: per controller and condition the bounded share, percentiles, the worst run and
the commands that replay it; the long flight's drift; where each controller breaks in the sweeps."""

from __future__ import annotations

import math

import numpy as np

from tools.experiment.study.accumulate import Cell, LongCell, records_batch, wilson
from tools.experiment.study.sampling import DEG, METRICS, SWEEPS, WINDOW_S, get_condition, get_controller


def aggregate(records: dict[tuple[str, int], dict], condition: str, controller: str, seed: int) -> dict:
    """summary.json's entry of one controller under one condition, from per-run records (``merge``)."""
    runs = sorted((i, r) for (c, i), r in records.items() if c == condition)
    if not runs:
        return {}
    cell = Cell(exact=True)
    cell.add(np.array([i for i, _ in runs]), records_batch([r for _, r in runs]), np.arange(len(runs)))
    return cell_summary(cell, condition, controller, seed)


def cell_summary(cell: Cell, condition: str, controller: str, seed: int) -> dict:
    """summary.json's entry of one controller under one condition: the bounded share with its Wilson 95 %
    interval (also per PFC), nearest-rank percentiles (a diverged run's +inf stays +inf: null in JSON), the worst
    run and the commands that replay it."""
    if cell is None or not cell.runs:
        return {}
    out: dict = {
        "runs": cell.runs,
        "bounded_share": cell.bounded / cell.runs,
        "bounded_ci95": wilson(cell.bounded, cell.runs),
        "bounded_share_by_pfc": {},
        # the runs out of the envelope by tracking (autopilot.envelope.window_flags), in any 20 s window
        "oscillating_share": cell.oscillating / cell.runs,
        "not_following_share": cell.not_following / cell.runs,
        "bounded_ci95_by_pfc": {},
        "p50": {m: _finite(cell.samples[m].percentile(50)) for m in METRICS},
        "p95": {m: _finite(cell.samples[m].percentile(95)) for m in METRICS},
    }
    for pfc, (n, k) in cell.by_pfc.items():
        if n and get_controller(controller).adaptive:  # the baseline has no PFC
            out["bounded_share_by_pfc"][pfc] = k / n
            out["bounded_ci95_by_pfc"][pfc] = wilson(k, n)
    _key, i, worst = cell.worst
    out["worst"] = {
        "run": i,
        "seed": seed,
        "bounded": worst["bounded"],
        "pfc": worst["pfc"],
        "metrics": {m: _finite(worst[m]) for m in METRICS},
        "draws": worst["draws"],
        "replay_inprocess": replay_command(controller, condition, seed, i),
        "replay_mavlink": mavlink_command(controller, condition, seed, i, worst),
    }
    return out


def _finite(x: float):
    return x if math.isfinite(x) else None


def replay_command(controller: str, condition: str, seed: int, run: int) -> str:
    return (
        f"python -m tools.experiment replay --controller {controller} --condition {condition} --seed {seed} --run {run}"
    )


def mavlink_command(controller: str, condition: str, seed: int, run: int, rec: dict, duration: float = 30.0) -> str:
    """The same run as one lockstep flight over MAVLink (``python -m tools.launch``, the SITL's disturbance flags):
    the same plant, PFC, gust, crosswind, bias, delay, loss and turbulence intensity; the SITL draws its own noise
    sequences from --seed, so the flight is an equivalent replay, not a bit-identical one."""
    from sitl.atmosphere import DrydenConfig
    from sitl.uncertainty import SCALE_NAMES

    ctrl = get_controller(controller)
    cond = get_condition(condition)
    d = rec["draws"]
    argv = ["python -m tools.launch --lockstep", f"--duration {duration:g}"]
    if not ctrl.adaptive:
        argv.append(f"--controller {ctrl.law}")
    else:
        argv += [f"--controller {'sac' if ctrl.lv == 0 else 'clsac'}", f"--lv {ctrl.lv:g}", f"--pfc {rec['pfc']}"]
        changes = dict(ctrl.changes)
        if "sigma_x" in changes:
            argv.append(f"--sigma-xu {changes['sigma_x']:g}")
        if "dead_zone_rad" in changes:
            argv.append(f"--dead-zone-deg {changes['dead_zone_rad'] / DEG:.6g}")
        if "ki_max" in changes:
            argv.append(f"--ki-max {changes['ki_max']:g}")
        if changes.get("freeze_when_saturated"):
            argv.append("--freeze-when-saturated")
    for name, f in zip(SCALE_NAMES, d["scales"]):
        if f != 1.0:
            argv.append(f"--scale {name}={f:.6g}")
    if cond.turbulence:
        sev = DrydenConfig.intensity("severe")
        argv.append(f"--turbulence-sigma {sev.sigma_v * cond.turbulence:.6g},{sev.sigma_w * cond.turbulence:.6g}")
    if d["gust_amplitude_m_s"]:
        argv.append(f"--gust {d['gust_amplitude_m_s']:.6g},{d['gust_length_m']:.6g},{d['gust_start_s']:.6g}")
    if d["crosswind_m_s"]:
        argv.append(f"--crosswind {d['crosswind_m_s']:.6g}")
    if cond.roll_noise:
        argv.append(f"--roll-noise {cond.roll_noise / DEG:.6g}")
    if d["roll_bias_rad"]:
        argv.append(f"--roll-bias {d['roll_bias_rad'] / DEG:.6g}")
    if cond.delay:
        argv.append(f"--sensor-delay {cond.delay}")
    if cond.loss:
        argv.append(f"--loss {cond.loss:g}")
    argv.append(f"--seed {seed * 1_000_000 + run}")
    return " ".join(argv)


LONG_CONTROLLERS = ("clsac", "clsac_leak", "clsac_deadzone", "clsac_projection", "clsac_freeze", "baseline")


LONG_DURATION_S = 600.0


LONG_CONDITIONS = ("nominal", "moderate")


def long_flight_summary(records: dict[tuple[str, int], dict], condition: str) -> dict:
    """The drift of a 600 s flight from per-run records (``merge``): see ``long_cell_summary``."""
    rs = [r for (c, _), r in records.items() if c == condition]
    if not rs:
        return {}
    cell = LongCell(exact=True, windows=len(rs[0]["window_peak_roll"]))
    cell.add(records_batch(rs), np.arange(len(rs)))
    return long_cell_summary(cell)


def long_cell_summary(cell: LongCell | None) -> dict:
    """The drift of a 600 s flight: median peak |roll| (deg) of each 30 s window, per PFC."""
    out = {}
    for pfc in ("paper", "robust"):
        d = None if cell is None else cell.by_pfc.get(pfc)
        if not d:
            continue
        med = cell.medians(pfc)
        out[pfc] = {
            "runs": d["runs"],
            "bounded_share": d["bounded"] / d["runs"],
            "bounded_ci95": wilson(d["bounded"], d["runs"]),
            "median_window_peak_roll_deg": [_finite(round(float(v), 3)) for v in med],
            "peak_first_window_deg": _finite(float(med[0])),
            "peak_180_210_s_deg": _finite(float(med[6])) if len(med) > 6 else None,
            "peak_last_window_deg": _finite(float(med[-1])),
            "first_window_over_60_deg_s": next((WINDOW_S * (j + 1) for j, v in enumerate(med) if v >= 60.0), None),
        }
    return out


def breaks(summary: dict, share: float = 0.9) -> dict:
    """Per controller and sweep: the smallest swept value at which fewer than ``share`` of the runs stay bounded
    (None: bounded at every value tried), over all runs and per PFC (``by_pfc``)."""
    out: dict = {}
    for ctrl, by_cond in summary["results"].items():
        out[ctrl] = {"by_pfc": {"paper": {}, "robust": {}}}
        for label, (_field, values) in SWEEPS.items():
            aggs = [(v, by_cond.get(f"{label}={v:.3g}")) for v in values]
            aggs = [(v, a) for v, a in aggs if a]
            if not aggs:
                continue
            out[ctrl][label] = next((v for v, a in aggs if a["bounded_share"] < share), None)
            for pfc in ("paper", "robust"):
                if all(pfc in a["bounded_share_by_pfc"] for _, a in aggs):
                    out[ctrl]["by_pfc"][pfc][label] = next(
                        (v for v, a in aggs if a["bounded_share_by_pfc"][pfc] < share), None
                    )
    return out
