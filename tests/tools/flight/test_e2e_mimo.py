"""The P-mimo checks (issue 32), on the real processes: ``python -m tools.pfc design
jsbsim:c172x:surface=aileron+rudder --out F``, then ``python -m tools.launch --lockstep --duration 30 --plant
jsbsim:c172x:surface=aileron+rudder --params F`` with ``--controller clsac`` and ``--controller baseline``: exit 0,
a sideslip channel in summary.json, and servo1 (aileron) and servo4 (rudder) of SERVO_OUTPUT_RAW both moving in
flight.tlog, read with pymavlink; the sideslip reached the autopilot in ArduPilot's AOA_SSA and is JSBSim's."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

pytestmark = pytest.mark.e2e
ROOT = Path(__file__).resolve().parents[3]
ENV = dict(os.environ, PYTHONPATH=str(ROOT))
PLANT = "jsbsim:c172x:surface=aileron+rudder"


def _run(*args: str, timeout: float = 400.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=timeout, env=ENV)


@pytest.fixture(scope="module")
def design():
    """The design `python -m tools.pfc design PLANT --out F` writes: the shipped file, which
    tests/tools/design/test_mimo_design.py checks is every value of a fresh design (the must-show's two steps, the
    design run once in the suite)."""
    return ROOT / "sitl" / "plants" / "jsbsim-c172x-aileron+rudder.params"


def _tlog(path: Path) -> dict:
    """SERVO_OUTPUT_RAW's servo1 and servo4 from the autopilot to the SITL (1:140), AOA_SSA's sideslip (deg)."""
    m = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    out = {"servo1": [], "servo4": [], "ssa": []}
    while (msg := m.recv_match(type=["SERVO_OUTPUT_RAW", "AOA_SSA"])) is not None:
        if msg.get_type() == "AOA_SSA":
            out["ssa"].append(msg.SSA)
        elif (msg.get_srcSystem(), msg.get_srcComponent()) == (1, 140):
            out["servo1"].append(msg.servo1_raw)
            out["servo4"].append(msg.servo4_raw)
    return {k: np.array(v, dtype=float) for k, v in out.items()}


@pytest.mark.parametrize("controller", ["clsac", "baseline"])
def test_the_mimo_flight_flies_both_surfaces(design, controller, tmp_path):
    r = _run(
        "tools.launch", "--lockstep", "--quiet", "--duration", "30", "--plant", PLANT, "--params", str(design),
        "--controller", controller, "--out", str(tmp_path / "run"),
    )  # fmt: skip
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    out = Path(re.search(r"files: (\S+)/flight\.tlog", r.stdout).group(1))
    summary = json.loads((out / "summary.json").read_text())
    side = summary["sideslip"]
    last = r.stdout.strip().splitlines()[-1]  # the verdict names both channels, and the header both surfaces
    assert last.startswith("OK: flown to the end; controlled: ") and "; sideslip: max |sideslip| " in last, last
    assert "c172x-aileron+rudder (aileron: roll, rudder: sideslip)" in r.stdout
    assert summary["controlled"]["sideslip_ok"] is True
    assert side is not None and [c["channel"] for c in side["channels"]] == ["roll", "sideslip"]
    assert set(side["saturated_fraction"]) == {"aileron", "rudder"} and side["within_envelope"]
    tlog = _tlog(out / "flight.tlog")
    assert tlog["servo1"].size >= 2900 and tlog["servo4"].size == tlog["servo1"].size
    # both surfaces move: each pulse spans tens of us around its trim, on its own channel
    assert np.ptp(tlog["servo1"]) > 100 and np.ptp(tlog["servo4"]) > 10
    assert set(np.unique(tlog["servo4"])) != {1500.0}
    # the sideslip came in AOA_SSA, one a frame, and the summary's max |sideslip| is the largest of them
    assert tlog["ssa"].size >= 3000
    assert side["max_abs_sideslip_deg"] == pytest.approx(np.max(np.abs(tlog["ssa"][:3000])), rel=0.05, abs=0.05)
    assert summary["runs"][0]["steps"] == 3000
    # each channel's parameters under the names a ground station shows, and the matrix gain in the recording
    start = summary["parameters"]["start"]
    assert ("CLSAC_PFC2_NUM" in start) if controller == "clsac" else ("PID2_KP" in start)
    rrd = _run("tools.rrd", "summary", str(out / "flight.rrd"))
    assert rrd.returncode == 0 and "/autopilot/mimo/ke " in rrd.stdout and "/autopilot/mimo/sideslip" in rrd.stdout


def test_the_second_setpoint_comes_from_the_gcs_profile(design, tmp_path):
    """A CSV profile's third column (sideslip_deg): the GCS sends it as NAMED_VALUE_FLOAT SSA_SP, the autopilot flies
    it on the rudder, and the sideslip JSBSim reports (AOA_SSA in the tlog) follows it."""
    csv = tmp_path / "profile.csv"
    csv.write_text("time_s, roll_deg, sideslip_deg\n0, 10, 0\n10, -10, 3\n20, 0, -3\n30, 0, -3\n")
    r = _run(
        "tools.launch", "--lockstep", "--quiet", "--duration", "30", "--plant", PLANT, "--params", str(design),
        "--controller", "baseline", "--csv", str(csv), "--out", str(tmp_path / "run"),
    )  # fmt: skip
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    out = Path(re.search(r"files: (\S+)/flight\.tlog", r.stdout).group(1))
    m = mavutil.mavlink_connection(str(out / "flight.tlog"), dialect="ardupilotmega")
    sp, ssa = [], []
    while (msg := m.recv_match(type=["NAMED_VALUE_FLOAT", "AOA_SSA"])) is not None:
        if msg.get_type() == "AOA_SSA":
            ssa.append((msg.time_usec / 1e6, msg.SSA))
        elif msg.name == "SSA_SP":
            sp.append((msg.time_boot_ms / 1e3, msg.value))
    assert sp and {round(v) for _t, v in sp} >= {0, 3, -3}
    beta = np.array(ssa)
    late = {lo: beta[(beta[:, 0] > lo) & (beta[:, 0] < lo + 5), 1].mean() for lo in (5.0, 15.0, 25.0)}
    assert abs(late[5.0]) < 1.0 and late[15.0] > 1.5 and late[25.0] < -1.5, late
