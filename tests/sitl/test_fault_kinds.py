"""The fault kinds as records (sitl/fault_kinds.py): the docs read them, every reader of a kind reads them, the
actuator's copies are held to sitl.damage.Actuator bit for bit, and docs/adding-a-fault-kind.md's worked example
flies as the page says."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from autopilot.shared.servo_failures import LIMITS
from sitl import damage, fault_kinds
from sitl import plant as plants
from sitl.aircraft import Aircraft, AircraftConfig

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "adding-a-fault-kind.md"


def _rows(path: Path, header: str) -> dict[str, list[str]]:
    """The rows of the markdown table under ``header`` (its first cell's kind in backticks -> the other cells)."""
    text = path.read_text(encoding="utf-8")
    body = text.split(header, 1)[1]
    rows = {}
    for line in body.splitlines():
        m = re.match(r"\| `(\w+)[^|]*\|(.*)\|$", line)
        if m:
            rows[m.group(1)] = [c.strip() for c in m.group(2).split("|")]
        elif rows and not line.startswith("|"):
            break
    return rows


def _cells(k: fault_kinds.FaultKind) -> list[str]:
    """A record as the page's table writes it (independent of the record's own formatting)."""
    unit = k.unit or ("-" if k.value == "none" else "factor")
    sev = "(none)" if k.severities == (None,) else ", ".join(f"{v:g}" for v in k.severities)
    bound = "-" if k.bound is None else f"{k.bound:g}"
    return [unit, bound, k.group, k.worse, sev, k.study or "-", k.design or "-"]


def test_the_guide_page_lists_every_kind_as_its_record_says():
    rows = _rows(PAGE, "## The kinds")
    assert list(rows) == list(fault_kinds.KINDS)
    for name, k in fault_kinds.KINDS.items():
        assert rows[name] == _cells(k), name


def test_every_kind_is_in_the_users_table_of_faults_md_with_its_plants():
    rows = _rows(ROOT / "docs" / "faults.md", "| kind | what it does | plants |")
    assert list(rows) == list(fault_kinds.KINDS)
    for name in fault_kinds.KINDS:
        flown = plants.plants_flying(name)
        assert (rows[name][-1] == "JSBSim") == (flown == ("jsbsim",)), name


def test_the_bounds_are_the_ground_stations_and_the_help_is_unchanged():
    for name, most in LIMITS.items():
        assert fault_kinds.KINDS[name].bound == most
        assert fault_kinds.KINDS[name].servo
    assert fault_kinds.help_text() == (
        "effectiveness=F, stuck[=DEG], off, rate=DEG_PER_S, delay=S, damping=F; on JSBSim also inertia=F, cg=M, "
        "airspeed=KT"
    )
    # the bound written once holds on the command line: just inside passes, just beyond is refused by name
    assert damage.parse("rate=1000@1").value == pytest.approx(np.radians(1000.0))
    with pytest.raises(damage.FaultSpecError, match="at most 1000 deg/s"):
        damage.parse("rate=1000.001@1")
    with pytest.raises(damage.FaultSpecError, match=r"within \+-5 m"):
        damage.parse("cg=5.01@1")


def test_the_sets_every_reader_uses_come_from_the_records():
    assert fault_kinds.SERVO_KINDS == {"stuck", "off", "rate", "delay"}
    assert set(fault_kinds.DESIGN_KINDS) == {"effectiveness", "damping", "delay"}
    assert set(fault_kinds.STUDY_KINDS) == {"effectiveness", "damping", "stuck", "off", "delay", "rate"}
    assert set(fault_kinds.WORSE_LOWER) == {"effectiveness", "rate", "damping", "airspeed"}
    assert set(damage.SERVO_FIELDS) == {"stuck", "stuck_at", "off", "rate", "delay"}
    from tools.experiment.damage import grid
    from tools.experiment.study import faults as study_faults
    from tools.view import damage_png

    assert grid.SEVERITIES["rate"] == (5.0, 20.0, 60.0) and set(grid.SEVERITIES) == set(fault_kinds.KINDS)
    assert study_faults.KINDS == fault_kinds.STUDY_KINDS
    # damage.png: from the fault-free flight to the worst, a lower rate and a longer delay being worse
    assert damage_png._order("rate", [20.0, None, 5.0, 60.0]) == [None, 60.0, 20.0, 5.0]
    assert damage_png._order("delay", [0.1, 0.02, 0.05]) == [0.02, 0.05, 0.1]
    # the plants: every kind's group is flown by the kinds of plant the records say, the KH2013A refuses the rest
    assert set(plants.fault_refusals("kh2013a")) == {"inertia", "cg", "airspeed"}
    assert plants.plants_flying("cg") == ("jsbsim",)
    assert set(plants.plants_flying("stuck")) == set(plants.KINDS)


def test_a_retuned_design_refuses_exactly_the_kinds_without_a_design():
    from tools.design.linearise import linear_model
    from tools.design.tuning import faulted_plant

    a, b, c, p = linear_model("kh2013a")
    for name, k in fault_kinds.KINDS.items():
        value = None if k.value == "none" else (k.severities[0] if k.severities[0] else 1.0) * k.to_si
        effect = damage.combine([damage.Fault(name, value, 0.0)])
        if k.design is None and k.servo:
            with pytest.raises(ValueError, match="not a linear plant"):
                faulted_plant((a, b, c), p, effect)
        else:
            faulted_plant((a, b, c), p, effect)


# ---------------------------------------------------------------------------------------------- the actuator
def _actuator_rule(delta, delta_free, rate_free, rate, dt):
    act = damage.Actuator(damage.Effect(rate=rate), dt)
    return act.surface(delta, delta_free, rate_free)


def test_the_studys_rate_limit_is_the_actuators_bit_for_bit():
    """faults.slew (the numpy loop; kernel.c's rate_limited is held to the numpy loop by
    tests/tools/experiment/study/test_study_faults.py) against sitl.damage.Actuator.surface, case by case, on both
    sides of the limit and exactly on it."""
    from tools.experiment.study.faults import slew

    rng = np.random.default_rng(7)
    rate, dt = np.radians(20.0), 1e-3
    move_max = rate * dt
    delta = rng.normal(0.0, 0.1, 400)
    moves = np.concatenate([rng.normal(0.0, 2 * move_max, 394), [move_max, -move_max, 0.0, 1e-300, -1e-300, 1.0]])
    delta_free = delta + moves
    edge = delta_free - delta
    # moves of exactly +-move_max after the subtraction (the comparison's edge)
    delta_free[394:396] = delta[394:396] + np.array([move_max, -move_max])
    edge = delta_free - delta
    rate_free = rng.normal(0.0, 2 * rate, 400)
    coast, at, clipped = slew(delta, delta_free, rate_free, move_max, rate)
    for i in range(400):
        c, r = _actuator_rule(float(delta[i]), float(delta_free[i]), float(rate_free[i]), rate, dt)
        assert bool(coast[i]) == c, (i, edge[i])
        got = float(at[i]) if c else float(clipped[i])
        assert np.float64(got).tobytes() == np.float64(r).tobytes(), i
    assert coast.any() and (~coast).any()


# ---------------------------------------------------------------------------------------------- the guide's example
def _example() -> fault_kinds.FaultKind:
    text = PAGE.read_text(encoding="utf-8")
    block = re.search(r"```python\n(.*?)```", text, re.S).group(1)
    scope: dict = {}
    exec(compile(block, str(PAGE), "exec"), scope)  # the page's record, as a reader would paste it
    return scope["LOSS"]


def _fly(spec: str) -> bytes:
    plant = Aircraft(AircraftConfig(physics_rate_hz=1000.0))
    sched = damage.Schedule([damage.parse(spec)], 0.0, plant.config.dt)
    flown = damage.ScheduledEffects(plant, sched)
    out = [flown.advance(0.05 * np.sin(0.1 * k), 10).copy() for k in range(300)]
    return np.array(out).tobytes()


def test_the_worked_example_flies_as_the_page_says(monkeypatch):
    loss = _example()
    monkeypatch.setitem(fault_kinds.KINDS, "loss", loss)
    assert damage.parse("loss=40@1").value == pytest.approx(0.4)
    with pytest.raises(damage.FaultSpecError, match=r"must be in \[0, 99\] %"):
        damage.parse("loss=100@1")
    assert loss.syntax == "loss=P" and loss.active(damage.combine([damage.parse("loss=40@1")]))
    assert _fly("loss=40@1") == _fly("effectiveness=0.6@1")  # 1 - 40 * 0.01 is 0.6 to the last bit
    assert _fly("loss=40@1") != _fly("effectiveness=0.5@1")
