"""The plant kinds as records (sitl/plant_kinds.py): one interface (Plant), one table (KINDS), a --plant value parsed
once into a PlantSpec that every consumer reads, MIMO a property of the plant, and no test of a plant's kind
outside the table."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from sitl import plant as plants
from sitl import plant_kinds

ROOT = Path(__file__).resolve().parents[2]
MIMO = "jsbsim:c172x:surface=aileron+rudder"


def test_each_text_has_one_kind_from_the_table():
    assert [plants.kind(t) for t in ("kh2013a", "jsbsim:c172x", MIMO, "my.toml", "kh2013a.toml")] == [
        "kh2013a",
        "jsbsim",
        "jsbsim",
        "file",
        "file",
    ]
    assert list(plant_kinds.KINDS) == ["kh2013a", "jsbsim", "file"]


def test_the_kh2013a_and_a_plant_file_build_a_plant_of_the_interface():
    for text in ("kh2013a", str(plants.shipped("kh2013a.toml"))):
        p = plants.build(text, 1000.0)
        assert isinstance(p, plant_kinds.Plant)
        x = p.advance(0.01, 5)
        assert x.shape == (6,) and p.steps == 5 and p.time == pytest.approx(0.005)
    # the shipped file is the paper's plant: the same response from the same command
    a = plants.build("kh2013a", 1000.0).advance(0.02, 200)
    b = plants.build(str(plants.shipped("kh2013a.toml")), 1000.0).advance(0.02, 200)
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)


def test_a_jsbsim_aircraft_is_a_plant_of_the_interface():
    pytest.importorskip("jsbsim")
    p = plants.build("jsbsim:c172x", 1000.0)
    assert isinstance(p, plant_kinds.Plant)
    x = p.advance(0.0, 10)
    assert x.shape == (6,) and p.steps == 10 and len(p.attitude()) == 6


def test_a_spec_is_parsed_once_and_again_when_its_file_changes(tmp_path):
    src = plants.shipped("kh2013a.toml").read_text(encoding="utf-8")
    path = tmp_path / "mine.toml"
    path.write_text(src, encoding="utf-8")
    first = plants.spec(str(path))
    assert plants.spec(str(path)) is first  # one parse, read by every consumer
    assert plants.spec(first) is first
    path.write_text(src.replace('name = "kh2013a"', 'name = "Renamed"', 1) + "\n", encoding="utf-8")
    again = plants.spec(str(path))
    assert again is not first and again.name == "Renamed" != first.name
    with pytest.raises(plants.PlantError):
        plants.spec(str(tmp_path / "absent.toml"))


def test_mimo_is_a_property_of_the_plant_record():
    assert plants.spec(MIMO).mimo and plants.spec(MIMO).surfaces == ("aileron", "rudder")
    assert plants.spec(MIMO).surface == "aileron+rudder"  # what --plant's surface says, as before
    assert not plants.spec("jsbsim:c172x").mimo and not plants.spec("kh2013a").mimo
    assert plants.spec(str(plants.shipped("jsbsim-c172x-aileron+rudder.toml"))).mimo  # a 2-input plant file too
    assert not plants.spec(str(plants.shipped("kh2013a.toml"))).mimo


def test_what_the_record_says_of_each_kind():
    texts = ("kh2013a", "jsbsim:c172x:surface=rudder", str(plants.shipped("kh2013a.toml")))
    kh, js, f = (plants.spec(t) for t in texts)
    assert (kh.paper, kh.batched, kh.design_file, kh.name) == (True, True, None, "KH2013A")
    assert (js.paper, js.own_atmosphere, js.euler, js.name) == (False, True, True, "c172x-rudder")
    assert js.design_file == plants.shipped("jsbsim-c172x-rudder.params")
    assert f.design_file == plants.shipped("kh2013a.params") and f.linear is f.model and f.jsbsim is None
    assert plants.check_disturbances("kh2013a", {"scale": None}) is None
    with pytest.raises(plants.PlantError, match="--gust cannot fly on --plant jsbsim:c172x"):
        plants.check_disturbances("jsbsim:c172x", {"gust": "x"})


# Kind tests a module outside the table might write: a kind's name compared, a JSBSim spec told by its prefix, a
# MIMO plant told by its text.
KIND_TEST = re.compile(
    r"""kind\([^)]*\)\s*[!=]=|\.kind\s*[!=]=\s*["'](file|jsbsim|kh2013a)["']|startswith\(\s*["']jsbsim:["']\s*\)"""
    r"""|^def is_mimo\(plant|["']\+["']\s+in\s+\w*plant|\(["'](jsbsim|file)["'],\s*["'](jsbsim|file)["']\)"""
)


def test_no_module_tests_a_plant_kind_outside_the_table():
    bad = []
    for package in ("autopilot", "sitl", "tools"):
        for path in sorted((ROOT / package).rglob("*.py")):
            if path == ROOT / "sitl" / "plant_kinds.py":
                continue
            for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                if KIND_TEST.search(line):
                    bad.append(f"{path.relative_to(ROOT)}:{i}: {line.strip()}")
    assert bad == []


def test_the_kind_test_finds_what_it_is_for():
    lines = (
        'if plants.kind(t) == "jsbsim":',
        'x = t.startswith("jsbsim:")',
        "def is_mimo(plant):",
        'k in ("jsbsim", "file")',
    )
    for line in lines:
        assert KIND_TEST.search(line), line


def test_every_plant_flags_help_is_written_from_the_kinds_records(monkeypatch):
    """Wherever --plant is defined, its help says each kind's syntax and words as its record has them (in the
    table's order); a kind added to the table (here a fourth record, put before the catch-all) is in every help."""
    import argparse
    import dataclasses

    import sitl.__main__ as sitl_main
    import tools.launch
    import tools.pfc
    from tools.experiment import cli as experiment_cli
    from tools.experiment import delay_margin
    from tools.experiment.damage import cli as damage_cli
    from tools.experiment.study import cli as study_cli

    parsers = (
        sitl_main.build_parser, tools.launch.build_parser, experiment_cli.build_parser, delay_margin.build_parser,
        damage_cli.build_parser, study_cli.build_parser,
    )  # fmt: skip

    def plant_help(build) -> str:
        p = build()
        parsers = [p] + [s for a in p._actions if isinstance(a, argparse._SubParsersAction) for s in a.choices.values()]  # noqa: SLF001
        (action,) = [a for q in parsers for a in q._actions if "--plant" in a.option_strings][:1]  # noqa: SLF001
        return " ".join(str(action.help).split())

    for build in parsers:
        text = plant_help(build)
        places = [text.index(f"{k.syntax} ({k.words}") for k in plant_kinds.KINDS.values()]
        assert places == sorted(places), (build.__module__, text)
    assert plant_kinds.KINDS["file"].words in plant_help(tools.pfc.build_parser)  # its --plant takes a file only
    new = dataclasses.replace(plant_kinds.KINDS["kh2013a"], name="toy", syntax="toy:N", words="a toy for this test")
    table = dict(plant_kinds.KINDS)
    monkeypatch.setattr(
        plant_kinds, "KINDS", {**{k: v for k, v in table.items() if k != "file"}, "toy": new, "file": table["file"]}
    )
    for build in parsers:
        assert "toy:N (a toy for this test" in plant_help(build), build.__module__
