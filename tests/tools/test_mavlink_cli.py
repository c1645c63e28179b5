"""Command lines of the MAVLink processes: --help, one-line errors on bad flags."""

from __future__ import annotations

import pytest

from tests._mavlink_procs import run_cli

pytestmark = pytest.mark.e2e  # the command lines as subprocesses

MODULES = ("sitl", "autopilot", "tools.gcs", "tools.launch")


@pytest.mark.parametrize("module", MODULES)
def test_help(module):
    r = run_cli(module, "--help", timeout=60)
    assert r.returncode == 0
    assert "usage:" in r.stdout and "--duration" in r.stdout


@pytest.mark.parametrize(
    "module,args,needle",
    [
        ("autopilot", ["--rate", "0"], "--rate"),
        ("autopilot", ["--rate", "abc"], "--rate"),
        ("autopilot", ["--sitl", "127.0.0.1:70000"], "0..65535"),
        ("autopilot", ["--controller", "pid"], "--controller"),
        ("autopilot", ["--pwm-min", "1600"], "pwm-min"),
        ("sitl", ["--listen", "nohostport"], "HOST:PORT"),
        ("sitl", ["--rate", "-5"], "--rate"),
        ("sitl", ["--lockstep", "--rate", "300", "--physics-rate", "1000"], "whole multiple"),
        ("tools.gcs", ["--period", "nan"], "--period"),
        ("tools.gcs", ["--csv", "/nonexistent.csv"], "--csv"),
        ("tools.launch", ["--rate", "0"], "--rate"),
        ("tools.launch", ["--controller", "pid"], "--controller"),
        ("tools.launch", ["--duration", "abc"], "--duration"),
        ("autopilot", ["--rt-priority", "100"], "--rt-priority"),
        ("sitl", ["--rt-priority", "x"], "--rt-priority"),
        ("tools.gcs", ["--cpu", "4096"], "--cpu"),
        ("tools.launch", ["--rt-priority", "100"], "--rt-priority"),
        # checked by tools.flight.Flight, reported with the flag's name
        ("tools.launch", ["--rate", "400", "--physics-rate", "1000"], "--physics-rate"),
        ("tools.launch", ["--base-port", "70000"], "--base-port"),
        ("tools.launch", ["--csv", "/nonexistent.csv"], "--csv"),
        ("tools.launch", ["--lockstep", "--busy-wait"], "--busy-wait is for real time"),
    ],
)
def test_bad_flags_give_one_line_error(module, args, needle):
    r = run_cli(module, *args, timeout=60)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert "error" in lines[0] and needle in lines[0]
