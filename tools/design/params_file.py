"""``python -m tools.pfc design PLANT``: a PFC, adaptation weights and a fixed-gain baseline designed for a plant.

PLANT is a linear plant file (``sitl.linear_plant``), ``kh2013a``, or ``jsbsim:MODEL[:...]`` (linearised first with
``tools.plant``; the plant file is written beside the output as OUT.toml).  How each value is chosen:
``tools.design.tuning``.  Writes OUT, a parameter file ``python -m autopilot --params`` loads, with every
controller's values (SAC's and CL-SAC's PFC and adaptation weights, the baseline's PID gains ``PID_KP``,
``_KI``, ``_KD``: each controller flies its own) and the design story in its comments.  OUT defaults to where the
launcher finds a plant's design (``tools.design.linearise.design_path``: ``sitl/plants/jsbsim-MODEL.params``, or
FILE.params beside FILE.toml), so that ``python -m tools.launch --plant PLANT`` flies it; another file there is
refused, never overwritten.  The last line printed is the command that flies it.

exit status: 0 on success, 2 on bad input, a plant no PFC of the family makes W-ASPR, one the surface cannot move
enough or one whose numbers defeat the analysis (one line on stderr naming the reason), 130 on Ctrl-C.
"""

from __future__ import annotations

import math
import sys
import warnings
from pathlib import Path

import numpy as np

from autopilot.shared.cli import OneLineArgumentParser


def build_parser() -> OneLineArgumentParser:
    p = OneLineArgumentParser(prog="python -m tools.pfc design", description=__doc__.split("\n\n")[0])
    p.add_argument("plant", help="FILE.toml, kh2013a or jsbsim:MODEL[:KEY=VALUE,...]")
    p.add_argument(
        "--out",
        default=None,
        metavar="FILE.params",
        help="the parameter file to write (a jsbsim plant is linearised to FILE.toml beside it first; an existing "
        "FILE.toml that is another plant is refused, never overwritten)",
    )
    p.add_argument("--airspeed", type=float, default=None, metavar="KT", help="jsbsim: linearise at this airspeed")
    from tools.design.linearise import add_timeout_argument

    add_timeout_argument(p)
    p.add_argument("--rate-hz", type=float, default=100.0, metavar="HZ", help="control rate (default 100)")
    p.add_argument(
        "--margin", type=float, default=3.0, metavar="G", help="gain margin of C = 1/D on the plant (default 3)"
    )
    p.add_argument("--lv", type=float, default=20.0, metavar="LV", help="CL-SAC Lv for the Kx-loop bands (default 20)")
    return p


def _plant_file(args, parser) -> tuple[str, Path]:
    """(the plant file's path as text, the output path): a jsbsim spec is linearised to OUT.toml first."""
    from dataclasses import replace

    from sitl import plant as plants
    from tools.design.linearise import design_path, shown_path

    ps = plants.spec(args.plant)
    if ps.paper:  # the paper's aircraft: its plant file shipped
        text = str(plants.shipped("kh2013a.toml"))
        return text, Path(args.out or "kh2013a.params")
    plants.check(args.plant)
    if ps.linear is not None:  # a linear plant file: designed as it is
        out = Path(args.out or design_path(args.plant))
        _refuse_another(out, parser)
        return args.plant, out
    from tools.design.linearise import linearise_bounded, to_toml

    spec = ps.jsbsim  # a JSBSim aircraft: linearised first
    if args.airspeed is not None:
        if not (math.isfinite(args.airspeed) and args.airspeed > 0):
            parser.error(f"--airspeed must be positive and finite, got {args.airspeed!r}")
        spec = replace(spec, airspeed_kt=args.airspeed)
    out = Path(args.out or design_path(args.plant))
    _refuse_another(out, parser)
    toml = out.with_suffix(".toml")
    text = to_toml(spec, linearise_bounded(spec, args.timeout))
    if toml.exists() and toml.read_text(encoding="utf-8", errors="replace") != text:  # never a user's file silently
        parser.error(f"{toml} exists and is not this linearisation: remove it or give another --out")
    toml.write_text(text)
    print(f"linearised {spec.text()} -> {shown_path(toml)}")
    return shown_path(toml), out


def _refuse_another(out: Path, parser) -> None:
    """An existing OUT that is not a design of ``python -m tools.pfc design`` is never overwritten."""
    if out.exists() and not out.read_text(encoding="utf-8", errors="replace").startswith(HEADER):
        parser.error(f"{out} exists and is not a design of python -m tools.pfc design: remove it or give another --out")


HEADER = "# CL-SAC parameters designed for "  # the first line of a design (write_params)


def fly_command(plant: str, out: Path) -> str:
    """The launcher command that flies the design written to ``out`` (no --params where the launcher finds it)."""
    from tools.design.linearise import design_path, shown_path

    found = design_path(plant)
    given = "" if found is not None and Path(found).resolve() == Path(out).resolve() else f" --params {shown_path(out)}"
    return f"python -m tools.launch --lockstep --plant {plant}{given}"


def _bands(bands) -> str:
    if not bands:
        return "none"
    return ", ".join(f"[{b.low:.4g}, {'inf' if math.isinf(b.high) else f'{b.high:.4g}'}]" for b in bands)


def design_text(plant_text: str, rate_hz: float, margin: float, lv: float) -> tuple[list[str], dict]:
    """The design's report lines and the parameter values (name -> value, and 'baseline' -> (kp, ki, kd))."""
    from sitl.linear_plant import load
    from tools import design as analysis
    from tools.design.linearise import PID_PARAMS
    from tools.design.tuning import GAMMA_NAMES, check_authority, choose_gamma, design_baseline, design_pfc
    from tools.experiment.scenario import PAPER

    lp = load(plant_text)
    if lp.is_mimo:
        from tools.design.mimo_report import design_text_mimo

        return design_text_mimo(lp, plant_text, rate_hz, margin, lv)
    mats = (lp.a_p, lp.b_p, lp.c_p)
    u_limit = lp.limit_rad if lp.limit_rad is not None else math.radians(30.0)
    tn, td = analysis.tf_coefficients(analysis.plant_tf(mats))
    check_authority(tn, td, u_limit, PAPER.profile.amplitude, PAPER.profile.period)
    pfc = design_pfc(mats, rate_hz=rate_hz, margin=margin)
    rep = analysis.analyse(pfc.num, pfc.den, rate_hz=rate_hz, lv=lv, pfc_name="designed", plant=mats)
    gamma, rows = choose_gamma(plant_text, pfc.num, pfc.den, u_limit)
    base = design_baseline(mats, rate_hz=rate_hz)
    zeros = ", ".join(f"{z:.4g}" for z in rep.zeros)
    lines = [
        f"plant {lp.name} ({plant_text}): poles " + ", ".join(f"{z:.4g}" for z in np.linalg.eigvals(lp.a_p)),
        f"PFC D(s) = {pfc.k:.6g}/(s + {pfc.a:.6g}): {pfc.explain()}",
        f"F = T + D: zeros {zeros}; relative degree {rep.relative_degree}; high-frequency gain {rep.hf_gain:.6g}; "
        f"W-ASPR {'yes' if rep.waspr else 'NO'}",
        f"unstable Ke bands of 1 + Ke F: continuous {_bands(rep.bands)}; sampled at {rate_hz:g} Hz "
        f"{_bands(rep.bands_discrete)}",
        f"CL-SAC Lv = {lv:g} Kx loop: -Kx {_bands(rep.kx_bands['minus_kx'])}, +Kx {_bands(rep.kx_bands['kx'])}",
        f"adaptation weights Gamma = {gamma:g} (all six): CL-SAC ise_ref on the linear plant "
        + ", ".join(f"{r['gamma']:g}: {r['ise_ref']:.4g}{' (saturated)' if r['saturated'] else ''}" for r in rows),
        f"baseline PID K_p {base.kp:.4g}, K_i {base.ki:.4g} 1/s, K_d {base.kd:.4g} s: gain margin "
        f"{base.margins['gain_margin_db']:.1f} dB, phase margin {base.margins['phase_margin_deg']:.1f} deg at "
        f"{base.margins['gain_crossover_rad_s']:.3g} rad/s (python-control)",
    ]
    values = {"CLSAC_PFC_NUM": pfc.k, "CLSAC_PFC_DEN1": 1.0, "CLSAC_PFC_DEN0": pfc.a}
    values.update({f"CLSAC_GAM_{n.upper()}": gamma for n in GAMMA_NAMES})
    # the baseline's gains (its own parameters: SAC and CL-SAC do not fly them, nor it theirs); no CLSAC_U_LIMIT:
    # the command limit is the plant's surface stop, which the launcher gives every controller
    values.update(zip(PID_PARAMS, (base.kp, base.ki, base.kd)))
    return lines, values


def write_params(path: Path, plant_text: str, lines: list[str], values: dict, plant: str | None = None) -> None:
    text = [f"{HEADER}{plant_text} by python -m tools.pfc design"]
    text += [f"#   {line}" for line in lines]
    if any(n.startswith("CLSAC_PFC2") for n in values):
        text.append("# SAC and CL-SAC fly the CLSAC_PFC*_* and CLSAC_GAM_* values, the baseline the PID*_* ones")
    else:
        text.append("# SAC and CL-SAC fly the CLSAC_PFC_* and CLSAC_GAM_* values, the baseline the PID_* ones")
    if plant is not None:
        text.append(f"#   fly it: {fly_command(plant, path)} [--controller sac|clsac|baseline]")
    text += [f"{name:<16s} {float(v)!r}" for name, v in values.items()]
    path.write_text("\n".join(text) + "\n")


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from sitl.jsbsim_plant import JsbsimPlantError
    from sitl.plant import PlantError
    from tools.design import AnalysisError
    from tools.design.linearise import LinearisationError
    from tools.design.tuning import PfcDesignError

    for name in ("rate_hz", "margin"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v > (1.0 if name == "margin" else 0.0)):
            parser.error(f"--{name.replace('_', '-')} must be finite and > {1 if name == 'margin' else 0}, got {v!r}")
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):  # the reasons are the one line below, not these
            warnings.simplefilter("ignore")
            plant_text, out = _plant_file(args, parser)
            lines, values = design_text(plant_text, args.rate_hz, args.margin, args.lv)
    except (PlantError, PfcDesignError, JsbsimPlantError, LinearisationError) as exc:
        parser.error(str(exc))
    except AnalysisError as exc:  # the plant's numbers defeat the analysis: a property of the plant given
        parser.error(f"this plant cannot be analysed: {exc}")
    except KeyboardInterrupt:
        print(f"{parser.prog}: interrupted", file=sys.stderr)
        return 130
    try:
        write_params(out, plant_text, lines, values, args.plant)
    except OSError as exc:
        parser.error(f"--out {out}: {exc.strerror or exc}")
    _design_laws(plant_text, out, args.rate_hz)  # first: the last line is the command that flies the design
    print("\n".join(lines))
    print(f"wrote {out}; fly it (every controller: --controller sac, clsac or baseline):")
    print(fly_command(args.plant, out))
    return 0


def _design_laws(plant_text: str, out: Path, rate_hz: float) -> None:
    """The adaptive-law bench's gains for the same plant (``tools.design.laws``, its stated rules), written beside
    the design as ``OUT-laws.params`` (where the launcher finds them: ``linearise.designed_law_params``); a line per
    law: its gains written, or the reason it could not be designed."""
    from tools.design import laws

    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            designs = laws.design_plant(plant_text, rate_hz)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:  # a plant these rules cannot take
        designs = str(exc)
    if isinstance(designs, str):
        print(f"adaptive laws ({', '.join(laws.LAWS)}): not designed: {designs}")
        return
    path = out.with_name(out.stem + "-laws.params")
    text = [f"# adaptive-law bench designs for {plant_text} by python -m tools.pfc design", *laws.params_lines(designs)]
    try:
        path.write_text("\n".join(text) + "\n", encoding="utf-8")
    except OSError as exc:
        print(f"adaptive laws: could not write {path}: {exc.strerror or exc}")
        return
    for law in laws.LAWS:
        d = designs.get(law)
        print(f"{law}: " + (f"not designed: {d}" if isinstance(d, str) else f"gains in {path}"))
