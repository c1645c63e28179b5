"""A flight in about a second (issue 21): what the launcher's start-up and end no longer wait for, each part checked
on its own with real processes and files: no scipy at start-up, the flight layout cached on disk
(``tools.view.layout_cache``), flight.png drawn by a helper process (``tools.view.flight_picture``), started before the
command's own imports, children's exits seen at once (``tools.flight.children.Child.wait``), and no rerun in the flying
processes of a file-only flight (they spool their rows: ``tests/autopilot/test_telemetry_spool.py``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tools.flight.children import Child
from tools.view import layout_cache
from tools.view.flight_picture import PngHelper, draw_flight_png

ROOT = Path(__file__).resolve().parents[3]


def _run(code: str, **env) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
        env=dict(os.environ, **env),
    )


# ---------------------------------------------------------------------------------------- imports
def test_the_launcher_and_the_sitl_start_without_scipy():
    """scipy (about 0.2 s) is for turbulence only: importing the launcher or the SITL's main does not load it, and a
    Dryden filter still gets it when it is built."""
    r = _run(
        "import sys, tools.launch, sitl.__main__, sitl.endpoint, autopilot.__main__, tools.gcs\n"
        "print('scipy' in sys.modules)\n"
        "from sitl.atmosphere import noise_zoh\n"
        "import numpy as np\n"
        "ad, qd, p = noise_zoh(np.array([[-2.0]]), np.array([[1.0]]), 0.01)\n"
        "print('scipy' in sys.modules, round(float(p[0, 0]), 12))\n"
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["False", "True", "0.25"]  # P of x' = -2x + w: 1 / (2 * 2)


def test_the_launcher_checks_a_flight_without_importing_the_loop():
    """Before its children start, the launcher parses and checks the flight: that needs the autopilot's defaults
    (the attitude timeout the sensor rate is checked against), not its loop, pymavlink's ``all`` dialect or signing
    (35 ms on the path to the children's start); the check still refuses a rate below two ATTITUDE per timeout."""
    r = _run(
        "import sys\n"
        "import tools.launch as L\n"
        "from tools.flight import Flight, FlightConfigError\n"
        "Flight(**vars(L.build_parser().parse_args(['--lockstep', '--out', 'unused'])))\n"
        "print(sorted(m for m in ('autopilot.loop', 'pymavlink.dialects.v20.all', 'rerun') if m in sys.modules))\n"
        "try:\n"
        "    Flight(sensor_rate=19.0)\n"
        "except FlightConfigError as exc:\n"
        "    print(exc.field)\n"
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.split("\n")[:2] == ["[]", "sensor_rate"], r.stdout


def test_the_picture_helper_does_not_import_the_launcher_nor_matplotlib(tmp_path):
    """The helper process imports the Pillow renderer (tools.view.flight_png), not the launcher's modules
    (tools.flight's config and supervision), rerun, or matplotlib (its import cost about 0.45 CPU s at the flight's
    start; the renderer only reads its font file): after its warm-up, and after drawing a picture."""
    _series(tmp_path)
    seen = (
        "print(sorted(m for m in ('tools.flight.config', 'tools.flight.command_lines', 'tools.flight.supervision', "
        "'rerun', 'tools.launch', 'tools.experiment.scenario') if m in sys.modules), "
        "sorted({m.split('.')[0] for m in sys.modules} & {'matplotlib', 'PIL', 'numpy'}), "
        "'tools.view.flight_png' in sys.modules)\n"
    )
    r = _run(
        "import sys\nfrom tools.view import flight_picture\nflight_picture._warm_up()\n"
        + seen
        + f"print(flight_picture.draw_flight_png(**{_request(tmp_path)!r}))\n"
        + seen
    )
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines == ["[] ['PIL', 'numpy'] True", str(tmp_path / "flight.png"), "[] ['PIL', 'numpy'] True"], lines


# ---------------------------------------------------------------------------------------- the layout cache
def test_the_flight_layout_is_built_once_then_read_from_the_cache(tmp_path):
    """First call: built (rerun imported) and saved with the sources it came from; second call, in a fresh process:
    the same file, without importing rerun; the saved layout is a blueprint rerun reads back."""
    env = {"CLSAC_CACHE_DIR": str(tmp_path / "cache")}
    code = (
        "import sys, time\nfrom tools.view.layout_cache import flight_blueprint_file\n"
        "p = flight_blueprint_file()\nprint(p, 'rerun' in sys.modules)\n"
    )
    first = _run(code, **env)
    assert first.returncode == 0, first.stderr
    path, imported = first.stdout.split()
    assert imported == "True" and Path(path).parent == tmp_path / "cache" and Path(path).stat().st_size > 1000
    meta = json.loads(Path(path).with_suffix(".json").read_text())
    assert "tools/view/views.py" in meta["sources"] and "autopilot/telemetry/layout.py" in meta["sources"]
    second = _run(code, **env)
    assert second.returncode == 0, second.stderr
    assert second.stdout.split() == [path, "False"]
    from tools.view import rrd_files as rrd
    from tools.view.views import flight_blueprint

    fresh = tmp_path / "fresh.rbl"
    flight_blueprint().save(meta["application_id"], str(fresh))
    for component in ("ViewBlueprint:display_name", "ViewContents:query"):  # the same views of the same entities
        cached = sorted(map(str, rrd.blueprint_components(path, component)))
        assert cached and cached == sorted(map(str, rrd.blueprint_components(fresh, component)))
    assert "Roll tracking [deg]" in rrd.blueprint_components(path, "ViewBlueprint:display_name")


def test_a_changed_source_or_rerun_rebuilds_the_cached_layout(tmp_path, monkeypatch):
    """A recorded source whose digest no longer matches, or another rerun, makes the cache invalid: rebuilt."""
    monkeypatch.setenv("CLSAC_CACHE_DIR", str(tmp_path))
    path = layout_cache.flight_blueprint_file()
    meta_path = path.with_suffix(".json")
    from autopilot.shared.telemetry.layout import APPLICATION_ID

    assert layout_cache._valid(path, meta_path, APPLICATION_ID)
    meta = json.loads(meta_path.read_text())
    meta["sources"]["tools/view/views.py"] = "0" * 64  # as if tools/view/views.py had changed since
    meta_path.write_text(json.dumps(meta))
    assert not layout_cache._valid(path, meta_path, APPLICATION_ID)
    before = path.stat().st_mtime_ns
    time.sleep(0.01)
    assert layout_cache.flight_blueprint_file() == path and path.stat().st_mtime_ns != before  # rebuilt
    assert layout_cache._valid(path, meta_path, APPLICATION_ID)
    meta = json.loads(meta_path.read_text())
    meta["rerun"][0][1] += 1  # another rerun_bindings
    meta_path.write_text(json.dumps(meta))
    assert not layout_cache._valid(path, meta_path, APPLICATION_ID)
    path.write_bytes(b"")  # a torn file is not a layout
    assert not layout_cache._valid(path, meta_path, APPLICATION_ID)


def test_no_cache_folder_means_no_cached_layout(tmp_path, monkeypatch):
    monkeypatch.setenv("CLSAC_CACHE_DIR", "off")
    assert layout_cache.flight_blueprint_file() is None
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("CLSAC_CACHE_DIR", str(blocker / "cache"))  # cannot be created: built in the caller
    assert layout_cache.flight_blueprint_file() is None


# ---------------------------------------------------------------------------------------- the picture helper
def _series(out: Path, n: int = 300) -> None:
    t = np.arange(n) / 100.0
    phi = 0.1 * np.sin(t)
    cols = {k: np.zeros(n) for k in ("um", "ym", "ym_ol", "e", "u", "ke", "kx", "ku")}
    cols["u"] = 0.01 * np.cos(t)
    np.savez(out / "autopilot_series.npz", t=t, phi=phi, mode=np.full(n, 2), **cols)


def _request(out: Path) -> dict:
    return {
        "out": str(out),
        "name": "clsac",
        "lv": 20.0,
        "lockstep": True,
        "rate": 100.0,
        "u_limit_deg": 30.0,
        "metrics": {"ise_ref": 0.01, "ise_crm": 0.0, "energy": 0.0, "tv": 0.0, "max_abs_u": 0.01},
    }


def test_the_helper_draws_the_same_picture_as_the_launcher(tmp_path):
    """One request, one answer: the helper's flight.png has the bytes of the one drawn in this process."""
    _series(tmp_path)
    req = _request(tmp_path)
    local = draw_flight_png(**req).read_bytes()
    (tmp_path / "flight.png").unlink()
    helper = PngHelper()
    try:
        assert helper.request(req)
        answered, png, error = helper.result(timeout_s=120)
    finally:
        helper.close()
    assert (answered, png, error) == (True, str(tmp_path / "flight.png"), None)
    assert helper.proc.returncode == 0
    assert local[:8] == b"\x89PNG\r\n\x1a\n" and (tmp_path / "flight.png").read_bytes() == local


def test_the_helper_says_why_a_picture_is_missing(tmp_path):
    """No series: no picture (null); a picture that cannot be saved: the error, one line (the flight not failed)."""
    helper = PngHelper()
    try:
        assert helper.request(_request(tmp_path))
        assert helper.result(timeout_s=120) == (True, None, None)
    finally:
        helper.close()
    (tmp_path / "ro").mkdir()
    _series(tmp_path / "ro")
    (tmp_path / "ro" / "flight.png").mkdir()  # the picture's path is taken by a folder: an OSError while saving
    helper = PngHelper()
    try:
        assert helper.request(_request(tmp_path / "ro"))
        answered, png, error = helper.result(timeout_s=120)
    finally:
        helper.close()
    assert answered and png is None and error.startswith(("IsADirectoryError: ", "OSError: ")), error


def test_a_helper_that_is_gone_is_reported_so_the_launcher_draws_itself(tmp_path):
    helper = PngHelper()
    helper.proc.kill()
    helper.proc.wait()
    sent = helper.request(_request(tmp_path))
    answered = helper.result(timeout_s=5)[0] if sent else False
    helper.close()
    assert not answered


def test_a_helper_without_a_request_exits_quietly():
    helper = PngHelper()
    helper.proc.stdin.close()
    assert helper.proc.wait(timeout=120) == 0
    helper.close()


# ---------------------------------------------------------------------------------------- children's exits
def test_a_childs_exit_is_seen_when_it_happens(tmp_path):
    """wait() returns at the exit (a pidfd), not at the next poll; None while the child runs."""
    c = Child("x", [sys.executable, "-c", "import time; time.sleep(0.3)"], tmp_path / "x.log", False)
    try:
        assert c.wait(0.0) is None
        t0 = time.monotonic()
        assert c.wait(600.0) == 0
        assert time.monotonic() - t0 < 300.0  # woken by the exit (0.3 s), not by the 600 s timeout
        assert c.wait(0.0) == 0 and c.code == 0
    finally:
        c.kill()
        c.finish()


@pytest.mark.parametrize("chosen", [None, "3"])
def test_a_child_gets_one_openblas_thread_unless_the_caller_chose(tmp_path, monkeypatch, chosen):
    """numpy's import starts an OpenBLAS thread per core (0.06 CPU s a process at the flight's contended start): the
    flight's processes get one, unless the environment already says how many."""
    if chosen is None:
        monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    else:
        monkeypatch.setenv("OPENBLAS_NUM_THREADS", chosen)
    code = "import os; print('threads', os.environ.get('OPENBLAS_NUM_THREADS'))"
    c = Child("x", [sys.executable, "-c", code], tmp_path / "x.log", False)
    try:
        assert c.wait(30.0) == 0
        c.finish()
    finally:
        c.kill()
    assert f"threads {chosen or 1}" in (tmp_path / "x.log").read_text()


@pytest.mark.e2e
def test_a_lockstep_launcher_imports_rerun_while_its_children_start_a_real_time_one_after(tmp_path):
    """A file-only lockstep flight's recorder (rerun, 0.27 CPU s) is imported in a thread as soon as the children
    are spawned, not after the flight, where it was the longest part of the wait; a real-time flight leaves it for
    the end (its loop is not to share a core with it), and a flight without a recording has none to import.  In one
    process, in that order: rerun is not loaded until the lockstep flight with a recording starts."""
    code = (
        "import sys\n"
        "from tools.flight import Flight\n"
        "for name, lockstep, rrd in (('rt', False, True), ('norrd', True, False), ('ls', True, True)):\n"
        f"    f = Flight(lockstep=lockstep, rrd=rrd, duration=1.0, quiet=True, png=False, out=r'{tmp_path}/' + name)\n"
        "    f.start()\n"
        "    if f._recorder is not None:\n"
        "        f._recorder.thread.join(60)\n"
        "    print(name, f._recorder is not None, 'rerun' in sys.modules)\n"
        "    res = f.wait(60)\n"
        "    print(name, res.ok, (f.out / 'flight.rrd').exists())\n"
    )
    r = _run(code)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split("\n")[:6] == [
        "rt False False",  # real time: nothing imported while it starts and flies
        "rt True True",  # the recording, after the flight
        "norrd False True",  # (rerun is loaded in this process since the first flight's end)
        "norrd True False",
        "ls True True",  # lockstep with a recording: the thread
        "ls True True",
    ], r.stdout


@pytest.mark.e2e
def test_a_launch_leaves_every_file_with_the_picture_from_the_helper(tmp_path):
    """The whole launcher: tlog, flight.rrd (with its layout and index, recorded straight from the spools: no part
    left), flight.png and summary.json, in one run."""
    from tools.flight import Flight
    from tools.view import rrd_files as rrd

    res = Flight(lockstep=True, duration=2.0, out=tmp_path / "f", quiet=True).run()
    assert res.ok, res.reason
    f = res.summary["files"]
    assert f["png"] == str(tmp_path / "f" / "flight.png") and Path(f["png"]).read_bytes()[:4] == b"\x89PNG"
    assert f["rrd_indexed"] and rrd.has_blueprint(f["rrd"])
    assert not (tmp_path / "f" / ".parts").exists()


@pytest.mark.e2e
def test_a_file_only_flight_flies_without_rerun_in_its_processes(tmp_path, monkeypatch):
    """The autopilot and the SITL of a default (file-only) lockstep flight import neither rerun nor pyarrow
    (``python -X importtime`` in each child's log); with ``rrd_live`` they do, as before, and both leave flight.rrd.
    No child imports scipy, matplotlib or gymnasium, nor pymavlink's ``all`` or ``ardupilotmega`` dialect: the links
    check the other dialects' messages a flight exchanges by heart (``autopilot.shared.mavlink.OTHER_DIALECT_MESSAGES``)
    and the autopilot packs its CURRENT_MODE itself (issue 37: each dialect costs a process ~30 ms to load)."""
    from tools.flight import Flight

    monkeypatch.setenv("PYTHONPROFILEIMPORTTIME", "1")  # each child logs every import to its stderr (its .log)
    for live in (False, True):
        out = tmp_path / f"live{live}"
        res = Flight(lockstep=True, duration=1.0, out=out, quiet=True, png=False, rrd_live=live).run()
        assert res.ok, res.reason
        assert res.summary["files"]["rrd_indexed"] and (out / "flight.rrd").stat().st_size > 10_000
        for name in ("autopilot", "sitl", "gcs"):
            imported = {
                line.rsplit("|", 1)[-1].strip()
                for line in (out / f"{name}.log").read_text().splitlines()
                if line.startswith("import time:")
            }
            assert "pymavlink.dialects.v20.common" in imported, name  # the log does list the child's imports
            dialects = {f"pymavlink.dialects.v20.{d}" for d in ("all", "ardupilotmega")}
            heavy = {"scipy", "matplotlib", "gymnasium"} | dialects
            assert not imported & heavy, (name, imported & heavy)
            if name != "gcs":
                assert "numpy" in imported, name
                assert ("rerun" in imported and "pyarrow" in imported) is live, (name, live)


@pytest.mark.e2e
def test_the_launch_bench_times_the_command_and_the_import_it_is_compared_with(tmp_path):
    """``python -m tools.bench launch``: real launches, every file checked, the figures and their targets."""
    from tools.bench import launch

    figs = launch.main(["--runs", "1"])
    wall = figs["launch 30 s lockstep, every file (wall)"]
    ref = figs["import numpy, scipy (wall)"]
    ratio = figs["the same / import numpy, scipy"]
    assert wall["target"] == launch.WALL_TARGET_S and ratio["target"] == launch.RATIO_TARGET
    assert 0 < ref["value"] < wall["value"] and ratio["value"] == pytest.approx(wall["value"] / ref["value"])
    assert figs["launch --no-rrd --no-png (wall)"]["value"] > 0
    assert 0 < figs["the flight itself (sim / RTF)"]["value"] < wall["value"]
    cpu, cpu_ref = figs["launch, CPU of all its processes"], figs["import numpy, scipy (CPU)"]
    assert cpu["unit"] == cpu_ref["unit"] == "CPU s" and 0 < cpu_ref["value"] < cpu["value"]
    assert cpu["value"] > 0.5  # five interpreters (launcher, autopilot, SITL, GCS, picture helper), each counted
    assert cpu["ratio"] == pytest.approx(cpu["value"] / cpu_ref["value"])
    # each child's own CPU (its stats file's cpu_s, process_time) is part of the total RUSAGE_CHILDREN counted
    per = {name: figs[f"launch, CPU of the {name}"]["value"] for name in launch.CHILDREN}
    rest = figs["launch, CPU of the launcher and picture helper"]["value"]
    assert all(0.02 < v < cpu["value"] for v in per.values()), per  # an interpreter's start-up is ~0.03 CPU s
    assert rest > 0.05, (per, rest)  # two interpreters more than the children reported: their CPU is counted too
    with pytest.raises(RuntimeError, match="left no flight.png"):  # a missing file is an error, not a fast run
        launch._flight(tmp_path / "no-png", ["--no-png"], launch.FILES)


def _picture_helpers() -> list[int]:
    """Process ids of this process's children that run the picture helper."""
    found = []
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                if int(f.read().rsplit(")", 1)[1].split()[1]) != os.getpid():
                    continue
            with open(f"/proc/{d}/cmdline", "rb") as f:
                if b"tools.view.flight_picture" in f.read():
                    found.append(int(d))
        except (OSError, IndexError, ValueError):
            continue
    return found


@pytest.mark.e2e
def test_only_a_lockstep_flight_has_the_picture_helper_beside_it(tmp_path):
    """A lockstep flight's picture is prepared while it flies; a real-time one's is drawn at the end (no process
    takes CPU from a loop on deadlines), as is a pinned one's; both still leave flight.png."""
    from tools.flight import Flight

    for kw, expect in (
        (dict(lockstep=True), True),
        (dict(lockstep=False), False),
        (dict(lockstep=True, pin=True), False),
    ):
        out = tmp_path / f"f{len(list(tmp_path.iterdir()))}"
        with Flight(duration=2.0, out=out, quiet=True, rrd=False, **kw) as flight:
            assert bool(_picture_helpers()) is expect, kw  # (the flight ends in wait(): the helper lives until then)
            res = flight.wait(timeout=120)
        assert res is not None and res.ok, (kw, res and res.reason)
        assert res.summary["files"]["png"] == str(out / "flight.png"), kw
        assert (out / "flight.png").read_bytes()[:4] == b"\x89PNG"
    assert not _picture_helpers()  # none left behind


def test_the_command_starts_the_picture_helper_before_its_own_imports():
    """``python -m tools.launch`` tells from its words alone whether a helper will be wanted (exact spellings only:
    anything unsure means no early helper, and the flight starts one as before)."""
    from tools.view.flight_picture import helper_wanted

    assert helper_wanted(["--lockstep", "--duration", "30"])
    for argv in (
        [],
        ["--duration", "30"],
        ["--lockstep", "--no-png"],
        ["--lockstep", "--no-series"],
        ["--lockstep", "--pin"],
        ["--lockstep", "--help"],
        ["--lockstep", "-h"],
        ["--lock", "--duration", "3"],
    ):
        assert not helper_wanted(argv), argv
    launcher = (ROOT / "tools" / "launch.py").read_text()
    assert launcher.index("EARLY_PNG_HELPER = PngHelper()") < launcher.index("from tools.flight import")


@pytest.mark.e2e
def test_an_adopted_helper_draws_the_picture_or_is_closed_when_not_wanted(tmp_path):
    """A helper started before the flight is the one that draws a lockstep flight's picture; a flight that does not
    want one (real time) closes it at its start, and still leaves flight.png, drawn at the end."""
    from tools.flight import Flight

    for kw, used in ((dict(lockstep=True), True), (dict(lockstep=False), False)):
        helper = PngHelper()
        flight = Flight(duration=1.0, out=tmp_path / f"f{used}", quiet=True, rrd=False, **kw)
        flight.adopt_png_helper(helper)
        with flight:
            assert (helper.proc.poll() is None) is used, kw
            assert (flight._png is helper) is used  # noqa: SLF001 - which helper the flight holds
            res = flight.wait(timeout=120)
        assert res is not None and res.ok, (kw, res and res.reason)
        assert (tmp_path / f"f{used}" / "flight.png").read_bytes()[:4] == b"\x89PNG"
        assert helper.proc.poll() is not None  # ended with the flight either way
    late = PngHelper()
    try:
        with pytest.raises(RuntimeError, match="started already"):
            flight.adopt_png_helper(late)
    finally:
        late.close()
    assert late.proc.poll() is not None


# ---------------------------------------------------------------------------------------- lockstep busy-poll
def test_the_launcher_asks_both_lockstep_processes_for_a_short_busy_poll(tmp_path):
    """``python -m tools.launch`` flies lockstep with a 100 us busy-poll on both sides (a 500 us spin waiting for a
    peer with no core took that core from it while the other processes start); a Flight without it keeps the
    processes' own default, a real-time flight gets no such flag, and an impossible value is refused in one line."""
    from tools.flight import FlightConfig, FlightConfigError, child_argvs
    from tools.launch import LOCKSTEP_SPIN_US, build_parser

    args = build_parser().parse_args(["--lockstep"])
    assert args.lockstep_spin_us == LOCKSTEP_SPIN_US == 100.0
    argv = child_argvs(FlightConfig(lockstep=True, lockstep_spin_us=args.lockstep_spin_us), tmp_path, 1, 2)
    ap, sitl = argv["autopilot"], argv["sitl"]
    assert ap[ap.index("--lockstep-spin-us") + 1] == "100.0" and sitl[sitl.index("--spin-us") + 1] == "100.0"
    default = child_argvs(FlightConfig(lockstep=True), tmp_path, 1, 2)
    assert "--lockstep-spin-us" not in default["autopilot"] and "--spin-us" not in default["sitl"]
    realtime = child_argvs(FlightConfig(lockstep=False, lockstep_spin_us=100.0), tmp_path, 1, 2)
    assert "--lockstep-spin-us" not in realtime["autopilot"] and "--spin-us" not in realtime["sitl"]
    with pytest.raises(FlightConfigError, match="lockstep_spin_us must be in 0..1000000 us"):
        FlightConfig(lockstep=True, lockstep_spin_us=-1.0)
    r = subprocess.run(
        [sys.executable, "-m", "tools.launch", "--lockstep", "--lockstep-spin-us", "-3", "--out", str(tmp_path / "x")],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "--lockstep-spin-us" in r.stderr


@pytest.mark.e2e
def test_the_busy_poll_changes_no_number_of_the_flight(tmp_path):
    """The spin is how long a process waits awake, not what it computes: flights with no spin, the launcher's 100 us
    and the processes' 500 us fly the same steps to the same metrics, bit for bit."""
    from tools.flight import Flight

    metrics = {}
    for spin in (0.0, 100.0, None):
        res = Flight(
            lockstep=True,
            duration=3.0,
            out=tmp_path / f"s{spin}",
            quiet=True,
            rrd=False,
            png=False,
            lockstep_spin_us=spin,
        ).run()
        assert res.ok, (spin, res.reason)
        run = res.summary["runs"][0]
        metrics[spin] = (run["steps"], run["metrics"])
    assert metrics[0.0] == metrics[100.0] == metrics[None] and metrics[None][0] == 300


# ------------------------------------------------------------------------------------- the autopilot's announcement
def _heartbeat_times(sock, seconds: float) -> list[float]:
    """When each HEARTBEAT reached ``sock`` (``time.monotonic``) during ``seconds``: MAVLink 2, unsigned, parsed by
    pymavlink; nothing is answered."""
    from pymavlink.dialects.v20 import common as mavlink

    mav = mavlink.MAVLink(None)
    mav.robust_parsing = True
    times, t_end = [], time.monotonic() + seconds
    while (left := t_end - time.monotonic()) > 0:
        sock.settimeout(left)
        try:
            data = sock.recv(65535)
        except TimeoutError:
            break
        now = time.monotonic()
        times += [now for m in mav.parse_buffer(data) or [] if m.get_type() == "HEARTBEAT"]
    return times


@pytest.mark.e2e
@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_a_sitl_that_binds_after_the_first_heartbeat_is_found_at_once(tmp_path, mode):
    """The launcher starts the three processes together, so the autopilot's first HEARTBEAT may go out before the
    SITL has bound its socket, and be lost.  It then announces itself 20 times a second for its first 2 s
    (``ANNOUNCE_FAST_S``), then 4 times a second, and 1 Hz only once both peers have answered: with a 1 s period from
    the start, 3 of 8 lockstep launches waited a whole second for the next one.  Here the SITL's port is bound 0.3 s
    after the autopilot has started, and answers nothing."""
    import socket

    from tests._mavlink_procs import Proc, free_ports

    sitl_port, gcs_port = free_ports(2)
    args = ["--sitl", f"127.0.0.1:{sitl_port}", "--gcs", f"127.0.0.1:{gcs_port}"]  # unsigned: no key given
    ap = Proc("autopilot", [*args, *(["--lockstep"] if mode == "lockstep" else [])], tmp_path / "autopilot.log")
    sitl = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        assert ap.wait_for("autopilot: clsac"), ap.output()
        time.sleep(0.3)
        sitl.bind(("127.0.0.1", sitl_port))
        t_bound = time.monotonic()
        times = np.array(_heartbeat_times(sitl, 4.2)) - t_bound
    finally:
        sitl.close()
        ap.stop()
    assert len(times) and times[0] < 0.4, (times, ap.output())  # with a 1 s period from the start: about 0.7 s
    first_second = np.count_nonzero(times < 1.0)  # 0.3-1.3 s after the start: about 16 (with a 1 s period: 1)
    later = np.count_nonzero((times >= 2.2) & (times < 4.2))  # past the fast 2 s: every 0.25 s, about 8, not 40
    assert first_second >= 8, (first_second, ap.output())
    assert 4 <= later <= 12, (later, ap.output())


def test_a_child_that_listened_and_ended_before_the_launcher_looked_did_not_fail_at_start_up(tmp_path):
    """A short lockstep flight can be flown to its end before the launcher's thread looks (a loaded machine: the
    suite's full run saw "sitl failed at start-up (exit code 0)" after 200 of 200 steps).  A child that said it
    listens and exited since is left to the verdict; one that exited without saying it failed at start-up."""
    from tools.flight import Flight

    def child(name: str, said: str) -> Child:
        c = Child(name, [sys.executable, "-c", f"print({said!r})"], tmp_path / f"{name}.log", False, "listening on")
        assert c.wait(30.0) == 0 and c.ready.wait(30.0)  # exited, and its output read to the end
        return c

    flight = Flight(lockstep=True, duration=1.0, out=tmp_path / "f", quiet=True)
    flight._children = {
        "sitl": child("sitl", "sitl: listening on 127.0.0.1:1"),
        "gcs": child("gcs", "gcs: listening on 127.0.0.1:2"),
    }
    assert flight._await_listening() is None
    flight._children["gcs"] = child("gcs", "gcs: bad flag")
    assert flight._await_listening() is flight._children["gcs"]
