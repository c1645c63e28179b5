"""The parameter table, the law's reconfiguration in flight and the bumpless transfer, without processes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.clsac import ClSac
from autopilot.config import ClSacConfig, ConfigError
from autopilot.params import PARAM_ID_LEN, PARAMS, ParamError, ParamTable, load_file, save_file
from autopilot.step import TRANSFER_TAU_S, ControlStep

OPTIONS = {"attitude_timeout_s": 0.1, "setpoint_timeout_s": 1.0, "max_roll_rad": 0.7}


def test_names_and_values_of_the_paper_law():
    t = ParamTable(ClSacConfig(), OPTIONS)
    assert len(t) == len(PARAMS) == 23 and all(len(p.name) <= PARAM_ID_LEN == 16 for p in PARAMS)
    assert {"CLSAC_LV", "CLSAC_SIGMA"} <= {p.name for p in PARAMS}
    v = dict(t.items())
    assert v["CLSAC_LV"] == 20 and v["CLSAC_SIGMA"] == 5 and v["CLSAC_AM"] == -5 and v["CLSAC_PFC_DEN1"] == 4
    assert v["CLSAC_U_LIMIT"] == math.radians(30) and v["CLSAC_FS_ATT_TMO"] == 0.1 and v["CLSAC_RATE"] == 100


def test_sets_are_validated_and_a_refused_one_changes_nothing():
    t = ParamTable(ClSacConfig(), OPTIONS)
    assert t.set("CLSAC_PFC_DEN1", 1.0) == 1.0 and t.config.pfc_den == (1.0, 40.0)
    for name, value, match in (
        ("CLSAC_GAM_PE", -1.0, r"CLSAC_GAM_PE must be in \[0, 10000\]"),  # the table's bound
        ("CLSAC_AM", 3.0, r"CLSAC_AM must be in \[-10000, 0\)"),
        ("CLSAC_CM", -1.0, r"CLSAC_CM must be in \(0, 10000\]"),  # A_m - L_v C_m = -5 + 20 would not be Hurwitz
        ("CLSAC_PFC_DEN0", -40.0, r"CLSAC_PFC_DEN0 must be in \(0"),  # an unstable PFC
        ("CLSAC_LV", math.nan, "finite"),
        ("CLSAC_ANTIWINDUP", 0.5, "0 or 1"),
        ("CLSAC_FS_ATT_TMO", 0.0, r"\[0.001"),
        ("NO_SUCH", 1.0, "unknown"),
    ):
        before = t.config
        with pytest.raises(ParamError, match=match):
            t.set(name, value)
        assert t.config is before
    t.flying = True
    with pytest.raises(ParamError, match="read-only"):
        t.set("CLSAC_RATE", 50.0)
    with pytest.raises(ParamError):  # a file with one bad value changes nothing
        t.update({"CLSAC_LV": 50.0, "CLSAC_AM": 1.0})
    assert t.get("CLSAC_LV") == 20.0


def test_files_round_trip_in_both_formats(tmp_path):
    t = ParamTable(ClSacConfig(), OPTIONS)
    items = [(n, float(np.float32(v))) for n, v in t.items()]  # as a ground station holds them (REAL32)
    for qgc in (False, True):
        path = tmp_path / f"p{qgc}"
        save_file(path, items, qgc=qgc)
        assert load_file(path) == dict(items)
    (tmp_path / "bad").write_text("CLSAC_LV\n")
    with pytest.raises(ParamError, match="bad:1"):
        load_file(tmp_path / "bad")


def test_reconfigure_with_the_same_config_changes_nothing_and_keeps_the_states():
    a, b = ClSac(ClSacConfig()), ClSac(ClSacConfig())
    for k in range(400):
        y = 0.2 * math.sin(0.03 * k)
        if k == 150:
            b.reconfigure(ClSacConfig())
        assert a(y, 0.17) == b(y, 0.17)
    kept = (b.xm, b.xm_ol, b.ki_e, b.ki_x, b.ki_u)
    b.reconfigure(ClSacConfig(lv=50.0, pfc_num=(10.0,), pfc_den=(1.0, 10.0)))
    assert (b.xm, b.xm_ol, b.ki_e, b.ki_x, b.ki_u) == kept
    assert b._cd[0, 0] * b.xd == pytest.approx(a._cd[0, 0] * a.xd)  # the PFC output y_d does not jump
    with pytest.raises(ConfigError):
        b.reconfigure(ClSacConfig(am=((-5.0, 0.0), (0.0, -5.0)), bm=((5.0,), (5.0,)), cm=((1.0, 0.0),), lv=0.0))


def test_transfer_flies_on_from_the_last_command_and_decays_exponentially():
    step = ControlStep(ClSacConfig())
    for k in range(50):
        step(k * 0.01, 0.0)
    step.armed = False
    assert step(0.5, 0.0).u == 0.0  # disarmed: neutral at once
    step.armed = True
    step.transfer()
    before = ClSac(ClSacConfig())
    before.__dict__.update(step.law.__dict__)  # the law's state before the transfer step
    u0 = step(0.51, 0.05).u
    offset = u0 - step.law.u  # the law's own command this step
    assert u0 == 0.0 and abs(offset) > 1e-3  # the first command is the last one flown, not the law's
    before.hold(u0)  # the PFC driven by what flew (ClSac.hold: the PFC alone)
    assert step.law.xd == before.xd
    decay = math.exp(-0.01 / TRANSFER_TAU_S)
    for k in range(2, 40):  # the offset decays exponentially, exactly
        u = step(0.5 + 0.01 * k, 0.05).u
        assert u == pytest.approx(step.law.u + offset * decay ** (k - 1), abs=1e-12)
