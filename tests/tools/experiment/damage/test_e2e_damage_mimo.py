"""The damage study on the square MIMO plant (issue 32, item 4): ``python -m tools.experiment damage --plant
jsbsim:c172x:surface=aileron+rudder`` flies MIMO CL-SAC and the MIMO baseline, refuses the study's SISO-only
controllers with their reasons in ``summary.json``'s ``not_flown``, and its cells carry max |sideslip|.  Checked
against facts the study does not compute: an effectiveness of 1.0 is the aircraft as built (the fault-free flight,
to the last bit), one worker and two give the same numbers, and a cell's flight is the lockstep MAVLink flight with
``--fault`` (three real processes over UDP)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.e2e
ROOT = Path(__file__).resolve().parents[4]
PLANT = "jsbsim:c172x:surface=aileron+rudder"
ARGS = ["--plant", PLANT, "--kinds", "effectiveness", "--severity", "effectiveness=1,0.3", "--onsets", "5",
        "--duration", "12", "--runs", "2", "--seed", "1", "--controllers", "clsac,baseline,pid-ff,pid-retuned",
        "--quiet", "--no-plot"]  # fmt: skip


def _study(tmp_path: Path, workers: int) -> tuple[dict, str]:
    out = tmp_path / f"w{workers}"
    argv = [sys.executable, "-m", "tools.experiment", "damage", *ARGS, "--workers", str(workers), "--out", str(out)]
    r = subprocess.run(argv, capture_output=True, text=True, timeout=900, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    return json.loads((out / "summary.json").read_text()), r.stdout


def _numbers(cells):
    drop = ("wall_s",)
    return [{k: v for k, v in c.items() if k not in drop} for c in cells]


def test_the_mimo_damage_study(tmp_path):
    one, stdout = _study(tmp_path, 1)
    two, _ = _study(tmp_path, 2)
    assert _numbers(one["cells"]) == _numbers(two["cells"])  # the numbers do not depend on the workers
    # flown: MIMO CL-SAC and the MIMO baseline; refused, each with its reason
    assert {c["controller"] for c in one["cells"]} == {"clsac", "baseline"}
    refused = one["not_flown"][PLANT]["controllers"]
    assert set(refused) == {"pid-ff", "pid-retuned"} and all(len(why) > 20 for why in refused.values())
    assert "not flown on jsbsim:c172x:surface=aileron+rudder: controller pid-ff" in stdout
    assert "max |sideslip|" in stdout
    cells = {(c["controller"], c["kind"], c["severity"]): c for c in one["cells"]}
    assert len(cells) == 6 and all(c["flights"] == 2 for c in cells.values())
    for ctrl in ("clsac", "baseline"):
        none, same, weak = (cells[(ctrl, k, v)] for k, v in (("none", None), ("effectiveness", 1.0),
                                                              ("effectiveness", 0.3)))  # fmt: skip
        # effectiveness 1.0 is the aircraft as built: its flights are the fault-free ones, seed by seed
        # (the paired statistics over periods after the onset, ``vs`` and ``long``, count the fault-free cell's
        # periods from its start: the flights are the same, the windows are not)
        strip = ("fault", "kind", "severity", "onset_s", "vs", "long")
        assert same["runs"] == none["runs"]
        assert {k: v for k, v in same.items() if k not in (*strip, "runs")} == {
            k: v for k, v in none.items() if k not in (*strip, "runs")
        }
        for c in (none, weak):
            assert 0.5 < c["max_abs_sideslip_deg_p50"] <= c["max_abs_sideslip_deg_max"] < 10.0
            assert all(r["max_abs_sideslip_deg"] > 0 for r in c["runs"])
        # the aileron at 0.3 tracks worse after the onset than the aircraft as built, and not before it
        for a, b in zip(weak["runs"], none["runs"]):
            assert a["ise_ref_after"] > 1.5 * b["ise_ref_after"]
            assert a["ise_ref_before"] == b["ise_ref_before"]


def test_a_mimo_cell_is_the_lockstep_flight_with_the_fault(tmp_path):
    from tools.experiment.damage.flight import fly_record
    from tools.experiment.damage.grid import DamageFlight

    argv = [sys.executable, "-m", "tools.launch", "--lockstep", "--quiet", "--duration", "12", "--plant", PLANT,
            "--controller", "clsac", "--fault", "effectiveness=0.3@5", "--turbulence", "light", "--seed", "1",
            "--out", str(tmp_path / "run"), "--no-png", "--no-rrd"]  # fmt: skip
    r = subprocess.run(argv, capture_output=True, text=True, timeout=300, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    out = Path(re.search(r"files: (\S+)/flight\.tlog", r.stdout).group(1))
    s = json.loads((out / "summary.json").read_text())
    mine = fly_record(DamageFlight(PLANT, "clsac", "effectiveness", 0.3, 5.0, 1, 12.0, "light"))
    assert mine["ise_ref"] == s["runs"][0]["metrics"]["ise_ref"]
    assert mine["energy"] == s["runs"][0]["metrics"]["energy"]
    assert mine["max_abs_sideslip_deg"] == pytest.approx(s["sideslip"]["max_abs_sideslip_deg"], abs=1e-9)
