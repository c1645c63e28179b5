"""A flight's outcome (tools.flight.outcome, the launcher's verdict): blame when several processes stall or go
silent, the split of a shortfall, the SITL's flown time net of its servo timeout, and the exit status out of the
envelope.  Each test sits at the boundary of a property that mutation testing found no fast test catching (issue 31,
item 11), checks it against numbers worked out here by hand, never against the code's own output, and names the
mutation it was seen to catch (docs/tests.md, "Boundaries")."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from tools.flight import STALL_S, FlightConfig, first_stall, flown_report, verdict
from tools.flight.outcome import envelope_verdict, outcome_of, shortfall


def _child(name, code=0, exited_at=None):
    return SimpleNamespace(name=name, code=code, exited_at=exited_at, started=0.0, reason=lambda: "(no output)")


def _sent(gap_from: float, gap: float, last: float = 30.0) -> dict:
    return {"last_mono": last, "longest_gap_s": gap, "longest_gap_from_mono": gap_from, "ended_mono": last}


# ------------------------------------------------------------------------------------- which stall began first
@pytest.mark.parametrize("gcs_from, named", [(11.99, "gcs"), (12.01, "sitl")])
def test_of_two_stalls_the_one_that_began_first_is_named_not_the_longest(gcs_from, named):
    """The SITL sent nothing for 6 s from 12.00, the GCS script for 3 s from ``gcs_from``: the one that began first
    is named, 0.01 s either way, whatever their lengths (mutation: ``min`` -> ``max`` in ``first_stall``)."""
    stats = {
        "autopilot": {"sent": _sent(5.0, 0.1)},
        "sitl": {"sent": _sent(12.0, 6.0)},
        "gcs": {"sent": _sent(gcs_from, 3.0)},
    }
    children = {n: _child(n) for n in stats}
    name, t_from, seconds, _ = first_stall(children, stats, t_end=30.0)
    assert (name, t_from, seconds) == ((named, gcs_from, 3.0) if named == "gcs" else (named, 12.0, 6.0))


@pytest.mark.parametrize("gap, stalled", [(STALL_S, True), (STALL_S - 1e-9, False)])
def test_a_silence_of_exactly_stall_s_is_a_stall(gap, stalled):
    """``STALL_S`` (2 s) or more without a send is a stall, a hair less is not (mutation: ``>=`` -> ``>``)."""
    stats = {"autopilot": {"sent": _sent(5.0, 0.1)}, "sitl": {"sent": _sent(12.0, gap)}, "gcs": {"sent": _sent(3, 0.2)}}
    got = first_stall({n: _child(n) for n in stats}, stats, t_end=30.0)
    assert (got is not None and got[0] == "sitl") == stalled


def test_a_killed_process_went_silent_when_its_peers_last_heard_it_until_it_exited():
    """The SITL left no stats (killed): the autopilot last heard it at 12.0 and it exited at 15.0, so it was silent
    3.0 s from 12.0, which began before the GCS script's own 2.5 s gap from 13.0 (mutations: the end taken at the
    flight's end, 30.0, instead of the exit; the receive clock of the wrong link)."""
    stats = {
        "autopilot": {"sent": _sent(5.0, 0.1), "links": {"sitl": {"last_rx_mono": 12.0}, "gcs": {"last_rx_mono": 29}}},
        "sitl": None,
        "gcs": {"sent": _sent(13.0, 2.5), "link": {"last_rx_mono": 29.0}},
    }
    children = {"autopilot": _child("autopilot"), "sitl": _child("sitl", -9, 15.0), "gcs": _child("gcs")}
    name, t_from, seconds, evidence = first_stall(children, stats, t_end=30.0)
    assert (name, t_from, seconds) == ("sitl", 12.0, 3.0) and "autopilot" in evidence


# --------------------------------------------------------------------------------------- a shortfall's owner
def _shortfall(late: int, servo_s: float, holds: int, rate: float = 100.0) -> str:
    flown = {
        "lost": {"late_steps": late, "servo_timeout_s": servo_s, "hold_steps": holds},
        "steps": 900,
        "steps_asked": 1000,
    }
    return shortfall(flown, {"autopilot": {"attitude_timeout_s": 0.1, "max_lateness_s": 0.5}}, rate)[0]


@pytest.mark.parametrize(
    "late, servo_s, holds, owner",
    [
        (20, 0.30, 50, "autopilot"),  # 20 + 30 = 50 periods against 50: a tie is the autopilot's
        (20, 0.30, 51, "sitl"),  # one hold more: the SITL's
        (0, 0.50, 50, "autopilot"),  # the servo timeout alone: 0.5 s at 100 Hz is 50 periods, a tie
        (0, 0.49, 50, "sitl"),  # 49 periods against 50
        (50, 0.0, 49, "autopilot"),
    ],
)
def test_a_shortfall_is_split_in_control_periods_and_a_tie_is_the_autopilots(late, servo_s, holds, owner):
    """Late steps and the SITL's time on its servo timeout (in periods) are the autopilot's loss, holds the SITL's;
    the larger loss is named, a tie the autopilot (mutations: ``>`` -> ``>=``; the servo time left out)."""
    assert _shortfall(late, servo_s, holds) == owner


def test_the_sitl_flew_its_commanded_time_net_of_its_servo_timeout():
    """An autopilot killed (no stats): the SITL applied commands from 1.0 s to 4.0 s of sim time and flew 0.5 s of
    that on its servo timeout, so 2.5 s at 100 Hz plus the last command's own period is 251 steps (mutation: the
    servo time added instead of taken off, 351)."""
    cfg = FlightConfig(duration=10.0, quiet=True)
    sitl = {"frames": 0, "first_servo_sim_s": 1.0, "last_servo_sim_s": 4.0, "servo_timeout_s": 0.5}
    flown = flown_report(cfg, {"autopilot": None, "sitl": sitl, "gcs": None})
    assert (flown["steps"], flown["source"]) == (251, "sitl")


def test_the_reason_names_the_stall_that_began_first_and_the_peer_that_reported_it():
    """The verdict on the first test's flight: FAILED, naming the GCS script that stopped first and what the
    autopilot said (mutation: the blame taken from the exit order, the SITL exiting first)."""
    cfg = FlightConfig(duration=30.0, quiet=True)
    stats = {
        "autopilot": {
            "steps": 1200,
            "metric_samples": 1200,
            "exit_reason": "SITL silent for 5.0 s after frame 1200",
            "peer_lost": "sitl",
            "sent": _sent(5.0, 0.1),
        },
        "sitl": {"frames": 1200, "sent": _sent(12.0, 6.0)},
        "gcs": {"sent": _sent(11.99, 3.0), "exit_reason": "vehicle lost"},
    }
    children = {"sitl": _child("sitl", 1, 18.0), "autopilot": _child("autopilot", 0, 19.0), "gcs": _child("gcs", 1, 20)}
    flown = flown_report(cfg, stats)
    code, failed, why = verdict(children, stats, flown, 1, None, None, t_end=30.0)
    assert (code, failed) == (1, "gcs") and why.startswith("gcs stalled: sent nothing for 3.0 s from 12.0 s"), why
    assert "autopilot reports: SITL silent" in why


@pytest.mark.parametrize("gcs_ms, named", [(29_500, "autopilot"), (29_499, "gcs")])
def test_a_ground_station_that_ended_at_the_end_of_the_run_is_not_blamed_for_exiting_first(gcs_ms, named):
    """The autopilot flew all 3000 steps, then failed (exit 1: a file it could not write) and was reaped after the
    GCS script, which had ended at the end of its profile with the clock at ``gcs_ms`` of 30 s (CI, a busy machine:
    "gcs exited early").  At 29.5 s (the end, less ``GCS_END_SLACK_S``) the autopilot is named; 1 ms before it, the
    GCS script ended early (mutation: the first exit blamed whatever it was)."""
    cfg = FlightConfig(duration=30.0, quiet=True)
    stats = {
        "autopilot": {"steps": 3000, "metric_samples": 3000, "exit_reason": "could not write flight.tlog"},
        "sitl": {"frames": 3000},
        "gcs": {"exit_reason": "end of run (profile done)", "sim_ms": gcs_ms, "origin_ms": 0},
    }
    children = {"sitl": _child("sitl", 0, 31.0), "autopilot": _child("autopilot", 1, 30.5)}
    children["gcs"] = _child("gcs", 0, 30.2)
    code, failed, why = verdict(children, stats, flown_report(cfg, stats), 1, None, None, t_end=40.0)
    assert (code, failed) == (1, named), why
    assert why.startswith("autopilot failed (exit code 1)" if named == "autopilot" else "gcs exited early"), why


@pytest.mark.parametrize("autopilot_code, named", [(1, "autopilot"), (0, "gcs")])
def test_a_ground_station_ended_by_a_failing_autopilots_poweroff_is_not_blamed(autopilot_code, named):
    """The autopilot raised at 5.7 s, powered off and exited after the GCS script, which had ended on that POWEROFF
    (CI, a busy machine: "gcs exited early").  The autopilot failed (exit 1): it is named.  An autopilot that exited 0
    did not fail: the script's early end on a POWEROFF (a forged one) is the culprit (mutation: the autopilot's exit
    status not tested)."""
    cfg = FlightConfig(duration=20.0, quiet=True)
    stats = {
        "autopilot": {"steps": 570, "metric_samples": 570, "exit_reason": "ZeroDivisionError: planted"},
        "sitl": {"frames": 570},
        "gcs": {"exit_reason": "end of run (vehicle powered off)", "sim_ms": 5_700, "origin_ms": 0},
    }
    children = {"sitl": _child("sitl", 0, 7.0), "autopilot": _child("autopilot", autopilot_code, 6.5)}
    children["gcs"] = _child("gcs", 0, 6.0)
    code, failed, why = verdict(children, stats, flown_report(cfg, stats), 1, None, None, t_end=10.0)
    assert (code, failed) == (1, named), why
    assert why.startswith("autopilot failed (exit code 1)" if named == "autopilot" else "gcs exited early"), why


# ------------------------------------------------------------------------------------ out of the envelope: 3
def test_a_completed_flight_out_of_the_envelope_exits_3():
    """Completed (0) but not controlled: exit 3, "OUT OF ENVELOPE" with the autopilot's reason; controlled: 0; a
    failed flight stays failed (mutations: the status of the branch, the test of ``ok`` reversed)."""
    assert envelope_verdict(0, None, None, {"ok": False, "reason": "|roll| reached 96.8 deg"}) == (
        3,
        None,
        "out of envelope: |roll| reached 96.8 deg",
    )
    assert envelope_verdict(0, None, None, {"ok": True, "reason": "controlled"}) == (0, None, None)
    assert envelope_verdict(1, "sitl", "x", {"ok": False, "reason": "y"}) == (1, "sitl", "x")
    assert [outcome_of(c) for c in (0, 3, 1, 130)] == ["OK", "OUT OF ENVELOPE", "FAILED", "FAILED"]


def test_a_lockstep_flight_out_of_its_envelope_exits_3(tmp_path):
    """A real 2 s lockstep launch judged against a 5 deg roll envelope: the 10 deg square command leaves it, so the
    launcher exits 3 and says OUT OF ENVELOPE on its last line (a few seconds, not the slow end-to-end tests)."""
    from tests._mavlink_procs import run_cli

    r = run_cli(
        "tools.launch", "--lockstep", "--duration", "2", "--envelope-roll", "5", "--out", str(tmp_path), "--quiet",
        "--no-png", "--no-rrd", timeout=120,
    )  # fmt: skip
    assert r.returncode == 3, r.stdout[-1500:] + r.stderr[-1500:]
    assert r.stdout.strip().splitlines()[-1].startswith("OUT OF ENVELOPE: |roll| reached")
