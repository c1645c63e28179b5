"""Bad input on every command line (issue 17, part 4): one line on stderr, exit 2, nothing started, no traceback.

Real subprocesses of the real entry points.  The bounds come from one table (autopilot.params.PARAMS for the
controller's values, autopilot.shared.cli for the rest), so a parameter file is refused as the flag is.
"""

from __future__ import annotations

import json

import pytest

from tests._mavlink_procs import run_cli

pytestmark = pytest.mark.e2e  # the command lines as subprocesses


def _one_line_refusal(r, needle: str) -> str:
    """The process exited 2 with exactly one stderr line holding ``needle``, and no traceback."""
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert "error" in lines[0] and needle in lines[0], lines[0]
    return lines[0]


# ---------------------------------------------------------------------------------------------- --params files
@pytest.mark.parametrize(
    "content,needle",
    [
        (b"CLSAC_RATE 1e9\n", "CLSAC_RATE must be in (0, 1000] Hz, got 1e+09"),  # 1e9 Hz never ended
        (b"CLSAC_LV 1e300\n", "CLSAC_LV must be in [0, 10000] 1/s, got 1e+300"),
        (b"CLSAC_FS_ATT_TMO 1e30\n", "CLSAC_FS_ATT_TMO must be in [0.001, 86400] s, got 1e+30"),
        (b"1\t1\tCLSAC_U_LIMIT\t2.0\t9\n", "CLSAC_U_LIMIT must be in (0, 1.5708] rad, got 2"),  # QGC format
        (b"CLSAC_GAM_PX -1\n", "CLSAC_GAM_PX must be in [0, 10000]"),
        (b"\xff\xfe\x00\x81binary\n", "not a text parameter file (byte 0 is not UTF-8)"),  # was UnicodeDecodeError
        (b"CLSAC_LV 20\n\x00\x00\x00\n", "not a text parameter file (it holds NUL bytes)"),
        (b"CLSAC_LV twenty\n", "p.parm:1: CLSAC_LV: not a number"),
    ],
)
def test_a_bad_parameter_file_is_one_line_and_the_autopilot_never_starts(tmp_path, content, needle):
    path = tmp_path / "p.parm"
    path.write_bytes(content)
    r = run_cli("autopilot", "--lockstep", "--params", str(path), timeout=60)
    line = _one_line_refusal(r, needle)
    assert line.startswith("python -m autopilot: error: --params ") and line.count(str(path)) == 1
    assert "listening" not in r.stdout and "autopilot:" not in r.stdout  # no start line: nothing ran


# ------------------------------------------------------------------------------------ flags of every process
@pytest.mark.parametrize(
    "module,args,needle",
    [
        ("autopilot", ["--rate", "1e9"], "--rate: must be in (0, 1000] Hz (CLSAC_RATE)"),
        ("autopilot", ["--attitude-timeout", "1e30"], "--attitude-timeout: must be in [0.001, 86400] s"),
        ("autopilot", ["--setpoint-timeout", "0.001"], "--setpoint-timeout: must be in [0.01, 86400] s"),
        ("autopilot", ["--max-roll-deg", "91"], "--max-roll-deg: must be in (0, 90] deg"),
        ("autopilot", ["--telemetry-rate", "1e9"], "--telemetry-rate: must be in [0, 1000] Hz"),
        ("autopilot", ["--spin-us", "1e300"], "--spin-us: must be in [0, 1e+06] us"),
        ("autopilot", ["--lockstep-spin-us", "-1"], "--lockstep-spin-us"),
        ("autopilot", ["--connect", "garbage"], "--connect: expected rerun|rerun+http|rerun+https://HOST:PORT"),
        ("sitl", ["--seed", "-1"], "--seed: must be in [0, 2^63-1], got '-1'"),  # was a numpy traceback
        ("sitl", ["--seed", "1.5"], "--seed: expected a whole number"),
        ("sitl", ["--connect", "rerun+http://127.0.0.1:9876/other"], "the path must be /proxy"),
        ("sitl", ["--delay", "1e300"], "--delay: must be in [0, 60] s"),
        ("sitl", ["--sensor-delay", "1000000000"], "--sensor-delay: must be in [0, 100000] samples"),
        ("sitl", ["--crosswind", "1e300"], "--crosswind: must be in [-100, 100] m/s"),
        ("sitl", ["--roll-noise", "1e9"], "--roll-noise: must be in [0, 180] deg"),
        ("tools.gcs", ["--setpoint-rate", "1e9"], "--setpoint-rate: must be in (0, 1000] Hz"),
        ("tools.gcs", ["--print-rate", "1e9"], "--print-rate: must be in (0, 1000] Hz"),
        ("tools.gcs", ["--point-dt", "1e300"], "--point-dt: must be in (0, 86400] s"),
        ("tools.experiment", ["robustness", "--seed", "-1"], "--seed: must be in [0, 2^63-1]"),
        (
            "tools.experiment",
            ["replay", "--controller", "clsac", "--condition", "severe", "--seed", "-1", "--run", "0"],
            "--seed",
        ),
        (
            "tools.experiment",
            [
                "replay",
                "--controller",
                "clsac",
                "--condition",
                "severe",
                "--seed",
                "1",
                "--run",
                "0",
                "--duration",
                "1e308",
            ],
            "--duration: must be in (0, 86400] s",
        ),  # noqa: E501
        ("tools.experiment", ["robustness", "--seed", "-1"], "--seed: must be in [0, 2^63-1]"),
        ("tools.experiment", ["robustness", "--runs", "100000000000"], "--runs: must be in [1, 10000000]"),
        ("sitl", ["--spin-us", "1e300"], "--spin-us: must be in [0, 1e+06] us"),
        ("tools.pfc", ["--rate-hz", "1e9"], "--rate-hz: must be in (0, 1000] Hz (CLSAC_RATE)"),
        ("tools.experiment", ["paper", "--sigma-xu", "1e300"], "--sigma-xu: must be in [0, 10000] 1/s (CLSAC_SIGMA_X)"),
    ],
)
def test_bad_flags_are_one_line(module, args, needle):
    _one_line_refusal(run_cli(module, *args, timeout=60), needle)


def test_a_gcs_csv_with_an_impossible_time_is_one_line(tmp_path):
    csv = tmp_path / "far.csv"
    csv.write_text("time_s, roll_deg\n0, 5\n1e308, 0\n")
    _one_line_refusal(run_cli("tools.gcs", "--csv", str(csv), timeout=60), "far.csv:3: time must be in [0, 86400] s")


# ------------------------------------------------------------------------------------- the launcher: not started
@pytest.mark.parametrize(
    "argv,needle,process",
    [
        (["--seed", "-1"], "--seed: must be in [0, 2^63-1]", "sitl"),
        (["--connect", "garbage"], "--connect: expected rerun", "launch"),
        (["--telemetry-rate", "1e9"], "--telemetry-rate: must be in [0, 1000] Hz", "autopilot"),
        (["--delay", "1e300"], "--delay: must be in [0, 60] s", "sitl"),
        (["--sensor-delay", "1000000000"], "--sensor-delay", "sitl"),
        (["--rate", "1e9"], "(0, 1000] Hz (CLSAC_RATE)", "autopilot"),
        (["--u-limit-deg", "90.5"], "--u-limit-deg: must be in (0, 90] deg (CLSAC_U_LIMIT)", "autopilot"),
        (["--sigma-xu", "1e300"], "--sigma-xu: must be in [0, 10000] 1/s", "autopilot"),
        (["--csv", "{far}"], "time must be in [0, 86400] s, got '1e308'", "gcs"),  # it crashed the GCS mid-flight
        (["--csv", "{steep}"], "roll must be in [-180, 180] deg", "gcs"),
        (["--csv", "{zero}"], "the last breakpoint", "gcs"),
        (["--csv", "{binary}"], "not a text file (byte 0 is not UTF-8)", "gcs"),  # named neither file nor line
        # a --params value beyond the table of bounds: refused by the launcher, not by the autopilot mid-launch
        (["--params", "{rate}"], "CLSAC_RATE must be in (0, 1000] Hz, got 1e+09", "autopilot"),
        (["--params", "{unknown}"], "FOO", "autopilot"),
    ],
)
def test_the_launcher_refuses_before_starting_anything(tmp_path, argv, needle, process):
    csvs = {"far": "0, 5\n1e308, 0\n", "steep": "0, 5\n2, 1000\n", "zero": "0, 5\n"}
    for name, text in csvs.items():
        (tmp_path / f"{name}.csv").write_text("time_s, roll_deg\n" + text)
    (tmp_path / "binary.csv").write_bytes(b"\xff\xfe\x00binary")
    (tmp_path / "rate.params").write_text("CLSAC_RATE 1e9\n")
    (tmp_path / "unknown.params").write_text("FOO 1\n")
    files = {k: str(tmp_path / f"{k}.csv") for k in (*csvs, "binary")}
    files.update({k: str(tmp_path / f"{k}.params") for k in ("rate", "unknown")})
    argv = [a.format(**files) for a in argv]
    out = tmp_path / "never"
    r = run_cli("tools.launch", "--lockstep", *argv, "--out", str(out), timeout=60)
    _one_line_refusal(r, needle)
    assert sorted(p.name for p in out.iterdir()) == ["summary.json"]  # no process was started, no log written
    s = json.loads((out / "summary.json").read_text())
    assert s["ok"] is False and s["refused"] is True and s["failed"] == process and s["flown"]["steps"] == 0


# ---------------------------------------------------------------------------------------------------- keygen
@pytest.mark.parametrize("path,needle", [("/proc/x.key", "/proc/x.key"), ("/no/such/dir/k.key", "no folder")])
def test_keygen_to_an_unwritable_path_exits_2_like_its_other_errors(path, needle):
    _one_line_refusal(run_cli("tools.flight.keygen", path, timeout=60), needle)


# ------------------------------------------------------------------------------------------------ rrd verify
@pytest.fixture
def recording(tmp_path):
    """A real recording with a footer, written by the project's telemetry writer."""
    import time

    from autopilot.shared import telemetry as tm
    from sitl import telemetry as S

    path = tmp_path / "t.rrd"
    with tm.Telemetry("sitl", None, path, write_footer=True) as tel:
        st = tel.table(S.SITL_TABLE)
        for k in range(50):
            st.append(k * 0.01, time.time(), (0.0,) * len(S.SITL_FIELDS))
    return path


@pytest.mark.parametrize("keep", [0, 7, 100])
@pytest.mark.parametrize("footers", [True, False])
def test_rrd_verify_fails_an_empty_or_truncated_file(tmp_path, recording, keep, footers):
    data = recording.read_bytes()
    assert len(data) > 1000
    cut = tmp_path / f"cut{keep}.rrd"
    cut.write_bytes(data[:keep])
    flags = [] if footers else ["--no-footer-check"]
    whole = run_cli("tools.rrd", "verify", *flags, str(recording), timeout=120)
    assert whole.returncode == 0 and whole.stdout.strip() == f"{recording}: ok", whole.stdout + whole.stderr
    r = run_cli("tools.rrd", "verify", *flags, str(cut), timeout=120)
    lines = (r.stdout + r.stderr).strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1 and "Traceback" not in r.stderr, r.stdout + r.stderr
    assert lines[0].startswith(f"{cut}: FAILED: ")
    assert ("empty file" if keep == 0 else "decode") in lines[0]


# ---------------------------------------------------------------------------------------------- faults
FAULT_CLIS = {
    "tools.launch": ["tools.launch", "--lockstep", "--duration", "5"],
    "sitl": ["sitl"],
    "robustness": ["tools.experiment", "robustness", "--runs", "2", "--long-runs", "0"],
    "replay": ["tools.experiment", "replay", "--controller", "clsac", "--condition", "severe", "--seed", "0"]
    + ["--run", "1"],
}


@pytest.mark.parametrize("cli", sorted(FAULT_CLIS))
@pytest.mark.parametrize(
    "spec,needle",
    [
        ("stuck=1000@1", "stuck must be within +-90 deg, got 1000"),  # was taken
        ("stuck@1e308", "START must be at most 1e+06 s, got 1e308"),  # was an OverflowError traceback
        ("effectiveness=0.3@\uff11\uff10", "START must be a number in ASCII digits"),  # fullwidth 10: was taken
        ("effectiveness=0.3@\u0661\u0660", "START must be a number in ASCII digits"),  # Arabic-Indic 10
        ("delay=0.05@1_0", "START must be a number in ASCII digits"),
        ("airspeed=1e6@1", "airspeed must be > 0 and at most 5000 kt"),
        ("effectiveness=1e308@10", "effectiveness must be > 0 and at most 10"),
        ("stuck=45@1", "45 deg is beyond the rudder's travel, +-30 deg"),  # the KH2013A's own bound
    ],
)
def test_a_fault_beyond_the_aircraft_is_one_line_on_every_command_line(tmp_path, cli, spec, needle):
    module, *args = FAULT_CLIS[cli]
    if spec.startswith("airspeed") and cli in ("robustness", "replay"):
        needle = "airspeed must be > 0"  # refused as a value before the study says it flies no airspeed
    out = ["--out", str(tmp_path / "out")] if cli in ("tools.launch", "robustness") else []
    _one_line_refusal(run_cli(module, *args, *out, "--fault", spec, timeout=60), needle)


@pytest.mark.parametrize(
    "severity,needle",
    [
        ("stuck=45", "--severity stuck=45 on --plant kh2013a: 45 deg is beyond the rudder's travel, +-30 deg"),
        ("stuck=\uff15", "is not a finite number in ASCII digits"),
        ("effectiveness=1e308", "effectiveness must be > 0 and at most 10"),
        ("delay=1_0", "is not a finite number in ASCII digits"),
    ],
)
def test_a_damage_severity_beyond_the_aircraft_is_one_line(tmp_path, severity, needle):
    r = run_cli(
        "tools.experiment", "damage", "--plant", "kh2013a", "--severity", severity, "--out", str(tmp_path / "o")
    )
    _one_line_refusal(r, needle)
