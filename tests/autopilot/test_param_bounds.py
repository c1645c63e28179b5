"""Each of the 23 parameters lands on its own field, and both bounds of each hold (issue 17, part 5).

The expected field and bounds of every parameter are written out here, from the parameter table of
docs/spec.md ("Parameters"), not read from ``autopilot.params``: a parameter wired to the wrong field or a
bound moved is caught.  The flags that set a parameter refuse exactly what a parameter file refuses.
"""

from __future__ import annotations

import dataclasses
import math

import pytest

from autopilot.__main__ import build_parser as autopilot_parser
from autopilot.config import ClSacConfig
from autopilot.params import PARAMS, ParamError, ParamTable
from tools.flight import FlightConfig, FlightConfigError
from tools.launch import build_parser as launch_parser

OPTIONS = {"attitude_timeout_s": 0.1, "setpoint_timeout_s": 1.0, "max_roll_rad": 0.7, "failure_injection": 0.0}
G = 10_000.0
DEG = math.pi / 180.0

# name: (config field or option, index in a tuple field, low, high, low_open, high_open)
SPEC = {
    "CLSAC_LV": ("lv", None, 0.0, G, False, False),
    "CLSAC_SIGMA": ("sigma", None, 0.0, G, False, False),
    "CLSAC_GAM_PE": ("gamma_pe", None, 0.0, G, False, False),
    "CLSAC_GAM_IE": ("gamma_ie", None, 0.0, G, False, False),
    "CLSAC_GAM_PX": ("gamma_px", None, 0.0, G, False, False),
    "CLSAC_GAM_IX": ("gamma_ix", None, 0.0, G, False, False),
    "CLSAC_GAM_PU": ("gamma_pu", None, 0.0, G, False, False),
    "CLSAC_GAM_IU": ("gamma_iu", None, 0.0, G, False, False),
    "CLSAC_SIGMA_X": ("sigma_x", None, 0.0, G, False, False),
    "CLSAC_SIGMA_U": ("sigma_u", None, 0.0, G, False, False),
    "CLSAC_AM": ("am", None, -G, 0.0, False, True),
    "CLSAC_BM": ("bm", None, -G, G, False, False),
    "CLSAC_CM": ("cm", None, 0.0, G, True, False),
    "CLSAC_PFC_NUM": ("pfc_num", 0, 0.0, G, True, False),
    "CLSAC_PFC_DEN1": ("pfc_den", 0, 0.0, G, True, False),
    "CLSAC_PFC_DEN0": ("pfc_den", 1, 0.0, G, True, False),
    "CLSAC_U_LIMIT": ("u_limit_rad", None, 0.0, math.pi / 2, True, False),
    "CLSAC_ANTIWINDUP": ("anti_windup", None, 0.0, 1.0, False, False),
    "CLSAC_RATE": ("control_rate_hz", None, 0.0, 1000.0, True, False),
    "CLSAC_FS_ATT_TMO": ("attitude_timeout_s", None, 1e-3, 86_400.0, False, False),
    "CLSAC_FS_SP_TMO": ("setpoint_timeout_s", None, 0.01, 86_400.0, False, False),
    "CLSAC_MAX_ROLL": ("max_roll_rad", None, 0.0, math.pi / 2, True, False),
    "SYS_FAILURE_EN": ("failure_injection", None, 0.0, 1.0, False, False),
}


def _delta(bound: float) -> float:
    return 1e-6 * max(1.0, abs(bound))


def inside(name: str) -> tuple[float, float]:
    """The values just inside both bounds: the bound itself when it is allowed, else a hair inside."""
    _, _, lo, hi, lo_open, hi_open = SPEC[name]
    return (lo + _delta(lo) if lo_open else lo), (hi - _delta(hi) if hi_open else hi)


def outside(name: str) -> tuple[float, float]:
    """The values just outside both bounds: the bound itself when it is excluded, else a hair beyond."""
    _, _, lo, hi, lo_open, hi_open = SPEC[name]
    return (lo if lo_open else lo - _delta(lo)), (hi if hi_open else hi + _delta(hi))


def _state(t: ParamTable) -> dict:
    """Every configuration field and every option the table holds."""
    cfg = {f.name: getattr(t.config, f.name) for f in dataclasses.fields(ClSacConfig) if f.init}
    return {**cfg, **{k: t.option(k) for k in OPTIONS}}


def _landed(name: str, state: dict) -> float:
    """The value of parameter ``name`` read from the state, by the spec's field."""
    field, index, *_ = SPEC[name]
    v = state[field]
    return float(v[index] if index is not None else v)


def test_the_spec_covers_every_parameter_once():
    assert [p.name for p in PARAMS] == list(SPEC) and len(SPEC) == 23


@pytest.mark.parametrize("name", list(SPEC))
def test_each_parameter_changes_its_own_field_and_nothing_else(name):
    t = ParamTable(ClSacConfig(), OPTIONS)
    before = _state(t)
    lo, hi = inside(name)
    value = lo if _landed(name, before) != lo else hi  # a value the field does not hold yet
    assert t.set(name, value) == pytest.approx(value, rel=1e-12)
    after = _state(t)
    field = SPEC[name][0]
    assert _landed(name, after) == pytest.approx(value, rel=1e-12)
    changed = {k for k in before if before[k] != after[k]}
    assert changed == {field}, changed
    index = SPEC[name][1]
    if index is not None:  # one element of a tuple field: the others stay
        assert len(after[field]) == len(before[field])
        assert all(a == b for i, (a, b) in enumerate(zip(after[field], before[field])) if i != index)


@pytest.mark.parametrize("name", list(SPEC))
def test_values_just_inside_both_bounds_are_taken_and_just_outside_refused(name):
    for value in inside(name):
        t = ParamTable(ClSacConfig(), OPTIONS)
        assert t.set(name, value) == pytest.approx(value, rel=1e-12), value
        assert _landed(name, _state(t)) == pytest.approx(value, rel=1e-12)
    for value in outside(name):
        t = ParamTable(ClSacConfig(), OPTIONS)
        before = _state(t)
        with pytest.raises(ParamError, match=rf"^{name} must be in "):
            t.set(name, value)
        assert _state(t) == before  # a refused value changes nothing
    with pytest.raises(ParamError):  # a file with one value beyond a bound is refused whole
        ParamTable(ClSacConfig(), OPTIONS).update({"CLSAC_SIGMA": 1.0, name: outside(name)[1]})


def test_antiwindup_takes_zero_or_one_only():
    t = ParamTable(ClSacConfig(), OPTIONS)
    with pytest.raises(ParamError, match="0 or 1"):
        t.set("CLSAC_ANTIWINDUP", 0.5)
    assert t.set("CLSAC_ANTIWINDUP", 0.0) == 0.0 and t.config.anti_windup is False


def test_failure_injection_takes_zero_or_one_only_and_is_off_unless_given():
    t = ParamTable(ClSacConfig(), {k: v for k, v in OPTIONS.items() if k != "failure_injection"})
    assert t.get("SYS_FAILURE_EN") == 0.0  # PX4's default: MAV_CMD_INJECT_FAILURE refused
    with pytest.raises(ParamError, match="SYS_FAILURE_EN must be 0 or 1, got 0.5"):
        t.set("SYS_FAILURE_EN", 0.5)
    assert t.get("SYS_FAILURE_EN") == 0.0
    assert t.set("SYS_FAILURE_EN", 1.0) == 1.0 and t.option("failure_injection") == 1.0


# flag -> (parameter, flag units per SI unit); the autopilot's and the launcher's flags
FLAGS = {
    "--lv": ("CLSAC_LV", 1.0),
    "--sigma-xu": ("CLSAC_SIGMA_X", 1.0),
    "--u-limit-deg": ("CLSAC_U_LIMIT", DEG),
    "--rate": ("CLSAC_RATE", 1.0),
    "--attitude-timeout": ("CLSAC_FS_ATT_TMO", 1.0),
    "--setpoint-timeout": ("CLSAC_FS_SP_TMO", 1.0),
    "--max-roll-deg": ("CLSAC_MAX_ROLL", DEG),
}
LAUNCH_KEYWORDS = {"--lv": "lv", "--sigma-xu": "sigma_xu", "--u-limit-deg": "u_limit_deg", "--rate": "rate"}


def _parses(parser, flag: str, value: float) -> bool:
    try:
        parser.parse_args([flag, repr(value)])
    except SystemExit as exc:
        assert exc.code == 2
        return False
    return True


@pytest.mark.parametrize("flag", list(FLAGS))
def test_a_flag_refuses_exactly_what_a_parameter_file_refuses(flag, capsys):
    name, per = FLAGS[flag]
    parsers = [autopilot_parser()] + ([launch_parser()] if flag in LAUNCH_KEYWORDS else [])
    for value, ok in [(v, True) for v in inside(name)] + [(v, False) for v in outside(name)]:
        flag_value = value / per
        for parser in parsers:
            assert _parses(parser, flag, flag_value) is ok, (parser.prog, flag, flag_value)
        if flag in LAUNCH_KEYWORDS:  # tools.flight.Flight's keyword of the same name
            kw = {LAUNCH_KEYWORDS[flag]: flag_value}
            if ok:
                FlightConfig(**kw)
            else:
                with pytest.raises(FlightConfigError, match=name):
                    FlightConfig(**kw)
    capsys.readouterr()
