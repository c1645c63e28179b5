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
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sitl import model


class PlantFileError(ValueError):
    """A plant file is unreadable or malformed; the message names the file and the offending key."""


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

    def aircraft_params(self) -> dict:
        """The ``params`` of ``sitl.aircraft.Aircraft`` that fly this plant."""
        out = {"A": self.a_p, "B": self.b_p}
        if self.truth is not None:
            out["truth"] = self.truth
        return out


def _matrix(path, table: dict, key: str, shape: tuple[int | None, int | None]) -> np.ndarray:
    if key not in table:
        raise PlantFileError(f"{path}: [airframe] has no {key} matrix")
    try:
        m = np.array(table[key], dtype=float)
    except (TypeError, ValueError):
        raise PlantFileError(f"{path}: [airframe] {key} must be a matrix of numbers (a list of rows)") from None
    if m.ndim != 2 or any(want is not None and got != want for got, want in zip(m.shape, shape)):
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
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or (positive and v <= 0):
        what = "a positive finite" if positive else "a finite"
        raise PlantFileError(f"{path}: [{section}] {key} must be {what} number, got {v!r}")
    return float(v)


def _coefficients(path, table: dict, key: str) -> np.ndarray:
    try:
        c = np.trim_zeros(np.array(table[key], dtype=float), "f")
    except (TypeError, ValueError):
        raise PlantFileError(f"{path}: [airframe] {key} must be a list of numbers, highest power first") from None
    if c.ndim != 1 or c.size == 0 or not np.all(np.isfinite(c)):
        raise PlantFileError(f"{path}: [airframe] {key} must be a non-empty list of finite numbers")
    return c


def _from_transfer_function(path, air: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str], np.ndarray]:
    """Observable canonical form of num/den; the truth rows: phi = C x, p = C A x when C B = 0, v = r = 0."""
    num, den = _coefficients(path, air, "num"), _coefficients(path, air, "den")
    if num.size >= den.size:
        raise PlantFileError(f"{path}: [airframe] num/den must be strictly proper (deg num < deg den)")
    num, den = num / den[0], den / den[0]
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
    if states == ["v", "p", "r", "phi"] and all(
        air.get(k, d) == d for k, d in (("roll", "phi"), ("roll_rate", "p"), ("yaw_rate", "r"), ("side_velocity", "v"))
    ):
        return None
    truth = np.zeros((4, len(states)))
    for key, row, required in (("side_velocity", 0, False), ("roll_rate", 1, False), ("yaw_rate", 2, False)) + (
        ("roll", 3, True),
    ):
        name = air.get(key)
        if name is None:
            if required:
                raise PlantFileError(f"{path}: [airframe] has no roll (the name of the roll-angle state)")
            continue
        if name not in states:
            raise PlantFileError(f"{path}: [airframe] {key} = {name!r} is not one of the states {states}")
        truth[row, states.index(name)] = 1.0
    return truth


def _airframe(path, air: dict):
    if "num" in air or "den" in air:
        return _from_transfer_function(path, air)
    a = _matrix(path, air, "A", (None, None))
    n = a.shape[0]
    if a.shape != (n, n):
        raise PlantFileError(f"{path}: [airframe] A must be square, got shape {a.shape}")
    b = _matrix(path, air, "B", (n, 1))
    c = _matrix(path, air, "C", (1, n))
    states = air.get("states", [f"x{i + 1}" for i in range(n)])
    if not isinstance(states, list) or len(states) != n or not all(isinstance(s, str) for s in states):
        raise PlantFileError(f"{path}: [airframe] states must be {n} names, one per row of A")
    return a, b, c, states, _truth_rows(path, air, states)


def augment(a: np.ndarray, b: np.ndarray, c: np.ndarray, wn2: float, two_zeta_wn: float):
    """(A_p, B_p, C_p): the servo (paper eq. (65)) appended as the last two states, as in
    ``sitl.model.augmented_matrices``: the deflection drives the airframe through B, the command is the input."""
    n = a.shape[0]
    a_p = np.zeros((n + 2, n + 2))
    a_p[:n, :n] = a
    a_p[:n, n : n + 1] = b
    a_p[n:, n:] = np.array([[0.0, 1.0], [-wn2, -two_zeta_wn]])
    b_p = np.zeros((n + 2, 1))
    b_p[n:, :] = np.array([[0.0], [wn2]])
    c_p = np.hstack([c, np.zeros((1, 2))])
    return a_p, b_p, c_p


def _read(path: Path) -> dict:
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as exc:
        raise PlantFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise PlantFileError(f"{path}: not a TOML plant file (not UTF-8 text)") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise PlantFileError(f"{path}: not a TOML plant file: {exc}") from None


def _table(path, doc: dict, name: str) -> dict:
    t = doc.get(name)
    if not isinstance(t, dict):
        raise PlantFileError(f"{path}: no [{name}] table")
    return t


def load(path) -> LinearPlant:
    """Parse and check a plant file; raises PlantFileError with a one-line reason."""
    path = Path(path)
    doc = _read(path)
    air, servo = _table(path, doc, "airframe"), _table(path, doc, "servo")
    inp, out = doc.get("input", {}), doc.get("output", {})
    a, b, c, states, truth = _airframe(path, air)
    wn2 = _number(path, servo, "servo", "wn2")
    two_zeta_wn = _number(path, servo, "servo", "two_zeta_wn")  # both > 0: the servo is stable (Hurwitz)
    a_p, b_p, c_p = augment(a, b, c, wn2, two_zeta_wn)
    surface = inp.get("surface", "rudder")
    if surface not in ("rudder", "aileron"):
        raise PlantFileError(f"{path}: [input] surface must be rudder or aileron, got {surface!r}")
    units = air.get("units", ["?"] * len(states))
    atm = doc.get("atmosphere", {})
    if not isinstance(atm, dict):
        raise PlantFileError(f"{path}: [atmosphere] must be a table (airspeed, span, altitude)")
    airspeed, span = (_number(path, atm, "atmosphere", k, required=False) for k in ("airspeed", "span"))
    if (airspeed is None) != (span is None):
        raise PlantFileError(f"{path}: [atmosphere] needs both airspeed (m/s) and span (m), or neither")
    return LinearPlant(
        name=str(doc.get("name", path.stem)),
        a_p=a_p,
        b_p=b_p,
        c_p=c_p,
        truth=truth,
        surface=surface,
        limit_rad=_number(path, inp, "input", "limit", required=False),
        rate_limit_rad_s=_number(path, inp, "input", "rate_limit", required=False),
        states=tuple(states),
        units=tuple(str(u) for u in units),
        input_name=str(inp.get("name", "delta")),
        output_name=str(out.get("name", "phi")),
        airspeed_m_s=airspeed,
        span_m=span,
        altitude_m=_number(path, atm, "atmosphere", "altitude", required=False),
    )
