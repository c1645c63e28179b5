"""The launcher's three outcomes over real processes (issue 17, part 1): OK, OUT OF ENVELOPE (exit 3) and the
envelope's flags; the numbers of the verdict checked against the flight's own recorded series."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from autopilot.envelope import SAT_RTOL
from autopilot.shared.process import EXIT_OUT_OF_ENVELOPE
from tests._mavlink_procs import run_cli
from tools.flight import Flight

pytestmark = pytest.mark.e2e  # real processes over loopback UDP

ROOT = Path(__file__).resolve().parents[3]
# The front page and the manual (the Python API page first: its Flight example is the one run below).
PAGES = [ROOT / "docs" / "python-api.md", ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _manual() -> str:
    return "\n".join(p.read_text(encoding="utf-8") for p in PAGES)


# The README's disturbance example, verbatim (Disturbances).
DISTURBED = (
    "python -m tools.launch --lockstep --turbulence moderate --gust 2,10,5 --roll-noise 0.2 --sensor-delay 1 "
    "--loss 0.05 --delay 0.02 --duplicate 0.02 --reorder 0.02 --scale control=0.7:1.3 --seed 3"
)


def _summary(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


def _independent_verdict(out: Path, u_limit_rad: float = math.radians(30.0)) -> tuple[float, float, float]:
    """(max |roll| deg, saturated share, first time |roll| >= 60 deg) straight from DIR/autopilot_series.npz."""
    s = np.load(out / "autopilot_series.npz")
    flying = s["t"] >= 0.0  # real time: the steps before the first ATTITUDE (clock -1 ms) are stand-by, not flight
    t, phi, u = s["t"][flying], s["phi"][flying], s["u_cmd"][flying]
    over = np.flatnonzero(np.abs(phi) >= math.radians(60.0))
    first = float(t[over[0]] - t[0]) if len(over) else math.nan
    return float(np.degrees(np.max(np.abs(phi)))), float(np.mean(np.abs(u) >= u_limit_rad * (1 - SAT_RTOL))), first


def test_readme_disturbance_example_ends_out_of_envelope_with_its_numbers(tmp_path):
    assert DISTURBED in _manual()
    out = tmp_path / "run"
    r = run_cli(*DISTURBED.split()[2:], "--out", str(out), "--quiet", "--no-png", timeout=300)
    assert r.returncode == EXIT_OUT_OF_ENVELOPE == 3, r.stdout[-2000:] + r.stderr[-2000:]
    last = r.stdout.strip().splitlines()[-1]
    s = _summary(out)
    c = s["controlled"]
    assert s["ok"] is False and s["completed"] is True and s["outcome"] == "OUT OF ENVELOPE"
    assert s["flown"]["complete"] and s["runs"][0]["controlled"] == c
    assert last == f"OUT OF ENVELOPE: {c['reason']}"
    readme = _manual()
    assert f"`{last}`" in readme  # the line the README publishes (Disturbances) is what this flight prints
    roll_deg, share, first = _independent_verdict(out)
    # the aircraft ran away: past 60 deg and the rudder at its limit far beyond 20 % of the flight
    assert roll_deg > 90.0 and share > 0.4
    assert c["ok"] is False and c["max_abs_roll_deg"] == pytest.approx(roll_deg, rel=1e-12)
    assert c["saturated_share"] == pytest.approx(share, abs=1e-12) and c["first_exit_s"] == pytest.approx(first)
    assert c["reason"].startswith(
        f"|roll| reached {roll_deg:.1f} deg (limit 60; first past it at {first:.1f} s); "
        f"rudder saturated {100 * share:.1f} % of the flight (limit 20 %); sustained oscillation +-"
    )
    # it oscillates from its first 20 s window to its last (autopilot.envelope, tracking)
    tr = c["tracking"]
    assert tr["first_oscillation"]["end_s"] == 20.0 and tr["oscillating_windows"] == tr["windows"] == 11
    assert c["limits"] == {"max_abs_roll_deg": 60.0, "max_saturated_share": 0.2} and c["checked"] is True
    # announced while flying, once per excursion: STATUSTEXT to the ground station, an event in flight.rrd
    gcs = json.loads((out / "gcs.json").read_text())
    texts = [t for t in gcs["statustexts"] if t.startswith("ENVELOPE: ")]
    assert any(t.startswith("ENVELOPE: |roll| ") and t.endswith(f"at {first:.1f} s") for t in texts), texts
    assert any(t.startswith("ENVELOPE: rudder saturated ") for t in texts), texts
    assert f"e.g. `{texts[0]}`" in " ".join(readme.split())  # the README's example of an announcement
    exits = s["events"]["autopilot"]["envelope_exits"]
    assert 1 < exits < 3000 / 10  # once per excursion, not once per step
    from tools.view.rrd_files import load_text

    events = [txt for _, txt in load_text(out / "flight.rrd", "/autopilot/events") if txt.startswith("ENVELOPE: ")]
    assert len(events) == exits and events[0].endswith(f"at {first:.1f} s")


def test_envelope_limits_and_the_check_off(tmp_path):
    """The paper's square wave rolls 10 deg: outside an envelope of 5 deg, inside with the check off."""
    base = dict(lockstep=True, duration=5.0, quiet=True, rrd=False, png=False)
    res = Flight(**base, out=tmp_path / "tight", envelope_roll=5.0).run()
    roll_deg, share, _ = _independent_verdict(res.out)
    assert res.completed and res.controlled is False and not res.ok and res.exit_code == 3
    assert res.outcome == "OUT OF ENVELOPE" and 5.0 < roll_deg < 20.0
    assert res.reason.startswith(f"out of envelope: |roll| reached {roll_deg:.1f} deg (limit 5; first past it at ")
    off = Flight(**base, out=tmp_path / "off", envelope_roll=5.0, envelope=False).run()
    assert off.ok and off.completed and off.controlled is True and off.exit_code == 0
    assert off.summary["controlled"]["reason"] == (
        f"not checked: max |roll| {roll_deg:.1f} deg, rudder saturated {100 * share:.1f} % of the flight"
    )
    sat = Flight(**base, out=tmp_path / "sat", envelope_saturated=0.01).run()  # 0.01 %: any saturation at all
    _, share, _ = _independent_verdict(sat.out)
    assert sat.completed and (sat.exit_code == 3) is (share >= 1e-4)


def test_default_realtime_paper_flight_is_ok_and_says_so_last(tmp_path):
    out = tmp_path / "rt"
    r = run_cli("tools.launch", "--out", str(out), "--quiet", "--no-png", "--no-rrd", timeout=180)
    s = _summary(out)
    assert r.returncode == 0 and s["outcome"] == "OK" and s["ok"] and s["completed"], r.stderr[-2000:]
    c = s["controlled"]
    roll_deg, share, _ = _independent_verdict(out)
    assert c["ok"] and c["first_exit_s"] is None and c["max_abs_roll_deg"] == pytest.approx(roll_deg, rel=1e-12)
    assert c["saturated_share"] == pytest.approx(share, abs=1e-12) and share < 0.2 and roll_deg < 60.0
    assert r.stdout.strip().splitlines()[-1] == f"OK: flown to the end; {c['reason']}"
    assert c["reason"].startswith(f"controlled: max |roll| {roll_deg:.1f} deg, rudder saturated ")


def test_readme_flight_example_prints_why(tmp_path):
    """The README's ``Flight`` example, run as written: the SAC flight is completed but not controlled and says
    why; the flight left early says it was stopped (issue 17: it printed a bare ``False``)."""
    import re
    import subprocess
    import sys

    text = _manual()
    code = next(b for b in re.findall(r"```python\n(.*?)```", text, re.S) if "from tools.flight import Flight" in b)
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    first, second = [ln for ln in r.stdout.splitlines() if ln.startswith(("True", "False"))]
    assert first.startswith("False True False out of envelope: |roll| reached "), first
    assert "False True False out of envelope" in text  # what the README says it prints
    assert re.fullmatch(r"False stopped by the caller after [\d.]+ s of 3600 s \(sim time\)", second), r.stdout
    s = _summary(tmp_path / "runs" / "x")
    assert s["outcome"] == "OUT OF ENVELOPE" and f"out of envelope: {s['controlled']['reason']}" in first


def test_baseline_flight_header_names_the_pid_not_an_lv(tmp_path):
    """Lv means nothing for the fixed-gain PID (issue 17): neither the launcher's header nor the autopilot's start
    line print one for it; they still do for CL-SAC."""
    out = tmp_path / "pid"
    r = run_cli(
        "tools.launch", "--lockstep", "--controller", "baseline", "--duration", "2", "--out", str(out), "--no-png"
    )
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    header = next(ln for ln in r.stdout.splitlines() if ln.startswith("== "))
    assert header == "== lockstep flight, baseline (fixed-gain PID) on KH2013A (rudder), 100 Hz, 2 s: OK"
    start = next(ln for ln in (out / "autopilot.log").read_text().splitlines() if ln.startswith("autopilot: baseline"))
    assert "Lv" not in start and start.startswith("autopilot: baseline (fixed-gain PID) lockstep at 100 Hz")
    assert r.stdout.strip().splitlines()[-1].startswith("OK: flown to the end; controlled: max |roll| ")
