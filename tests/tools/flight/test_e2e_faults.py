"""Mid-flight faults end to end (issue 29, the L-faults checks): real SITL, autopilot and GCS processes over UDP,
in lockstep (``tools.flight.Flight``, ``python -m tools.launch``, ``python -m sitl``); what a flight records of
them (summary.json, the tlog's STATUSTEXT, the .rrd's markers and event logs, flight.png)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

from tests._mavlink_procs import run_cli
from tools.flight import Flight, FlightConfigError
from tools.view.plot_engine import C_FAULT

pytestmark = pytest.mark.e2e

BAD = ("effectiveness=-1@10", "bogus@1", "effectiveness=0.3@nan", "stuck@-5", "rate=0@1", "effectiveness=0.3")


def _fly(out, **kw):
    res = Flight(lockstep=True, duration=20.0, quiet=True, out=out, **kw).run()
    assert res.completed, res.reason
    with np.load(res.out / "sitl_series.npz") as s, np.load(res.out / "autopilot_series.npz") as a:
        return res, {k: s[k] for k in s.files}, {k: a[k] for k in a.files}


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    root = tmp_path_factory.mktemp("faults")
    return _fly(root / "free"), _fly(root / "eff", fault=["effectiveness=0.3@10"])


def test_effectiveness_changes_the_flight_from_its_start_and_not_before(flights):
    (free, sf, af), (eff, s, a) = flights
    t = s["t"]
    assert np.array_equal(t, sf["t"])
    d = np.abs(s["phi"] - sf["phi"])
    assert d[t < 9.9].max() <= 1e-9 and d[t > 10.5].min() >= 0 and d[t > 10.5].max() > math.radians(0.5)
    ta = a["t"]
    da = np.abs(a["phi"] - af["phi"])  # the autopilot's measured roll (float32 on the wire)
    assert da[ta < 9.9].max() <= 1e-9 and da[ta > 10.5].max() > math.radians(0.5)
    assert eff.summary["faults"] == [
        {
            "kind": "effectiveness",
            "surface": "rudder",  # the KH2013A's one surface
            "value": 0.3,
            "unit": None,
            "start": 10.0,
            "end": None,
            "source": "command line",
            "spec": "effectiveness=0.3@10",
            "started": True,
        }
    ]
    assert free.summary["faults"] == [] and eff.summary["scenario"] == "custom"


def test_the_tlog_the_rrd_and_the_picture_show_the_fault(flights):
    from pymavlink import mavutil

    from autopilot.shared.telemetry.layout import fault_mark_path
    from tools.view import rrd_files as rrd

    (free, _sf, _af), (eff, _s, _a) = flights
    texts = []
    log = mavutil.mavlink_connection(str(eff.out / "flight.tlog"), dialect="common", robust_parsing=True)
    while (m := log.recv_match(type="STATUSTEXT")) is not None:
        texts.append((m.get_srcComponent(), m.text))
    want = "fault start t=10.000: effectiveness=0.3 on the rudder (command line)"
    assert (200, want[:50]) in texts  # from the SITL (two chunks: the first 50 characters)
    assert any(c == 1 and t.startswith("SITL: fault start t=10.000") for c, t in texts)  # relayed to the GCS
    signals = rrd.load(eff.summary["files"]["rrd"])
    for path in ("/sitl/roll", "/sitl/rudder", "/autopilot/error", "/autopilot/gains/ku", "/autopilot/link/sitl"):
        marks = signals[fault_mark_path(path)]
        assert list(marks.t) == [10.0], path
        line = signals[path]
        k = np.searchsorted(line.t, 10.0, side="right") - 1  # the last row at the fault (links: at 10 Hz)
        assert np.array_equal(marks.values[0], line.values[k], equal_nan=True), path  # on the line
    events = rrd.load_texts(eff.summary["files"]["rrd"])
    assert (10.0, want) in events["/sitl/events"] and (10.0, "SITL: " + want) in events["/autopilot/events"]
    assert not any(p.endswith("/fault_marks") or "/fault_marks/" in p for p in rrd.load(free.summary["files"]["rrd"]))

    def orange(out):
        px = np.asarray(Image.open(out / "flight.png").convert("RGB")).reshape(-1, 3)
        return int(np.sum(np.all(px == tuple(int(C_FAULT[i : i + 2], 16) for i in (1, 3, 5)), axis=1)))

    assert orange(eff.out) > 100 and orange(free.out) == 0  # the dotted line in 3 panels and its text


def test_a_stuck_aileron_on_jsbsim_stays_still(tmp_path):
    _res, s, _a = _fly(tmp_path / "stuck", plant="jsbsim:c172x", fault="stuck@10")
    t = s["t"]
    assert np.ptp(s["delta_r"][t > 10.5]) == 0.0 and np.all(s["delta_r_dot"][t > 10.5] == 0.0)
    assert np.ptp(s["delta_r"][(t > 5) & (t < 9.9)]) > math.radians(0.5)  # it moved before


@pytest.mark.parametrize(("plant", "rate"), [("jsbsim:c172x", 20.0), ("kh2013a", 5.0)])  # KH2013A's rudder: <25 deg/s
def test_a_rate_limit_is_never_exceeded(tmp_path, plant, rate):
    res, s, _a = _fly(tmp_path / "rate", plant=plant, fault=[f"rate={rate:g}@10"])
    t, d = s["t"], s["delta_r"]
    slope = np.abs(np.diff(d)) / np.diff(t)
    after = t[1:] > 10.0
    assert slope[after].max() <= math.radians(rate) * (1 + 1e-9)
    assert slope[after].max() > 0.99 * math.radians(rate)  # it is the limit that held the surface back
    assert slope[~after].max() > 1.5 * math.radians(rate)  # before the fault the surface moved faster
    assert res.summary["faults"][0]["value"] == pytest.approx(math.radians(rate))


@pytest.mark.parametrize("spec", BAD)
@pytest.mark.parametrize("module", ["tools.launch", "sitl"])
def test_a_bad_fault_is_one_line_and_exit_2(tmp_path, module, spec):
    r = run_cli(module, "--lockstep", "--duration", "1", "--fault", spec, timeout=60)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert "--fault" in lines[0] and spec in lines[0], lines[0]
    assert "listening" not in r.stdout


def test_a_fault_the_plant_cannot_fly_is_refused_by_both(tmp_path):
    for module in ("tools.launch", "sitl"):
        r = run_cli(module, "--lockstep", "--fault", "inertia=1.5@1", timeout=60)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert "inertia=1.5@1 cannot fly on --plant kh2013a" in r.stderr
    with pytest.raises(FlightConfigError) as exc:
        Flight(lockstep=True, fault=["off@1", "bogus@1"])
    assert exc.value.field == "fault" and "bogus" in str(exc.value)


def test_recovery_after_the_fault_against_the_settled_deviation_computed_here(flights, tmp_path):
    """summary.json ``recovery`` for the effectiveness flight, against the trailing 1 s RMS deviation of the roll
    from y_m,ol computed here step by step from the series (judged where the window starts >= 2 s after a step of
    the 5 s square wave and holds none), in the command's band (25 % of 10 deg, at least 3 deg); a surface stuck at
    10 s is no recovery, and the line never says "recovered"."""
    from tools.flight import recovery_text

    _free, (eff, _s, a) = flights
    rec = eff.summary["recovery"]
    assert len(rec) == 1 and rec[0]["kind"] == "effectiveness" and rec[0]["band_deg"] == pytest.approx(3.0)
    t, d = a["t"], np.degrees(a["phi"] - a["ym_ol"])
    out_at = []
    for k in range(100, len(t)):
        start = t[k] - 1.0
        since = start - 5.0 * math.floor(start / 5.0 + 1e-9)  # seconds from the last step to the window's start
        if start < 10.0 - 1e-9 or since < 2.0 - 1e-9 or since > 4.0 + 1e-9:
            continue  # before the onset, unsettled, or holding a step
        if math.sqrt(np.mean(d[k - 99 : k + 1] ** 2)) > 3.0:
            out_at.append(t[k])
    assert rec[0]["recovered"] is True
    if out_at:
        assert rec[0]["time_s"] >= out_at[-1] - 10.0
    else:
        assert rec[0]["time_s"] == 0.0
    stuck = Flight(lockstep=True, duration=20.0, quiet=True, out=tmp_path / "stuck", fault=["stuck@10"]).run()
    r = stuck.summary["recovery"]
    assert len(r) == 1 and r[0]["recovered"] is False and "recovered" not in recovery_text(r[0])
