"""``tools.flight.Flight``, the programmatic launcher: real SITL, autopilot and GCS processes over loopback UDP.

* a short lockstep flight: result, metrics equal to summary.json's, series of the right length;
* a long flight left early from its ``with`` block: valid summary.json, tlog and flight.rrd, no process left;
* the experiment's mavlink transport (``fly_run_over_mavlink``) against the in-process loop with the wire model;
* bad keywords (``FlightConfigError`` naming the value, TypeError naming unknown ones);
* ``Profile``, the command profile every flight flies, against the plain profile functions.
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path

import numpy as np
import pytest

from autopilot.metrics import METRIC_NAMES
from autopilot.shared.pwm import PwmMap
from autopilot.shared.tlog import packet_ids, read_tlog
from tests._mavlink_procs import mavlink
from tools.experiment.scenario import PAPER_RUNS, Scenario, run_inprocess
from tools.flight import Flight, FlightConfigError, fly_run_over_mavlink, profiles
from tools.flight.profiles import Profile, ProfileError
from tools.view import rrd_files as rrd

SERVO = mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW
ATTITUDE = mavlink.MAVLINK_MSG_ID_ATTITUDE


def msg_counts(tlog: Path) -> dict[int, int]:
    counts: dict[int, int] = {}
    for _t, raw in read_tlog(str(tlog)):
        mid = packet_ids(raw)[2]
        counts[mid] = counts.get(mid, 0) + 1
    return counts


@pytest.fixture(scope="module")
def short_flight(tmp_path_factory):
    out = tmp_path_factory.mktemp("flight") / "sac"
    return out, Flight(lockstep=True, duration=3, controller="sac", out=out, quiet=True).run()


@pytest.mark.e2e
def test_run_returns_the_result_of_what_flew(short_flight):
    out, res = short_flight
    # flown to the end, but SAC with the paper's PFC runs away (paper sec. 5): the rudder at its limit > 20 % of 3 s
    assert res.completed and res.controlled is False and not res.ok and res.exit_code == 3, res.reason
    assert res.reason == f"out of envelope: {res.summary['controlled']['reason']}"
    assert res.reason.startswith("out of envelope: rudder saturated ")
    assert isinstance(res.out, Path) and res.out == out
    assert tuple(res.metrics) == METRIC_NAMES
    assert all(math.isfinite(v) for v in res.metrics.values()), res.metrics
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["completed"] and on_disk["outcome"] == "OUT OF ENVELOPE" and not on_disk["ok"]
    assert on_disk["controller"] == "sac" and on_disk["Lv"] == 0.0
    (run,) = on_disk["runs"]
    assert run["steps"] == 300 and run["metrics"] == res.metrics
    assert res.summary["runs"] == on_disk["runs"]
    assert on_disk["files"]["rrd"] == str(out / "flight.rrd") and (out / "flight.rrd").stat().st_size > 0


@pytest.mark.e2e
def test_summary_says_failure_injection_was_on_when_a_params_file_turned_it_on(tmp_path, short_flight):
    """Issue 35: with SYS_FAILURE_EN 1 from --params, summary.json said ``failure_injection: false``: what the
    launcher was told, not what was in force."""
    params = tmp_path / "inject.params"
    params.write_text("SYS_FAILURE_EN 1\n")
    res = Flight(lockstep=True, duration=2, out=tmp_path / "f", quiet=True, params=str(params), rrd=False).run()
    assert res.summary["parameters"]["start"]["SYS_FAILURE_EN"] == 1.0
    assert res.summary["failure_injection"] is True
    assert short_flight[1].summary["failure_injection"] is False  # off: nothing turned it on


def test_failure_injection_in_force_counts_a_param_set_in_flight():
    from tools.flight.config import FlightConfig
    from tools.flight.files import failure_injection_in_force

    cfg = FlightConfig()
    start = {"SYS_FAILURE_EN": 0.0, "CLSAC_LV": 20.0}
    on = {"t_s": 4.0, "name": "SYS_FAILURE_EN", "from": 0.0, "to": 1.0}
    off = {"t_s": 9.0, "name": "SYS_FAILURE_EN", "from": 1.0, "to": 0.0}
    lv = {"t_s": 2.0, "name": "CLSAC_LV", "from": 20.0, "to": 1.0}  # another parameter's 1 is not it
    for changes, expect in (([], False), ([lv], False), ([on], True), ([on, off], True)):
        stats = {"autopilot": {"params_start": start, "param_changes": changes}}
        assert failure_injection_in_force(cfg, stats) is expect, changes
    assert failure_injection_in_force(FlightConfig(failure_injection=True), {"autopilot": None}) is True


@pytest.mark.e2e
def test_the_series_are_the_flown_steps(short_flight):
    _, res = short_flight
    s = res.series
    for key in ("t", "um", "phi", "e", "u", "ke", "v", "delta_r"):
        assert len(s[key]) == 300, key
    np.testing.assert_allclose(s["t"], np.arange(300) / 100.0, atol=1e-9)
    assert s["um"][0] == pytest.approx(math.radians(10.0), rel=1e-6)  # the square wave starts at +amplitude
    assert float(np.sum(s["u"] ** 2) / 100.0) == pytest.approx(res.metrics["energy"], rel=1e-9)


def _wait_for_steps(tlog: Path, steps: int, timeout: float) -> int:
    """SERVO_OUTPUT_RAW records in the growing tlog once there are at least ``steps`` (0 on timeout)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if tlog.exists():
            n = msg_counts(tlog).get(SERVO, 0)
            if n >= steps:
                return n
        time.sleep(0.1)
    return 0


@pytest.mark.e2e
def test_leaving_the_with_block_stops_the_flight_and_leaves_valid_files(tmp_path):
    out = tmp_path / "long"
    with Flight(lockstep=True, duration=600, quiet=True, out=out) as flight:
        assert flight.running and flight.out == out
        assert flight.wait(timeout=0.1) is None  # still flying
        pids = flight.pids
        # SERVO_OUTPUT_RAW records are the steps' (SITL link) plus the GCS stream's, one per 10 steps (10 Hz of sim
        # time): 340 records are at least 300 steps, however soon after them the flight is stopped.
        assert _wait_for_steps(out / "flight.tlog", 340, timeout=60) >= 340
    res = flight.result
    assert not flight.running and res is not None
    assert not res.ok and res.exit_code == 130
    assert res.reason.startswith("stopped by the caller after ") and res.reason.endswith(" of 600 s (sim time)")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["ok"] is False and summary["error"] == res.reason
    (run,) = summary["runs"]
    assert 300 <= run["steps"] < 60000 and run["metrics"] == res.metrics
    assert all(math.isfinite(v) for v in res.metrics.values())
    counts = msg_counts(out / "flight.tlog")  # both links: the SITL's frames and the GCS stream
    assert counts.get(ATTITUDE, 0) >= run["steps"] and counts.get(SERVO, 0) >= run["steps"]
    ok, text = rrd.verify(out / "flight.rrd")
    assert ok, text
    assert len(res.series["t"]) == run["steps"]
    for pid in pids.values():  # every child ended and was reaped
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


@pytest.mark.e2e
def test_experiment_transport_flies_the_scenario_like_the_wire_model(tmp_path):
    scenario, run = Scenario(duration_s=2.0), PAPER_RUNS[1]
    res = fly_run_over_mavlink(scenario, run, tmp_path / run.name)
    assert res.name == "clsac" and res.lv == 20.0
    expected = run_inprocess(scenario, run, wire=PwmMap())
    for key in METRIC_NAMES:
        assert res.metrics[key] == pytest.approx(expected.metrics[key], rel=1e-6), key
    assert len(res.series["u"]) == scenario.steps
    np.testing.assert_allclose(res.series["u"], expected.series["u"], rtol=0, atol=1e-12)
    assert not (tmp_path / run.name / "flight.rrd").exists()  # the experiment logs its own recording


@pytest.mark.parametrize(
    "kwargs,field,needle",
    [
        (dict(rate=0), "rate", "(0, 1000] Hz"),
        (dict(rate=5000), "rate", "(0, 1000] Hz (CLSAC_RATE), got 5000"),
        (dict(rate=400, physics_rate=1000), "physics_rate", "whole multiple"),
        (dict(duration=-1), "duration", "-1"),
        (dict(duration="abc"), "duration", "'abc'"),
        (dict(lockstep=True, busy_wait=True), "busy_wait", "real time"),
        (dict(base_port=70000), "base_port", "70000"),
        (dict(csv="/nonexistent.csv"), "csv", "/nonexistent.csv"),
        (dict(controller="pid"), "controller", "'pid'"),
        (dict(pfc="best"), "pfc", "'best'"),
        (dict(profile="triangle"), "profile", "'triangle'"),
        (dict(amplitude=math.nan), "amplitude", "nan"),
        (dict(period=0), "period", "(0, 86400] s"),
        (dict(rt_priority=100), "rt_priority", "100"),
        (dict(lv=-2), "lv", "-2"),
        # values that parse but cannot be flown: rejected with the allowed range
        (dict(duration=1e308), "duration", "(0, 86400] s, got 1e+308"),
        (dict(lv=1e300), "lv", "[0, 10000]"),
        (dict(start_time=5e6), "start_time", "[0, 86400] s"),
        (dict(physics_rate=1e12), "physics_rate", "(0, 100000] Hz"),
        (dict(sensor_rate=1e9), "sensor_rate", "(0, 1000] Hz"),
        (dict(out="/etc/passwd"), "out", "not a folder"),
        (dict(signing_key="/nonexistent.key"), "signing_key", "no such file"),
        # faults: the bounds of the command line's --fault, the plant's own travel
        (dict(fault=["stuck=1000@1"]), "fault", "stuck must be within +-90 deg, got 1000"),
        (dict(fault=["stuck@1e308"]), "fault", "START must be at most 1e+06 s"),
        (dict(fault=["effectiveness=0.3@\uff11\uff10"]), "fault", "START must be a number in ASCII digits"),
        (dict(fault=["stuck=-31@1"]), "plant", "-31 deg is beyond the rudder's travel, +-30 deg"),
    ],
)
def test_bad_keywords_raise_flight_config_error(kwargs, field, needle):
    with pytest.raises(FlightConfigError) as info:
        Flight(**kwargs)
    message = str(info.value)
    assert info.value.field == field and message.startswith(field) and needle in message
    assert "\n" not in message


SWITCHES = (  # every on/off keyword of Flight, by hand (the test below checks none is missing)
    "lockstep", "freeze_when_saturated", "envelope", "pin", "busy_wait", "quiet", "viewer", "rrd", "rrd_live",
    "series", "png", "web", "failure_injection", "signing",
)  # fmt: skip


@pytest.mark.parametrize("switch", SWITCHES)
@pytest.mark.parametrize("value", ["no", "yes", "False", "", 0, 1, None, 1.0])
def test_a_switch_takes_only_true_or_false(switch, value):
    """Issue 35: ``Flight(failure_injection="no")`` turned injection on (a non-empty string is true) and recorded
    "no"; ``signing="no"`` kept signing on.  Every switch refuses what is not a bool, naming itself."""
    with pytest.raises(FlightConfigError) as info:
        Flight(**{switch: value})
    assert info.value.field == switch and str(info.value) == f"{switch} must be True or False, got {value!r}"


def test_the_switches_are_every_bool_keyword_and_take_true_and_false():
    import dataclasses

    from tools.flight import FlightConfig

    bools = {f.name for f in dataclasses.fields(FlightConfig) if f.init and isinstance(f.default, bool)}
    assert bools == set(SWITCHES)
    for value in (True, False):
        assert Flight(failure_injection=value).config.failure_injection is value
        assert Flight(signing=value).config.signing is value


def test_a_malformed_csv_is_refused_at_construction(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s, roll_deg\n0, 1\n1, x\n")
    with pytest.raises(FlightConfigError, match=r"bad\.csv:3"):
        Flight(csv=str(bad))
    with pytest.raises(FlightConfigError, match="not both"):
        Flight(profile="sine", csv=str(bad))


def test_unknown_keywords_raise_type_error_naming_them():
    with pytest.raises(TypeError, match="unexpected keyword argument 'warp'"):
        Flight(lockstep=True, warp=9)


def test_flight_has_the_config_s_keywords_in_its_signature():
    """help(Flight) and an IDE show the keywords (issue 30, item 9): one per FlightConfig field, keyword-only, with
    the same defaults; ``quiet`` among them and documented."""
    import dataclasses
    import inspect

    from tools.flight import FlightConfig

    sig = inspect.signature(Flight)
    expect = {f.name: f.default for f in dataclasses.fields(FlightConfig) if f.init}
    assert {n: p.default for n, p in sig.parameters.items()} == expect
    assert all(p.kind is inspect.Parameter.KEYWORD_ONLY for p in sig.parameters.values())
    assert "``quiet``" in Flight.__init__.__doc__ and "DIR/<process>.log" in Flight.__init__.__doc__


def test_keywords_are_normalised_like_the_flags():
    cfg = Flight(duration=3, rate=400).config
    assert cfg.duration == 3.0 and isinstance(cfg.duration, float)
    assert cfg.physics_rate == 1200.0 and cfg.lv_value == 20.0
    assert cfg.series and cfg.rrd and not cfg.lockstep


def test_profile_values_are_the_plain_functions():
    ts = [k / 100.0 for k in range(-100, 3000)] + [4.999999999, 5.0, 9.9999999999]
    a = math.radians(10.0)
    for profile, plain in (
        (Profile.square(amplitude_deg=10, period=10), lambda t: profiles.square(t, a, 10)),
        (Profile.step(amplitude_deg=10, step_time=2.5), lambda t: profiles.step(t, a, 2.5)),
        (Profile.sine(amplitude_deg=10, period=4), lambda t: profiles.sine(t, a, 4)),
    ):
        assert [profile.value(t) for t in ts] == [plain(t) for t in ts], profile.kind


def test_csv_profile_holds_its_breakpoints(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("time_s, roll_deg\n0, 0\n1.5, 5\n4, -5\n")
    p = Profile.from_csv(str(path))
    assert p.kind == "csv" and p.times == (0.0, 1.5, 4.0)
    assert [p.value(t) for t in (0.0, 1.49, 1.5, 3.9, 10.0)] == [
        0.0,
        0.0,
        math.radians(5),
        math.radians(5),
        math.radians(-5),
    ]
    assert p.breakpoints_ms(1, 4000) == [1500, 4000]
    assert Profile.square(period=2).breakpoints_ms(0, 3000) == [0, 1000, 2000, 3000]
    assert Profile.step(step_time=1.25).breakpoints_ms(0, 2000) == [1250]
    assert Profile.sine().breakpoints_ms(0, 10000) == []


@pytest.mark.parametrize(
    "kwargs,field",
    [
        (dict(kind="triangle"), "kind"),
        (dict(period=-1.0), "period"),
        (dict(amplitude=math.inf), "amplitude"),
        (dict(step_time=math.nan), "step_time"),
        (dict(kind="csv"), "times"),
        (dict(kind="csv", times=(0.0, 0.0), values=(0.0, 1.0)), "times"),
    ],
)
def test_bad_profiles_raise_profile_error(kwargs, field):
    with pytest.raises(ProfileError) as info:
        Profile(**kwargs)
    assert isinstance(info.value, ValueError) and info.value.field == field and str(info.value).startswith(field)
