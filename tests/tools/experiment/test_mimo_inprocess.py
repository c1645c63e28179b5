"""The MIMO flight in one process (``tools.experiment.mimo_inprocess.run_mimo``) against the same flight over MAVLink
(``python -m tools.launch --lockstep``, three processes): bit for bit the same roll metrics and sideslip block, the
aileron's effectiveness fault included."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.e2e
ROOT = Path(__file__).resolve().parents[3]
PLANT = "jsbsim:c172x:surface=aileron+rudder"


@pytest.mark.parametrize(
    ("controller", "fault", "turbulence"),
    [("clsac", "effectiveness=0.3@10", None), ("baseline", None, None), ("clsac", None, "moderate")],
)
def test_in_process_is_the_mavlink_flight(controller, fault, turbulence, tmp_path):
    from tools.experiment.mimo_inprocess import run_mimo

    argv = [sys.executable, "-m", "tools.launch", "--lockstep", "--quiet", "--duration", "20", "--plant", PLANT]
    argv += ["--controller", controller, "--out", str(tmp_path / "run"), "--no-png", "--no-rrd"]
    argv += ["--fault", fault] if fault else []
    argv += ["--turbulence", turbulence, "--seed", "7"] if turbulence else []
    r = subprocess.run(argv, capture_output=True, text=True, timeout=300, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    out = Path(re.search(r"files: (\S+)/flight\.tlog", r.stdout).group(1))
    s = json.loads((out / "summary.json").read_text())
    dist = (("seed", 7), ("turbulence", turbulence)) if turbulence else ()
    mine = run_mimo(PLANT, controller, duration_s=20.0, faults=(fault,) if fault else (), disturbances=dist)
    assert mine["metrics"] == s["runs"][0]["metrics"]
    assert mine["sideslip"] == s["sideslip"]
