"""An internal error puts its traceback in the process's log file; the console gets one line (autopilot.shared.crash).

Issue 35: the autopilot died of a ZeroDivisionError and autopilot.log held only "autopilot: error:
ZeroDivisionError: float division by zero", so nobody could say where.  Here the error is provoked in real
processes: a ``sitecustomize`` on the PYTHONPATH of the flight (which every process of it imports at start-up)
makes one process's link raise after a number of reads, a bug planted from outside the code, and the log file and
the console are read back.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from autopilot.shared import crash
from tools.flight.children import Child

ROOT = Path(__file__).resolve().parents[3]

# Planted in the process started with ``-m TARGET`` only: the n-th call of CLASS.METHOD raises.
PLANT = """
import sys
argv = sys.orig_argv
if "-m" in argv and argv[argv.index("-m") + 1 :][:1] == [{target!r}]:
    import importlib
    cls = getattr(importlib.import_module({module!r}), {cls!r})
    real = getattr(cls, {method!r})
    calls = [0]
    def planted(*a, **k):
        calls[0] += 1
        if calls[0] >= {after}:
            raise ZeroDivisionError("planted by the test")
        return real(*a, **k)
    setattr(cls, {method!r}, planted)
"""


def _plant(tmp_path: Path, target: str, module: str, cls: str, method: str, after: int) -> dict:
    """The environment of a process tree in which ``-m target``'s ``after``-th call of cls.method raises."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(
        PLANT.format(target=target, module=module, cls=cls, method=method, after=after)
    )
    env = {k: v for k, v in os.environ.items() if k != crash.LOG_ENV}
    env["PYTHONPATH"] = f"{site}{os.pathsep}{ROOT}"
    return env


# ------------------------------------------------------------------------------------------------- fast
def test_under_the_launcher_the_traceback_is_marked_for_the_log_and_the_one_line_names_it(monkeypatch):
    monkeypatch.setenv(crash.LOG_ENV, "/x/autopilot.log")
    out = io.StringIO()
    try:
        _ = 1 / 0
    except ZeroDivisionError as exc:
        line = crash.report("autopilot", exc, file=out)
    lines = out.getvalue().splitlines()
    assert lines[-1] == line == "autopilot: error: ZeroDivisionError: division by zero (traceback in /x/autopilot.log)"
    body = lines[:-1]
    assert body[0] == "autopilot: traceback: Traceback (most recent call last):"
    assert all(crash.is_traceback_line(x, "autopilot") for x in body) and not crash.is_traceback_line(line, "autopilot")
    assert any("test_crash.py" in x and "test_under_the_launcher" in x for x in body)  # where it happened


def test_by_hand_the_traceback_goes_to_a_file_the_one_line_names(monkeypatch, tmp_path):
    monkeypatch.delenv(crash.LOG_ENV, raising=False)
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)  # TMPDIR read again
    out = io.StringIO()
    try:
        {}["missing"]
    except KeyError as exc:
        line = crash.report("sitl", exc, file=out)
    assert out.getvalue() == line + "\n"  # the console: one line
    path = Path(line.split("(traceback in ")[1].rstrip(")"))
    assert path.parent == tmp_path and path.name.startswith(f"sitl-traceback-{os.getpid()}-")
    text = path.read_text()
    assert text.startswith("Traceback (most recent call last):") and text.rstrip().endswith("KeyError: 'missing'")


def test_a_process_s_own_log_gets_the_traceback_appended(tmp_path):
    log = tmp_path / "launch.log"
    log.write_text("before\n")
    out = io.StringIO()
    try:
        raise RuntimeError("two\nlines")
    except RuntimeError as exc:
        line = crash.report("launch", exc, log=log, file=out)
    assert line == f"launch: error: RuntimeError: two lines (traceback in {log})" and out.getvalue() == line + "\n"
    assert log.read_text().startswith("before\nTraceback (most recent call last):")


def test_the_launchers_child_logs_the_traceback_and_echoes_one_line(tmp_path, capsys):
    """``Child`` (the launcher's): the child's traceback lines go to its log only; the console and its reason get
    the one line."""
    code = "from autopilot.shared import crash\ntry:\n    1 / 0\nexcept ZeroDivisionError as e:\n"
    code += "    crash.report('x', e)\nraise SystemExit(1)\n"
    log = tmp_path / "x.log"
    c = Child("x", [sys.executable, "-c", code], log, True)
    try:
        assert c.wait(120.0) == 1
    finally:
        c.kill()
        c.finish()
    text = log.read_text()
    assert "x: traceback: Traceback (most recent call last):" in text and 'x: traceback:   File "<string>"' in text
    one = f"x: error: ZeroDivisionError: division by zero (traceback in {log})"
    assert c.reason() == one
    console = capsys.readouterr().out.splitlines()
    assert console == [f"[x] {one}"]


# ---------------------------------------------------------------------------------------- real processes
@pytest.mark.e2e
@pytest.mark.parametrize("process", ["autopilot", "sitl", "gcs"])
def test_a_flight_process_s_internal_error_is_in_its_log_with_the_traceback(tmp_path, process):
    """A lockstep flight whose ``process`` raises mid-flight (its UDP link's 300th read, the GCS script's 5th: it
    reads in batches): the launcher fails it (exit 1) naming the one line; DIR/<process>.log holds the whole
    traceback down to the planted raise; the console shows no line of it."""
    target = {"autopilot": "autopilot", "sitl": "sitl", "gcs": "tools.gcs"}[process]
    env = _plant(tmp_path, target, "autopilot.shared.link", "UdpLink", "poll", 300 if process != "gcs" else 5)
    out = tmp_path / "f"
    r = subprocess.run(
        [sys.executable, "-m", "tools.launch", "--lockstep", "--duration", "20", "--no-rrd", "--out", str(out)],
        capture_output=True, text=True, cwd=tmp_path, env=env, timeout=300,
    )  # fmt: skip
    console = r.stdout + r.stderr
    assert r.returncode == 1, console[-3000:]
    log = (out / f"{process}.log").read_text()
    one = f"{process}: error: ZeroDivisionError: planted by the test (traceback in {out / f'{process}.log'})"
    assert one in log and f"{process}: traceback: Traceback (most recent call last):" in log, log[-3000:]
    assert f'{process}: traceback:     raise ZeroDivisionError("planted by the test")' in log  # to the raise
    assert f"[{process}] {one}" in console and "traceback:" not in console and "Traceback" not in console
    summary = json.loads((out / "summary.json").read_text())
    assert summary["ok"] is False and one in summary["error"]


@pytest.mark.e2e
def test_the_launcher_s_own_internal_error_is_one_line_and_its_traceback_in_launch_log(tmp_path):
    env = _plant(tmp_path, "tools.launch", "tools.flight.supervision", "Flight", "_poll", 3)
    out = tmp_path / "f"
    r = subprocess.run(
        [sys.executable, "-m", "tools.launch", "--lockstep", "--duration", "20", "--no-rrd", "--out", str(out)],
        capture_output=True, text=True, cwd=tmp_path, env=env, timeout=300,
    )  # fmt: skip
    assert r.returncode == 1, r.stdout[-3000:] + r.stderr[-3000:]
    last = r.stdout.strip().splitlines()[-1]
    log = out / "launch.log"
    assert last == f"FAILED: launch: error: ZeroDivisionError: planted by the test (traceback in {log})"
    assert "Traceback" not in r.stdout + r.stderr
    text = log.read_text()
    assert text.startswith("Traceback (most recent call last):") and "in wait" in text  # where it happened
    assert text.rstrip().endswith("ZeroDivisionError: planted by the test")
    left = subprocess.run(["pgrep", "-f", str(out)], capture_output=True, text=True).stdout.split()
    assert not left, "a process of the flight outlived the launcher"


@pytest.mark.e2e
def test_a_process_run_by_hand_prints_one_line_naming_its_traceback_file(tmp_path):
    env = _plant(tmp_path, "autopilot", "autopilot.loop", "Autopilot", "run", 1)
    env["TMPDIR"] = str(tmp_path)
    r = subprocess.run(
        [sys.executable, "-m", "autopilot", "--lockstep", "--duration", "1"],
        capture_output=True, text=True, cwd=tmp_path, env=env, timeout=120,
    )  # fmt: skip
    assert r.returncode == 1
    errors = [x for x in r.stderr.splitlines() if "error" in x]
    assert len(errors) == 1 and "Traceback" not in r.stderr, r.stderr
    assert errors[0].startswith("autopilot: error: ZeroDivisionError: planted by the test (traceback in ")
    path = Path(errors[0].split("(traceback in ")[1].rstrip(")"))
    assert path.parent == tmp_path
    assert path.read_text().rstrip().endswith("ZeroDivisionError: planted by the test")
