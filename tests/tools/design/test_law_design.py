"""tools.design.laws: the adaptive-law bench's designs (the residualised roll model, pole placement, the stated rules,
the NAME value lines), checked against independent computations (numpy/scipy written here) and the shipped files."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from autopilot import indi, l1, mrac
from sitl.model import A_P, B_P, C_P, P
from tools.design import laws
from tools.design.linearise import linear_model

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def kh():
    return laws.design_plant("kh2013a")


@pytest.fixture(scope="module")
def c172x():
    return laws.design_plant("jsbsim:c172x")


def test_residualised_roll_model_keeps_the_steady_state_and_the_slow_poles():
    model = laws.roll_model(A_P, B_P, C_P, P)
    # The full plant's steady roll and roll rate per rad of surface, -C A^-1 B, against the 2-state model's.
    full = -np.linalg.solve(A_P, B_P[:, 0])[[3, 1]]
    reduced = -np.linalg.solve(model.a, model.b)
    assert reduced == pytest.approx(full, rel=1e-9, abs=1e-12)
    # Its poles near the full plant's two slow ones (roll subsidence -2.45, spiral -0.57): within 10 %.
    slow = sorted(e.real for e in np.linalg.eigvals(A_P) if abs(e) < 5)
    assert sorted(np.linalg.eigvals(model.a).real) == pytest.approx(slow, rel=0.1)
    assert model.g_hf == 59.7 and model.servo_wn == pytest.approx(math.sqrt(2367.0))


def test_a_plant_the_laws_cannot_fly_gets_a_reason():
    assert "roll-rate" in laws.roll_model(A_P, B_P, C_P, None)
    a = np.array(A_P)
    a[:4, 4] *= -1.0  # the surface rolls the wrong way
    assert "effectiveness" in laws.roll_model(a, B_P, C_P, P)
    two_outputs = np.vstack([C_P, np.eye(6)[1]])
    assert "one state" in laws.roll_model(A_P, B_P, two_outputs, P)


def test_place_puts_the_poles_where_asked():
    a = np.array([[0.0, 1.0, 0.0], [0.0, 0.3, 1.1], [0.0, -2.2, -3.2]])
    b = np.array([0.0, 0.1, 196.0])
    k = laws.place(a, b, [-2.0, -4.0, -6.0])
    assert sorted(np.linalg.eigvals(a - np.outer(b, k)).real) == pytest.approx([-6.0, -4.0, -2.0], rel=1e-9)


def _closed_loop_poles(k_phi, k_p, k_i=None, f=1.0):
    """The full continuous KH2013A under u = -(k_i x_I + k_phi phi + k_p p), the surface's effect scaled by f."""
    a = np.array(A_P)
    a[:4, 4] *= f
    n = 7 if k_i is not None else 6
    cl = np.zeros((n, n))
    cl[:6, :6] = a
    gain = np.zeros(n)
    gain[3], gain[1] = k_phi, k_p
    if k_i is not None:
        cl[6, 3], gain[6] = 1.0, k_i
    cl[:6] -= np.outer(B_P[:, 0], gain)
    return np.linalg.eigvals(cl)


def test_kh2013a_designs_are_the_laws_defaults_and_meet_their_rules(kh):
    assert set(kh) == set(laws.LAWS) and not any(isinstance(v, str) for v in kh.values())
    assert kh["mrac"][0] == mrac.MracConfig()
    assert kh["crm-mrac"][0] == mrac.crm_config()
    assert kh["l1"][0] == l1.L1Config()
    assert kh["indi"][0] == indi.IndiConfig()
    m = kh["mrac"][0]
    for f in laws.ROBUST_GAINS:
        assert max(_closed_loop_poles(m.k_phi, m.k_p, m.k_i, f).real) < 0
        c = kh["l1"][0]
        assert max(_closed_loop_poles(c.k_phi, c.k_p, None, f).real) < 0
    # The L1-norm condition's value, printed in the design's notes, below 1 and recomputed here.
    cfg = kh["l1"][0]
    lam = l1.l1_condition(cfg, abs(cfg.a22) / cfg.b2)
    assert 0 < lam < 1
    assert f"= {lam:.4g} < 1" in " ".join(kh["l1"][1])
    print("\n" + "\n".join(f"{law}: {note}" for law, (_, notes) in kh.items() for note in notes))


def test_c172x_designs_every_law(c172x):
    assert set(c172x) == set(laws.LAWS) and not any(isinstance(v, str) for v in c172x.values())
    assert c172x["mrac"][0].u_limit_rad == pytest.approx(math.radians(17.5))  # the file's aileron limit
    model = laws.roll_model(*linear_model("jsbsim:c172x"))
    assert c172x["indi"][0].g0 == pytest.approx(model.b[1])
    print("\n" + "\n".join(f"{law}: {note}" for law, (_, notes) in c172x.items() for note in notes))


@pytest.mark.parametrize("plant, name", [("kh2013a", "kh2013a-laws.params"), ("c172x", "jsbsim-c172x-laws.params")])
def test_shipped_files_are_the_designs_lines(kh, c172x, plant, name):
    designs = kh if plant == "kh2013a" else c172x
    shipped = (ROOT / "sitl" / "plants" / name).read_text(encoding="utf-8").splitlines()
    assert shipped[1:] == laws.params_lines(designs)
    values = dict(line.split() for line in shipped if line and not line.startswith("#"))
    tables = mrac.PARAMETERS + mrac.CRM_PARAMETERS + l1.PARAMETERS + indi.PARAMETERS
    assert set(values) == {row[0] for row in tables}
    for row in tables:
        law = {"MRAC": "mrac", "CRM": "crm-mrac", "L1": "l1", "INDI": "indi"}[row[0].split("_")[0]]
        assert float(values[row[0]]) == getattr(designs[law][0], row[1])  # repr round-trips


def test_cli_writes_lines_and_refuses_a_bad_plant_in_one_line(tmp_path):
    bad = subprocess.run([sys.executable, "-m", "tools.design.laws", str(tmp_path / "none.toml")],
                         capture_output=True, text=True, timeout=120, cwd=ROOT)  # fmt: skip
    assert bad.returncode == 2
    assert bad.stderr.count("\n") == 1 and bad.stderr.startswith("error: ") and "Traceback" not in bad.stderr
