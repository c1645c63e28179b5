"""``python -m tools.pfc``: the W-ASPR analysis of the plant with its parallel feedforward compensator.

Thin command line over ``tools.design`` (flags and JSON keys: docs/spec.md, "Command lines").  Prints
the transfer functions T(s) and F(s) = T(s) + D(s), the W-ASPR conditions of F, the bands of constant
K_e > 0 for which 1 + K_e F is unstable (continuous time, and sampled with a zero-order hold at the control
rate) and the steady-state error the PFC adds; ``--closed-loop`` also flies the paper scenario in-process.
``--json`` prints one JSON object instead.  ``python -m tools.pfc design PLANT`` designs a PFC for another plant
(``tools.design.params_file``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

from autopilot import flags
from autopilot.shared.cli import OneLineArgumentParser, angle_deg
from tools import design as analysis

EPILOG = """\
design: python -m tools.pfc design PLANT [--out FILE.params] designs a PFC, the adaptation weights and a baseline
PID for another plant (FILE.toml or jsbsim:MODEL[:KEY=VALUE,...]) and writes them where the launcher finds them
(python -m tools.pfc design --help; docs/plants.md).  A square MIMO plant (jsbsim:MODEL:surface=aileron+rudder, a
plant file of m inputs) gets a PFC per channel, its transmission zeros, K_e bands along rays and two PIDs
(docs/spec.md, "Square MIMO CL-SAC").

coefficients are comma-separated, highest power first: --pfc-num 10 --pfc-den 4,40 is 10/(4s + 40).
A list starting with a minus sign needs the = form: --pfc-den=-1,-2 (which is then rejected as unstable).

JSON keys (docs/spec.md, "Command lines"): minimum_phase, relative_degree, hf_gain, unstable_gain_bands
(the answer: each band of Ke > 0 making 1 + Ke F unstable, with the crossing frequencies in rad/s; empty
if none; a null high means the band extends to infinity), unstable_gain_bands_hull ([first low, last
high]: a hull that also covers any stable window between bands, or null), waspr, plant/pfc/F numerators
and denominators, zeros, poles, steady_state_error_deg, compensator_gain_margin, discrete (the same bands
for the ZOH-sampled loop at --rate-hz), clsac_kx (bands of -Kx and +Kx destabilising CL-SAC's
reference-model feedback at --lv), notes and, with --closed-loop, closed_loop (the paper scenario's
metrics per run).

exit status: 0 on success, 2 on bad input (one-line reason on stderr), 1 if the analysis fails.
"""


def build_parser() -> argparse.ArgumentParser:
    from sitl.plant_kinds import KINDS

    p = OneLineArgumentParser(
        prog="python -m tools.pfc",
        usage="python -m tools.pfc [options]\n       python -m tools.pfc design PLANT [--out FILE.params] [options]",
        description="W-ASPR analysis of the KH2013A roll plant with a parallel feedforward compensator "
        "(Jana & Bhat 2017, sections 2 and 5);\n'design PLANT' designs one for another plant.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.add_argument(
        "--pfc",
        choices=sorted(analysis.PFC_PRESETS),
        default=None,
        help="a named PFC: paper = 10/(4s+40) (the default), robust = 10/(s+10) (no unstable Ke band)",
    )
    p.add_argument("--pfc-num", metavar="LIST", help="numerator of a custom PFC D(s) (needs --pfc-den)")
    p.add_argument("--pfc-den", metavar="LIST", help="denominator of a custom PFC D(s) (needs --pfc-num)")
    p.add_argument(
        "--command-deg",
        type=angle_deg,
        default=10.0,
        metavar="DEG",
        help="steady roll command for the steady-state error the PFC adds (default 10, the paper scenario)",
    )
    p.add_argument(
        "--rate-hz",
        type=flags.rate_arg,  # the parameter table's bounds (autopilot.params.PARAMS), as the flying commands
        default=100.0,
        metavar="HZ",
        help="control rate for the sampled-loop (ZOH) analysis (default 100, the paper scenario)",
    )
    p.add_argument(
        "--lv",
        type=flags.lv_arg,
        default=20.0,
        metavar="LV",
        help="CL-SAC Lv for the reference-model feedback loop through Kx (default 20, the paper's)",
    )
    p.add_argument(
        "--plant",
        default=None,
        metavar="FILE.toml",
        help=f"analyse {KINDS['file'].words} (sitl.linear_plant) instead of the KH2013A",  # sitl.plant_kinds
    )
    p.add_argument(
        "--closed-loop",
        action="store_true",
        help="also fly the paper scenario's five runs in-process with this PFC and report their metrics",
    )
    return p


def _select_pfc(args, parser) -> tuple[str, tuple, tuple]:
    custom = args.pfc_num is not None or args.pfc_den is not None
    if custom and args.pfc is not None:
        parser.error(f"--pfc {args.pfc} and --pfc-num/--pfc-den are mutually exclusive")
    if not custom:
        name = args.pfc or "paper"
        num, den = analysis.PFC_PRESETS[name]
        return name, num, den
    if args.pfc_num is None:
        parser.error(f"--pfc-den {args.pfc_den!r} given without --pfc-num")
    if args.pfc_den is None:
        parser.error(f"--pfc-num {args.pfc_num!r} given without --pfc-den")
    num = analysis.parse_coefficients(args.pfc_num, "--pfc-num")
    den = analysis.parse_coefficients(args.pfc_den, "--pfc-den")
    analysis.validate_pfc(num, den, names=("--pfc-num", "--pfc-den"))
    for name, (pnum, pden) in analysis.PFC_PRESETS.items():
        if _same_tf(num, den, pnum, pden):
            return name, num, den
    return "custom", num, den


def _same_tf(n1, d1, n2, d2) -> bool:
    """Equal as rational functions (cross-multiplied polynomials agree)."""
    a = np.polymul(np.trim_zeros(np.asarray(n1, float), "f"), np.asarray(d2, float))
    b = np.polymul(np.trim_zeros(np.asarray(n2, float), "f"), np.asarray(d1, float))
    a, b = np.trim_zeros(a, "f"), np.trim_zeros(b, "f")
    return a.shape == b.shape and bool(np.allclose(a, b, rtol=1e-12, atol=0.0))


# ----------------------------------------------------------------------------- text output
def _poly_str(c, var: str = "s") -> str:
    c = np.asarray(c, dtype=float)
    deg = c.size - 1
    terms = []
    for i, v in enumerate(c):
        p = deg - i
        if v == 0.0:
            continue
        mag = f"{abs(v):.6g}"
        mon = "" if p == 0 else (var if p == 1 else f"{var}^{p}")
        body = mag if not mon else (mon if mag == "1" else f"{mag} {mon}")
        sign = "-" if v < 0 else "+"
        terms.append((sign, body))
    if not terms:
        return "0"
    first = ("-" if terms[0][0] == "-" else "") + terms[0][1]
    return " ".join([first] + [f"{s} {b}" for s, b in terms[1:]])


def _roots_str(zs) -> str:
    parts = []
    for z in zs:
        z = complex(z)
        if z.imag < 0:
            continue  # print a conjugate pair once, as a +- b j
        parts.append(f"{z.real:.6g}" if z.imag == 0 else f"{z.real:.6g} +- {z.imag:.6g}j")
    return ", ".join(parts) if parts else "none"


def _bands_str(bands, gain: str = "Ke") -> str:
    if not bands:
        return f"none (stable for every {gain} > 0)"
    out = []
    for b in bands:
        hi = "inf" if math.isinf(b.high) else f"{b.high:.10g}"
        w = []
        if b.omega_low is not None:
            w.append(f"w = {b.omega_low:.6g} rad/s at {b.low:.6g}")
        if b.omega_high is not None:
            w.append(f"w = {b.omega_high:.6g} rad/s at {b.high:.6g}")
        out.append(f"[{b.low:.10g}, {hi}]" + (f"  (crossing {'; '.join(w)})" if w else ""))
    return ("\n" + " " * 4).join(out)


def format_text(rep: analysis.WasprReport, cl: list[dict] | None = None, plant_name: str = "KH2013A") -> str:
    ss = rep.steady_state
    g = rep.compensator_gain_margin
    lines = [
        f"W-ASPR analysis, {plant_name} roll (Jana & Bhat 2017, sections 2 and 5)",
        "",
        "plant T(s) = C_p (sI - A_p)^-1 B_p = num/den",
        f"  num = {_poly_str(rep.plant_num)}",
        f"  den = {_poly_str(rep.plant_den)}",
        f"  zeros: {_roots_str(rep.plant_zeros)}",
        f"  poles: {_roots_str(rep.plant_poles)}",
        f"  DC gain T(0) = {rep.plant_dc_gain:.6g}",
        "",
        f"PFC D(s) [{rep.pfc_name}] = ({_poly_str(rep.pfc_num)}) / ({_poly_str(rep.pfc_den)}),"
        f"  D(0) = {rep.pfc_dc_gain:.6g}",
        "  C = 1/D gain margin in feedback with T: "
        + (
            "none (1 + C T unstable)"
            if g is None
            else "unlimited"
            if math.isinf(g)
            else f"{g:.6g} ({20 * math.log10(g):.2f} dB)"
        ),
        "",
        "augmented plant F(s) = T(s) + D(s) = num_F/den_F",
        f"  num_F = {_poly_str(rep.f_num)}",
        f"  den_F = {_poly_str(rep.f_den)}",
        f"  zeros: {_roots_str(rep.zeros)}",
        f"  poles: {_roots_str(rep.poles)}",
        "",
        "W-ASPR conditions of F (paper section 2)",
        f"  minimum phase:       {'yes' if rep.minimum_phase else 'NO'}",
        f"  relative degree:     {rep.relative_degree}",
        f"  high-frequency gain: {rep.hf_gain:.6g}",
        f"  W-ASPR:              {'yes' if rep.waspr else 'NO'}",
        "",
        "constant Ke > 0 for which 1 + Ke F(s) is unstable:",
        f"    {_bands_str(rep.bands)}",
    ]
    if rep.bands_discrete is not None:
        lines += [
            f"the same loop sampled at {rep.rate_hz:g} Hz with a zero-order hold (1 + Ke F_zoh(z)):",
            f"    {_bands_str(rep.bands_discrete)}",
        ]
    lines += [
        f"CL-SAC, Lv = {rep.lv:g}: y_a fed back through the reference model and Kx (Ke = 0), unstable for",
        f"  -Kx in {_bands_str(rep.kx_bands.get('minus_kx', []), 'Kx')}",
        f"  +Kx in {_bands_str(rep.kx_bands.get('kx', []), 'Kx')}",
    ]
    lines += [
        "",
        f"steady-state error the PFC adds at a {math.degrees(ss['command']):.6g} deg command "
        f"(y_a = y_m = command, y_p = y_a - D(0) u): {math.degrees(ss['offset']):.6g} deg",
        "",
        "notes:",
    ]
    lines += [f"  - {n}" for n in rep.notes]
    if cl is not None:
        lines += [
            "",
            "paper scenario in-process with this PFC:",
            f"  {'run':<12} {'Lv':>5} {'ise_ref':>10} {'ise_crm':>10} {'energy':>10} {'tv':>9} "
            f"{'max_abs_u':>9} {'Ke max':>8}",
        ]
        for r in cl:
            m = r["metrics"]
            lines.append(
                f"  {r['name']:<12} {r['Lv']:>5g} {m['ise_ref']:>10.5g} {m['ise_crm']:>10.5g} {m['energy']:>10.5g} "
                f"{m['tv']:>9.5g} {m['max_abs_u']:>9.4g} {r['ke_max']:>8.4g}"
            )
    return "\n".join(lines)


def _plant(args, parser):
    """(A_p, B_p, C_p) of --plant FILE.toml and its name, or (None, "KH2013A")."""
    from sitl import plant as plants

    if args.plant is None or plants.kind_of(args.plant).paper:
        return None, "KH2013A"
    if args.closed_loop:
        parser.error("--closed-loop flies the KH2013A paper scenario: not with --plant")
    from sitl.linear_plant import PlantFileError, load

    try:
        lp = load(args.plant)
    except PlantFileError as exc:
        parser.error(str(exc))
    mats = (lp.a_p, lp.b_p, lp.c_p)
    if not lp.is_mimo:  # a surface that cannot move the plant (B = 1e-300): said as the design says it, exit 2
        from tools import design as analysis
        from tools.design.tuning import check_authority
        from tools.experiment.scenario import PAPER

        tn, td = analysis.tf_coefficients(analysis.plant_tf(mats))
        u_limit = lp.limit_rad if lp.limit_rad is not None else math.radians(30.0)
        try:
            check_authority(tn, td, u_limit, PAPER.profile.amplitude, PAPER.profile.period)
        except analysis.AnalysisError as exc:
            parser.error(f"--plant {args.plant}: {exc}")
    return mats, lp.name


# ----------------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["design"]:  # a PFC (and a baseline) designed for a plant: tools.design.params_file
        from tools.design.params_file import main as design_main

        return design_main(argv[1:])
    parser = build_parser()
    args = parser.parse_args(argv)
    name = None
    try:
        name, num, den = _select_pfc(args, parser)
        if not math.isfinite(args.command_deg):
            parser.error(f"--command-deg must be finite, got {args.command_deg!r}")
        if not (math.isfinite(args.rate_hz) and args.rate_hz > 0):
            parser.error(f"--rate-hz must be positive and finite, got {args.rate_hz!r}")
        if not (math.isfinite(args.lv) and args.lv >= 0):
            parser.error(f"--lv must be finite and >= 0, got {args.lv!r}")
        mats, plant_name = _plant(args, parser)
        rep = analysis.analyse(
            num,
            den,
            command_rad=math.radians(args.command_deg),
            rate_hz=args.rate_hz,
            lv=args.lv,
            pfc_name=name,
            plant=mats,
        )
    except analysis.PfcError as exc:
        parser.error(str(exc))
    except analysis.AnalysisError as exc:  # the input's own numbers (a plant, a PFC) defeat the analysis: exit 2
        where = f"--plant {args.plant}" if args.plant not in (None, "kh2013a") else f"the PFC {name or ''}".rstrip()
        parser.error(f"{where} cannot be analysed: {exc}")
    cl = analysis.paper_scenario_runs(num, den) if args.closed_loop else None
    if args.json:
        d = rep.to_dict()
        if cl is not None:
            d["closed_loop"] = cl
        print(json.dumps(d, indent=2, allow_nan=False))
    else:
        print(format_text(rep, cl, plant_name))
    return 0


if __name__ == "__main__":
    sys.exit(main())
