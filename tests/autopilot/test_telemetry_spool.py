"""One Rerun writer per file-only flight (issue 21): the processes spool their rows (``--telemetry-spool``, no rerun
import) and one process records the spools afterwards through the same ``RerunSink`` a live writer sends with.

Checked with real rerun files: the same rows through a live writer and through a spool give the same recording
(entities, rows, values, both timelines, states, event texts, 3D poses); a spooling process never imports rerun; a
malformed or cut-short spool is reported, not silently read; a launched file-only flight's ``flight.rrd`` holds
what a ``--rrd-live`` one's does.
"""

from __future__ import annotations

import errno
import math
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from autopilot.shared import telemetry as tm
from autopilot.shared.telemetry.spool import MAGIC, SpoolError, SpoolReader, layout_from_data, layout_to_data
from autopilot.telemetry import layout as L
from autopilot.telemetry.hooks import autopilot_tables
from sitl import telemetry as S
from tools.view import rrd_files as rrd

ROOT = Path(__file__).resolve().parents[2]
N = 250  # rows per table, sent in three flushes


def _fill(tel) -> None:
    """The same rows, states and events into any writer: the autopilot's tables (a NaN PWM now and then), its
    mode and failsafe channels, a PARAM_SET marker, the SITL's truth table (with the 3D pose) and the JSBSim held
    table (a pose with pitch, a NaN attitude on one row), in three flushes."""
    ap, links, mode, failsafe = autopilot_tables(tel)
    params = tel.table(L.PARAM_SETS)
    truth = tel.table(S.SITL_TABLE)
    held = tel.table(S.SITL_HELD_TABLE)
    rng = np.random.default_rng(7)
    n_ap, n_sitl, n_held = len(L.AUTOPILOT.fields), len(S.SITL_FIELDS), len(S.SITL_HELD_TABLE.fields)
    for k in range(N):
        t = k * 0.01
        wall = 1.7e9 + k * 0.0137
        row = tuple(float(v) for v in rng.normal(size=n_ap))
        if k % 17 == 0:
            row = row[:-3] + (math.nan,) + row[-2:]
        ap.push((t, wall, row))
        truth.push((t, wall, tuple(float(v) for v in rng.normal(size=n_sitl))))
        h = tuple(float(v) for v in rng.normal(size=n_held))
        held.push((t, wall, h if k != 5 else h[:-1] + (math.nan,)))
        if k % 10 == 0:
            for table in links.values():
                table.push((t, wall, (float(k), float(k + 1), 0.0)))
        if k == 40:
            mode.set(t, wall, "CLSAC")
            failsafe.set(t, wall, "NO_ATTITUDE", "no ATTITUDE for 0.5 s")
            tel.log_event(t, wall, "a status text", "WARN")
        if k == 41:
            params.push((t, wall, L.param_set_row((1.0, 2.0, 3.0), True)))
            tel.log_event(t, wall, "PARAM_SET CLSAC_LV = 12: accepted")
        if k == 120:
            failsafe.set(t, wall, "OK")
        if k in (90, 200):
            tel.flush()


def _same_recording(a: Path, b: Path, skip: tuple[str, ...] = ()) -> None:
    """The two files hold the same recording: entities, rows, values on both timelines, states, texts, poses."""
    assert rrd.entity_paths(a) == rrd.entity_paths(b)
    for timeline in ("sim_time", "wall_time"):
        la, lb = rrd.load(a, timeline=timeline), rrd.load(b, timeline=timeline)
        assert sorted(la) == sorted(lb)
        for ep in la:
            if ep in skip:
                continue
            x, y = la[ep], lb[ep]
            assert x.names == y.names, ep
            assert np.array_equal(x.t_ns, y.t_ns), (ep, timeline)
            assert np.array_equal(x.values, y.values, equal_nan=True), (ep, timeline)
    assert rrd.load_states(a) == rrd.load_states(b)
    assert rrd.load_texts(a) == rrd.load_texts(b)
    pa, pb = rrd.load_poses(a), rrd.load_poses(b)
    assert sorted(pa) == sorted(pb) and pa
    for ep in pa:
        assert np.array_equal(pa[ep][0], pb[ep][0]) and np.array_equal(pa[ep][1], pb[ep][1]), ep


def test_a_spooled_recording_is_the_live_one(tmp_path):
    """The same rows through a live writer (rerun, a part file) and through a spool recorded afterwards: the same
    recording id, entities, rows and values, on both timelines, with the same states, texts and poses."""
    rid = tm.new_recording_id()
    with tm.Telemetry("autopilot", rid, tmp_path / "live.rrd") as live:
        _fill(live)
    with tm.Telemetry("autopilot", rid, spool_path=tmp_path / "ap.spool") as spooled:
        _fill(spooled)
    assert spooled.rec is None and spooled.errors == live.errors == 0
    assert spooled.rows_sent == live.rows_sent and spooled.rows_sent["autopilot"] == N
    done = tm.record_spools([tmp_path / "ap.spool"], tmp_path / "spooled.rrd")
    assert done["recording_id"] == rid and done["truncated"] == [] and done["chunks"] > 0
    assert (
        rrd.recordings(tmp_path / "spooled.rrd") == rrd.recordings(tmp_path / "live.rrd") == [(tm.APPLICATION_ID, rid)]
    )
    _same_recording(tmp_path / "live.rrd", tmp_path / "spooled.rrd")
    assert rrd.load_text(tmp_path / "spooled.rrd", "/autopilot/events")[0][1] == "mode: - -> CLSAC"
    ok, msg = rrd.verify(tmp_path / "spooled.rrd", check_footers=False)
    assert ok, msg


def test_two_spools_make_one_recording_with_each_processes_events(tmp_path):
    """Both processes' spools into one stream: each process's events stay under its own entity."""
    rid = tm.new_recording_id()
    for process in ("autopilot", "sitl"):
        with tm.Telemetry(process, rid, spool_path=tmp_path / f"{process}.spool") as tel:
            tel.log_event(0.5, 1.7e9, f"hello from {process}")
    tm.record_spools([tmp_path / "autopilot.spool", tmp_path / "sitl.spool"], tmp_path / "f.rrd")
    texts = rrd.load_texts(tmp_path / "f.rrd")
    assert texts == {"/autopilot/events": [(0.5, "hello from autopilot")], "/sitl/events": [(0.5, "hello from sitl")]}
    assert len(rrd.recordings(tmp_path / "f.rrd")) == 1


def test_spools_recorded_with_their_layout_and_index_are_the_merge_of_a_part(tmp_path):
    """``record_spools(..., write_footer=True, blueprint=...)`` (the launcher's one pass) makes what recording a
    footerless part and merging it with the same layout (``rerun rrd merge``) makes: the same recording, rows,
    values and layout, and an index (footer) that ``rerun rrd verify`` requires."""
    from tools.view.views import flight_blueprint

    rid = tm.new_recording_id()
    with tm.Telemetry("autopilot", rid, spool_path=tmp_path / "autopilot.spool") as tel:
        _fill(tel)
    spool = [tmp_path / "autopilot.spool"]
    span, limit = (0.0, 3.0), 12.5
    tm.record_spools(
        spool, tmp_path / "direct.rrd", write_footer=True, blueprint=flight_blueprint(span, rudder_limit_deg=limit)
    )
    tm.record_spools(spool, tmp_path / "part.rrd")
    tm.merge_recordings(
        [tmp_path / "part.rrd"], tmp_path / "merged.rrd", blueprint=flight_blueprint(span, rudder_limit_deg=limit)
    )
    direct, merged = tmp_path / "direct.rrd", tmp_path / "merged.rrd"
    assert rrd.recordings(direct) == rrd.recordings(merged) == [(tm.APPLICATION_ID, rid)]
    _same_recording(merged, direct)
    assert rrd.has_blueprint(direct)
    assert rrd.visible_time_ranges(direct) == rrd.visible_time_ranges(merged) != {}
    assert rrd.y_ranges(direct) == rrd.y_ranges(merged) != {}
    for component in ("ViewBlueprint:display_name", "TimePanelBlueprint:timeline"):
        same = sorted(rrd.blueprint_components(direct, component)) == sorted(
            rrd.blueprint_components(merged, component)
        )
        assert same, component  # (the merge may reorder the layout's chunks)
    ok, msg = rrd.verify(direct)  # footers required
    assert ok, msg
    assert not rrd.verify(tmp_path / "part.rrd")[0]  # (a part has none: the check can fail)


def test_a_layout_survives_the_spool():
    for layout in (L.AUTOPILOT, L.PARAM_SETS, S.SITL_TABLE, S.SITL_HELD_TABLE, L.link_layout("gcs")):
        assert layout_from_data(layout_to_data(layout)) == layout


def test_a_spooling_writer_never_imports_rerun(tmp_path):
    """The autopilot's hook on a spooling writer, in a fresh process: rows spooled, rerun never loaded."""
    code = (
        "import sys\n"
        "from autopilot.shared import telemetry as tm\n"
        "from autopilot.telemetry.hooks import autopilot_tables\n"
        f"tel = tm.Telemetry('autopilot', 'r', spool_path={str(tmp_path / 'a.spool')!r})\n"
        "ap, _, _, _ = autopilot_tables(tel)\n"
        "ap.push((0.0, 1.0, (0.0,) * len(ap.layout.fields)))\n"
        "tel.close()\n"
        "print('rerun' in sys.modules, 'pyarrow' in sys.modules, tel.rows_sent['autopilot'])\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["False", "False", "1"]
    with SpoolReader(tmp_path / "a.spool") as reader:
        kinds = [head["k"] for head, _ in reader]
    assert kinds.count("rows") == 1 and "table" in kinds and reader.process == "autopilot"


def test_a_writer_has_a_spool_or_a_file_not_both(tmp_path):
    """A spool and a part file are two recordings of the same rows: refused.  A spool beside a viewer is what a
    live flight does (the viewer has a stream of its own; a viewer nobody runs is dropped, the spool stays)."""
    with pytest.raises(ValueError, match="two recordings"):
        tm.Telemetry("x", None, tmp_path / "a.rrd", spool_path=tmp_path / "a.spool")
    with tm.Telemetry("x", None, connect_url="rerun+http://127.0.0.1:1/proxy", spool_path=tmp_path / "a.spool") as t:
        assert t.enabled and t.connect_url is None and t.rec is None and t.live_rec is None
    for prog in ("autopilot", "sitl"):
        r = subprocess.run(
            [sys.executable, "-m", prog, "--telemetry-spool", str(tmp_path / "s"), "--rrd", str(tmp_path / "r.rrd")],
            capture_output=True,
            text=True,
            timeout=60,
            cwd=ROOT,
        )
        assert r.returncode == 2 and r.stderr.strip().splitlines()[-1].count("--telemetry-spool") == 1, r.stderr
        assert "not with --rrd" in r.stderr


def _spool(tmp_path: Path, rid: str = "r1", name: str = "a.spool") -> Path:
    with tm.Telemetry("sitl", rid, spool_path=tmp_path / name) as tel:
        table = tel.table(S.SITL_TABLE)
        for k in range(10):
            table.push((k * 0.01, 1.7e9 + k, (float(k),) * len(S.SITL_FIELDS)))
    return tmp_path / name


def test_a_cut_short_spool_is_read_to_its_last_whole_record(tmp_path):
    """A process killed while it wrote: what was written whole is recorded, and the reader says it was cut."""
    path = _spool(tmp_path)
    data = path.read_bytes()
    path.write_bytes(data[:-5])
    with SpoolReader(path) as reader:
        kinds = [head["k"] for head, _ in reader]
        assert reader.truncated and "rows" not in kinds  # the one rows record was the last
    done = tm.record_spools([path], tmp_path / "f.rrd")
    assert done["truncated"] == [str(path)]


def test_a_malformed_spool_is_an_error_that_says_what(tmp_path):
    bad = tmp_path / "bad.spool"
    bad.write_bytes(b"RRF2 not a spool")
    with pytest.raises(SpoolError, match="not a telemetry spool"):
        SpoolReader(bad)
    path = _spool(tmp_path)
    data = bytearray(path.read_bytes())
    # the last record (the rows) claims one row more than its payload holds
    pos = len(MAGIC)
    last = pos
    while pos < len(data):
        last = pos
        n_head, n_payload = struct.unpack_from("<II", data, pos)
        pos += 8 + n_head + n_payload
    n_head, n_payload = struct.unpack_from("<II", data, last)
    head = bytes(data[last + 8 : last + 8 + n_head]).replace(b'"n":10', b'"n":11')
    data[last:] = struct.pack("<II", len(head), n_payload) + head + bytes(data[last + 8 + n_head :])
    path.write_bytes(bytes(data))
    with pytest.raises(SpoolError, match="values for 11 rows"):
        tm.record_spools([path], tmp_path / "f.rrd")
    other = _spool(tmp_path, "r2", "b.spool")
    with pytest.raises(SpoolError, match="one flight has one"):
        tm.record_spools([_spool(tmp_path, "r1", "c.spool"), other], tmp_path / "g.rrd")


def test_check_room_is_the_free_space_to_the_byte(tmp_path):
    """``check_room`` on a real 256 kB tmpfs: what is free passes, one byte more is ENOSPC naming the file."""
    from autopilot.shared.telemetry.files import check_room
    from tests._small_disk import free_bytes, small_disk

    with small_disk(tmp_path / "disk", 256) as disk:
        free = free_bytes(disk)
        check_room(disk / "f.rrd", free)
        with pytest.raises(OSError) as exc:
            check_room(disk / "f.rrd", free + 1, "the layout")
        assert exc.value.errno == errno.ENOSPC and exc.value.filename == str(disk / "f.rrd")
        assert "for the layout: it needs about" in exc.value.strerror


def test_check_room_is_also_the_largest_file_the_process_may_write(tmp_path):
    """Under ``ulimit -f`` (RLIMIT_FSIZE, 300 kB) a write past the limit fails as on a full disk, so ``check_room``
    refuses one byte more than the limit (EFBIG, naming the file and the limit) and passes the limit itself, on a
    disk with room for both; in a process of its own (the limit is the process's)."""
    code = (
        "import errno, resource, sys\n"
        "from autopilot.shared.telemetry.files import check_room\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (300_000, resource.RLIM_INFINITY))\n"
        "check_room(sys.argv[1], 300_000)\n"
        "try:\n"
        "    check_room(sys.argv[1], 300_001, 'the layout')\n"
        "except OSError as exc:\n"
        "    print(exc.errno == errno.EFBIG, exc.filename, exc.strerror)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path / "f.rrd")], capture_output=True, text=True, timeout=60, cwd=ROOT
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(f"True {tmp_path / 'f.rrd'} File too large for the layout: it needs about 0.3 MB"), out
    assert "files of 0.3 MB at most (RLIMIT_FSIZE, ulimit -f)" in out.stdout


def test_spools_are_recorded_only_onto_a_disk_with_room_for_the_recording(tmp_path):
    """rerun 0.41's FileSink can hang its process for good when the disk fills under it (``telemetry.files``), so
    ``record_spools`` measures first: on a real tmpfs with 8 kB less than the recording is allowed (4 bytes per
    spooled byte and 1 MB) it raises ENOSPC naming the file before rerun writes a byte, and rerun is never called
    (no error of its own); with 8 kB more it records the whole recording, footer included."""
    from autopilot.shared.telemetry.files import RRD_FIXED_BYTES, RRD_PER_SPOOL_BYTE, has_footer
    from tests._small_disk import fill, small_disk

    with tm.Telemetry("autopilot", tm.new_recording_id(), spool_path=tmp_path / "ap.spool") as tel:
        _fill(tel)
    need = RRD_PER_SPOOL_BYTE * (tmp_path / "ap.spool").stat().st_size + RRD_FIXED_BYTES
    assert RRD_PER_SPOOL_BYTE == 4 and RRD_FIXED_BYTES == 1 << 20  # the figures this test and the docs quote
    for leave_kb, fits in ((need // 1024 - 8, False), (need // 1024 + 8, True)):
        with small_disk(tmp_path / "disk", need // 1024 + 64) as disk:
            fill(disk, leave_kb=leave_kb)
            target = disk / "f.rrd"
            if not fits:
                with pytest.raises(OSError) as exc:
                    tm.record_spools([tmp_path / "ap.spool"], target, write_footer=True)
                assert exc.value.errno == errno.ENOSPC and exc.value.filename == str(target)
                assert not target.exists()
            else:
                done = tm.record_spools([tmp_path / "ap.spool"], target, write_footer=True)
                assert done["chunks"] > 0 and has_footer(target)
                assert target.stat().st_size < need  # the allowance holds this recording


def test_a_recording_without_its_end_is_told_from_a_whole_one(tmp_path):
    """``has_footer``: a recording ended with its footer, not one cut by a byte, not a footerless part."""
    from autopilot.shared.telemetry.files import has_footer

    spool = _spool(tmp_path)
    tm.record_spools([spool], tmp_path / "whole.rrd", write_footer=True)
    tm.record_spools([spool], tmp_path / "part.rrd", write_footer=False)
    assert has_footer(tmp_path / "whole.rrd") and not has_footer(tmp_path / "part.rrd")
    data = (tmp_path / "whole.rrd").read_bytes()
    (tmp_path / "cut.rrd").write_bytes(data[:-1])
    (tmp_path / "empty.rrd").write_bytes(b"")
    assert not has_footer(tmp_path / "cut.rrd") and not has_footer(tmp_path / "empty.rrd")


# ---------------------------------------------------------------------------------------- the launcher
def test_a_file_only_flight_spools_and_a_live_one_writes_parts(tmp_path):
    """Without a viewer the processes spool (no rerun in either); with ``rrd_live`` (or a viewer) they write their
    own parts with rerun as before; one recording id for both either way."""
    from tools.flight import FlightConfig
    from tools.flight.telemetry import telemetry_argvs

    argv, parts, rid = telemetry_argvs(FlightConfig(lockstep=True), tmp_path)
    assert parts == tm.spool_paths(tmp_path)
    for name in ("autopilot", "sitl"):
        assert argv[name] == ["--recording-id", rid, "--telemetry-spool", str(parts[name])]
    argv, parts, rid = telemetry_argvs(FlightConfig(lockstep=True, rrd_live=True), tmp_path)
    assert parts == tm.part_paths(tmp_path)
    for name in ("autopilot", "sitl"):
        assert argv[name] == ["--recording-id", rid, "--rrd", str(parts[name])]
    assert telemetry_argvs(FlightConfig(lockstep=True, rrd=False), tmp_path) == (None, {}, None)
    # a live viewer: the recording is spooled all the same, the viewer gets a thinned stream of its own
    url = "rerun+http://127.0.0.1:1/proxy"  # nobody listens: the layout is not sent, the flags are what matters
    argv, parts, rid = telemetry_argvs(FlightConfig(lockstep=True, connect=url, live_rate=25), tmp_path)
    assert parts == tm.spool_paths(tmp_path)
    for name in ("autopilot", "sitl"):
        assert argv[name] == ["--recording-id", rid, "--telemetry-spool", str(parts[name])] + [
            "--connect",
            url,
            "--live-rate",
            "25.0",
        ]


@pytest.mark.e2e
def test_a_file_only_flight_records_what_a_live_one_does(tmp_path):
    """The same lockstep flight, spooled (the default) and written live (``--rrd-live``): the same entities, rows
    and values in flight.rrd, the same layout, indexed either way.  Left out of the values (their row counts are
    compared): the loop timing, measured on the wall clock, and both links' counters, which count what was sent and
    received while the other processes were still starting (HEARTBEATs); they differ from one flight to the next
    however the recording is written.  The unit test above compares those too, from the same rows."""
    from tools.flight import Flight

    files = {}
    for live in (False, True):
        res = Flight(lockstep=True, duration=3.0, out=tmp_path / f"live{live}", quiet=True, png=False, rrd_live=live)
        res = res.run()
        assert res.ok, res.reason
        assert res.summary["files"]["rrd_indexed"] and not (tmp_path / f"live{live}" / ".parts").exists()
        files[live] = Path(res.summary["files"]["rrd"])
    assert "--telemetry-spool" in (tmp_path / "liveFalse" / "autopilot.log").read_text().splitlines()[0]
    assert "--rrd" in (tmp_path / "liveTrue" / "sitl.log").read_text().splitlines()[0].split()
    wall_clock = ("/autopilot/timing/loop", "/autopilot/link/gcs", "/autopilot/link/sitl")
    spooled, live = files[False], files[True]
    a, b = rrd.load(spooled), rrd.load(live)
    for ep in wall_clock:
        assert len(a[ep].t) == len(b[ep].t) > 0, ep
    assert len(a[L.AP_ROLL].t) == 300
    # the sim-time values only: wall times differ between two flights
    assert rrd.entity_paths(spooled) == rrd.entity_paths(live)
    assert sorted(a) == sorted(b)
    for ep in a:
        if ep in wall_clock:
            continue
        assert a[ep].names == b[ep].names and np.array_equal(a[ep].t_ns, b[ep].t_ns), ep
        assert np.array_equal(a[ep].values, b[ep].values, equal_nan=True), ep
    assert rrd.load_states(spooled) == rrd.load_states(live)
    assert rrd.load_texts(spooled) == rrd.load_texts(live)
    pa, pb = rrd.load_poses(spooled), rrd.load_poses(live)
    assert sorted(pa) == sorted(pb) and all(np.array_equal(pa[k][1], pb[k][1]) for k in pa)
    assert rrd.has_blueprint(spooled) and sorted(
        map(str, rrd.blueprint_components(spooled, "ViewBlueprint:display_name"))
    ) == sorted(map(str, rrd.blueprint_components(live, "ViewBlueprint:display_name")))
    assert rrd.verify(spooled)[0]  # with rerun's footer (index), as the live flight's


def test_the_rrd_tool_records_spools_by_hand(tmp_path):
    """``python -m tools.rrd record OUT SPOOL...``: one recording with the flight layout and rerun's footer; a file
    that is not a spool is one line on stderr, exit 1."""
    rid = tm.new_recording_id()
    with tm.Telemetry("autopilot", rid, spool_path=tmp_path / "autopilot.spool") as tel:
        _fill(tel)
    spools = [str(tmp_path / "autopilot.spool"), str(_spool(tmp_path, rid, "sitl.spool"))]
    r = subprocess.run(
        [sys.executable, "-m", "tools.rrd", "record", str(tmp_path / "f.rrd"), *spools],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )
    assert r.returncode == 0, r.stderr
    assert rrd.recordings(tmp_path / "f.rrd") == [(tm.APPLICATION_ID, rid)]
    assert rrd.has_blueprint(tmp_path / "f.rrd") and rrd.verify(tmp_path / "f.rrd")[0]
    assert (
        len(rrd.load(tmp_path / "f.rrd")[L.AP_ROLL].t) == N
        and len(rrd.load(tmp_path / "f.rrd")[S.SITL_ROLL].t) == N + 10
    )
    (tmp_path / "x.spool").write_text("hello")
    r = subprocess.run(
        [sys.executable, "-m", "tools.rrd", "record", str(tmp_path / "g.rrd"), str(tmp_path / "x.spool")],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )
    assert r.returncode == 1 and r.stderr.strip().count("\n") == 0 and "not a telemetry spool" in r.stderr


def _peak_rss_recording(tmp_path: Path, minutes: int) -> tuple[float, int]:
    """(peak RSS MB of a fresh process that records a spool of ``minutes`` of a 100 Hz autopilot table, .rrd bytes)."""
    code = f"""
import sys
import numpy as np
from autopilot.shared import telemetry as tm
from autopilot.telemetry import layout as L
tel = tm.Telemetry("autopilot", "r", spool_path=sys.argv[1])
table = tel.table(L.AUTOPILOT)
row = tuple(float(x) for x in np.arange(len(L.AUTOPILOT.fields)))
for k in range({minutes} * 6000):
    table.push((k * 0.01, 1.7e9 + k * 0.01, row))
    if k % 5000 == 4999:
        tel.flush()
tel.close()
tm.record_spools([sys.argv[1]], sys.argv[2])
# VmHWM: this program's own peak (ru_maxrss would hold the forking pytest worker's image, often larger)
print(next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM:")) / 1024)
"""
    spool, out = tmp_path / f"{minutes}.spool", tmp_path / f"{minutes}.rrd"
    r = subprocess.run([sys.executable, "-c", code, str(spool), str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return float(r.stdout.split()[-1]), out.stat().st_size


def test_recording_spools_takes_bounded_memory(tmp_path):
    """Recording is read a record at a time and flushed to the file every FLUSH_EVERY_BYTES: six times the flight,
    six times the file, about the same peak memory (without the flushes rerun queued the recording: measured 55 MB
    more for the hour than for 10 minutes)."""
    short_mb, short_size = _peak_rss_recording(tmp_path, 10)
    long_mb, long_size = _peak_rss_recording(tmp_path, 60)
    assert long_size > 5 * short_size and long_size - short_size > 75e6
    assert long_mb - short_mb < 15, (short_mb, long_mb)
