"""What a user sees (issue 17, part 6): a --csv flight lasts to its last breakpoint, breakpoints are held, and the
lines that read like errors or nonsense (``received 93 ... of 65 datagrams``, ``+nan deg``, ``stopped by signal``
after a good real-time flight) say what they mean."""

from __future__ import annotations

import math

import pytest

from autopilot.shared.link import format_counters
from tools.flight import Flight, FlightConfig, FlightConfigError
from tools.flight.profiles import Profile
from tools.gcs import Gcs, GcsOptions, build_parser, profile_duration


def _csv(tmp_path, rows: str):
    path = tmp_path / "p.csv"
    path.write_text("time_s, roll_deg\n" + rows)
    return str(path)


# ------------------------------------------------------------------------------------------------------ --csv
def test_a_csv_flight_lasts_to_its_last_breakpoint_unless_a_duration_is_given(tmp_path):
    path = _csv(tmp_path, "0, 5\n2, -5\n47.5, 0\n")
    assert FlightConfig(csv=path).duration == 47.5  # was 30 s, whatever the file
    assert FlightConfig(csv=path, duration=10.0).duration == 10.0
    assert FlightConfig().duration == 30.0  # the other profiles: 30 s as before
    with pytest.raises(FlightConfigError, match="last breakpoint .* is at 0 s: give a duration"):
        FlightConfig(csv=_csv(tmp_path, "0, 5\n"))
    assert FlightConfig(csv=_csv(tmp_path, "0, 5\n"), duration=3.0).duration == 3.0


def test_the_gcs_flies_a_csv_to_its_last_breakpoint_too(tmp_path):
    profile = Profile.from_csv(_csv(tmp_path, "0, 5\n12.25, 0\n"))
    assert build_parser().parse_args(["--csv", "x"]).duration is None  # "not given" is seen
    assert profile_duration(None, profile) == 12.25
    assert profile_duration(5.0, profile) == 5.0 and profile_duration(0.0, profile) == 0.0
    assert profile_duration(None, Profile.square()) == 0.0  # until the vehicle powers off, as before


def test_csv_breakpoints_are_held_not_interpolated(tmp_path):
    p = Profile.from_csv(_csv(tmp_path, "0, 10\n2, -10\n4, 0\n"))
    for t, deg in ((0.0, 10), (1.0, 10), (1.999, 10), (2.0, -10), (3.5, -10), (4.0, 0), (100.0, 0)):
        assert p.value(t) == pytest.approx(math.radians(deg)), t  # interpolation would give 0 at t = 1


# ----------------------------------------------------------------------------------------------- the lines
def test_counters_say_messages_in_datagrams():
    c = {
        "rx_packets": 93,
        "rx_datagrams": 65,
        "tx_packets": 33,
        "tx_errors": 0,
        "rx_by_type": {"ATTITUDE": 30},
        "tx_by_type": {"HEARTBEAT": 2},
        "rejected": {},
    }
    line = format_counters("gcs link", c)
    assert line.startswith("gcs link: received 93 messages (ATTITUDE=30) in 65 datagrams; sent 33 messages")
    assert " of 65" not in line


def test_the_gcs_live_line_before_any_attitude_has_no_nan():
    gcs = Gcs(GcsOptions(listen=("127.0.0.1", 0)), Profile.square())
    try:
        gcs.sim_ms = 0  # SYSTEM_TIME came first: a clock, no roll, no setpoint yet
        line = gcs.live_line()
        assert "nan" not in line.lower() and line.count(" - deg") == 3, line
        gcs.roll, gcs.target = math.radians(1.5), math.radians(10.0)
        assert "setpoint= +10.00 deg  roll=  +1.50 deg  error= +8.50 deg" in gcs.live_line()
    finally:
        gcs.link.close()


@pytest.mark.e2e
def test_flown_lines_read_as_what_happened(tmp_path):
    """A lockstep CSV flight: flown to the last breakpoint, its GCS log without nan; a good real-time flight: the
    SITL's last line is a normal end."""
    path = _csv(tmp_path, "0, 5\n1, -5\n2.5, 0\n")
    res = Flight(lockstep=True, csv=path, out=tmp_path / "ls", quiet=True, rrd=False, png=False).run()
    assert res.ok, res.reason
    assert res.summary["duration_s"] == 2.5 and res.summary["runs"][0]["steps"] == 250
    gcs_log = (tmp_path / "ls" / "gcs.log").read_text()
    assert "nan" not in gcs_log and " messages (" in gcs_log and " datagrams" in gcs_log, gcs_log
    res = Flight(duration=2.0, out=tmp_path / "rt", quiet=True, rrd=False, png=False, series=False).run()
    assert res.ok, res.reason
    sitl_log = (tmp_path / "rt" / "sitl.log").read_text()
    assert "stopped by signal" not in sitl_log and "stopped on request (SIGINT/SIGTERM)" in sitl_log, sitl_log
