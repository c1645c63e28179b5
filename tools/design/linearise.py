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

import contextlib
import dataclasses
import math
import os
import signal
import sys
import threading
from pathlib import Path

import numpy as np

from autopilot.shared.process import standard_json

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
    Any airspeed: a design is flown off its design point.  The plant kind's record says
    (``sitl.plant_kinds.PlantKind.design``)."""
    from sitl import plant as plants

    return plants.spec(plant).design_file


def designed_params(plant: str) -> Path | None:
    """The parameter file designed for ``plant`` (``python -m tools.pfc design``), found where ``design_path`` says;
    None if there is none (and for kh2013a: the paper's defaults)."""
    path = design_path(plant)
    return path if path is not None and path.is_file() else None


def designed_law_params(plant: str, suffix: str = "-laws") -> Path | None:
    """The adaptive-law bench's designs for ``plant`` (``python -m tools.design.laws``): the file beside the plant's
    design (``sitl/plants/jsbsim-c172x-laws.params``, ``sitl/plants/kh2013a-laws.params``), None if there is none."""
    from sitl import plant as plants

    base = design_path(plant)
    path = plants.shipped(f"kh2013a{suffix}.params") if base is None else base.with_name(base.stem + suffix + ".params")
    return path if path is not None and Path(path).is_file() else None


def shown_path(path: Path) -> str:
    """``path`` as a command line shows it: relative to the working folder when inside it."""
    try:
        return str(Path(path).resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def design_command(plant: str) -> str:
    """The command that designs ``plant`` into the file the launcher finds."""
    return f"python -m tools.pfc design {plant} --out {shown_path(design_path(plant))}"


def design_advice(plant: str) -> str:
    """What a refusal of ``plant`` for want of a design tells the user to do: run ``design_command``, unless JSBSim's
    linearisation of its model is known to take longer than the design's limit (``SLOW_LINEARISATION_S``): then
    that, since a design that would stop on the clock is not one to recommend."""
    slow = slow_linearisation_s(plant)
    if slow is None:
        return f"make it with `{design_command(plant)}`"
    return (
        f"JSBSim's linearisation of it takes about {slow:g} s, beyond the design's {LINEARISE_TIMEOUT_S:g} s limit, so "
        f"`python -m tools.pfc design` makes none by default"
    )


def slow_linearisation_s(plant: str) -> float | None:
    """The measured FGLinearization time of ``plant``'s JSBSim model if it is in ``SLOW_LINEARISATION_S``, else None."""
    from sitl import plant as plants

    js = plants.spec(plant).jsbsim
    return None if js is None else SLOW_LINEARISATION_S.get(js.model)


PID_PARAMS = ("PID_KP", "PID_KI", "PID_KD")  # the baseline's gains in a parameter file (aliases CLSAC_PID_*)
PFC_PARAMS = ("CLSAC_PFC_NUM", "CLSAC_PFC_DEN1", "CLSAC_PFC_DEN0")  # SAC's and CL-SAC's PFC


def designed_baseline(plant: str) -> tuple[float, float, float] | None:
    """The baseline gains designed for ``plant`` (``PID_KP``, ``_KI``, ``_KD`` of its designed parameter file,
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


def flown_baseline_gains(controller: str, plant: str, given=None) -> tuple | None:
    """The gains a fixed-gain controller (``autopilot.controllers``, law ``baseline``) flies on ``plant``: ``given``
    (KP, KI, KD[, KFF]), else the ones designed for the plant (``designed_baseline``); None: the built-in defaults.
    pid-ff also feeds forward: unless given a fourth, the plant's roll-mode K_ff
    (``feedforward_gain`` on ``linear_model``; without a linear model, the built-in
    KH2013A's)."""
    from autopilot import controllers

    gains = tuple(given) if given is not None else designed_baseline(plant)
    if not dict(controllers.get(controller).options).get("feedforward") or (gains is not None and len(gains) > 3):
        return gains
    model = linear_model(plant)
    if model is None or model[3] is None:
        return gains
    if gains is None:
        from autopilot.baseline import BaselineConfig

        d = BaselineConfig()
        gains = (d.kp, d.ki, d.kd)
    return (*gains, feedforward_gain(model[:3], model[3]))


def feedforward_gain(plant, roll_rate: int) -> float:
    """pid-ff's feed-forward K_ff (s): the roll-mode inverse -L_p / L_delta of the plant's roll-rate row, the
    surface a steady roll rate p needs in p' = L_p p + L_delta delta (``autopilot.baseline``): L_p = A_p[p, p],
    L_delta = A_p[p, delta] (the deflection's column, the servo's first state).  ValueError unless both are
    nonzero and K_ff > 0."""
    a = np.asarray(plant[0], dtype=float)
    lp, ld = float(a[roll_rate, roll_rate]), float(a[roll_rate, a.shape[0] - 2])
    if lp == 0.0 or ld == 0.0 or -lp / ld <= 0:
        raise ValueError(f"no roll-mode feed-forward: L_p = {lp:g}, L_delta = {ld:g}")
    return -lp / ld


def linear_model(plant: str):
    """The linear model a plant is designed on: (A_p, B_p, C_p) with the servo last and the index of its roll-rate
    state (None when the roll rate is not one state).  kh2013a: the paper's matrices (``sitl.model``); a plant
    file: itself; ``jsbsim:MODEL[...]``: its linearised file shipped beside its designed parameter file
    (``sitl/plants/jsbsim-MODEL.toml``, at its design point, whatever the airspeed flown), None if none: the plant
    kind's record (``sitl.plant_kinds.PlantKind.linear``)."""
    from sitl import plant as plants

    return plants.spec(plant).linear_model


def linearise(spec, physics_rate_hz: float = 1000.0) -> dict:
    """The roll channel of a trimmed JSBSim model: {"A", "B", "C", "trim", ...} (SI, input in rad)."""
    import jsbsim

    from sitl.jsbsim_plant import SURFACE_SIGN, SURFACES, trimmed_fdm

    fdm = trimmed_fdm(spec, 1.0 / physics_rate_hz)
    if spec.is_mimo:
        return _linearise_mimo(jsbsim, fdm, spec)
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


def _trim_of(spec, fdm) -> dict:
    return {
        "airspeed_kt": spec.airspeed_kt,
        "altitude_m": spec.altitude_m,
        "phi": float(fdm["attitude/phi-rad"]),
        "theta": float(fdm["attitude/theta-rad"]),
    }


def _linearise_mimo(jsbsim, fdm, spec) -> dict:
    """A square MIMO plant (``sitl.jsbsim_plant.MIMO``): one column of B per surface (in rad, each with its sign
    ``spec.signs`` and the model's slope at its trim), one row of C per output (phi, beta), the same lateral states."""
    from sitl.jsbsim_plant import SURFACES

    maps = spec.surface_maps
    lin = jsbsim.FGLinearization(fdm)
    x_names, u_names = list(lin.x_names), list(lin.u_names)
    missing = [n for n in (*LATERAL, *(INPUTS[s] for s in spec.surfaces)) if n not in x_names + u_names]
    if missing:
        raise LinearisationError(f"JSBSim's linearisation of {spec.model} has no {', '.join(missing)}")
    idx = [x_names.index(n) for n in LATERAL]
    a_full, b_full = np.array(lin.system_matrix), np.array(lin.input_matrix)
    cols = []
    for surface, sign, m in zip(spec.surfaces, spec.signs, maps):
        slope = m.slope(float(fdm[SURFACES[surface]]))
        cols.append(sign * b_full[idx, u_names.index(INPUTS[surface])] / slope)
    c = np.zeros((len(spec.outputs), 4))
    for i, y in enumerate(spec.outputs):
        c[i, STATES.index(y)] = 1.0
    return {
        "A": a_full[np.ix_(idx, idx)],
        "B": np.column_stack(cols),
        "C": c,
        "surface": list(maps),
        "trim": _trim_of(spec, fdm),
    }


LINEARISE_TIMEOUT_S = 60.0  # JSBSim's FGLinearization of one model: c172x takes 1.3 s, pa28 3.7 s, Boeing314 340 s
# Models whose FGLinearization takes far longer than LINEARISE_TIMEOUT_S (measured on the 2-core development VM, one
# C++ call that no iteration count bounds): their design is refused at once, not after the limit's wall clock (a
# result that depended on the machine's load), unless --linearise-timeout covers the time; no refusal recommends it.
SLOW_LINEARISATION_S = {"Boeing314": 340.0}


@contextlib.contextmanager
def _ctrl_c_flag():
    """A list that Ctrl-C (SIGINT) appends to while the block runs, for the caller to raise KeyboardInterrupt where
    it is safe.  Answered even in a process started with SIGINT ignored (a script's background job, as CI runs the
    suite: Python then installs no KeyboardInterrupt of its own and the design ignored Ctrl-C), and never raised
    inside ``subprocess.Popen.poll`` between taking its waitpid lock and its ``try`` (the lock left held, the
    ``proc.wait()`` after it waits for ever).  Outside the main thread (no handler can be set there): never set."""
    stop: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    previous = signal.signal(signal.SIGINT, lambda signum, _frame: stop.append(signum))
    try:
        yield stop
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler if previous is None else previous)


def linearise_bounded(spec, timeout_s: float = LINEARISE_TIMEOUT_S, physics_rate_hz: float = 1000.0) -> dict:
    """:func:`linearise` in a child process, within ``timeout_s`` of wall clock (FGLinearization is one C++ call that
    holds the interpreter: in this process neither a timeout nor Ctrl-C could stop it).  LinearisationError if it
    takes longer; Ctrl-C (KeyboardInterrupt here, within a poll of 50 ms: :func:`_ctrl_c_flag`) kills the child at
    once; JsbsimPlantError as the child had it."""
    import json
    import subprocess
    import tempfile
    import time

    from sitl.jsbsim_plant import JsbsimPlantError

    slow = SLOW_LINEARISATION_S.get(spec.model)
    if slow is not None and timeout_s < slow:  # decided by the measured time, not by this machine's clock
        raise LinearisationError(
            f"JSBSim's linearisation (FGLinearization) of {spec.model} takes about {slow:g} s, longer than the "
            f"{timeout_s:g} s limit (--linearise-timeout): not started; give --linearise-timeout "
            f"{math.ceil(2 * slow / 100) * 100:g} to wait for it"
        )
    root = str(Path(__file__).resolve().parents[2])  # the folder holding tools/ and sitl/
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p)}
    with tempfile.TemporaryDirectory(prefix="linearise-") as tmp, _ctrl_c_flag() as stop:
        out = Path(tmp) / "lin.json"
        argv = [sys.executable, "-m", "tools.plant", "_linearise", spec.text(), str(physics_rate_hz), str(out)]
        proc = subprocess.Popen(
            argv,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,  # JSBSim's own chatter
            stderr=subprocess.PIPE,
            env=env,
            process_group=0,  # Ctrl-C reaches this process, which kills the child; not a session (children.py)
            text=True,
        )
        try:
            t_end = time.monotonic() + timeout_s
            while proc.poll() is None and not stop:
                if time.monotonic() >= t_end:
                    raise LinearisationError(
                        f"JSBSim's linearisation (FGLinearization) of {spec.model} did not finish within "
                        f"{timeout_s:g} s; stopped"
                    )
                time.sleep(0.05)
            if stop:
                raise KeyboardInterrupt
            err = proc.stderr.read().strip().splitlines()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            proc.stderr.close()
        why = err[-1] if err else f"exit status {proc.returncode}"
        if proc.returncode == 3:
            raise JsbsimPlantError(why)
        if proc.returncode != 0 or not out.is_file():
            raise LinearisationError(f"JSBSim's linearisation of {spec.model} failed: {why}")
        lin = json.loads(out.read_text())
    if isinstance(lin.get("surface"), dict):  # the child's surface map, back to its dataclass
        from sitl.jsbsim_models import SurfaceMap

        lin["surface"] = SurfaceMap(**lin["surface"])
    elif isinstance(lin.get("surface"), list):  # a MIMO plant's, one per surface
        from sitl.jsbsim_models import SurfaceMap

        lin["surface"] = [SurfaceMap(**m) for m in lin["surface"]]
    return {k: (np.array(v) if k in ("A", "B", "C") else v) for k, v in lin.items()}


def _linearise_child(argv: list[str]) -> int:
    """The child of :func:`linearise_bounded`: SPEC RATE_HZ OUT.json; exit 3 on a JsbsimPlantError, 4 on a
    LinearisationError (the reason the last stderr line)."""

    from sitl.jsbsim_plant import JsbsimPlantError, parse_spec

    text, rate, out = argv
    try:
        lin = linearise(parse_spec(text), float(rate))
    except JsbsimPlantError as exc:
        print(exc, file=sys.stderr)
        return 3
    except LinearisationError as exc:
        print(exc, file=sys.stderr)
        return 4

    def plain(v):  # arrays as lists, the surface map (a dataclass) as its fields
        if isinstance(v, np.ndarray):
            return v.tolist()
        if isinstance(v, list):
            return [plain(x) for x in v]
        return dataclasses.asdict(v) if dataclasses.is_dataclass(v) else v

    Path(out).write_text(standard_json({k: plain(v) for k, v in lin.items()}))
    return 0


def add_timeout_argument(p) -> None:
    from autopilot.shared.cli import timeout_s

    p.add_argument(
        "--linearise-timeout",
        dest="timeout",
        type=timeout_s,
        default=LINEARISE_TIMEOUT_S,
        metavar="S",
        help=f"give up JSBSim's linearisation after S s of wall clock (default {LINEARISE_TIMEOUT_S:g})",
    )


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

    if spec.is_mimo:
        return _to_toml_mimo(spec, lin)
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


def _strings(v) -> str:
    return "[" + ", ".join(f'"{x}"' for x in v) + "]"


def _to_toml_mimo(spec, lin: dict) -> str:
    """The plant file of a square MIMO linearisation: B of m columns, C of m rows, the inputs and outputs named."""
    from sitl import model

    a, b, c = lin["A"], lin["B"], lin["C"]
    trim, maps = lin["trim"], lin.get("surface") or [None] * len(spec.surfaces)
    limits = spec.surface_limits_rad
    rates = [None if m is None else m.rate_limit_rad_s for m in maps]
    pairs = ", ".join(f"{y} on the {s}" for s, y in zip(spec.surfaces, spec.outputs))
    lines = [
        f"# {spec.model} lateral channels ({pairs}), linearised by JSBSim (FGLinearization) at the trim point of",
        f"# {spec.text()} (python -m tools.plant linearise).  States [beta, phi, p, r]; the inputs are the",
        "# surface deflections in rad, each with the sign that makes its own output's high-frequency gain positive.",
        f'name = "{spec.model}-{spec.airspeed_kt:g}kt-{spec.surface}"',
        f'source = "{spec.text()}"',
        "",
        "[input]",
        "name = " + _strings(f"delta_{s[0]}" for s in spec.surfaces),
        'unit = "rad"',
        "surface = " + _strings(spec.surfaces),
        f"limit = {_row(limits)}  # JSBSim's normalised commands saturate at +-1",
    ]
    for m in maps:
        lines += [line.replace("# ", f"# {m.surface}: ", 1) for line in _actuator_lines(m) if line.startswith("#")]
    if all(r is not None for r in rates):
        lines.append(f"rate_limit = {_row(rates)}  # rad/s, the model's actuators")
    lines += [
        "",
        "[output]",
        "name = " + _strings(spec.outputs),
        'unit = "rad"',
        "",
        "[airframe]",
        "states = [" + ", ".join(f'"{s}"' for s in STATES) + "]",
        "units = [" + ", ".join(f'"{u}"' for u in UNITS) + "]",
        "A = [\n" + "".join(f"    {_row(r)},\n" for r in a) + "]",
        "B = [\n" + "".join(f"    {_row(r)},\n" for r in b) + "]",
        "C = [\n" + "".join(f"    {_row(r)},\n" for r in c) + "]",
        'roll = "phi"',
        'roll_rate = "p"',
        'yaw_rate = "r"',
        "",
        "[servo]  # the SITL's servo (paper eq. (65) form), one per surface",
        f"wn2 = {model.SERVO_WN2!r}",
        f"two_zeta_wn = {model.SERVO_2ZETA_WN!r}",
        "",
        "[trim]  # informative",
        *(f"{k} = {v!r}" for k, v in trim.items()),
        "",
    ]
    return "\n".join(lines)
