"""The controller's command-line flags, shared by ``python -m autopilot`` and ``python -m tools.launch``."""

from __future__ import annotations

import argparse
import math

from autopilot import controllers
from autopilot.params import arg_type
from autopilot.shared.cli import bounded, nonneg_float, positive_float

CONTROLLERS = controllers.NAMES  # the registry's (autopilot.controllers); baseline: the fixed-gain PID
PFC_CHOICES = ("paper", "robust")  # the keys of autopilot.config.PFC_PRESETS (spelled out: --help needs no numpy)
SURFACES = ("rudder", "aileron")  # the surfaces a plant's command drives (sitl.plant.surface_of)
DEG = math.pi / 180.0
# The flags' types come from the parameter table (autopilot.params.PARAMS): one set of bounds for a flag, a
# parameter file and PARAM_SET.
lv_arg = arg_type("CLSAC_LV")
sigma_xu_arg = arg_type("CLSAC_SIGMA_X")  # --sigma-xu sets CLSAC_SIGMA_X and CLSAC_SIGMA_U (same bounds)
u_limit_deg_arg = arg_type("CLSAC_U_LIMIT", DEG, "deg")
rate_arg = arg_type("CLSAC_RATE")


def default_lv(controller: str) -> float:
    """L_v of a named controller: 0 for SAC (paper sec. 2), 20 for CL-SAC (paper sec. 5), 0 for the baseline (no
    reference-model feedback): ``autopilot.controllers.CONTROLLERS``."""
    return controllers.get(controller).lv


def controller_arg(text: str) -> str:
    """``--controller``: a registered name, ``FILE.py:Class``, ``module:Class`` or an installed law (the entry-point
    group ``clsac_autopilot.laws``), loaded and checked here (``autopilot.law``): one line naming what is missing."""
    try:
        return controllers.get(str(text)).name
    except ValueError as exc:  # autopilot.law.LawSpecError is one
        raise argparse.ArgumentTypeError(str(exc)) from None


def baseline_gains(text: str) -> tuple[float, ...]:
    """``KP,KI,KD[,KFF]``: three finite numbers (rad/rad, 1/s, s), the fixed-gain baseline's PID gains, and for
    pid-ff optionally a fourth, its feed-forward K_FF (s)."""
    try:
        values = tuple(float(v) for v in str(text).split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected KP,KI,KD (three numbers), got {text!r}") from None
    if len(values) not in (3, 4) or not all(v == v and abs(v) != float("inf") for v in values):
        raise argparse.ArgumentTypeError(f"expected KP,KI,KD[,KFF] (three or four finite numbers), got {text!r}")
    return values


def add_controller_arguments(parser: argparse.ArgumentParser) -> None:
    """``--controller``, ``--lv``, ``--pfc``, ``--sigma-xu``, ``--u-limit-deg``."""
    g = parser.add_argument_group("controller")
    g.add_argument(
        "--controller",
        type=controller_arg,
        default=controllers.DEFAULT,
        metavar="NAME|FILE.py:Class|module:Class",
        help=", ".join(c.help for c in controllers.CONTROLLERS.values() if c.help)
        + "; or a law of your own: FILE.py:Class, module:Class or an installed clsac_autopilot.laws entry point "
        "(docs/adding-a-law.md)",
    )
    g.add_argument(
        "--lv",
        type=lv_arg,
        default=None,
        help="override the closed-loop reference gain Lv (default: "
        + ", ".join(f"{c.lv:g} for {c.name}" for c in controllers.CONTROLLERS.values() if c.adaptive)
        + ")",
    )
    g.add_argument(
        "--pfc",
        choices=PFC_CHOICES,
        default=None,
        help="parallel feedforward compensator: paper = 10/(4s+40) (default), robust = 10/(s+10)",
    )
    g.add_argument(
        "--sigma-xu",
        type=sigma_xu_arg,
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
    g.add_argument("--u-limit-deg", type=u_limit_deg_arg, default=30.0, help="rudder command limit (default 30)")
    g.add_argument(
        "--baseline-gains",
        type=baseline_gains,
        default=None,
        metavar="KP,KI,KD[,KFF]",
        help="the baseline's PID gains (default 0.1,0.1,0.02, tuned on the KH2013A; python -m tools.pfc design "
        "tunes them for another plant); pid-ff also takes its feed-forward KFF (s, default the plant's "
        "roll-mode -L_p/L_delta)",
    )


# The options only an adaptive law reads (SAC, CL-SAC), each with the value that means "not given" or "off".
ADAPTIVE_ONLY = {
    "lv": None,
    "pfc": None,
    "sigma_xu": 0.0,
    "dead_zone_deg": 0.0,
    "ki_max": None,
    "freeze_when_saturated": False,
}


def value_text(value) -> str:
    """A flag's value as typed after it (with its leading blank): `` 50``, `` 1,0.1,0.2``; nothing for a switch."""
    if value is True:
        return ""
    if isinstance(value, tuple):
        return " " + ",".join(f"{v:g}" for v in value)
    return f" {value:g}" if isinstance(value, float) else f" {value}"


def flag_text(key: str, value) -> str:
    """The flag of keyword ``key`` with its value, as typed: ``--lv 50``, ``--freeze-when-saturated``."""
    return "--" + key.replace("_", "-") + value_text(value)


def inapplicable(controller: str, given: dict) -> tuple[str, str] | None:
    """The first option in ``given`` (keyword -> value, as the flags' dests) that ``controller`` would not fly,
    with why: (keyword, reason), None if all apply.  An option left at its "not given" value always applies."""
    c = controllers.get(controller)
    if c.adaptive:
        if given.get("baseline_gains") is not None:
            return "baseline_gains", f"{c.name} is adaptive: the PID's gains are the baseline's (--controller baseline)"
        lv = given.get("lv")
        if c.lv_fixed is not None and lv is not None and lv != c.lv_fixed:
            return "lv", (
                f"{c.name} flies Lv = {c.lv_fixed:g} whatever --lv says (paper sec. 2); for Lv = {lv:g} fly "
                f"--controller clsac --lv {lv:g}"
            )
        return None
    if c.kind.generic and given.get("baseline_gains") is not None:
        return "baseline_gains", f"{c.name} is not a PID: its values are its own parameters (--params FILE)"
    for key, off in ADAPTIVE_ONLY.items():
        value = given.get(key, off)
        if value != off and not (key == "lv" and value == 0.0):
            return key, f"for sac and clsac only: {c.name} is a {c.label} (no PFC, adaptation or Lv)"
    return None


# The envelope's limits on the command line (autopilot.envelope.Envelope takes the share as a fraction).
envelope_roll_deg = bounded(0.0, 180.0, "deg", lo_open=True, name="envelope_roll_deg")
envelope_saturated_pct = bounded(0.0, 100.0, "%", lo_open=True, name="envelope_saturated_pct")


def add_envelope_arguments(parser: argparse.ArgumentParser) -> None:
    """``--envelope-roll``, ``--envelope-saturated``, ``--no-envelope``: the limits of a controlled flight."""
    from autopilot.envelope import MAX_ROLL_DEG, MAX_SATURATED_SHARE

    g = parser.add_argument_group("flight envelope (a flight is controlled inside it; docs/flying.md, Outcomes)")
    g.add_argument(
        "--envelope-roll",
        type=envelope_roll_deg,
        default=MAX_ROLL_DEG,
        metavar="DEG",
        help=f"controlled only while |roll| < DEG (default {MAX_ROLL_DEG:g})",
    )
    g.add_argument(
        "--envelope-saturated",
        type=envelope_saturated_pct,
        default=100.0 * MAX_SATURATED_SHARE,
        metavar="PCT",
        help=f"controlled only if the rudder command sat at its limit in < PCT %% of the control steps "
        f"(default {100.0 * MAX_SATURATED_SHARE:g})",
    )
    g.add_argument(
        "--no-envelope",
        dest="envelope",
        action="store_false",
        help="do not judge the flight against the envelope (its numbers are still measured and reported)",
    )


def add_surface_argument(parser: argparse.ArgumentParser) -> None:
    """``--surface``: the surface the command drives, as the autopilot's verdict and messages name it."""
    parser.add_argument(
        "--surface",
        choices=SURFACES,
        default=SURFACES[0],
        help="the control surface the command drives, as the verdict and the messages name it (default rudder, the "
        "KH2013A's; the launcher gives the plant's)",
    )


def envelope_from_args(args: argparse.Namespace):
    """The ``autopilot.envelope.Envelope`` of the parsed envelope flags."""
    from autopilot.envelope import Envelope

    return Envelope(
        args.envelope_roll,
        args.envelope_saturated / 100.0,
        check=args.envelope,
        surface=getattr(args, "surface", SURFACES[0]),
    )
