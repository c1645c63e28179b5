"""The controller's command-line flags, shared by ``python -m autopilot`` and ``python -m tools.launch``."""

from __future__ import annotations

import argparse

from autopilot.shared.cli import gain, limit_deg, nonneg_float, positive_float

CONTROLLERS = ("sac", "clsac", "baseline")  # baseline: the fixed-gain PID of autopilot.baseline
PFC_CHOICES = ("paper", "robust")  # the keys of autopilot.config.PFC_PRESETS (spelled out: --help needs no numpy)


def default_lv(controller: str) -> float:
    """L_v of a named controller: 0 for SAC (paper sec. 2), 20 for CL-SAC (paper sec. 5)."""
    return 20.0 if controller == "clsac" else 0.0  # the baseline has no reference-model feedback


def baseline_gains(text: str) -> tuple[float, float, float]:
    """``KP,KI,KD``: three finite numbers (rad/rad, 1/s, s), the fixed-gain baseline's PID gains."""
    try:
        values = tuple(float(v) for v in str(text).split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected KP,KI,KD (three numbers), got {text!r}") from None
    if len(values) != 3 or not all(v == v and abs(v) != float("inf") for v in values):
        raise argparse.ArgumentTypeError(f"expected KP,KI,KD (three finite numbers), got {text!r}")
    return values


def add_controller_arguments(parser: argparse.ArgumentParser) -> None:
    """``--controller``, ``--lv``, ``--pfc``, ``--sigma-xu``, ``--u-limit-deg``."""
    g = parser.add_argument_group("controller")
    g.add_argument(
        "--controller",
        choices=CONTROLLERS,
        default="clsac",
        help="sac (Lv = 0), clsac (Lv = 20, the paper's; default) or baseline (fixed-gain PID; ignores --lv, "
        "--pfc, --sigma-xu)",
    )
    g.add_argument(
        "--lv",
        type=gain,
        default=None,
        help="override the closed-loop reference gain Lv (default: 0 for sac, 20 for clsac)",
    )
    g.add_argument(
        "--pfc",
        choices=PFC_CHOICES,
        default="paper",
        help="parallel feedforward compensator: paper = 10/(4s+40) (default), robust = 10/(s+10)",
    )
    g.add_argument(
        "--sigma-xu",
        type=gain,
        default=0.0,
        metavar="SIGMA",
        help="sigma-modification of K_Ix and K_Iu (default 0, the paper; 0.1 keeps long flights bounded)",
    )
    g.add_argument(
        "--dead-zone-deg",
        type=nonneg_float,
        default=0.0,
        metavar="DEG",
        help="robustness option: no integral adaptation while |e| <= this (default 0: off, the paper)",
    )
    g.add_argument(
        "--ki-max",
        type=positive_float,
        default=None,
        metavar="K",
        help="robustness option: project every integral gain onto [-K, K] (default: off, the paper)",
    )
    g.add_argument(
        "--freeze-when-saturated",
        action="store_true",
        help="robustness option: no integral adaptation while the rudder command saturates (default: off)",
    )
    g.add_argument("--u-limit-deg", type=limit_deg, default=30.0, help="rudder command limit (default 30)")
    g.add_argument(
        "--baseline-gains",
        type=baseline_gains,
        default=None,
        metavar="KP,KI,KD",
        help="the baseline's PID gains (default 0.1,0.1,0.02, tuned on the KH2013A; python -m tools.pfc design "
        "tunes them for another plant)",
    )
