"""``python -m tools.plant linearise jsbsim:MODEL --airspeed KT --out plant.toml``: a JSBSim aircraft's roll channel
as a linear plant file (``sitl.linear_plant``).

JSBSim's own linearisation (``jsbsim.FGLinearization``: A, B, C, D of its 13 states and 4 inputs, by central
differences at the trim point of ``sitl.jsbsim_plant.trimmed_fdm``) reduced to the lateral states the loop flies,
x = [beta, phi, p, r] (rad, rad, rad/s, rad/s), and the chosen surface's input, rescaled from JSBSim's normalised
command to radians (B_rad = sign B_norm / surface_max, the SITL's mapping: a positive command rolls right).  The
longitudinal states are left out: in the SITL the safety pilot holds them.  The servo of the file is the SITL's
(paper eq. (65) form), so flying the file and flying the JSBSim plant differ only by what the linearisation
leaves out.

Also: :func:`designed_params`, the parameter file designed for a plant (``python -m tools.pfc design``) that the
launcher gives the autopilot by default.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

LATERAL = ("Beta", "Phi", "P", "R")  # JSBSim's names of the states kept
STATES = ("beta", "phi", "p", "r")
UNITS = ("rad", "rad", "rad/s", "rad/s")
INPUTS = {"aileron": "DaCmd", "rudder": "DrCmd"}


class LinearisationError(RuntimeError):
    """JSBSim's linearisation did not give the states or inputs the roll channel needs."""


def design_path(plant: str) -> Path | None:
    """Where the design of ``plant`` is looked for (docs/plants.md, "Where a design is found"):
    ``sitl/plants/jsbsim-MODEL.params`` for ``jsbsim:MODEL[...]`` on the aileron (``jsbsim-MODEL-rudder.params`` on
    the rudder), ``FILE.params`` beside a plant ``FILE.toml``; None for kh2013a (the paper's values are its design).
    Any airspeed: a design is flown off its design point."""
    from sitl import plant as plants

    kind = plants.kind(plant)
    if kind == "jsbsim":
        from sitl.jsbsim_plant import parse_spec

        spec = parse_spec(plant)
        suffix = "" if spec.surface == "aileron" else f"-{spec.surface}"
        return plants.shipped(f"jsbsim-{spec.model}{suffix}.params")
    if kind == "file":
        return Path(plant).with_suffix(".params")
    return None


def designed_params(plant: str) -> Path | None:
    """The parameter file designed for ``plant`` (``python -m tools.pfc design``), found where ``design_path`` says;
    None if there is none (and for kh2013a: the paper's defaults)."""
    path = design_path(plant)
    return path if path is not None and path.is_file() else None


def shown_path(path: Path) -> str:
    """``path`` as a command line shows it: relative to the working folder when inside it."""
    try:
        return str(Path(path).resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def design_command(plant: str) -> str:
    """The command that designs ``plant`` into the file the launcher finds."""
    return f"python -m tools.pfc design {plant} --out {shown_path(design_path(plant))}"


PID_PARAMS = ("CLSAC_PID_KP", "CLSAC_PID_KI", "CLSAC_PID_KD")  # the baseline's gains in a parameter file
PFC_PARAMS = ("CLSAC_PFC_NUM", "CLSAC_PFC_DEN1", "CLSAC_PFC_DEN0")  # SAC's and CL-SAC's PFC


def designed_baseline(plant: str) -> tuple[float, float, float] | None:
    """The baseline gains designed for ``plant`` (``CLSAC_PID_KP``, ``_KI``, ``_KD`` of its designed parameter file,
    written by ``python -m tools.pfc design``), or None."""
    path = designed_params(plant)
    if path is None:
        return None
    from autopilot.params import load_file

    values = load_file(path)
    if not all(n in values for n in PID_PARAMS):
        return None
    kp, ki, kd = (values[n] for n in PID_PARAMS)
    return kp, ki, kd


def linearise(spec, physics_rate_hz: float = 1000.0) -> dict:
    """The roll channel of a trimmed JSBSim model: {"A", "B", "C", "trim", ...} (SI, input in rad)."""
    import jsbsim

    from sitl.jsbsim_plant import SURFACE_SIGN, SURFACES, trimmed_fdm

    fdm = trimmed_fdm(spec, 1.0 / physics_rate_hz)
    surface = spec.surface_map  # the model's command -> deflection, as the SITL maps it
    lin = jsbsim.FGLinearization(fdm)
    x_names, u_names = list(lin.x_names), list(lin.u_names)
    missing = [n for n in (*LATERAL, INPUTS[spec.surface]) if n not in x_names + u_names]
    if missing:
        raise LinearisationError(f"JSBSim's linearisation of {spec.model} has no {', '.join(missing)}")
    idx = [x_names.index(n) for n in LATERAL]
    a_full, b_full = np.array(lin.system_matrix), np.array(lin.input_matrix)
    a = a_full[np.ix_(idx, idx)]
    # as the SITL maps the command: positive rolls right, in rad of deflection (the model's slope at the trim)
    sign, slope = SURFACE_SIGN[spec.surface], surface.slope(float(fdm[SURFACES[spec.surface]]))
    b = sign * b_full[idx, u_names.index(INPUTS[spec.surface])].reshape(-1, 1) / slope
    c = np.zeros((1, 4))
    c[0, STATES.index("phi")] = 1.0
    return {
        "A": a,
        "B": b,
        "C": c,
        "surface": surface,
        "trim": {
            "airspeed_kt": spec.airspeed_kt,
            "altitude_m": spec.altitude_m,
            "phi": float(fdm["attitude/phi-rad"]),
            "theta": float(fdm["attitude/theta-rad"]),
        },
    }


def _actuator_lines(surface) -> list[str]:
    """The model's actuator in the plant file: its rate limit as ``rate_limit``; what a linear file cannot carry (the
    hysteresis, an asymmetric travel) as comments."""
    if surface is None:
        return []
    lines = [f"# {surface.describe()}"]
    if surface.rate_limit_rad_s is not None:
        lines.append(f"rate_limit = {surface.rate_limit_rad_s!r}  # rad/s, the model's actuator")
    if surface.hysteresis_rad > 1e-9:
        lines.append(
            f"# not carried: the actuator's hysteresis (backlash) of {surface.hysteresis_rad:.4g} rad, a dead band no "
            "linear plant has (docs/jsbsim.md)"
        )
    if not surface.symmetric:
        lines.append("# not carried: the travel's other side (the file's limit is the smaller one)")
    return lines


def _row(v) -> str:
    return "[" + ", ".join(repr(float(x)) for x in v) + "]"


def to_toml(spec, lin: dict) -> str:
    """The plant file text (``sitl.linear_plant`` format) of a linearisation."""
    from sitl import model

    a, b, c = lin["A"], lin["B"], lin["C"]
    trim = lin["trim"]
    lines = [
        f"# {spec.model} roll channel, linearised by JSBSim (FGLinearization) at the trim point of {spec.text()}",
        "# (python -m tools.plant linearise).  States [beta, phi, p, r]; the input is the surface deflection in rad.",
        f'name = "{spec.model}-{spec.airspeed_kt:g}kt"',
        f'source = "{spec.text()}"',
        "",
        "[input]",
        f'name = "delta_{spec.surface[0]}"',
        'unit = "rad"',
        f'surface = "{spec.surface}"',
        f"limit = {spec.surface_max_rad!r}  # JSBSim's normalised command saturates at +-1",
        *_actuator_lines(lin.get("surface")),
        "",
        "[output]",
        'name = "phi"',
        'unit = "rad"',
        "",
        "[airframe]",
        "states = [" + ", ".join(f'"{s}"' for s in STATES) + "]",
        "units = [" + ", ".join(f'"{u}"' for u in UNITS) + "]",
        "A = [\n" + "".join(f"    {_row(r)},\n" for r in a) + "]",
        "B = [" + ", ".join(f"[{float(v)!r}]" for v in b[:, 0]) + "]",
        "C = [" + _row(c[0]) + "]",
        'roll = "phi"',
        'roll_rate = "p"',
        'yaw_rate = "r"',
        "",
        "[servo]  # the SITL's servo (paper eq. (65) form)",
        f"wn2 = {model.SERVO_WN2!r}",
        f"two_zeta_wn = {model.SERVO_2ZETA_WN!r}",
        "",
        "[trim]  # informative",
        f"airspeed_kt = {trim['airspeed_kt']!r}",
        f"altitude_m = {trim['altitude_m']!r}",
        f"phi = {trim['phi']!r}",
        f"theta = {trim['theta']!r}",
        "",
    ]
    return "\n".join(lines)
