"""The launcher's verdict rules and what it refuses before a flight, none of it flown in real time: the rule that
names who stalled (issue 17), the GCS script's end of run, the one-line refusals of impossible values, paths and
peers (issue 11), and the give-up thresholds the launcher passes to its processes.  The real-time flights that
exercise them are in ``test_stalls.py`` and ``test_launch_verdict.py``, which run alone (tests/conftest.py); these
run in the parallel phase."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest

from tests._mavlink_procs import run_cli
from tools.flight import STALL_S, first_stall, flown_report, verdict


# ---------------------------------------------------------------------------------------- who stalled first
def _child(name, code, exited_at):
    return SimpleNamespace(name=name, code=code, exited_at=exited_at, started=0.0, reason=lambda: "(no output)")


def _sent(last, gap=0.05, gap_from=None, ended=None):
    return {"last_mono": last, "longest_gap_s": gap, "longest_gap_from_mono": gap_from or last - 1, "ended_mono": ended}


def _flown_to_the_end(steps: int, last_sent: float) -> dict:
    """The stats of an autopilot that flew ``steps`` steps, none late or held, and ended its run itself."""
    return {
        "steps": steps,
        "hold_steps": 0,
        "late_steps": 0,
        "attitude_timeout_s": 0.1,
        "metric_samples": steps,
        "exit_reason": "end of run (duration reached)",
        "sent": _sent(last_sent),
    }


def test_a_completed_profile_seen_exiting_first_is_not_blamed_for_the_autopilots_shortfall():
    """Under load the GCS script's exit (at the autopilot's POWEROFF, its profile complete) was seen before the
    autopilot's; the flight was 5 autopilot steps short and the reason said "gcs exited early"."""
    from tools.flight import FlightConfig

    cfg = FlightConfig(duration=30.0, quiet=True)
    stats = {
        "autopilot": dict(_flown_to_the_end(3000, 40.0), late_steps=5, max_lateness_s=0.2),
        "sitl": {"frames": 6000, "servo_timeout_s": 0.0, "servo_timeout_open_s": 0.0, "sent": _sent(40.5)},
        "gcs": {"exit_reason": "end of run (vehicle powered off)", "origin_ms": 0, "sim_ms": 30000, "sent": _sent(40)},
    }
    flown = flown_report(cfg, stats)
    assert flown["steps"] == 2995 and not flown["complete"]
    children = {
        "gcs": _child("gcs", 0, 40.01),
        "autopilot": _child("autopilot", 0, 40.02),
        "sitl": _child("sitl", 0, 41),
    }
    code, failed, why = verdict(children, stats, flown, 0, None, None, t_end=40.5)
    assert (code, failed) == (1, "autopilot"), why
    assert why.startswith("autopilot: 5 steps flown later than the attitude timeout (0.1 s)"), why
    assert "gcs" not in why and "flown 99.8 % (2995 of 3000 steps" in why


# ------------------------------------------------------------------------- the blame follows peer_lost
def _peer_chain(gcs_peer, ap_peer, sitl_peer=None):
    """A flight 1200 of 3000 steps long whose three processes exited in the order GCS script (t = 20 s), autopilot
    (21 s), SITL (22 s, killed), none of them silent for STALL_S on its own send clock (so no stall decides), each
    saying whose silence ended it (``peer_lost``)."""
    from tools.flight import FlightConfig

    stats = {
        "gcs": {"exit_reason": "vehicle lost (nothing for 5 s)", "peer_lost": gcs_peer, "sent": _sent(19.9)},
        "autopilot": {
            "steps": 1200,
            "metric_samples": 1200,
            "exit_reason": "SITL silent for 5.0 s after frame 1200",
            "peer_lost": ap_peer,
            "sent": _sent(20.9),
        },
        "sitl": {"frames": 1200, "exit_reason": "autopilot silent", "peer_lost": sitl_peer, "sent": _sent(21.9)},
    }
    children = {"gcs": _child("gcs", 1, 20.0), "autopilot": _child("autopilot", 1, 21.0), "sitl": _child("sitl", 1, 22)}
    flown = flown_report(FlightConfig(duration=30.0, quiet=True), stats)
    return verdict(children, stats, flown, 1, None, None, t_end=30.0)


def test_the_blame_follows_peer_lost_to_the_end_of_the_chain():
    """The GCS script exited first because the autopilot went silent, and the autopilot because the SITL did: the
    SITL is blamed, with what the last one that noticed it said (mutations: peer_lost not followed, the GCS
    blamed; followed one link only, the autopilot blamed)."""
    code, failed, why = _peer_chain("autopilot", "sitl")
    assert (code, failed) == (1, "sitl"), why
    assert why.startswith("sitl stalled or died: autopilot reports: SITL silent for 5.0 s after frame 1200"), why
    assert "flown 40 % (1200 of 3000 steps" in why


@pytest.mark.parametrize(
    ("gcs_peer", "ap_peer", "sitl_peer", "blamed", "blamer"),
    [
        ("autopilot", None, None, "autopilot", "gcs"),  # one link: the autopilot, which blamed nobody
        ("autopilot", "sitl", "autopilot", "sitl", "autopilot"),  # a circle: followed once round, then stopped
        ("autopilot", "nobody", None, "autopilot", "gcs"),  # a name that is no process of the flight: not followed
        (None, "sitl", None, "gcs", None),  # the first to exit blamed nobody: it is named, whatever came after
    ],
)
def test_the_chain_stops_where_no_process_is_named_or_one_comes_round_again(
    gcs_peer, ap_peer, sitl_peer, blamed, blamer
):
    code, failed, why = _peer_chain(gcs_peer, ap_peer, sitl_peer)
    assert (code, failed) == (1, blamed), why
    if blamer is None:
        assert why.startswith("gcs failed (exit code 1)"), why
    else:
        assert why.startswith(f"{blamed} stalled or died: {blamer} reports: "), why


@pytest.mark.parametrize("received", [300, 0])
def test_a_real_time_sitl_that_applied_no_command_fails_the_flight(received):
    """Every process ran to its end and the autopilot flew every step, but the SITL applied none of its commands
    (a downlink that dropped them: the aircraft flew with the rudder at neutral, and the SITL's servo timeout,
    which counts from a command applied, never started).  That flight said OK; it fails, naming the SITL if the
    commands reached it, else the autopilot."""
    from tools.flight import FlightConfig

    cfg = FlightConfig(duration=3.0, quiet=True)
    stats = {
        "autopilot": _flown_to_the_end(300, 13.0),
        "sitl": {
            "frames": 600,
            "servo_timeout_s": 0.0,
            "servo_timeout_open_s": 0.0,
            "first_servo_sim_s": None,
            "last_servo_sim_s": None,
            "link": {"rx_by_type": {"SERVO_OUTPUT_RAW": received} if received else {}},
            "sent": _sent(13.5),
        },
        "gcs": {"exit_reason": "end of run (vehicle powered off)", "origin_ms": 0, "sim_ms": 3000, "sent": _sent(13)},
    }
    flown = flown_report(cfg, stats)
    assert flown["steps"] == 0 and flown["lost"]["no_command_applied"] and not flown["complete"]
    children = {n: _child(n, 0, 13.0 + i / 100) for i, n in enumerate(("gcs", "autopilot", "sitl"))}
    code, failed, why = verdict(children, stats, flown, 0, None, None, t_end=13.5)
    expected = (
        "sitl: the SITL applied none of the 300 servo commands it received"
        if received
        else "autopilot: no servo command reached the SITL"
    )
    assert (code, failed) == (1, "sitl" if received else "autopilot") and why.startswith(expected), why
    assert "flown 0 % (0 of 300 steps" in why
    stats["sitl"]["first_servo_sim_s"] = stats["sitl"]["last_servo_sim_s"] = 0.01  # one applied: no such verdict
    assert not flown_report(cfg, stats)["lost"]["no_command_applied"]


def test_the_first_to_stop_sending_is_named_not_the_first_to_exit():
    """Evidence beats exit order: the GCS exits first (it noticed), the SITL's own clock shows it stopped earlier;
    a process without stats is judged on its peers' receive clocks; silences under STALL_S are no stall."""
    ok_ap = {"exit_reason": "SITL silent", "sent": _sent(20.0), "links": {"sitl": {}, "gcs": {"last_rx_mono": 19.9}}}
    stats = {
        "autopilot": {**ok_ap, "links": {"sitl": {"last_rx_mono": 12.0}, "gcs": {"last_rx_mono": 19.9}}},
        "sitl": {"sent": _sent(18.0, gap=6.0, gap_from=12.0)},
        "gcs": {"sent": _sent(19.95, gap=0.9, gap_from=15.0), "link": {"last_rx_mono": 20.0}},
    }
    children = {
        "gcs": _child("gcs", 1, 19.96),
        "autopilot": _child("autopilot", 0, 20.1),
        "sitl": _child("sitl", 0, 25),
    }
    assert first_stall(children, stats, t_end=20.2)[:3] == ("sitl", 12.0, 6.0)
    stats["sitl"] = None  # killed while stopped: the autopilot last heard it at 12.0, then nothing to the end
    name, t_from, seconds, evidence = first_stall(children, stats, t_end=20.2)
    assert (name, t_from) == ("sitl", 12.0) and seconds == pytest.approx(8.2) and "autopilot" in evidence
    stats["autopilot"]["links"]["sitl"]["last_rx_mono"] = 20.2 - STALL_S + 0.01  # heard until just under STALL_S
    assert first_stall(children, stats, t_end=20.2) is None


def test_send_clock_keeps_the_longest_gap_and_the_tail_to_the_end():
    """The longest interval without a send, between two sends or from the last one to the end of the run loop."""
    from autopilot.shared.link import SendClock

    clock = SendClock()
    for t in (10.0, 10.01, 10.02, 13.52, 13.53):  # a 3.5 s gap from 10.02
        clock.tick(t)
    assert (clock.gap_s, clock.gap_from, clock.sends, clock.first) == (pytest.approx(3.5), 10.02, 5, 10.0)
    clock.end(15.0)  # 1.47 s to the end: shorter, the 3.5 s gap stays
    assert clock.gap_s == pytest.approx(3.5)
    clock.end(20.0)  # stopped after its last send until its end: 6.47 s from 13.53
    s = clock.summary()
    assert s["longest_gap_s"] == pytest.approx(6.47) and s["longest_gap_from_mono"] == 13.53
    assert s["last_mono"] == 13.53 and s["ended_mono"] == 20.0


# ---------------------------------------------------------------------------------------- the end of a run
@pytest.mark.parametrize("seen_s,ok", [(7.5, True), (7.49, False), (8.0, True), (3.0, False), (None, False)])
def test_a_ground_station_ends_the_run_only_at_its_end(seen_s, ok):
    """The boundary of ``_reached_end`` for an 8 s flight: the GCS script's "end of run" counts only if the
    vehicle clock it saw reached the duration, less one slack of 0.5 s (it sees the clock a telemetry period late)."""
    from tools.flight import GCS_END_SLACK_S, _reached_end

    assert GCS_END_SLACK_S == 0.5
    st = {"exit_reason": "end of run (vehicle powered off)", "origin_ms": 2000, "sim_ms": None}
    if seen_s is not None:
        st["sim_ms"] = 2000 + round(seen_s * 1000)
    assert _reached_end("gcs", st, 8.0) is ok
    assert _reached_end("gcs", {"exit_reason": "stopped by signal", "origin_ms": 0, "sim_ms": 8000}, 8.0) is False
    assert _reached_end("sitl", {"exit_reason": "end of run (duration reached)"}, 8.0) is True  # by frame count


# ---------------------------------------------------------------------------------------- refused before a flight
@pytest.mark.e2e
@pytest.mark.parametrize(
    "argv,needle,process",
    [
        (["--physics-rate", "1e12"], "(0, 100000] Hz", "sitl"),
        (["--sensor-rate", "1e9"], "(0, 1000] Hz", "sitl"),
        (["--sensor-rate", "19.9"], "at least 20 Hz in real time", "sitl"),  # just below: attitude would time out
        (["--rate", "5000"], "(0, 1000] Hz", "autopilot"),
        (["--rate", "100", "--physics-rate", "1050"], "whole multiple of the control rate", "sitl"),
        (["--duration", "1e308"], "(0, 86400] s", "launch"),
        (["--start-time", "5e6"], "[0, 86400] s", "sitl"),
        (["--lv", "1e300"], "[0, 10000]", "autopilot"),
        (["--amplitude", "1e9"], "[-180, 180] deg", "gcs"),
    ],
)
def test_impossible_values_are_refused_before_the_flight(tmp_path, argv, needle, process):
    """Exit 2 with one line naming the flag and its range; nothing is started; summary.json says so."""
    out = tmp_path / "never"
    r = run_cli("tools.launch", *argv, "--out", str(out), timeout=60)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and argv[-2] in lines[0] and needle in lines[0], r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["summary.json"]  # nothing was started, the verdict is written
    s = json.loads((out / "summary.json").read_text())
    assert s["ok"] is False and s["exit_code"] == 2 and s["refused"] is True
    assert s["failed"] == process and needle in s["error"]
    assert s["flown"]["fraction"] == 0.0 and s["flown"]["steps"] == 0


@pytest.mark.e2e
@pytest.mark.parametrize("bad", ["file", "in_a_file"])
def test_output_paths_are_checked_before_the_flight(tmp_path, bad):
    f = tmp_path / "f"
    f.write_text("x")
    out = f if bad == "file" else f / "run"
    r = run_cli("tools.launch", "--out", str(out), timeout=60)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "--out" in r.stderr, r.stderr
    r = run_cli("autopilot", "--stats-json", str(tmp_path), timeout=60)
    assert r.returncode == 2 and "--stats-json" in r.stderr and "is a folder" in r.stderr


@pytest.mark.e2e
def test_unresolvable_peer_is_a_one_line_error():
    r = run_cli("autopilot", "--sitl", "no.such.host.invalid:5", "--duration", "1", timeout=60)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1 and "no.such.host.invalid:5" in lines[0] and "resolve" in lines[0]


@pytest.mark.e2e
def test_peer_port_0_is_refused_at_parse_time(tmp_path):
    """Port 0 is "any port" only for a bound socket; as a peer it sends nowhere (it blamed the SITL, empty reason)."""
    r = run_cli("tools.launch", "--gcs-peer", "127.0.0.1:0", "--out", str(tmp_path / "never"), timeout=60)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "--gcs-peer" in lines[0] and "0 only binds" in lines[0], r.stderr
    assert sorted(p.name for p in (tmp_path / "never").iterdir()) == ["summary.json"]
    for module, flag in (("autopilot", "--gcs-peer"), ("autopilot", "--sitl"), ("sitl", "--autopilot")):
        r = run_cli(module, flag, "127.0.0.1:0", timeout=60)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and flag in lines[0] and "0 only binds" in lines[0], r.stderr
    assert run_cli("tools.gcs", "--vehicle", "localhost:0", timeout=60).returncode == 2


# ---------------------------------------------------------------------------------------- the give-ups passed on
def test_the_give_ups_default_to_5_s_and_reach_the_processes(tmp_path):
    """The lockstep autopilot's give-up on a silent SITL and the GCS script's on a silent vehicle: 5 s unless asked
    (docs/spec.md, "Honest outcomes"), as ``--lockstep-idle-exit`` and ``--vehicle-timeout`` of those processes; a
    Flight keyword and a launcher flag each, refused in one line when not a positive time."""
    from tools import gcs
    from tools.flight import LOCKSTEP_IDLE_EXIT_S, VEHICLE_TIMEOUT_S, FlightConfig, FlightConfigError, child_argvs
    from tools.launch import build_parser

    assert LOCKSTEP_IDLE_EXIT_S == VEHICLE_TIMEOUT_S == 5.0
    assert gcs.build_parser().parse_args([]).vehicle_timeout == VEHICLE_TIMEOUT_S == gcs.GcsOptions().vehicle_timeout
    args = build_parser().parse_args(["--lockstep"])
    assert args.lockstep_idle_exit == LOCKSTEP_IDLE_EXIT_S and args.vehicle_timeout == VEHICLE_TIMEOUT_S
    cfg = FlightConfig(lockstep=True)
    assert (cfg.lockstep_idle_exit, cfg.vehicle_timeout) == (5.0, 5.0)

    def value(argv, flag):
        assert argv.count(flag) == 1, argv
        return argv[argv.index(flag) + 1]

    argv = child_argvs(cfg, tmp_path, 1, 2)
    assert (
        value(argv["autopilot"], "--lockstep-idle-exit") == "5.0" and value(argv["gcs"], "--vehicle-timeout") == "5.0"
    )
    argv = child_argvs(FlightConfig(lockstep=True, lockstep_idle_exit=2.5, vehicle_timeout=3), tmp_path, 1, 2)
    assert (
        value(argv["autopilot"], "--lockstep-idle-exit") == "2.5" and value(argv["gcs"], "--vehicle-timeout") == "3.0"
    )
    realtime = child_argvs(FlightConfig(vehicle_timeout=4.0), tmp_path, 1, 2)
    assert "--lockstep-idle-exit" not in realtime["autopilot"] and value(realtime["gcs"], "--vehicle-timeout") == "4.0"
    for name in ("lockstep_idle_exit", "vehicle_timeout"):
        with pytest.raises(FlightConfigError, match=f"^{name}: must be in \\(0, 86400\\] s, got "):
            FlightConfig(lockstep=True, **{name: 0.0})


@pytest.mark.e2e
@pytest.mark.parametrize("flag,process", [("--lockstep-idle-exit", "autopilot"), ("--vehicle-timeout", "gcs")])
def test_a_give_up_that_is_no_time_is_refused_before_the_flight(tmp_path, flag, process):
    out = tmp_path / "never"
    r = run_cli("tools.launch", "--lockstep", flag, "-1", "--out", str(out), timeout=60)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and flag in lines[0] and "(0, 86400] s" in lines[0], r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["refused"] is True and s["failed"] == process
