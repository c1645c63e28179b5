"""Output paths (issue 31, item 9): a character device or a FIFO given as an output file is refused in one line
before anything starts, never replaced by a regular file nor written into; an unwritable ``--out`` is one line;
a lockstep ``--start-time`` that is not a whole frame is refused up front; and a disk that fills up in mid-flight
leaves a FAILED verdict naming the file, with what was written kept.  Real processes, real files."""

from __future__ import annotations

import json
import os
import resource
import stat
import subprocess
import sys

import pytest

from autopilot.shared.process import NotRegularFileError, write_json_atomic
from tests._mavlink_procs import run_cli


def _one_line(r: subprocess.CompletedProcess, *needles: str) -> str:
    lines = (r.stdout + r.stderr).strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stdout + r.stderr
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


def _device(tmp_path, kind: str):
    path = tmp_path / kind
    if kind == "fifo":
        os.mkfifo(path)
    else:  # a character device, as /dev/null is (1, 3): only root may make one
        if os.geteuid() != 0:
            pytest.skip("making a character device needs root")
        os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    return path


@pytest.mark.parametrize("kind", ["fifo", "chardev"])
@pytest.mark.parametrize("module", ["autopilot", "sitl", "tools.gcs"])
def test_stats_json_on_a_device_is_refused_and_left_alone(tmp_path, module, kind):
    """Run as root, ``--stats-json /dev/null`` used to replace the device by a regular file (written by a rename).
    Refused now, before any socket is opened; the device is the same device afterwards."""
    target = _device(tmp_path, kind)
    before = os.stat(target)
    r = run_cli(module, "--lockstep", "--stats-json", str(target), timeout=60)
    _one_line(r, "--stats-json", str(target), "not a regular file")
    after = os.stat(target)
    assert stat.S_IFMT(after.st_mode) == stat.S_IFMT(before.st_mode) and after.st_rdev == before.st_rdev
    assert not (tmp_path / f"{kind}.tmp").exists()


@pytest.mark.parametrize("flag, module", [("--tlog", "autopilot"), ("--rrd", "autopilot"), ("--rrd", "sitl")])
def test_a_full_device_as_tlog_or_rrd_is_one_line_naming_it(flag, module):
    """/dev/full (every write fails with ENOSPC) was a traceback at the first flush; now one line, exit 2."""
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full here")
    _one_line(run_cli(module, "--lockstep", flag, "/dev/full", timeout=60), flag, "/dev/full", "character device")


def test_stats_are_never_written_over_a_fifo():
    """The library's own guard, below the command lines' check."""
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        fifo = os.path.join(d, "f")
        os.mkfifo(fifo)
        with pytest.raises(NotRegularFileError, match="not a regular file"):
            write_json_atomic(fifo, {"a": 1})
        assert stat.S_ISFIFO(os.stat(fifo).st_mode) and os.listdir(d) == ["f"]


@pytest.mark.parametrize("out", ["/proc/clsac-out", "/proc/self/clsac-out"])
def test_an_out_folder_that_cannot_be_made_is_one_line(out):
    """``os.access`` says yes to root on /proc; a real probe (a temporary folder made and removed) says no."""
    _one_line(run_cli("tools.launch", "--lockstep", "--duration", "1", "--out", out, timeout=60), "--out", out)


def test_a_start_time_between_frames_is_refused_before_the_flight(tmp_path):
    """0.005 s at 100 Hz is half a frame: the SITL refused it at run time (exit 1 after the launch); now the launcher
    refuses it in one line naming the SITL (its value), before anything starts."""
    r = run_cli(
        "tools.launch", "--lockstep", "--start-time", "0.005", "--duration", "1", "--out", str(tmp_path), timeout=60
    )
    _one_line(r, "--start-time", "0.005", "whole number of frames", "0.01 s")
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["refused"] and summary["failed"] == "sitl" and summary["flown"]["fraction"] == 0
    assert run_cli("tools.launch", "--lockstep", "--start-time", "0.05", "--duration", "0.5", "--no-rrd",
                   "--no-png", "--quiet", "--out", str(tmp_path / "ok"), timeout=120).returncode == 0  # fmt: skip


@pytest.mark.e2e
def test_a_disk_full_in_mid_flight_fails_the_flight_naming_the_file_and_keeps_what_was_written(tmp_path):
    """Files may grow to 300 kB only (RLIMIT_FSIZE: a write past it fails, as on a full disk): a 30 s lockstep flight
    writes more than that to its tlog.  The flight flies on to its end; the verdict is FAILED, naming the file; the
    stats are written and the tlog keeps its first 300 kB."""
    limit = 300_000

    def small_files():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    r = subprocess.run(
        [sys.executable, "-m", "tools.launch", "--lockstep", "--duration", "30", "--out", str(tmp_path), "--quiet",
         "--no-png"],
        capture_output=True, text=True, timeout=300, preexec_fn=small_files, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert r.returncode == 1 and "Traceback" not in r.stdout + r.stderr, r.stdout[-2000:] + r.stderr[-2000:]
    last = r.stdout.strip().splitlines()[-1]
    assert last.startswith("FAILED: autopilot failed (exit code 1): autopilot: error: could not write "), last
    assert "flown 100 %" in last
    log = (tmp_path / "autopilot.log").read_text()
    assert f"could not write {tmp_path / 'flight.tlog'}: File too large" in log and "Traceback" not in log
    assert (tmp_path / "flight.tlog").stat().st_size == limit
    stats = json.loads((tmp_path / "autopilot.json").read_text())
    assert stats["steps"] == 3000 and any("flight.tlog" in e for e in stats["output_errors"])


# ---------------------------------------------------------------------------------------- a real full disk (issue 35)
def test_json_is_standard_and_a_write_that_does_not_fit_leaves_no_temporary_file(tmp_path):
    """On a real 64 kB tmpfs: NaN and Infinity are written as null (a strict parser reads the file); a write that
    does not fit raises naming the file and leaves no ``.tmp``; with a reserve made before the disk filled, the
    same write fits and the reserve is gone."""
    from autopilot.shared.process import SpaceReserve
    from tests._small_disk import fill, leftovers, small_disk

    def strict(text):
        return json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))

    with small_disk(tmp_path / "disk", 64) as disk:
        write_json_atomic(disk / "a.json", {"x": float("inf"), "y": [float("nan"), -float("inf"), 1.5]})
        assert strict((disk / "a.json").read_text()) == {"x": None, "y": [None, None, 1.5]}
        reserve = SpaceReserve(disk / ".r.reserve", 16 * 1024)
        assert reserve.held == 16 * 1024
        fill(disk)
        doc = {"values": list(range(1000))}  # about 6 kB, more than a full disk takes
        with pytest.raises(OSError) as exc:
            write_json_atomic(disk / "b.json", doc)
        assert exc.value.filename == str(disk / "b.json") and exc.value.strerror == "No space left on device"
        assert not (disk / "b.json").exists() and leftovers(disk) == [str(disk / ".r.reserve")]
        write_json_atomic(disk / "b.json", doc, reserve=reserve)
        assert strict((disk / "b.json").read_text()) == doc and leftovers(disk) == []


@pytest.mark.e2e
def test_a_full_disk_ends_the_launch_failed_with_the_whole_summary_and_no_temporary_file(tmp_path):
    """`tools.launch --lockstep --duration 30` into a real 200 kB tmpfs (issue 35, item 6): the tlog fills the disk
    in mid-flight.  The flight flies on; the launcher ends with the documented FAILED line naming the file, exit 1,
    no traceback; summary.json is the whole verdict (not the start stub), the stats files are written, and no
    temporary file or space reserve is left."""
    from tests._small_disk import leftovers, small_disk

    with small_disk(tmp_path / "disk", 200) as disk:
        out = disk / "run"
        r = subprocess.run(
            [sys.executable, "-m", "tools.launch", "--lockstep", "--duration", "30", "--out", str(out)],
            capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL,
        )  # fmt: skip
        both = r.stdout + r.stderr
        assert r.returncode == 1 and "Traceback" not in both, both[-3000:]
        last = r.stdout.strip().splitlines()[-1]
        # the first process to exit failing to write is named: the autopilot (the tlog filled the disk), or on a busy
        # machine the SITL, whose series did not fit either and which ends sooner (CI, three workers)
        named = "sitl" if last.startswith("FAILED: sitl failed") else "autopilot"
        assert last.startswith(f"FAILED: {named} failed (exit code 1): {named}: error: could not write "), last
        assert "No space left on device" in last and "flown 100 % (3000 of 3000 steps, 30 of 30 s)" in last
        summary = json.loads((out / "summary.json").read_text())
        assert "running" not in summary and summary["exit_code"] == 1 and summary["ok"] is False
        assert summary["failed"] == named and summary["error"] in last
        assert summary["flown"]["steps"] == 30 * 100 and summary["flown"]["fraction"] == 1.0  # 30 s at 100 Hz
        assert summary["runs"][0]["steps"] == 3000 and "cut" not in summary  # the whole summary, not the verdict only
        stats = json.loads((out / "autopilot.json").read_text())
        assert stats["steps"] == 3000 and any("No space left on device" in e for e in stats["output_errors"])
        assert json.loads((out / "sitl.json").read_text())["frames"] == 3000
        assert leftovers(out) == [], leftovers(out)
        assert not (out / "autopilot_series.npz").exists()  # not written at all rather than half an archive


@pytest.mark.e2e
def test_a_disk_that_holds_the_flight_but_not_its_recording_keeps_the_spools(tmp_path):
    """A real 3 MB tmpfs holds a 30 s lockstep flight's files and spools, not their recording: the recording is not
    started (rerun 0.41's FileSink can hang its process for good on a full disk, ``autopilot.shared.telemetry.files``;
    in CI a launch did so until its 300 s timeout), one FAILED line says what it needs and how to record the kept
    spools later; that command, run elsewhere, makes the whole recording."""
    from tests._small_disk import leftovers, small_disk

    with small_disk(tmp_path / "disk", 3000) as disk:
        out = disk / "run"
        r = run_cli("tools.launch", "--lockstep", "--duration", "30", "--out", str(out), timeout=300)
        both = r.stdout + r.stderr
        assert r.returncode == 1 and "Traceback" not in both, both[-3000:]
        last = r.stdout.strip().splitlines()[-1]
        spools = [out / ".parts" / "autopilot.spool", out / ".parts" / "sitl.spool"]
        later = f"python -m tools.rrd record {out / 'flight.rrd'} {spools[0]} {spools[1]}"
        assert last.startswith(
            f"FAILED: recording the telemetry spools into {out / 'flight.rrd'} failed: No space left on device for "
            "the recording of the spools: it needs about "
        ), last
        assert f"(the spools are kept: {later});" in last and "flown 100 % (3000 of 3000 steps" in last, last
        summary = json.loads((out / "summary.json").read_text())
        assert summary["failed"] == "telemetry" and summary["exit_code"] == 1 and summary["files"]["rrd"] is None
        assert not (out / "flight.rrd").exists() and leftovers(out) == [] and all(p.stat().st_size for p in spools)
        kept = tmp_path / "kept"
        kept.mkdir()
        for p in spools:
            (kept / p.name).write_bytes(p.read_bytes())
    r = run_cli("tools.rrd", "record", str(tmp_path / "later.rrd"), *(str(kept / p.name) for p in spools), timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    from autopilot.shared.telemetry.files import verify_rrd

    ok, msg = verify_rrd(tmp_path / "later.rrd")  # footer included
    assert ok, msg


@pytest.mark.e2e
def test_a_disk_full_before_the_flight_is_one_failed_line(tmp_path):
    """Not even the start stub fits: one FAILED line, exit 1, nothing flown, nothing left behind."""
    from tests._small_disk import fill, leftovers, small_disk

    with small_disk(tmp_path / "disk", 64) as disk:
        (disk / "run").mkdir()
        fill(disk)
        r = run_cli("tools.launch", "--lockstep", "--duration", "2", "--out", str(disk / "run"), timeout=120)
        lines = (r.stdout + r.stderr).strip().splitlines()
        assert r.returncode == 1 and "Traceback" not in r.stdout + r.stderr, r.stdout + r.stderr
        assert lines[-1] == (
            f"FAILED: launch: could not write {disk / 'run' / 'summary.json'}: No space left on device; "
            "nothing was flown"
        ), lines
        assert leftovers(disk) == [] and not (disk / "run" / "summary.json").exists()


@pytest.mark.e2e
@pytest.mark.parametrize("study", ["robustness", "paper"])
def test_a_full_disk_keeps_a_study_s_summary_and_names_each_file_it_could_not_write(tmp_path, study):
    """The robustness study and the paper experiment on a real tmpfs with 40 kB free: summary.json is written first
    and whole; the picture and the recording that do not fit are one line each, exit 1, no traceback, no half file
    and no temporary file."""
    from tests._small_disk import fill, leftovers, small_disk

    args = {
        "robustness": ["robustness", "--runs", "4", "--sweep-runs", "0", "--long-runs", "0", "--controllers",
                       "clsac,baseline", "--no-progress"],
        "paper": ["paper", "--runs", "clsac"],
    }[study]  # fmt: skip
    with small_disk(tmp_path / "disk", 300) as disk:
        fill(disk, leave_kb=40)
        out = disk / "out"
        r = run_cli("tools.experiment", *args, "--out", str(out), timeout=300)
        assert r.returncode == 1 and "Traceback" not in r.stdout + r.stderr, r.stdout[-2000:] + r.stderr[-2000:]
        summary = json.loads((out / "summary.json").read_text())
        assert summary["runs"] if study == "paper" else summary["results"]["clsac"]["nominal"]["runs"] == 4
        errors = [line for line in r.stderr.splitlines() if "error: could not write" in line]
        picture = out / ("robustness.png" if study == "robustness" else "paper.png")
        assert errors and any(str(picture) in e for e in errors), r.stderr
        assert not picture.exists() and leftovers(disk) == []
        assert {p.name for p in out.iterdir()} <= {"summary.json", "table.md"}


def test_a_summary_that_does_not_fit_is_cut_to_its_verdict_and_the_flight_is_not_ok(tmp_path):
    """``tools.flight.files.write_summary`` on a real 64 kB tmpfs with 8 kB free: a summary of about 30 kB does not
    fit, so the file holds its verdict only (``cut``), and an OK flight whose summary was cut is FAILED, exit 1,
    naming the file.  With nothing free, the file before (the provisional one) stays."""
    from tests._small_disk import fill, leftovers, small_disk
    from tools.flight.files import provisional_summary, write_summary

    ok = {"ok": True, "outcome": "OK", "exit_code": 0, "failed": None, "error": None, "completed": True,
          "flown": {"fraction": 1.0}, "events": ["x" * 100] * 300}  # fmt: skip
    with small_disk(tmp_path / "disk", 64) as disk:
        write_json_atomic(disk / "summary.json", provisional_summary(1))
        fill(disk, leave_kb=8)
        s = write_summary(disk, dict(ok))
        written = json.loads((disk / "summary.json").read_text())
        assert s["exit_code"] == written["exit_code"] == 1 and s["outcome"] == written["outcome"] == "FAILED"
        assert (
            s["error"]
            == written["error"]
            == (f"launch: could not write {disk / 'summary.json'}: No space left on device (the flight itself: OK)")
        )
        assert "events" not in written and written["flown"] == {"fraction": 1.0} and "did not fit" in written["cut"]
        assert leftovers(disk) == []
        (disk / "summary.json").unlink()
        write_json_atomic(disk / "summary.json", provisional_summary(1))
        fill(disk)
        s = write_summary(disk, dict(ok))
        assert s["exit_code"] == 1 and json.loads((disk / "summary.json").read_text())["running"] is True
        assert leftovers(disk) == []


@pytest.mark.e2e
def test_a_disk_with_no_room_for_the_logs_ends_the_flight_and_names_them(tmp_path):
    """40 kB free: the provisional summary, the launcher's 32 kB reserve and the signing key (a 4 kB page each) take
    it all, so not even the first line of a process's log fits.  A log that cannot be written must never stop the
    launcher reading the process's output (the process would block on its next print and the flight hang, as it
    did): the flight ends, FAILED, exit 1, each log named in summary.json.  With 36 kB free the key does not fit
    either: one line, nothing started, no empty key file left."""
    from tests._small_disk import fill, leftovers, small_disk

    def launch(out):
        return subprocess.run(
            [sys.executable, "-m", "tools.launch", "--lockstep", "--duration", "10", "--out", str(out)],
            capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL,
        )  # fmt: skip

    with small_disk(tmp_path / "disk", 200) as disk:
        out = disk / "run"
        out.mkdir()
        fill(disk, leave_kb=40)
        r = launch(out)
        both = r.stdout + r.stderr
        assert r.returncode == 1 and "Traceback" not in both, both[-3000:]
        assert r.stdout.strip().splitlines()[-1].startswith("FAILED: "), both[-2000:]
        summary = json.loads((out / "summary.json").read_text())
        assert summary["exit_code"] == 1 and "running" not in summary
        logged = " ".join(summary.get("output_errors") or [])
        assert all(f"{out / name}.log: No space left on device" in logged for name in ("sitl", "gcs", "autopilot"))
        assert leftovers(out) == []
    with small_disk(tmp_path / "disk2", 200) as disk:
        out = disk / "run"
        out.mkdir()
        fill(disk, leave_kb=36)
        r = launch(out)
        assert r.returncode == 1 and "Traceback" not in r.stdout + r.stderr, r.stdout + r.stderr
        assert r.stdout.strip().splitlines()[-1] == (
            f"FAILED: launch: could not write in {out}: No space left on device; nothing was flown"
        )
        summary = json.loads((out / "summary.json").read_text())
        assert summary["exit_code"] == 1 and summary["flown"]["steps"] == 0 and summary["failed"] == "launch"
        assert sorted(p.name for p in out.iterdir()) == ["summary.json"]  # no empty signing.key, no .parts
