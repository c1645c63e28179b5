"""The registry of controllers (``autopilot.controllers``; docs/architecture.md, "Laws"): what the command
lines offer, what the autopilot builds and flies, and what the experiments and studies name all come from it."""

from __future__ import annotations

import math

import pytest

from autopilot import controllers
from autopilot.baseline import Baseline, BaselineConfig
from autopilot.clsac import ClSac
from autopilot.config import ClSacConfig
from autopilot.step import ControlStep

OPTIONS = dict(control_rate_hz=100.0, u_limit_rad=math.radians(30.0))


BUILT_IN = ("sac", "clsac", "baseline", "pid-ff", "mrac", "crm-mrac", "l1", "indi")


def _help(parser, flag="--controller"):
    return next(a.help for a in parser._actions if flag in a.option_strings)


def test_the_command_lines_offer_the_registered_controllers():
    from autopilot.__main__ import build_parser as autopilot_parser
    from tools.launch import build_parser as launch_parser

    assert controllers.NAMES == BUILT_IN
    for parser in (autopilot_parser(), launch_parser()):
        assert all(f"{n} (" in _help(parser) for n in BUILT_IN) and "FILE.py:Class" in _help(parser)
    for n in BUILT_IN:  # a user's own law too: tests/autopilot/test_law.py
        assert launch_parser().parse_args(["--controller", n]).controller == n
    assert launch_parser().parse_args([]).controller == controllers.DEFAULT == "clsac"


@pytest.mark.parametrize("name", controllers.NAMES)
def test_each_controller_builds_and_flies_its_law(name):
    c = controllers.get(name)
    cfg = c.config(**OPTIONS, gains=None)
    assert controllers.law_of(cfg) is c.kind
    law = controllers.make_law(cfg)
    assert controllers.law_of(law) is c.kind
    # a law on the interface of autopilot.law (the bench's) flies through autopilot.law.Flown
    assert type(law.inner if c.kind.generic else law) is c.kind.law_class()
    step = ControlStep(cfg)
    assert type(step.law) is type(law)
    assert math.isfinite(step(0.0, 0.0).u)


def test_the_registry_says_what_each_law_is():
    clsac = controllers.get("clsac").config(**OPTIONS)
    assert isinstance(clsac, ClSacConfig) and clsac.lv == 20.0 and clsac == ClSacConfig(**OPTIONS)  # the paper's
    assert controllers.get("sac").config(**OPTIONS, lv=7.0).lv == 7.0  # the table's L_v; mode SAC flies 0
    assert controllers.flown_lv("sac", 7.0) == 0.0 and controllers.flown_lv("clsac", 7.0) == 7.0
    base = controllers.get("baseline").config(**OPTIONS, gains=(1.0, 0.5, 0.25))
    assert (base.kp, base.ki, base.kd) == (1.0, 0.5, 0.25) and isinstance(base, BaselineConfig)
    assert isinstance(controllers.make_law(base), Baseline) and isinstance(controllers.make_law(clsac), ClSac)
    assert [c.adaptive for c in controllers.CONTROLLERS.values()] == [True, True] + [False] * 6
    ff = controllers.get("pid-ff").config(**OPTIONS, gains=(1.0, 0.5, 0.25, 0.125))
    assert (ff.kp, ff.ki, ff.kd, ff.kff, ff.derivative) == (1.0, 0.5, 0.25, 0.125, "measurement")
    assert controllers.get("pid-ff").law == "baseline" and isinstance(controllers.make_law(ff), Baseline)
    assert base.kff == 0.0 and base.derivative == "error"  # the baseline is unchanged
    assert controllers.LAWS["clsac"].modes == ("SAC", "CLSAC") and controllers.LAWS["baseline"].modes == ("BASELINE",)


def test_an_unknown_controller_or_law_is_refused_by_name():
    known = "sac, clsac, baseline, pid-ff, mrac, crm-mrac, l1, indi, FILE.py:Class, module:Class"
    with pytest.raises(ValueError, match=f"unknown controller 'lqr' \\(known: {known}\\)"):
        controllers.get("lqr")
    with pytest.raises(ValueError, match="not a registered law"):
        controllers.law_of(object())


def test_the_experiments_and_studies_read_the_registry():
    from tools.experiment.scenario import BASELINE_RUN, PAPER_RUNS, run_of
    from tools.experiment.study import flights

    # the flights of a JSBSim aircraft or plant file: by default the laws of the published tables
    assert flights.CONTROLLERS == ("sac", "clsac", "baseline", "pid-ff")
    assert (run_of("sac"), run_of("clsac"), run_of("baseline")) == (PAPER_RUNS[0], PAPER_RUNS[1], BASELINE_RUN)
    # the robustness study's controllers: the registry's, its choices and CL-SAC's VARIANTS, labels from the records
    studied = {n: controllers.studied(n) for n in controllers.ROBUSTNESS}
    assert {c.law for c in studied.values()} == {"clsac", "baseline"}
    assert [n for n, c in studied.items() if not c.adaptive] == ["baseline"]
    assert studied["baseline"] is controllers.CONTROLLERS["baseline"] and set(controllers.VARIANTS) < set(studied)
    assert studied["clsac"].robustness_words == "CL-SAC Lv 20 (paper)" and studied["sac"].robustness_words == "SAC"
    assert studied["baseline"].robustness_words == controllers.CONTROLLERS["baseline"].label == "fixed-gain PID"
    assert not set(controllers.VARIANTS) & set(controllers.NAMES)  # not --controller choices
    with pytest.raises(ValueError, match="unknown controller 'pid-ff'"):
        controllers.studied("pid-ff")  # a --controller choice the batched study does not compare
    # the damage study's default set: the records with a damage place, in its order, labelled by the registry
    from tools.experiment.damage import grid

    assert grid.CONTROLLERS[:4] == ("baseline", "sac", "clsac", "pid-ff")
    assert [controllers.get(n).damage for n in grid.CONTROLLERS[:4]] == [0, 1, 2, 3]
    assert grid.label("baseline") == controllers.get("baseline").study_label and grid.label("sac") == "SAC"
