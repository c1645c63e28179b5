"""tools.pfc design on ordinary plants the transfer-function conversion used to call "num is zero", and the true
reasons where the method does not apply; the critical gains and F's zeros checked against numbers computed here
from the matrices alone (frequency responses by linear solves, the Rosenbrock pencil), not with the design's
polynomials."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
import scipy.linalg
from scipy.optimize import brentq

from autopilot.params import load_file
from sitl import linear_plant, model
from tools.design.aspr import plant_tf, tf_coefficients
from tools.design.tuning import PfcDesignError, check_authority, design_pfc

SERVO = f"[servo]\nwn2 = {model.SERVO_WN2!r}\ntwo_zeta_wn = {model.SERVO_2ZETA_WN!r}\n"


def _file(tmp_path, airframe: str, name: str = "plant.toml"):
    f = tmp_path / name
    f.write_text("[airframe]\n" + airframe + SERVO)
    return f


def _chain(n: int) -> str:
    a = [[-1.0 if i == j else (1.0 if i == j + 1 else 0.0) for j in range(n)] for i in range(n)]
    return f"A = {a!r}\nB = {[[1.0]] + [[0.0]] * (n - 1)!r}\nC = {[[0.0] * (n - 1) + [1.0]]!r}\nroll = 'x{n}'\n"


def _response(mats, w: float) -> complex:
    """T(jw) = C (jw I - A)^-1 B by a linear solve."""
    a, b, c = mats
    return complex((c @ np.linalg.solve(1j * w * np.eye(a.shape[0]) - a, b)).item())


def _critical_gain(mats, a: float) -> float:
    """The least g of C = g (s + a) at which 1 + C T reaches the imaginary axis, for a stable T: where the phase of
    (jw + a) T(jw), unwrapped from w -> 0, first crosses -180 deg (Nyquist), g = 1 / |(jw + a) T(jw)| there."""
    ws = np.logspace(-4, 4, 20000)
    phase = np.unwrap([np.angle((1j * w + a) * _response(mats, w)) for w in ws])
    i = int(np.argmax(phase < -math.pi))
    f = lambda lw: np.interp(lw, np.log(ws), phase) + math.pi  # noqa: E731
    w0 = math.exp(brentq(f, math.log(ws[i - 1]), math.log(ws[i])))
    return 1.0 / abs((1j * w0 + a) * _response(mats, w0))


def _f_zeros(mats, k: float, a: float) -> np.ndarray:
    """Zeros of F = T + k/(s + a): the finite generalised eigenvalues of the Rosenbrock pencil of the parallel
    realisation."""
    a_p, b_p, c_p = mats
    n = a_p.shape[0]
    big = np.zeros((n + 2, n + 2))
    big[:n, :n], big[n, n] = a_p, -a
    big[: n + 1, n + 1 :] = np.vstack([b_p, [[1.0]]])
    big[n + 1 :, : n + 1] = np.hstack([c_p, [[k]]])
    e = np.zeros_like(big)
    e[: n + 1, : n + 1] = np.eye(n + 1)
    z = scipy.linalg.eigvals(big, e)
    return z[np.isfinite(z)]


@pytest.mark.parametrize("n", [2, 3, 5])
def test_a_chain_of_first_order_lags_designs_with_the_critical_gain_of_its_frequency_response(tmp_path, n):
    lp = linear_plant.load(_file(tmp_path, _chain(n)))
    mats = (lp.a_p, lp.b_p, lp.c_p)
    pfc = design_pfc(mats)
    assert pfc.critical_gain == pytest.approx(_critical_gain(mats, pfc.a), rel=1e-4)
    assert pfc.k == pytest.approx(pfc.margin / pfc.critical_gain, rel=1e-12)
    zeros = _f_zeros(mats, pfc.k, pfc.a)
    assert zeros.size == n + 2 and np.all(zeros.real < 0)  # F minimum phase, relative degree 1 (k > 0)


def test_one_over_s_plus_one_squared_designs_end_to_end(tmp_path):
    f = _file(tmp_path, "num = [1.0]\nden = [1.0, 2.0, 1.0]\n", "lag2.toml")
    out = tmp_path / "lag2.params"
    r = subprocess.run(
        [sys.executable, "-m", "tools.pfc", "design", str(f), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""  # no warnings on the way
    v = load_file(out)
    lp = linear_plant.load(f)
    zeros = _f_zeros((lp.a_p, lp.b_p, lp.c_p), v["CLSAC_PFC_NUM"], v["CLSAC_PFC_DEN0"])
    assert np.all(zeros.real < 0) and v["CLSAC_PFC_NUM"] > 0


def test_fifty_states_design_their_pfc(tmp_path):
    """At the order limit the PFC's critical gain still agrees with the frequency response."""
    lp = linear_plant.load(_file(tmp_path, _chain(50)))
    mats = (lp.a_p, lp.b_p, lp.c_p)
    pfc = design_pfc(mats, corners=(1.0,))
    assert pfc.critical_gain == pytest.approx(_critical_gain(mats, 1.0), rel=1e-4)


def test_a_non_minimum_phase_plant_designs_a_minimum_phase_f(tmp_path):
    """num = [-1, 2] (a zero at +2) behind an integrator: C = g (s + a) stabilises it at small gains, so Barkana's
    rule applies (F's zeros are the closed-loop poles of 1 + C T, not T's zeros): the design is W-ASPR."""
    lp = linear_plant.load(_file(tmp_path, "num = [-1.0, 2.0]\nden = [1.0, 3.0, 2.0, 0.0]\n"))
    mats = (lp.a_p, lp.b_p, lp.c_p)
    tn, _td = tf_coefficients(plant_tf(mats))
    assert np.roots(tn) == pytest.approx([2.0])  # T keeps its zero at +2
    pfc = design_pfc(mats)
    assert np.all(_f_zeros(mats, pfc.k, pfc.a).real < 0)


ROLL = "A = [[-2.0, 0.0], [1.0, 0.0]]\nB = [[{b}], [0.0]]\nC = [[0.0, 1.0]]\nroll = 'x2'\n"
W0 = 2 * math.pi / 10.0  # the fundamental of the reference scenario's 10 s square wave


def _authority(tn, td):
    check_authority(tn, td, math.radians(30.0), math.radians(10.0), 10.0)


def test_a_surface_that_cannot_move_the_plant_is_named_with_its_numbers(tmp_path):
    """B = 1e-300: |T(j w0)| times the 30 deg limit is far below the 10 deg commanded."""
    lp = linear_plant.load(_file(tmp_path, ROLL.format(b=1e-300)))
    mats = (lp.a_p, lp.b_p, lp.c_p)
    assert abs(_response(mats, W0)) * 30.0 < 1e-290
    with pytest.raises(PfcDesignError, match=r"rolls it by at most .*e-29\d deg at 0.628 rad/s"):
        _authority(*tf_coefficients(plant_tf(mats)))


def test_the_authority_bound_at_its_boundary(tmp_path):
    """The roll mode with its gain scaled to reach 10.001 deg at w0 at full surface (a linear solve gives |T(j w0)|):
    accepted; 9.999 deg: refused."""
    lp = linear_plant.load(_file(tmp_path, ROLL.format(b=30.0)))
    mats = (lp.a_p, lp.b_p, lp.c_p)
    reach_deg = abs(_response(mats, W0)) * 30.0
    tn, td = tf_coefficients(plant_tf(mats))
    _authority(tn * (10.001 / reach_deg), td)
    with pytest.raises(PfcDesignError, match="cannot move"):
        _authority(tn * (9.999 / reach_deg), td)


REASONS = {
    "B = 1e-300": (
        "A = [[-2.0, 0.0], [1.0, 0.0]]\nB = [[1e-300], [0.0]]\nC = [[0.0, 1.0]]\nroll = 'x2'\n",
        "cannot move",
    ),
    "a +200 1/s pole": ("num = [1.0]\nden = [1.0, -200.0, 0.0]\n", "cannot move"),
    "order 51": (_chain(51), "order 51, above the maximum of 50"),
    "B = 0": ("A = [[-2.0, 0.0], [1.0, 0.0]]\nB = [[0.0], [0.0]]\nC = [[0.0, 1.0]]\nroll = 'x2'\n", "uncontrollable"),
}


@pytest.mark.parametrize("case", REASONS)
def test_where_the_method_does_not_apply_the_reason_is_one_line_exit_2(tmp_path, case):
    text, needle = REASONS[case]
    f = _file(tmp_path, text)
    r = subprocess.run(
        [sys.executable, "-m", "tools.pfc", "design", str(f), "--out", str(tmp_path / "x.params")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and needle in r.stderr and "num is zero" not in r.stderr


@pytest.mark.parametrize("b", ["1e-300", "1e-12"])
def test_the_analysis_of_a_plant_no_surface_moves_is_one_line_exit_2(tmp_path, b, capsys):
    """Issue 35: ``python -m tools.pfc --plant FILE`` with B = 1e-300 exited 1, "analysis failed: band [...] failed
    its root check": the plant's own numbers, so one line naming the file and why, exit 2, as the design says it.
    |T(j w0)| = 1e-300 / |j w0 (j w0 + 2)| at w0 = 2 pi / 10 s, far below the 10 deg / 30 deg the scenario needs."""
    from tools import pfc

    f = _file(tmp_path, f"A = [[-2.0, 0.0], [1.0, 0.0]]\nB = [[{b}], [0.0]]\nC = [[0.0, 1.0]]\nroll = 'x2'\n")
    with pytest.raises(SystemExit) as exc:
        pfc.main(["--plant", str(f)])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and len(err.splitlines()) == 1, err
    assert err.startswith(f"python -m tools.pfc: error: --plant {f}: the surface cannot move this plant enough")
    w0 = 2 * math.pi / 10
    gain = float(b) / abs(1j * w0 * (1j * w0 + 2.0))  # the servo's gain is 1 at w0 to 0.1 %
    assert f"|T(j w) = {gain:.3g};" in err.replace("|T(j w)| = ", "|T(j w) = ")


def test_an_open_loop_unstable_plant_that_no_gain_stabilises_from_zero_is_told_so(tmp_path):
    """1/(s - 1) behind the servo and an integrator: unstable at g -> 0 (the pole at +1), so the method (C stabilising
    T from g = 0 up) does not apply; the reason names the pole."""
    lp = linear_plant.load(_file(tmp_path, "num = [1.0]\nden = [1.0, -1.0, 0.0]\n"))
    with pytest.raises(PfcDesignError, match=r"open-loop unstable: pole at 1\b"):
        design_pfc((lp.a_p, lp.b_p, lp.c_p))
