"""Plant files from a hostile or careless hand (sitl.plant_file, sitl.linear_plant): one line, exit 2, quickly, from the
launcher, the SITL and tools.pfc design; and each limit at its boundary (just inside accepted, just outside refused),
against numbers computed here independently (scipy's matrix exponential, the file's size)."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest
import scipy.linalg

from sitl import linear_plant, model, plant_file
from sitl import plant as plants
from sitl.linear_plant import PlantFileError

SERVO = f"[servo]\nwn2 = {model.SERVO_WN2!r}\ntwo_zeta_wn = {model.SERVO_2ZETA_WN!r}\n"
ROLL = """[input]
surface = "aileron"
[airframe]
states = ["p", "phi"]
A = [[-2.0, 0.0], [1.0, 0.0]]
B = [[30.0], [0.0]]
C = [[0.0, 1.0]]
roll = "phi"
roll_rate = "p"
"""
GOOD = ROLL + SERVO


def _write(tmp_path, text: str | bytes, name: str = "plant.toml"):
    f = tmp_path / name
    f.write_bytes(text if isinstance(text, bytes) else text.encode())
    return f


def _refused(path, needle: str) -> str:
    with pytest.raises(PlantFileError) as exc:
        linear_plant.load(path)
    msg = str(exc.value)
    assert needle in msg and str(path) in msg and "\n" not in msg, msg
    return msg


# ----------------------------------------------------------------------------------- the must-show hostile files
def _deep(tmp_path):
    return _write(tmp_path, "[airframe]\nnum = " + "[" * 100_000 + "]" * 100_000 + "\n" + SERVO, "deep.toml")


def _fifo(tmp_path):
    f = tmp_path / "fifo.toml"
    os.mkfifo(f)  # nobody ever writes to it: an open() for reading would block forever
    return f


def _zero(tmp_path):
    f = tmp_path / "zero.toml"
    f.symlink_to("/dev/zero")  # endless bytes: a read to the end would never end
    return f


HOSTILE = {
    "input = 5": (
        lambda p: _write(p, "input = 5\n" + GOOD.replace('[input]\nsurface = "aileron"\n', "")),
        "input must",
    ),
    "wn2 = 1e300": (lambda p: _write(p, ROLL + "[servo]\nwn2 = 1e300\ntwo_zeta_wn = 72.22\n"), "servo's poles"),
    "A = 1e300": (lambda p: _write(p, GOOD.replace("-2.0", "1e300")), "puts a pole at |s| = 1e+300 rad/s"),
    "100,000-deep nesting": (_deep, "nested too deeply"),
    "a FIFO": (_fifo, "it is a FIFO"),
    "a symlink to /dev/zero": (_zero, "it is a character device"),
    "den misspelt": (
        lambda p: _write(p, GOOD.replace("A = ", "num = [30.0]\ndne = [1.0, 2.0, 0.0]\nA = ")),
        "no den",
    ),
}
TOOLS = {
    "launcher": lambda f, tmp: [sys.executable, "-m", "tools.launch", "--lockstep", "--plant", str(f), "--out", tmp],
    "sitl": lambda f, tmp: [sys.executable, "-m", "sitl", "--plant", str(f), "--duration", "0.01"],
    "tools.pfc design": lambda f, tmp: [sys.executable, "-m", "tools.pfc", "design", str(f), "--out", f"{tmp}.params"],
}


@pytest.mark.parametrize("tool", TOOLS)
@pytest.mark.parametrize("case", HOSTILE)
def test_a_hostile_plant_file_is_one_line_exit_2_quickly(tmp_path, case, tool):
    make, needle = HOSTILE[case]
    f = make(tmp_path)
    t0 = time.monotonic()
    r = subprocess.run(TOOLS[tool](f, str(tmp_path / "run")), capture_output=True, text=True, timeout=60)
    assert time.monotonic() - t0 < 60
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    lines = r.stderr.strip().splitlines()
    assert "Traceback" not in r.stderr and len(lines) == 1, r.stderr[-2000:]
    assert needle in lines[0] and str(f) in lines[0]
    if case == "den misspelt":
        assert "num and den under [airframe]" in lines[0]


# --------------------------------------------------------------------------------------------- what is read
def test_only_a_regular_file_is_read(tmp_path):
    _refused(tmp_path, "it is a folder")
    link = tmp_path / "urandom.toml"
    link.symlink_to("/dev/urandom")
    _refused(link, "it is a character device")
    _refused(tmp_path / "missing.toml", "cannot read: No such file or directory")
    good = _write(tmp_path, GOOD)
    alias = tmp_path / "alias.toml"
    alias.symlink_to(good)  # a symlink to a regular file is followed
    assert linear_plant.load(alias).states == ("p", "phi")


def test_the_size_limit_at_its_boundary(tmp_path):
    pad = plant_file.MAX_BYTES - len(GOOD.encode()) - 3  # "# " + pad + "\n"
    at = _write(tmp_path, "# " + "x" * pad + "\n" + GOOD, "at.toml")
    assert at.stat().st_size == plant_file.MAX_BYTES == 1 << 20
    assert linear_plant.load(at).name == "at"
    over = _write(tmp_path, "# " + "x" * (pad + 1) + "\n" + GOOD, "over.toml")
    assert over.stat().st_size == plant_file.MAX_BYTES + 1
    _refused(over, f"{plant_file.MAX_BYTES + 1} bytes, above the {plant_file.MAX_BYTES} (1 MiB)")


def test_a_100_mb_name_is_refused_from_its_size_at_once(tmp_path):
    f = _write(tmp_path, 'name = "' + "x" * 1000)
    with open(f, "r+b") as fh:
        fh.truncate(100 * 1024 * 1024)  # 100 MB (sparse): the size alone refuses it, nothing is parsed
    import tracemalloc

    tracemalloc.start()
    try:
        _refused(f, "104857600 bytes")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20, peak  # not read: reading it would hold 100 MB (no time asserted: a loaded machine is slow)


WRONG = {
    "output is a string": ('output = "phi"\n' + GOOD, "output must be a table"),
    "units = 5": (GOOD.replace('roll = "phi"', 'units = 5\nroll = "phi"'), "units must be a list of 2 strings"),
    "units of the wrong length": (
        GOOD.replace('roll = "phi"', 'units = ["rad/s"]\nroll = "phi"'),
        "units must be a list of 2 strings, one per state, got list of 1",
    ),
    "a boolean in A": (GOOD.replace("-2.0", "true"), "A must be a matrix of numbers, got the entry True"),
    "a boolean in num": ("[airframe]\nnum = [true]\nden = [1.0, 2.0, 0.0]\n" + SERVO, "num must be a non-empty list"),
    "a boolean wn2": (ROLL + "[servo]\nwn2 = true\ntwo_zeta_wn = 72.22\n", "wn2 must be a positive finite number"),
    "ragged A": (GOOD.replace("[1.0, 0.0]]", "[1.0]]"), "its rows have different lengths"),
    "surface = 5": (GOOD.replace('surface = "aileron"', "surface = 5"), "surface must be a string"),
    "a name over two lines": ('name = "a\\nb"\n' + GOOD, "one printable line"),
    "unit deg": (GOOD.replace('surface = "aileron"', 'surface = "aileron"\nunit = "deg"'), "unit must be 'rad'"),
    "a limit past 90 deg": (GOOD.replace('surface = "aileron"', 'surface = "aileron"\nlimit = 2.0'), "(0, pi/2]"),
    "states twice": (GOOD.replace('["p", "phi"]', '["phi", "phi"]'), "2 different names"),
    "a misspelt key": (GOOD.replace("roll_rate", "rol_rate"), "unknown key 'rol_rate' in [airframe]: did you mean"),
    "den at the top level": ("den = [1.0, 1.0]\n" + GOOD, "den goes under [airframe]"),
    "num without den": ("[airframe]\nnum = [1.0]\n" + SERVO, "has num but no den"),
    "num/den and A": (GOOD.replace("A = ", "num = [1.0]\nden = [1.0, 1.0]\nA = "), "not both"),
    "no A": ("[airframe]\nroll = 'phi'\n" + SERVO, "give A, B, C (a state space) or num, den"),
}


@pytest.mark.parametrize("case", WRONG)
def test_a_value_of_the_wrong_type_or_shape_is_one_line(tmp_path, case):
    text, needle = WRONG[case]
    _refused(_write(tmp_path, text), needle)


# -------------------------------------------------------------------------------- what cannot be flown or analysed
def test_a_plant_whose_surface_moves_nothing_or_whose_output_shows_nothing_is_refused(tmp_path):
    _refused(_write(tmp_path, GOOD.replace("[[30.0], [0.0]]", "[[0.0], [0.0]]")), "B = 0: the surface moves no state")
    _refused(_write(tmp_path, GOOD.replace("C = [[0.0, 1.0]]", "C = [[0.0, 0.0]]")), "C = 0: the output shows")
    _refused(_write(tmp_path, "[airframe]\nnum = [0.0]\nden = [1.0, 1.0]\n" + SERVO), "num is zero")
    # B drives a state the roll never sees: C (sI - A)^-1 B = 0 although neither B nor C is zero
    hidden = GOOD.replace("A = [[-2.0, 0.0], [1.0, 0.0]]", "A = [[-2.0, 0.0], [0.0, -1.0]]")
    _refused(_write(tmp_path, hidden), "C (sI - A)^-1 B = 0")
    r = subprocess.run(
        [sys.executable, "-m", "sitl", "--plant", str(_write(tmp_path, GOOD.replace("[[30.0]", "[[0.0]")))],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2 and "uncontrollable" in r.stderr  # B = 0 never flies "OK: controlled"


def _chain(n: int) -> str:
    a = [[-1.0 if i == j else (1.0 if i == j + 1 else 0.0) for j in range(n)] for i in range(n)]
    b = [[1.0]] + [[0.0]] * (n - 1)
    c = [[0.0] * (n - 1) + [1.0]]
    return f"[airframe]\nA = {a!r}\nB = {b!r}\nC = {c!r}\nroll = 'x{n}'\n" + SERVO


def test_the_order_limit_at_its_boundary(tmp_path):
    n = linear_plant.MAX_STATES
    assert n == 50
    assert linear_plant.load(_write(tmp_path, _chain(n), "at.toml")).a_p.shape == (n + 2, n + 2)
    _refused(_write(tmp_path, _chain(n + 1), "over.toml"), "order 51, above the maximum of 50")
    den = [1.0] + [0.0] * n
    assert linear_plant.load(_write(tmp_path, f"[airframe]\nnum = [1.0]\nden = {den}\n" + SERVO)).a_p.shape[0] == n + 2
    _refused(_write(tmp_path, f"[airframe]\nnum = [1.0]\nden = {den + [0.0]}\n" + SERVO), "den gives order 51")


def test_the_pole_limit_at_its_boundary(tmp_path):
    def plant(pole):
        return GOOD.replace("A = [[-2.0, 0.0]", f"A = [[{-pole!r}, 0.0]")

    assert linear_plant.MAX_POLE_RAD_S == 1e5
    linear_plant.load(_write(tmp_path, plant(0.99e5)))
    _refused(_write(tmp_path, plant(1.01e5)), "a pole at |s| = 1.01e+05 rad/s, above the 100000 rad/s")
    # the servo's poles |s| = sqrt(wn2) when underdamped
    linear_plant.load(_write(tmp_path, ROLL + "[servo]\nwn2 = 0.98e10\ntwo_zeta_wn = 72.22\n"))
    _refused(_write(tmp_path, ROLL + "[servo]\nwn2 = 1.02e10\ntwo_zeta_wn = 72.22\n"), "|s| = 1.01e+05 rad/s")


def _largest_zoh_entry(b: float, dt: float = 1e-3) -> float:
    """The largest entry of e^(M dt), M = [[A_p, B_p], [0, 0]] of the roll plant with B = [[b], [0]], by scipy."""
    a_p, b_p, _c = linear_plant.augment(
        np.array([[-2.0, 0.0], [1.0, 0.0]]), np.array([[b], [0.0]]), np.zeros((1, 2)), model.SERVO_WN2, 72.22
    )
    m = np.zeros((5, 5))
    m[:4, :4], m[:4, 4:] = a_p, b_p
    return float(np.max(np.abs(scipy.linalg.expm(m * dt))))


def test_the_physics_step_limit_at_its_boundary(tmp_path):
    """B large enough that one 1 ms step multiplies the deflection by just under / just over 1e6 (scipy's expm of
    the augmented plant, not the SITL's own): accepted / refused, at 1 kHz; the same file flies at 10 kHz."""
    per_b = _largest_zoh_entry(1e6) / 1e6  # the entries B enters scale with B
    b_in, b_out = 0.99e6 / per_b, 1.01e6 / per_b
    assert _largest_zoh_entry(b_in) < linear_plant.MAX_STEP_GAIN < _largest_zoh_entry(b_out)
    linear_plant.load(_write(tmp_path, GOOD.replace("[[30.0]", f"[[{b_in!r}]"), "in.toml"))
    out = _write(tmp_path, GOOD.replace("[[30.0]", f"[[{b_out!r}]"), "out.toml")
    _refused(out, "one 1 ms physics step multiplies a state by up to 1.01e+06")
    assert plants.build(str(out), 10_000.0).n == 4  # at 10 kHz the step is ten times smaller: it integrates
    with pytest.raises(plants.PlantError, match="cannot be integrated"):
        plants.build(str(out), 1000.0)
    _refused(_write(tmp_path, GOOD.replace("[[30.0]", "[[1e300]")), "multiplies a state by up to")


def test_the_output_gain_limit_at_its_boundary(tmp_path):
    linear_plant.load(_write(tmp_path, GOOD.replace("C = [[0.0, 1.0]]", "C = [[0.0, 1e6]]")))
    _refused(_write(tmp_path, GOOD.replace("C = [[0.0, 1.0]]", "C = [[0.0, 1.1e6]]")), "above the 1e+06 an output")


def test_the_markov_relative_degree_is_scale_free():
    """1/(s+1)^2 behind the servo has relative degree 4 (C A^3 B = wn2, the lower ones exactly 0), at any surface
    gain; so has the KH2013A (paper sec. 5: T's numerator has degree 2 over its 6th-order denominator)."""
    a = np.array([[-2.0, 1.0], [-1.0, 0.0]])  # observable form of 1/(s^2 + 2 s + 1)
    for gain in (1.0, 1e-300, 1e300 / model.SERVO_WN2**4):
        a_p, b_p, c_p = linear_plant.augment(a, np.array([[0.0], [gain]]), np.array([[1.0, 0.0]]), 2367.0, 72.22)
        assert linear_plant.markov_relative_degree(a_p, b_p, c_p) == 4
    assert linear_plant.markov_relative_degree(model.A_P, model.B_P, model.C_P) == 4
    assert linear_plant.markov_relative_degree(np.eye(2), np.array([[1.0], [0.0]]), np.array([[0.0, 1.0]])) is None
