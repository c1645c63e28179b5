"""The law interface (autopilot.law) and the one registry (autopilot.controllers): a law of the user's own from a
file or an entry point, checked in one line; flown by the control step with the rates, the limit, the reference
model and the failsafe of a failed law; its parameters and telemetry; the law of docs/adding-a-law.md flown by the
launcher, a ground station, the damage and robustness studies, bit for bit its lockstep flight in-process.
"""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from autopilot import controllers
from autopilot.config import NonFiniteInputError
from autopilot.law import AM, BM, Flown, LawSpecError, check, load
from autopilot.params import ParamError, ParamTable
from autopilot.step import ControlStep, Failsafe, ProfileSetpoints

ROOT = Path(__file__).resolve().parents[2]
PY = sys.executable
OPTIONS = {"attitude_timeout_s": 0.1, "setpoint_timeout_s": 1.0, "max_roll_rad": 0.8}


def docs_law() -> str:
    """The first Python block of docs/adding-a-law.md, verbatim."""
    text = (ROOT / "docs" / "adding-a-law.md").read_text(encoding="utf-8")
    return re.search(r"```python\n(.*?)```", text, re.S).group(1)


@pytest.fixture
def registry():
    """The registry as it was: a test's user laws leave no trace in it."""
    laws, ctrls = dict(controllers.LAWS), dict(controllers.CONTROLLERS)
    yield
    controllers.LAWS.clear()
    controllers.LAWS.update(laws)
    controllers.CONTROLLERS.clear()
    controllers.CONTROLLERS.update(ctrls)


@pytest.fixture
def law_file(tmp_path, registry) -> str:
    """docs/adding-a-law.md's law saved outside the repository; its --controller spec."""
    path = tmp_path / "my_law.py"
    path.write_text(docs_law(), encoding="utf-8")
    return f"{path}:ProportionalFF"


def _write(tmp_path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


# ------------------------------------------------------------------------------------------------ loading
def test_the_docs_law_loads_and_is_registered_by_its_spec(law_file):
    c = controllers.get(law_file)
    assert c.name == law_file and c.mode == "LAW" and c.label == "P + feed-forward"
    d = controllers.describe(law_file)
    assert d["name"] == "p-ff" and d["parameters"] == ["PFF_KP", "PFF_KFF"] and d["telemetry"] == ["error"]
    cfg = c.config(control_rate_hz=50.0, u_limit_rad=0.3)
    assert (cfg.control_rate_hz, cfg.u_limit_rad, cfg.kp, cfg.kff) == (50.0, 0.3, 0.05, 0.0065)
    assert controllers.law_of(cfg).name == law_file
    assert isinstance(ControlStep(cfg).law, Flown)


@pytest.mark.parametrize(
    "text, why",
    [
        (docs_law().replace("def step(", "def stop("), "the law has no step"),
        (docs_law().replace("    Config = PffConfig\n", ""), "has no Config"),
        (docs_law().replace('"PFF_KP"', '"PFF_KP_IS_FAR_TOO_LONG"'), "must be 1 to 16 ASCII characters"),
        (docs_law().replace('"kff", "1"', '"k_ff", "1"'), "its Config has no field 'k_ff'"),
        (docs_law().replace('("error",)', '("not a name",)'), "TELEMETRY_FIELDS must be a tuple of names"),
        (docs_law().replace("-10.0, 10.0", "10.0, -10.0"), "lower bound 10 above upper -10"),
    ],
)
def test_a_class_lacking_what_the_interface_needs_is_named_in_one_line(tmp_path, registry, text, why):
    path = _write(tmp_path, "bad_law.py", text)
    with pytest.raises(LawSpecError) as e:
        load(f"{path}:ProportionalFF")
    assert why in str(e.value) and "\n" not in str(e.value)


def test_a_file_that_does_not_import_or_lacks_the_class(tmp_path, registry):
    bad = _write(tmp_path, "broken.py", "import no_such_module_here\n")
    with pytest.raises(LawSpecError, match="broken.py does not import: ModuleNotFoundError: No module named"):
        load(f"{bad}:X")
    ok = _write(tmp_path, "ok.py", docs_law())
    with pytest.raises(LawSpecError, match="ok.py has no Nope"):
        load(f"{ok}:Nope")
    with pytest.raises(LawSpecError, match="no file"):
        load(f"{tmp_path / 'absent.py'}:X")
    with pytest.raises(LawSpecError, match="no_such_package_xyz does not import"):
        load("no_such_package_xyz:X")
    with pytest.raises(ValueError, match="unknown controller 'bogus'"):
        controllers.get("bogus")


def test_module_spec_and_entry_point(tmp_path, registry, monkeypatch):
    """``module:Class`` and an installed distribution's ``clsac_autopilot.laws`` entry point (a real dist-info on
    sys.path, read by importlib.metadata)."""
    _write(tmp_path, "my_laws_pkg.py", docs_law())
    dist = tmp_path / "my_laws-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: my-laws\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[clsac_autopilot.laws]\np-ff = my_laws_pkg:ProportionalFF\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert controllers.get("my_laws_pkg:ProportionalFF").label == "P + feed-forward"
    c = controllers.get("p-ff")
    assert c.name == "p-ff" and c.kind.cls.__name__ == "ProportionalFF"
    from autopilot.law import installed

    assert "p-ff" in installed()


def test_every_built_in_law_is_a_record_with_its_mode_parameters_and_telemetry():
    from autopilot.mrac import crm_config
    from autopilot.vehicle import Mode

    bench = (("mrac", 104, "MRAC_"), ("crm-mrac", 105, "CRM_"), ("l1", 106, "L1_"), ("indi", 107, "INDI_"))
    for name, mode, prefix in bench:
        c = controllers.get(name)
        law = c.kind
        assert law.generic and law.mimo and int(Mode[c.mode]) == mode
        assert all(row[0].startswith(prefix) and len(row[0]) <= 16 for row in law.rows()), name
        cfg = c.config(control_rate_hz=100.0, u_limit_rad=0.5)
        check(law.law_class(), name)  # the interface, as a user's law is checked
    assert controllers.law_of(crm_config()).name == "crm-mrac"
    table = ParamTable(controllers.get("l1").config(control_rate_hz=100.0, u_limit_rad=0.5), OPTIONS)
    assert [n for n, _ in table.items()][4:] == [row[0] for row in controllers.get("l1").kind.rows()]
    # one label per controller: the damage study's words come from the registry
    from tools.experiment.damage import grid

    assert grid.label("baseline") == "PID (as designed)" and grid.label("mrac") == "MRAC"
    del cfg


# ------------------------------------------------------------------------------------------------ flying
class Recorder:
    """A law that returns ``out`` and keeps what it was given."""

    TELEMETRY_FIELDS = ("calls",)
    PARAMETERS = ()

    def __init__(self, config, out=0.1):
        self.config, self.out, self.seen, self.held = config, out, [], []

    def step(self, roll, roll_rate, yaw_rate, command):
        self.seen.append((roll, roll_rate, yaw_rate, command))
        return self.out if not callable(self.out) else self.out(len(self.seen))

    def reset(self):
        self.seen.clear()

    def hold(self, u_applied):
        self.held.append(u_applied)

    def telemetry(self):
        return {"calls": len(self.seen)}


def _cfg(limit=0.2):
    from types import SimpleNamespace

    return SimpleNamespace(control_rate_hz=100.0, u_limit_rad=limit)


def test_the_step_gives_the_law_the_rates_limits_it_and_keeps_the_reference_model():
    inner = Recorder(_cfg(0.2), out=0.5)
    step = ControlStep(law=Flown(inner, "rec"), setpoints=ProfileSetpoints(lambda t: 0.1))
    for k in range(200):
        res = step(k / 100.0, 0.01 * k, p=0.3, r=-0.2)
    assert inner.seen[0] == (0.0, 0.3, -0.2, 0.1) and inner.seen[-1] == (1.99, 0.3, -0.2, 0.1)
    assert res.u == 0.2 and res.saturated  # 0.5 limited to the 0.2 rad limit
    # y_m,ol at step k (before the step's update) for a constant u_m: the exact solution 1 - e^{A_m t} of paper eq.
    # (3) (B_m = -A_m: unit gain), t = (k - 1) T with k = 200 steps taken
    t = 199 / 100.0
    assert step.law.ym_ol == pytest.approx(0.1 * (BM / -AM) * (1.0 - math.exp(AM * t)), rel=1e-12)
    assert step.law.law_row() == (200.0,)


class SideslipRecorder(Recorder):
    """A law whose step takes the sideslip (autopilot.law.SIDESLIP)."""

    def step(self, roll, roll_rate, yaw_rate, command, sideslip=0.0):
        self.seen.append((roll, roll_rate, yaw_rate, command, sideslip))
        return 0.01 * sideslip if math.isfinite(sideslip) else 0.0


class KwargsRecorder(Recorder):
    def step(self, roll, roll_rate, yaw_rate, command, **measurements):
        self.seen.append((roll, roll_rate, yaw_rate, command, measurements))
        return 0.0


def test_the_step_gives_the_sideslip_to_a_law_that_takes_it_and_the_four_measurements_to_one_that_does_not(law_file):
    """The sideslip is the law's where the plant measures it (``Flown.y2``, set by the loop as it sets
    ``MimoLaw.y2``: a square MIMO plant's AOA_SSA), NaN where it does not; a law written against the four
    measurements (docs/adding-a-law.md's, ``Recorder``) is called with those four, and flies the same numbers."""
    from autopilot.law import takes_sideslip

    assert takes_sideslip(SideslipRecorder.step) and takes_sideslip(KwargsRecorder.step)
    assert not takes_sideslip(Recorder.step) and not takes_sideslip(controllers.get(law_file).kind.cls.step)
    side = SideslipRecorder(_cfg())
    step = ControlStep(law=Flown(side, "side"), setpoints=ProfileSetpoints(lambda t: 0.1))
    step(0.0, 0.01, p=0.3, r=-0.2)
    assert side.seen[0][:4] == (0.01, 0.3, -0.2, 0.1) and math.isnan(side.seen[0][4])  # none measured: NaN
    step.law.y2 = 0.05  # as autopilot.loop.handlers does with each AOA_SSA (rad), before the step
    assert step(0.01, 0.01, p=0.3, r=-0.2).u == pytest.approx(0.01 * 0.05, rel=1e-15)
    assert side.seen[1] == (0.01, 0.3, -0.2, 0.1, 0.05)
    kw = KwargsRecorder(_cfg())
    flown = Flown(kw, "kw")
    flown.y2 = -0.02
    flown(0.0, 0.1, 0.0, 0.0)
    assert kw.seen == [(0.0, 0.0, 0.0, 0.1, {"sideslip": -0.02})]
    # the docs' four-measurement law with a sideslip set: called as before, the same command to the last bit
    cfg = controllers.get(law_file).config(control_rate_hz=100.0, u_limit_rad=0.5)
    a, b = (
        ControlStep(cfg, setpoints=ProfileSetpoints(lambda t: 0.1)),
        ControlStep(cfg, setpoints=ProfileSetpoints(lambda t: 0.1)),
    )
    b.law.y2 = 0.3
    assert [a(k / 100, 0.02 * k).u for k in range(5)] == [b(k / 100, 0.02 * k).u for k in range(5)]


def test_a_law_that_returns_nan_or_raises_trips_the_failsafe_and_is_not_flown_again():
    nan_at_3 = lambda n: math.nan if n >= 3 else 0.05  # noqa: E731
    raise_at_3 = lambda n: 1 / (n - 3)  # noqa: E731
    for out, why in ((nan_at_3, "returned nan"), (raise_at_3, "raised ZeroDivisionError")):
        inner = Recorder(_cfg(), out=out)
        step = ControlStep(law=Flown(inner, "mine"), setpoints=ProfileSetpoints(lambda t: 0.1))
        a, b = step(0.0, 0.0), step(0.01, 0.0)
        assert a.failsafe is b.failsafe is Failsafe.NONE and a.u != 0.0
        c, d = step(0.02, 0.0), step(0.03, 0.0)
        assert c.failsafe is d.failsafe is Failsafe.LAW_ERROR and c.u == d.u == 0.0
        assert len(inner.seen) == 3 and inner.held == []  # called once more, never again, nor its hold
        assert step.law_failure.startswith(f"law mine {why}") and step.law_failure_t == 0.02
    # a NaN measurement is not the law's failure: a hold, the law flown again on the next good one (as before)
    inner = Recorder(_cfg())
    step = ControlStep(law=Flown(inner, "mine"), setpoints=ProfileSetpoints(lambda t: 0.1))
    assert step(0.0, math.nan).failsafe is Failsafe.NO_ATTITUDE and step.law_failure is None
    assert step(0.01, 0.0).failsafe is Failsafe.NONE and step.nonfinite_inputs == 1
    with pytest.raises(NonFiniteInputError):
        Flown(Recorder(_cfg()), "x")(0.0, 0.0, math.inf, 0.0)
    # a hold that raises (in MANUAL, say): the law has failed; the ground station's command flies all the same
    inner = Recorder(_cfg())
    inner.hold = lambda u: 1 / 0
    step = ControlStep(law=Flown(inner, "mine"), setpoints=ProfileSetpoints(lambda t: 0.1))
    step.manual = 0.05
    assert step(0.0, 0.0).u == 0.05
    assert step.law_failure == "law mine raised ZeroDivisionError: division by zero in hold"
    step.manual = None
    assert step(0.01, 0.0).failsafe is Failsafe.LAW_ERROR and inner.seen == []


def test_the_laws_parameters_are_its_own_table_set_within_bounds_and_flown_from_the_next_step(law_file):
    cfg = controllers.get(law_file).config(control_rate_hz=100.0, u_limit_rad=0.5)
    table = ParamTable(cfg, OPTIONS)
    names = [n for n, _ in table.items()]
    assert names == ["CLSAC_FS_ATT_TMO", "CLSAC_FS_SP_TMO", "CLSAC_MAX_ROLL", "SYS_FAILURE_EN", "PFF_KP", "PFF_KFF"]
    with pytest.raises(ParamError, match=r"PFF_KP must be in \[0, 10\]"):
        table.set("PFF_KP", 11.0)
    with pytest.raises(ParamError, match="unknown parameter 'CLSAC_LV'"):
        table.set("CLSAC_LV", 20.0)
    step = ControlStep(table.config, setpoints=ProfileSetpoints(lambda t: 0.1))
    assert step(0.0, 0.02).u == pytest.approx(0.05 * 0.08 + 0.0065 * 0.1, rel=1e-15)
    assert table.set("PFF_KP", 0.2) == 0.2
    step.reconfigure(table.config)  # as a ground station's PARAM_SET does (autopilot.vehicle)
    assert step(0.01, 0.02).u == pytest.approx(0.2 * 0.08 + 0.0065 * 0.1, rel=1e-15)
    # a set the law's own constructor refuses (MRAC without roll feedback: its reference model A_ref - l I unstable)
    # is refused, the value unchanged: the loop never builds a law that raises
    cfg = controllers.get("mrac").config(control_rate_hz=100.0, u_limit_rad=0.5)
    mrac = ParamTable(cfg, OPTIONS)
    with pytest.raises(ParamError, match="MRAC_KPHI=0 rejected: the reference model A_ref - l I is not stable"):
        mrac.set("MRAC_KPHI", 0.0)
    assert mrac.get("MRAC_KPHI") == cfg.k_phi
    # a design file's values are checked together, not one by one (the c172x's gains on the KH2013A's model are not)
    from autopilot.params import load_file

    mine, _ = mrac.split(load_file(ROOT / "sitl" / "plants" / "jsbsim-c172x-laws.params"))
    mrac.update(mine)
    assert mrac.get("MRAC_KPHI") == mine["MRAC_KPHI"] and isinstance(ControlStep(mrac.config).law, Flown)
    # another law's values in a design file are not flown (the file the bench's designs are in)
    mine, other = table.split({"PFF_KFF": 0.01, "MRAC_KP": 1.0, "NOBODYS": 1.0})
    assert mine == {"PFF_KFF": 0.01, "NOBODYS": 1.0} and other == ["MRAC_KP"]


def test_a_laws_parameter_aliases_act_on_its_parameter_listed_once_and_load_from_files(tmp_path, registry):
    """PARAMETER_ALIASES {OLD: NAME}: the table gets and sets NAME by OLD, lists NAME once, and a parameter file with
    OLD loads as NAME (autopilot.params, "Aliases"); a bad alias is named in one line."""
    from autopilot.params import load_file

    alias = '    PARAMETER_ALIASES = {"OLD_KP": "PFF_KP"}\n'
    text = docs_law().replace("    Config = PffConfig\n", "    Config = PffConfig\n" + alias)
    spec = f"{_write(tmp_path, 'aliased.py', text)}:ProportionalFF"
    table = ParamTable(controllers.get(spec).config(control_rate_hz=100.0, u_limit_rad=0.5), OPTIONS)
    assert [n for n, _ in table.items()][-2:] == ["PFF_KP", "PFF_KFF"] and "OLD_KP" in table
    assert table.set("OLD_KP", 0.3) == 0.3 and table.get("PFF_KP") == 0.3 and table.config.kp == 0.3
    assert table.index("OLD_KP") == table.index("PFF_KP") and table.name_of("OLD_KP") == "PFF_KP"
    with pytest.raises(ParamError, match=r"must be in \[0, 10\]"):
        table.set("OLD_KP", 11.0)
    assert table.get("PFF_KP") == 0.3
    path = _write(tmp_path, "old.parm", "OLD_KP 0.2\nCLSAC_PID_KD 0.03\n")
    assert load_file(path) == {"PFF_KP": 0.2, "PID_KD": 0.03}
    mine, other = table.split(load_file(path))
    table.update(mine)
    assert table.config.kp == 0.2 and other == ["PID_KD"]
    for i, (aliases, why) in enumerate(
        (
            ('{"OLD_KP": "PFF_NOPE"}', "names 'PFF_NOPE', not a parameter of its table"),
            ('{"PFF_KFF": "PFF_KP"}', "alias PFF_KFF is a parameter's own name"),
            ('{"CLSAC_LV": "PFF_KP"}', "alias CLSAC_LV: CLSAC_ and SYS_ names are the autopilot's own"),
            ('{"OLD_NAME_FAR_TOO_LONG": "PFF_KP"}', "must be 1 to 16 ASCII characters"),
        )
    ):
        bad = _write(tmp_path, f"bad{i}.py", text.replace('{"OLD_KP": "PFF_KP"}', aliases))
        with pytest.raises(LawSpecError, match=re.escape(why)):
            load(f"{bad}:ProportionalFF")


# ------------------------------------------------------------------------------------------------ the CLIs
def _run(*args, timeout=120.0):
    t0 = time.monotonic()
    r = subprocess.run([PY, *args], capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL)
    return r, time.monotonic() - t0


@pytest.mark.parametrize("module", ["tools.launch", "autopilot"])
def test_a_law_without_step_or_that_does_not_import_is_one_line_exit_2_before_anything_starts(tmp_path, module):
    nostep = _write(tmp_path, "nostep.py", docs_law().replace("def step(", "def stop("))
    broken = _write(tmp_path, "broken.py", "raise ImportError('no such thing')\n")
    cases = ((f"{nostep}:ProportionalFF", "the law has no step"), (f"{broken}:X", "ImportError: no such thing"))
    if module == "tools.launch":  # the launcher builds a user's law once: its constructor's error before anything
        bad_init = docs_law().replace("        self.config = config\n", "        raise RuntimeError('bad gains')\n")
        cases += ((f"{_write(tmp_path, 'bad_init.py', bad_init)}:ProportionalFF", "RuntimeError: bad gains"),)
    for spec, why in cases:
        extra = ["--lockstep", "--duration", "10", "--out", str(tmp_path / "out")] if module == "tools.launch" else []
        r, took = _run("-m", module, "--controller", spec, *extra, timeout=60)
        assert r.returncode == 2 and took < 10.0, (r.returncode, took)
        lines = (r.stdout + r.stderr).strip().splitlines()
        assert len(lines) == 1 and why in lines[0] and "Traceback" not in r.stdout + r.stderr, lines
    assert not (tmp_path / "out" / "flight.tlog").exists()


def test_a_law_without_a_batch_form_flies_the_robustness_study_and_the_damage_study(tmp_path, law_file):
    r, _ = _run(
        "-m", "tools.experiment", "robustness", "--controllers", f"baseline,{law_file}", "--runs", "4",
        "--sweep-runs", "2", "--long-runs", "1", "--seeds", "1", "--turbulence", "none", "--no-progress",
        "--out", str(tmp_path / "robust"), timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    s = json.loads((tmp_path / "robust" / "summary.json").read_text())
    assert "kh2013a (one flight at a time)" in s["plants"] and "kh2013a" in s["plants"]
    assert "P + feed-forward" in r.stdout
    # a law without a batch form alone: its flights, and the batched study's flags refused with why
    r, _ = _run(
        "-m", "tools.experiment", "robustness", "--controllers", "l1", "--seeds", "1", "--turbulence", "none",
        "--no-progress", "--out", str(tmp_path / "l1"), timeout=300,
    )  # fmt: skip
    assert r.returncode == 0 and "L1 adaptive bounded" in r.stdout, r.stdout + r.stderr
    out = str(tmp_path / "x")
    r, _ = _run("-m", "tools.experiment", "robustness", "--controllers", "l1", "--runs", "5", "--out", out)
    assert r.returncode == 2 and "l1 (no batch form) fly --seeds flights" in r.stderr, r.stderr


# ------------------------------------------------------------------------------------------------ end to end
def _launch(out, *extra, timeout=300.0):
    return _run("-m", "tools.launch", "--lockstep", "--quiet", "--out", str(out), *extra, timeout=timeout)[0]


@pytest.mark.e2e
def test_the_docs_law_flies_lockstep_with_its_parameters_and_telemetry_and_bit_for_bit_in_process(tmp_path, law_file):
    r = _launch(tmp_path / "f", "--duration", "10", "--controller", law_file)
    assert r.returncode == 0, r.stdout + r.stderr
    s = json.loads((tmp_path / "f" / "summary.json").read_text())
    assert s["ok"] and s["law"]["name"] == "p-ff" and s["law"]["controller"] == law_file
    assert isinstance(s["law"]["telemetry_end"]["error"], float)  # its own telemetry by name, as the flight ended
    # its parameters in the tlog's PARAM_VALUE messages (the launcher's ground station reads them on connect)
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    m = mavutil.mavlink_connection(str(tmp_path / "f" / "flight.tlog"))
    values = {}
    while (msg := m.recv_match(type="PARAM_VALUE")) is not None:
        values[msg.param_id] = msg.param_value
    assert values["PFF_KP"] == np.float32(0.05) and values["PFF_KFF"] == np.float32(0.0065)
    # its telemetry field in the .rrd, read back with rerun: the error of each step, = command - roll
    from tools.view.rrd_files import load as load_rrd

    err = load_rrd(tmp_path / "f" / "flight.rrd")["/autopilot/law/error"]
    assert len(err.t) == 1000 and err.values[0, 0] == pytest.approx(math.radians(10.0), rel=1e-6)
    # the generic loop: the same numbers as the lockstep flight, to the last bit
    from autopilot.shared.pwm import PwmMap
    from tools.experiment.scenario import Scenario, run_inprocess, run_of

    ref = run_inprocess(Scenario(duration_s=10.0), run_of(law_file), wire=PwmMap()).metrics
    assert s["runs"][0]["metrics"] == ref


@pytest.mark.e2e
def test_a_law_that_returns_nan_from_its_501st_call_ends_not_ok_with_no_traceback(tmp_path, law_file):
    path = law_file.rpartition(":")[0]
    sub = _write(
        tmp_path, "nan_law.py",
        "import importlib.util, math\n"
        f"spec = importlib.util.spec_from_file_location('my_law_base', {path!r})\n"
        "base = importlib.util.module_from_spec(spec)\nspec.loader.exec_module(base)\n\n\n"
        "class NanAt501(base.ProportionalFF):\n    calls = 0\n\n"
        "    def step(self, roll, roll_rate, yaw_rate, command):\n        self.calls += 1\n"
        "        if self.calls >= 501:\n            return math.nan\n"
        "        return super().step(roll, roll_rate, yaw_rate, command)\n",
    )  # fmt: skip
    r = _launch(tmp_path / "f", "--duration", "10", "--controller", f"{sub}:NanAt501")
    assert r.returncode not in (0, 2), r.stdout + r.stderr
    assert "Traceback" not in r.stdout + r.stderr
    s = json.loads((tmp_path / "f" / "summary.json").read_text())
    assert not s["ok"] and "NanAt501 returned nan at 5.000 s" in s["controlled"]["reason"]
    assert (tmp_path / "f" / "flight.tlog").stat().st_size > 0


@pytest.mark.e2e
def test_the_docs_law_in_the_damage_study(tmp_path, law_file):
    r, _ = _run(
        "-m", "tools.experiment", "damage", "--plant", "kh2013a", "--controllers", f"baseline,{law_file}",
        "--kinds", "effectiveness", "--runs", "1", "--seed", "1", "--out", str(tmp_path / "d"), "--quiet",
        timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    text = (tmp_path / "d" / "summary.json").read_text()
    assert law_file in text and "P + feed-forward" in text
    s = json.loads(text)
    assert s["labels"][law_file] == "P + feed-forward"


@pytest.mark.e2e
@pytest.mark.parametrize("name", ["mrac", "crm-mrac", "l1", "indi"])
def test_each_bench_law_flies_lockstep_and_is_named(tmp_path, name):
    r = _launch(tmp_path / "f", "--duration", "10", "--controller", name)
    assert r.returncode == 0, r.stdout + r.stderr
    s = json.loads((tmp_path / "f" / "summary.json").read_text())
    assert s["law"]["name"] == name and s["law"]["mode"] == controllers.get(name).mode


@pytest.mark.e2e
def test_a_ground_station_sees_the_laws_mode_and_sets_its_parameters_live(tmp_path, law_file):
    from tests._mavlink_procs import free_ports
    from tests.autopilot.test_vehicle import Gcs, _download, _start_autopilot

    port = free_ports(1)[0]
    gcs = Gcs(port)
    ap = _start_autopilot(tmp_path, "autopilot", port, "--controller", law_file)
    try:
        gcs.connect()
        assert gcs.wait("HEARTBEAT").custom_mode == 108  # LAW
        values = _download(gcs)
        assert values["PFF_KP"] == np.float32(0.05) and "CLSAC_LV" not in values
        gcs.mav.param_set_send(1, 1, b"PFF_KP", 0.2, 9)  # REAL32
        assert gcs.wait("PARAM_VALUE", cond=lambda m: m.param_id == "PFF_KP").param_value == np.float32(0.2)
        gcs.mav.param_set_send(1, 1, b"PFF_KFF", 11.0, 9)
        assert gcs.wait("PARAM_VALUE", cond=lambda m: m.param_id == "PFF_KFF").param_value == np.float32(0.0065)
        assert gcs.wait("PARAM_ERROR").param_id == "PFF_KFF"
    finally:
        gcs.close()
        ap.stop()


def test_a_law_without_a_mimo_form_is_refused_on_a_square_mimo_plant(tmp_path, law_file):
    """A law on the interface flies one surface: refused on a square MIMO plant with its reason (the launcher: one
    line, exit 2; the damage study: summary.json's ``not_flown``), a law that takes the sideslip too."""
    mimo = "jsbsim:c172x:surface=aileron+rudder"
    r = _launch(tmp_path / "f", "--controller", "l1", "--plant", mimo, timeout=60)
    assert r.returncode == 2 and "l1 has no square-MIMO form" in r.stderr, r.stderr
    side = docs_law().replace(
        "def step(self, roll, roll_rate, yaw_rate, command):",
        "def step(self, roll, roll_rate, yaw_rate, command, sideslip=0.0):",
    )
    assert "sideslip=0.0" in side
    spec = f"{_write(tmp_path, 'side_law.py', side)}:ProportionalFF"
    r = _launch(tmp_path / "g", "--controller", spec, "--plant", mimo, timeout=60)
    assert r.returncode == 2 and "p-ff has no square-MIMO form (a law on autopilot.law's interface" in r.stderr, (
        r.stderr
    )
    from tools.experiment.damage import grid

    refused = grid.controller_refusals(mimo, ("baseline", "mrac", spec))
    assert set(refused) == {"mrac", spec} and "p-ff has no square-MIMO form" in refused[spec]


@pytest.mark.e2e
def test_the_docs_law_flies_in_real_time_and_through_flight(tmp_path, law_file):
    out = str(tmp_path / "rt")
    r = _run("-m", "tools.launch", "--quiet", "--duration", "5", "--controller", law_file, "--out", out)[0]
    assert r.returncode == 0, r.stdout + r.stderr
    s = json.loads((tmp_path / "rt" / "summary.json").read_text())
    assert s["mode"] == "realtime" and s["law"]["name"] == "p-ff"
    from tools.flight import Flight

    result = Flight(lockstep=True, duration=3, controller=law_file, out=str(tmp_path / "api"), quiet=True).run()
    assert result.ok
    assert json.loads((tmp_path / "api" / "summary.json").read_text())["law"]["label"] == "P + feed-forward"


@pytest.mark.e2e
def test_a_bench_law_in_turbulence_is_its_lockstep_flight_to_the_last_bit_in_the_generic_loop(tmp_path):
    """MRAC on the KH2013A in light turbulence (seed 1): the damage study's loop (``run_inprocess``, the SITL's own
    injector) and the lockstep flight over MAVLink give the same metrics, bit for bit."""
    from dataclasses import replace

    from autopilot.shared.pwm import PwmMap
    from tools.experiment.scenario import PAPER, run_inprocess, run_of

    r = _launch(tmp_path / "f", "--duration", "10", "--controller", "mrac", "--turbulence", "light", "--seed", "1")
    assert r.returncode in (0, 3), r.stdout + r.stderr
    flown = json.loads((tmp_path / "f" / "summary.json").read_text())["runs"][0]["metrics"]
    scen = replace(PAPER, duration_s=10.0, disturbances=(("seed", 1), ("turbulence", "light")))
    assert flown == run_inprocess(scen, run_of("mrac"), atmosphere=True, wire=PwmMap()).metrics


def test_a_bench_law_without_its_design_for_the_plant_is_refused_with_the_command(tmp_path):
    r = _launch(tmp_path / "f", "--controller", "l1", "--plant", "jsbsim:pa28", timeout=60)
    assert r.returncode == 2 and "jsbsim:pa28 has no design of l1" in r.stderr, r.stderr
    assert "python -m tools.design.laws jsbsim:pa28" in r.stderr
    from tools.experiment.damage import grid

    assert "no design of mrac" in grid.controller_refusals("jsbsim:pa28", ("baseline", "mrac"))["mrac"]
    assert grid.controller_refusals("jsbsim:c172x", ("baseline", "mrac")) == {}
