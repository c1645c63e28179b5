"""A linear plant of your own, from a TOML file (``--plant FILE.toml``).  No I/O beyond reading the file.

The file gives the airframe (state space A, B, C, or a transfer function num/den from the surface deflection
to the roll angle), its input and output with their units, the servo (paper eq. (65) form:
delta'' = -wn2 delta - two_zeta_wn delta' + wn2 delta_command), the surface limits, and which airframe
states are the roll angle and the rates.  The servo is appended as the last two states, exactly as
``sitl.model.augmented_matrices`` builds the KH2013A plant, so ``sitl/plants/kh2013a.toml`` flies bit for bit
like the built-in model.  Format (every key: docs/plants.md):

    name = "kh2013a"
    [input]    name = "delta_r", unit = "rad", surface = "rudder", limit = 0.5 (optional), rate_limit (optional)
    [output]   name = "phi", unit = "rad"
    [airframe] states = [...], units = [...], A = [[...]], B = [[...]], C = [[...]],
               roll = "phi", roll_rate = "p", yaw_rate = "r", side_velocity = "v"   (rates optional)
       or      num = [...], den = [...]   (highest power first; roll rate = phi' when the relative degree >= 2)
    [servo]    wn2 = 2367.0, two_zeta_wn = 72.22
    [atmosphere] airspeed = 7.79 (m/s), span = 0.15 (m), altitude = 10 (m): the aircraft the Dryden turbulence and
               the gusts are scaled to (optional; without airspeed and span the atmosphere flags are refused)

Refused, each in one line naming the file and the key (``PlantFileError``; reading and keys: ``sitl.plant_file``):
values of the wrong type or shape, more than ``MAX_STATES`` airframe states, a surface that moves nothing or an
output that shows nothing (B = 0, C = 0, C (sI - A)^-1 B = 0), a pole beyond ``MAX_POLE_RAD_S``, an output gain
beyond ``MAX_OUTPUT_GAIN``, and a plant whose exact ZOH over one physics step is not finite or has an entry beyond
``MAX_STEP_GAIN`` (``check_step``).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from autopilot.shared.numerics import zoh
from sitl import model, plant_file
from sitl.plant_file import PlantFileError

MAX_STATES = 50  # airframe states a plant file may have (the servo adds two)
MAX_POLE_RAD_S = 1e5  # |s| of the fastest pole a plant may have (airframe or servo)
MAX_STEP_GAIN = 1e6  # the largest entry of the exact ZOH (Ad, Bd) of one physics step
MAX_OUTPUT_GAIN = 1e6  # the largest entry of C
PHYSICS_RATE_HZ = 1000.0  # the physics rate a file is checked at unless the flight's is given
MARKOV_RTOL = 1e-10  # a normalised Markov parameter this far below the largest is round-off


@dataclass(frozen=True)
class LinearPlant:
    """A parsed plant file: the augmented (A_p, B_p, C_p) with the servo last, the [v, p, r, phi] rows of the
    airframe states (None when they are exactly [v, p, r, phi]), the surface limits and the descriptive fields."""

    name: str
    a_p: np.ndarray
    b_p: np.ndarray
    c_p: np.ndarray
    truth: np.ndarray | None
    surface: str
    limit_rad: float | None
    rate_limit_rad_s: float | None
    states: tuple[str, ...]
    units: tuple[str, ...]
    input_name: str
    output_name: str
    # [atmosphere]: the airspeed (m/s), wing span (m) and altitude (m) the turbulence and gusts are scaled to
    airspeed_m_s: float | None = None
    span_m: float | None = None
    altitude_m: float | None = None
    # A square plant of m inputs and m outputs (B of m columns, C of m rows; docs/plants.md, "m inputs, m outputs"):
    # each input's surface, limit, rate limit and name, each output's name, in order.  One input: 1 and
    # (surface,), (limit_rad,), ... so that a SISO file's fields above are exactly what they were.
    m: int = 1
    surfaces: tuple[str, ...] = ()
    limits_rad: tuple[float | None, ...] = ()
    rate_limits_rad_s: tuple[float | None, ...] = ()
    input_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()

    @property
    def is_mimo(self) -> bool:
        return self.m > 1

    def aircraft_params(self) -> dict:
        """The ``params`` of ``sitl.aircraft.Aircraft`` that fly this plant."""
        out = {"A": self.a_p, "B": self.b_p}
        if self.truth is not None:
            out["truth"] = self.truth
        return out


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)  # TOML's true/false are not numbers


def _order(path, key: str, n: int) -> None:
    if n > MAX_STATES:
        raise PlantFileError(
            f"{path}: [airframe] {key} gives order {n}, above the maximum of {MAX_STATES} airframe states a plant "
            "file may have"
        )


def _matrix(path, table: dict, key: str, shape: tuple[int | None, int | None]) -> np.ndarray:
    if key not in table:
        raise PlantFileError(f"{path}: [airframe] has no {key} matrix")
    rows = table[key]
    if not isinstance(rows, list) or not rows or not all(isinstance(r, list) and r for r in rows):
        raise PlantFileError(f"{path}: [airframe] {key} must be a matrix of numbers (a list of rows)")
    _order(path, key, max(len(rows), *(len(r) for r in rows)) if key == "A" else 0)
    bad = next((v for r in rows for v in r if not _is_number(v)), None)
    if bad is not None:
        raise PlantFileError(f"{path}: [airframe] {key} must be a matrix of numbers, got the entry {bad!r:.40}")
    if len({len(r) for r in rows}) != 1:
        raise PlantFileError(f"{path}: [airframe] {key} must be a matrix: its rows have different lengths")
    m = np.array(rows, dtype=float)
    if any(want is not None and got != want for got, want in zip(m.shape, shape)):
        want = " x ".join("n" if w is None else str(w) for w in shape)
        raise PlantFileError(f"{path}: [airframe] {key} must be {want}, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise PlantFileError(f"{path}: [airframe] {key} has a NaN or infinite entry")
    return m


def _number(path, table: dict, section: str, key: str, positive: bool = True, required: bool = True) -> float | None:
    if key not in table:
        if required:
            raise PlantFileError(f"{path}: [{section}] has no {key}")
        return None
    v = table[key]
    if not _is_number(v) or not math.isfinite(v) or (positive and v <= 0):
        what = "a positive finite" if positive else "a finite"
        raise PlantFileError(f"{path}: [{section}] {key} must be {what} number, got {v!r:.40}")
    return float(v)


def _coefficients(path, table: dict, key: str) -> np.ndarray:
    v = table[key]
    if not isinstance(v, list) or not v or not all(_is_number(x) for x in v):
        raise PlantFileError(f"{path}: [airframe] {key} must be a non-empty list of numbers, highest power first")
    _order(path, key, len(v) - 1)
    c = np.trim_zeros(np.array(v, dtype=float), "f")
    if not np.all(np.isfinite(c)):
        raise PlantFileError(f"{path}: [airframe] {key} must be a non-empty list of finite numbers")
    if c.size == 0:
        why = "the surface moves nothing (uncontrollable)" if key == "num" else "no dynamics"
        raise PlantFileError(f"{path}: [airframe] {key} is zero: {why}")
    return c


STATE_KEYS = ("states", "units", "A", "B", "C", "roll", "roll_rate", "yaw_rate", "side_velocity")


def _from_transfer_function(path, air: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str], np.ndarray]:
    """Observable canonical form of num/den; the truth rows: phi = C x, p = C A x when C B = 0, v = r = 0."""
    missing = "den" if "den" not in air else "num" if "num" not in air else None
    if missing is not None:
        other = "num" if missing == "den" else "den"
        raise PlantFileError(
            f"{path}: [airframe] has {other} but no {missing}: a transfer function needs both num and den under "
            "[airframe], highest power first"
        )
    mixed = [k for k in STATE_KEYS if k in air]
    if mixed:
        raise PlantFileError(
            f"{path}: [airframe] has num/den and {', '.join(mixed)}: give a transfer function (num, den) or a state "
            "space (A, B, C with states, units and roll), not both"
        )
    num, den = _coefficients(path, air, "num"), _coefficients(path, air, "den")
    if num.size >= den.size:
        raise PlantFileError(f"{path}: [airframe] num/den must be strictly proper (deg num < deg den)")
    with np.errstate(all="ignore"):
        num, den = num / den[0], den / den[0]
    if not (np.all(np.isfinite(num)) and np.all(np.isfinite(den))):
        raise PlantFileError(f"{path}: [airframe] num/den divided by den's leading coefficient are out of range")
    n = den.size - 1
    a = np.zeros((n, n))
    a[:, 0] = -den[1:]
    a[: n - 1, 1:] = np.eye(n - 1)
    b = np.zeros((n, 1))
    b[n - num.size :, 0] = num
    c = np.zeros((1, n))
    c[0, 0] = 1.0
    truth = np.zeros((4, n))
    truth[model.PHI] = c[0]
    if abs(float((c @ b)[0, 0])) == 0.0:
        truth[model.P] = (c @ a)[0]
    return a, b, c, [f"x{i + 1}" for i in range(n)], truth


def _truth_rows(path, air: dict, states: list[str]) -> np.ndarray | None:
    """Rows mapping the airframe states onto [v, p, r, phi]; None if they are exactly that."""
    keys = (("side_velocity", 0, False), ("roll_rate", 1, False), ("yaw_rate", 2, False), ("roll", 3, True))
    given = {key: plant_file.text(path, air, "[airframe]", key, None) for key, _row, _req in keys}
    kh = (("roll", "phi"), ("roll_rate", "p"), ("yaw_rate", "r"), ("side_velocity", "v"))
    if states == ["v", "p", "r", "phi"] and all(given[k] in (None, d) for k, d in kh):
        return None
    truth = np.zeros((4, len(states)))
    for key, row, required in keys:
        name = given[key]
        if name is None:
            if required:
                raise PlantFileError(f"{path}: [airframe] has no roll (the name of the roll-angle state)")
            continue
        if name not in states:
            raise PlantFileError(f"{path}: [airframe] {key} = {name!r} is not one of the states {states}")
        truth[row, states.index(name)] = 1.0
    return truth


def _airframe(path, air: dict):
    """(A, B, C, states, units, truth) of the [airframe] table."""
    if "num" in air or "den" in air:
        a, b, c, states, truth = _from_transfer_function(path, air)
        return a, b, c, states, ["?"] * len(states), truth
    if "A" not in air:
        raise PlantFileError(
            f"{path}: [airframe] has no A matrix: give A, B, C (a state space) or num, den (a transfer function)"
        )
    a = _matrix(path, air, "A", (None, None))
    n = a.shape[0]
    if a.shape != (n, n):
        raise PlantFileError(f"{path}: [airframe] A must be square, got shape {a.shape}")
    b = _matrix(path, air, "B", (n, None))
    m = b.shape[1]
    c = _matrix(path, air, "C", (1 if m == 1 else None, n))
    if c.shape[0] != m:
        raise PlantFileError(
            f"{path}: [airframe] B has {m} column(s) (inputs) and C {c.shape[0]} row(s) (outputs): a plant is square, "
            "one output per input"
        )
    if not np.any(b):
        raise PlantFileError(f"{path}: [airframe] B = 0: the surface moves no state (uncontrollable)")
    if not np.any(c):
        raise PlantFileError(f"{path}: [airframe] C = 0: the output shows no state (unobservable)")
    if float(np.max(np.abs(c))) > MAX_OUTPUT_GAIN:
        raise PlantFileError(
            f"{path}: [airframe] C has an entry of {float(np.max(np.abs(c))):.3g}, above the {MAX_OUTPUT_GAIN:g} an "
            "output gain may have (C maps the states onto the roll angle in rad)"
        )
    states = plant_file.names(path, air, "[airframe]", "states", n, [f"x{i + 1}" for i in range(n)])
    if len(set(states)) != n:
        raise PlantFileError(f"{path}: [airframe] states must be {n} different names, got {states}")
    units = plant_file.names(path, air, "[airframe]", "units", n, ["?"] * n)
    return a, b, c, states, units, _truth_rows(path, air, states)


def markov_relative_degree(a, b, c, tol: float = MARKOV_RTOL) -> int | None:
    """The relative degree r of C (sI - A)^-1 B: 1 + the index of the first Markov parameter h_k = C A^k B that is
    not negligible; None if none of h_0 .. h_(n-1) is (then C (sI - A)^-1 B = 0, by Cayley-Hamilton).

    Scale-free: with Omega the spectral radius of A (its 2-norm if that is 0), the normalised parameters
    m_k = |h_k| / Omega^k are the sizes of the terms h_k / s^(k+1) of T(s) at |s| = Omega, and h_k is negligible when
    m_k <= ``tol`` max_j m_j.  Scaling B, C or time changes no answer (a surface gain of 1e-300 has the relative
    degree of the same plant at gain 1), nor does a fast servo in series with a slow airframe (the bound
    |C| |A|^k |B| called the servo and 1/(s + 1)^2 in series zero).  Powers of A / Omega: nothing overflows.  Raises
    OverflowError if the parameters are not finite."""
    a = np.atleast_2d(np.asarray(a, dtype=float))
    n = a.shape[0]
    x = np.asarray(b, dtype=float).reshape(-1, 1)
    c = np.asarray(c, dtype=float).reshape(1, -1)
    with np.errstate(all="ignore"):
        omega = float(np.max(np.abs(np.linalg.eigvals(a)))) if n and np.all(np.isfinite(a)) else math.nan
        if not (math.isfinite(omega) and omega > 0.0):
            omega = float(np.linalg.norm(a, 2)) if np.all(np.isfinite(a)) else math.nan
            omega = omega if omega > 0.0 else 1.0
        scaled = a / omega
        m = []
        for _ in range(n):
            m.append(abs((c @ x).item()))
            x = scaled @ x
    if not all(math.isfinite(v) for v in m):
        raise OverflowError("the Markov parameters C A^k B are not finite: the coefficients are out of range")
    top = max(m, default=0.0)
    if top == 0.0:
        return None
    return next(k for k, v in enumerate(m) if v > tol * top) + 1


def _max_pole(a: np.ndarray) -> float:
    """The largest |pole| of A (inf if they are not finite numbers)."""
    if not a.size:
        return 0.0
    with np.errstate(all="ignore"):
        poles = np.linalg.eigvals(a)
    return float(np.max(np.abs(poles))) if np.all(np.isfinite(poles)) else math.inf


def _check_dynamics(path, a, b, c, form: str, wn2: float, two_zeta_wn: float) -> None:
    """The surface reaches the output, and no pole is beyond ``MAX_POLE_RAD_S`` (nor infinite)."""
    b, c = np.atleast_2d(b), np.atleast_2d(c)
    try:
        degrees = [[markov_relative_degree(a, b[:, j], c[i]) for j in range(b.shape[1])] for i in range(c.shape[0])]
        r = 0
    except OverflowError:
        r = -1
    if r == 0 and b.shape[1] == 1 and degrees[0][0] is None:
        raise PlantFileError(
            f"{path}: [airframe] C (sI - A)^-1 B = 0: the surface moves no state the output shows "
            "(uncontrollable or unobservable)"
        )
    if r == 0:
        for j in range(b.shape[1]):  # a square plant: every input moves some output, every output sees some input
            if all(degrees[i][j] is None for i in range(c.shape[0])):
                raise PlantFileError(f"{path}: [airframe] input {j + 1} (column {j + 1} of B) moves no output")
        for i in range(c.shape[0]):
            if all(degrees[i][j] is None for j in range(b.shape[1])):
                raise PlantFileError(f"{path}: [airframe] output {i + 1} (row {i + 1} of C) sees no input")
    servo = _max_pole(np.array([[0.0, 1.0], [-wn2, -two_zeta_wn]]))
    if servo > MAX_POLE_RAD_S:
        raise PlantFileError(
            f"{path}: [servo] wn2 = {wn2:g}, two_zeta_wn = {two_zeta_wn:g} put the servo's poles at |s| = {servo:.3g} "
            f"rad/s, above the {MAX_POLE_RAD_S:g} rad/s a plant may have"
        )
    fastest = _max_pole(a)
    if r == -1 or not math.isfinite(fastest):
        raise PlantFileError(f"{path}: [airframe] {form}: coefficients out of range (its poles are not finite numbers)")
    if fastest > MAX_POLE_RAD_S:
        raise PlantFileError(
            f"{path}: [airframe] {form} puts a pole at |s| = {fastest:.3g} rad/s, above the {MAX_POLE_RAD_S:g} rad/s "
            "a plant may have"
        )


def check_step(path, a_p: np.ndarray, b_p: np.ndarray, physics_rate_hz: float) -> None:
    """Refuse a plant whose exact ZOH over one physics step (Ad = e^(A_p dt), Bd) is not finite or has an entry above
    ``MAX_STEP_GAIN``: one step would multiply a state (or the command) by more than a million, and a state that
    large leaves what the SITL can integrate and send (ATTITUDE is float32) within a few steps."""
    dt = 1.0 / physics_rate_hz
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ad, bd = zoh(a_p, b_p, dt)
        worst = max(float(np.max(np.abs(ad))), float(np.max(np.abs(bd))))
    if not math.isfinite(worst) or worst > MAX_STEP_GAIN:
        got = "not finite" if not math.isfinite(worst) else f"up to {worst:.3g}"
        raise PlantFileError(
            f"{path}: cannot be integrated: one {dt * 1e3:g} ms physics step multiplies a state by {got} (the "
            f"exact ZOH e^(A dt) of the plant with its servo), above the {MAX_STEP_GAIN:g} the SITL can integrate: "
            "check the magnitudes of A, B (or num, den) and the servo"
        )


def augment(a: np.ndarray, b: np.ndarray, c: np.ndarray, wn2: float, two_zeta_wn: float):
    """(A_p, B_p, C_p): the servo (paper eq. (65)) appended as the last two states, as in
    ``sitl.model.augmented_matrices``: the deflection drives the airframe through B, the command is the input.
    B of m > 1 columns: one servo per input, the states [delta_1, delta_1', ..., delta_m, delta_m'] last."""
    if b.shape[1] > 1:
        return _augment_mimo(a, b, c, wn2, two_zeta_wn)
    n = a.shape[0]
    a_p = np.zeros((n + 2, n + 2))
    a_p[:n, :n] = a
    a_p[:n, n : n + 1] = b
    a_p[n:, n:] = np.array([[0.0, 1.0], [-wn2, -two_zeta_wn]])
    b_p = np.zeros((n + 2, 1))
    b_p[n:, :] = np.array([[0.0], [wn2]])
    c_p = np.hstack([c, np.zeros((1, 2))])
    return a_p, b_p, c_p


def _augment_mimo(a, b, c, wn2: float, two_zeta_wn: float):
    n, m = a.shape[0], b.shape[1]
    a_p = np.zeros((n + 2 * m, n + 2 * m))
    a_p[:n, :n] = a
    b_p = np.zeros((n + 2 * m, m))
    for j in range(m):
        k = n + 2 * j
        a_p[:n, k] = b[:, j]
        a_p[k : k + 2, k : k + 2] = np.array([[0.0, 1.0], [-wn2, -two_zeta_wn]])
        b_p[k + 1, j] = wn2
    c_p = np.hstack([c, np.zeros((c.shape[0], 2 * m))])
    return a_p, b_p, c_p


UNIT = "rad"  # the surface deflection and the roll angle are in rad (SI inside)


def _unit(path, section: dict, where: str) -> None:
    unit = plant_file.text(path, section, where, "unit", UNIT)
    if unit != UNIT:
        raise PlantFileError(f"{path}: {where} unit must be {UNIT!r} (SI inside), got {unit!r}")


SURFACES = ("rudder", "aileron")


def _limit(path, value, where: str = "[input] limit") -> float | None:
    """A surface's stop (rad, in (0, pi/2]) or None."""
    if value is None:
        return None
    limit = _number(path, {"limit": value}, "input", "limit")
    if limit > math.pi / 2:
        raise PlantFileError(f"{path}: {where} must be in (0, pi/2] rad (a surface's stop), got {limit!r}")
    return limit


def _per_channel(path, section: dict, where: str, key: str, m: int, default):
    """A key of a plant of ``m`` inputs: a list of ``m`` values, one per channel (``default``: m Nones)."""
    if key not in section:
        return [default] * m
    v = section[key]
    if not isinstance(v, list) or len(v) != m:
        got = f"a list of {len(v)}" if isinstance(v, list) else f"{type(v).__name__} {v!r:.40}"
        raise PlantFileError(
            f"{path}: {where} {key} must be a list of {m} values, one per input (B has {m} columns), got {got}"
        )
    return v


def _mimo_channels(path, inp: dict, out: dict, m: int):
    """((surfaces, limits, rate limits), (input names, output names)) of a plant of ``m`` inputs and outputs."""
    surfaces = tuple(_per_channel(path, inp, "[input]", "surface", m, None))
    if any(s not in SURFACES for s in surfaces) or len(set(surfaces)) != m:
        raise PlantFileError(
            f"{path}: [input] surface must be a list of {m} different surfaces of rudder, aileron, got {list(surfaces)}"
        )
    limits = tuple(
        _limit(path, v, f"[input] limit[{k}]")
        for k, v in enumerate(_per_channel(path, inp, "[input]", "limit", m, None))
    )
    rates = tuple(
        None if v is None else _number(path, {"rate_limit": v}, "input", "rate_limit")
        for v in _per_channel(path, inp, "[input]", "rate_limit", m, None)
    )
    names = []
    for where, section, key, default in (("[input]", inp, "name", "delta"), ("[output]", out, "name", "y")):
        given = _per_channel(path, section, where, key, m, None)
        got = tuple(
            plant_file.text(path, {key: v}, where, key, f"{default}{k + 1}") if v is not None else f"{default}{k + 1}"
            for k, v in enumerate(given)
        )
        if len(set(got)) != m:
            raise PlantFileError(f"{path}: {where} {key} must be {m} different names, got {list(got)}")
        names.append(got)
    return (surfaces, limits, rates), tuple(names)


def load(path, physics_rate_hz: float | None = PHYSICS_RATE_HZ) -> LinearPlant:
    """Parse and check a plant file; raises PlantFileError with a one-line reason.  ``physics_rate_hz``: the rate
    whose physics step must be integrable (``check_step``); None checks everything else."""
    path = Path(path)
    doc = plant_file.read(path)
    name = plant_file.text(path, doc, "the top-level", "name", path.stem)
    for key in ("description", "source"):
        if key in doc and not isinstance(doc[key], str):
            raise PlantFileError(f"{path}: {key} must be a string, got {type(doc[key]).__name__}")
    inp = plant_file.table(path, doc, "input", required=False)
    out = plant_file.table(path, doc, "output", required=False)
    plant_file.table(path, doc, "trim", required=False)
    air = plant_file.table(path, doc, "airframe", required=True)
    servo = plant_file.table(path, doc, "servo", required=True)
    a, b, c, states, units, truth = _airframe(path, air)
    wn2 = _number(path, servo, "servo", "wn2")
    two_zeta_wn = _number(path, servo, "servo", "two_zeta_wn")  # both > 0: the servo is stable (Hurwitz)
    for where, section in (("[input]", inp), ("[output]", out)):
        _unit(path, section, where)
    m = b.shape[1]
    if m == 1:
        surface = plant_file.text(path, inp, "[input]", "surface", "rudder")
        if surface not in SURFACES:
            raise PlantFileError(f"{path}: [input] surface must be rudder or aileron, got {surface!r}")
        limit = _limit(path, inp.get("limit"))
        rate_limit = _number(path, inp, "input", "rate_limit", required=False)
        channels = ((surface,), (limit,), (rate_limit,))
        names = ((plant_file.text(path, inp, "[input]", "name", "delta"),),)
        names += ((plant_file.text(path, out, "[output]", "name", "phi"),),)
    else:
        channels, names = _mimo_channels(path, inp, out, m)
    _check_dynamics(path, a, b, c, "num/den" if "den" in air else "A", wn2, two_zeta_wn)
    a_p, b_p, c_p = augment(a, b, c, wn2, two_zeta_wn)
    if physics_rate_hz is not None:
        check_step(path, a_p, b_p, physics_rate_hz)
    atm = plant_file.table(path, doc, "atmosphere", required=False)
    airspeed, span = (_number(path, atm, "atmosphere", k, required=False) for k in ("airspeed", "span"))
    if (airspeed is None) != (span is None):
        raise PlantFileError(f"{path}: [atmosphere] needs both airspeed (m/s) and span (m), or neither")
    return LinearPlant(
        name=name,
        a_p=a_p,
        b_p=b_p,
        c_p=c_p,
        truth=truth,
        surface=channels[0][0],
        limit_rad=channels[1][0],
        rate_limit_rad_s=channels[2][0],
        states=tuple(states),
        units=tuple(units),
        input_name=names[0][0],
        output_name=names[1][0],
        airspeed_m_s=airspeed,
        span_m=span,
        altitude_m=_number(path, atm, "atmosphere", "altitude", required=False),
        m=m,
        surfaces=channels[0],
        limits_rad=channels[1],
        rate_limits_rad_s=channels[2],
        input_names=names[0],
        output_names=names[1],
    )
