"""The launcher's command line (``python -m tools.launch``) as a user reads it: the Lv a parameter file sets is the Lv
reported, a --timeout is quoted as given, a child killed by a signal is named by that signal, not by its last log
line, and a reader that closes the pipe early does not end the flight in a traceback."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tests._mavlink_procs import run_cli
from tools.flight.children import Child

pytestmark = pytest.mark.e2e  # real processes


def test_the_lv_a_parameter_file_sets_is_the_lv_reported(tmp_path):
    params = tmp_path / "lv50.params"
    params.write_text("CLSAC_LV 50\n")
    out = tmp_path / "f"
    r = run_cli("tools.launch", "--lockstep", "--duration", "2", "--params", str(params), "--out", str(out), "--quiet")
    assert r.returncode == 0, r.stderr[-2000:]
    assert "== lockstep flight, clsac (Lv=50) on KH2013A (rudder), " in r.stdout
    s = json.loads((out / "summary.json").read_text())
    assert s["Lv"] == 50.0 and s["runs"][0]["Lv"] == 50.0 and s["params"] == str(params)


def test_a_timeout_is_quoted_as_given(tmp_path):
    out = tmp_path / "f"  # never the user's runs/: a test leaves nothing in the checkout
    r = run_cli(
        "tools.launch", "--lockstep", "--duration", "600", "--timeout", "0.4", "--quiet", "--no-rrd", "--out", str(out)
    )
    assert r.returncode == 1 and json.loads((out / "summary.json").read_text())["ok"] is False
    assert (
        r.stdout.strip()
        .splitlines()[-1]
        .startswith("FAILED: flight did not finish within 0.4 s of wall clock (--timeout)")
    ), r.stdout[-500:]


def test_a_child_killed_by_a_signal_is_named_by_the_signal(tmp_path):
    c = Child(
        "x",
        [sys.executable, "-c", "import time; print('x: a start-up banner', flush=True); time.sleep(60)"],
        tmp_path / "x.log",
        False,
    )  # (not input(): stdin is /dev/null, so it ended by itself with status 1 when the kill came late)
    c.proc.kill()
    assert c.wait(10.0) == -9
    assert c.reason() == "killed by SIGKILL"


def test_a_reader_that_closes_the_pipe_early_does_not_end_the_flight_in_a_traceback(tmp_path):
    """``python -m tools.launch | head -3``: the launcher's stdout closes after three lines; the flight still goes
    to its end, writes its summary and exits with the verdict's code, and nothing is traced back on stderr."""
    out = tmp_path / "f"
    p = subprocess.Popen(
        [sys.executable, "-m", "tools.launch", "--lockstep", "--duration", "3", "--no-png", "--no-rrd"]
        + ["--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
    )
    head = [p.stdout.readline() for _ in range(3)]
    p.stdout.close()  # as head does
    err = p.stderr.read().decode()
    code = p.wait(120)
    assert all(head) and code == 0, err[-2000:]
    assert "Traceback" not in err and "BrokenPipeError" not in err, err[-2000:]
    assert json.loads((out / "summary.json").read_text())["outcome"] == "OK"
