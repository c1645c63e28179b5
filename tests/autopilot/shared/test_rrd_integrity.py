"""``python -m tools.rrd verify`` fails a recording that is not whole (issue 31, items 5 and 9): real .rrd files
written by rerun-sdk 0.41's own API and by a short lockstep flight, cut at their end or with bytes flipped in the
middle, and ``tools.rrd merge`` never writing over what is not a regular file."""

from __future__ import annotations

import hashlib
import os
import stat
import struct
import subprocess
import sys

import pytest

from autopilot.shared.telemetry.integrity import FOOTER_MAGIC, stream_problem
from tests._mavlink_procs import run_cli

CUTS = (1, 4, 8, 16, 24, 32)


def _rerun_file(path, *, footer: bool = True, rows: int = 2000) -> None:
    """A recording written by rerun's own API (its FileSink), in a child so this process never imports rerun."""
    code = f"""
import rerun as rr
rec = rr.RecordingStream("trust_test", recording_id="r1")
rec.set_sinks(rr.FileSink({str(path)!r}, write_footer={footer!r}))
for i in range({rows}):
    rec.set_time("sim_time", duration=i * 0.01)
    rec.log("/x", rr.Scalars([float(i)]))
    rec.log("/y", rr.Scalars([2.0 * i, 3.0]))
rec.flush()
rec.disconnect()
"""
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, timeout=120)


@pytest.fixture(scope="module")
def footered(tmp_path_factory):
    path = tmp_path_factory.mktemp("rrd") / "api.rrd"
    _rerun_file(path)
    data = path.read_bytes()
    # rerun 0.41's stream: the last 32 bytes are the footer's trailer (offset, length, checksum, magic, version)
    off, length, _crc, magic, _ver = struct.unpack("<QQI8sI", data[-32:])
    assert magic == FOOTER_MAGIC and off + length + 32 == len(data)
    return path


def _verify(*args):
    r = run_cli("tools.rrd", "verify", *map(str, args), timeout=120)
    return r.returncode, (r.stdout + r.stderr).strip().splitlines()


def test_a_whole_recording_passes(footered):
    code, lines = _verify(footered)
    assert (code, lines) == (0, [f"{footered}: ok"])


@pytest.mark.parametrize("cut", CUTS)
@pytest.mark.parametrize("footers", [True, False])
def test_a_recording_cut_inside_its_footer_trailer_fails(tmp_path, footered, cut, footers):
    """rerun-sdk 0.41's own ``rrd verify`` passes these (it reads a file without a whole trailer as a footerless
    one); cut by 1 to 32 bytes it fails here, with or without ``--no-footer-check``, in one line saying so."""
    bad = tmp_path / f"cut{cut}.rrd"
    bad.write_bytes(footered.read_bytes()[:-cut])
    code, lines = _verify(*(["--no-footer-check"] if not footers else []), bad)
    assert code == 1 and len(lines) == 1, lines
    assert lines[0].startswith(f"{bad}: FAILED: cut off: the last {cut} of the 32 bytes of the footer's trailer")


def test_a_footerless_part_passes_only_without_the_footer_check_and_fails_cut_inside_a_message(tmp_path):
    part = tmp_path / "part.rrd"
    _rerun_file(part, footer=False, rows=50)
    assert _verify("--no-footer-check", part) == (0, [f"{part}: ok"])
    code, lines = _verify(part)
    assert code == 1 and "no footer" in lines[0]
    torn = tmp_path / "torn.rrd"
    torn.write_bytes(part.read_bytes()[:-5])
    code, lines = _verify("--no-footer-check", torn)
    assert code == 1 and len(lines) == 1, lines


def test_the_framing_walk_counts_every_byte(tmp_path, footered):
    """Two whole streams one after the other (``cat a.rrd b.rrd``) frame whole (rerun then judges what they hold:
    two footers of one recording it refuses); a byte more does not."""
    two = tmp_path / "two.rrd"
    two.write_bytes(footered.read_bytes() * 2)
    assert stream_problem(two) is None
    two.write_bytes(footered.read_bytes() * 2 + b"\0")
    assert "does not start with an RRD stream header" in stream_problem(two)


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    out = tmp_path_factory.mktemp("flight")
    r = run_cli("tools.launch", "--lockstep", "--duration", "3", "--out", str(out), "--quiet", "--no-png", timeout=180)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    return out


def test_a_flight_writes_the_sha256_of_its_recording_beside_it(flight):
    """``flight.rrd.sha256`` in sha256sum's format: the digest (checked here with hashlib), two spaces, the name."""
    rrd = flight / "flight.rrd"
    text = (flight / "flight.rrd.sha256").read_text()
    assert text == f"{hashlib.sha256(rrd.read_bytes()).hexdigest()}  flight.rrd\n"
    code, lines = _verify(rrd)
    assert (code, lines) == (0, [f"{rrd}: ok (sha256 matches flight.rrd.sha256)"])


def test_64_bytes_flipped_in_the_middle_of_a_flight_recording_fail(tmp_path, flight):
    """rerun checksums only its footer: a Scalars column with flipped bytes may still decode.  The digest the
    flight wrote sees any change."""
    rrd = tmp_path / "flight.rrd"
    data = bytearray((flight / "flight.rrd").read_bytes())
    mid = len(data) // 2
    data[mid - 32 : mid + 32] = bytes(b ^ 0xFF for b in data[mid - 32 : mid + 32])
    rrd.write_bytes(data)
    (tmp_path / "flight.rrd.sha256").write_text((flight / "flight.rrd.sha256").read_text())
    code, lines = _verify(rrd)
    assert code == 1 and len(lines) == 1 and lines[0].startswith(f"{rrd}: FAILED: content changed: its SHA-256"), lines


def _special(tmp_path, kind: str):
    path = tmp_path / kind
    if kind == "fifo":
        os.mkfifo(path)
    else:  # a character device, as /dev/null is (1, 3): only root may make one
        if os.geteuid() != 0:
            pytest.skip("making a character device needs root")
        os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    return path


@pytest.mark.parametrize("kind", ["fifo", "chardev"])
def test_merge_never_writes_over_what_is_not_a_regular_file(tmp_path, footered, kind):
    """``tools.rrd merge`` wrote by a rename over its target: run as root on /dev/null it replaced the device with a
    regular file.  Now a target that is not a regular file is refused in one line (exit 2), and left as it was."""
    target = _special(tmp_path, kind)
    before = os.stat(target)
    r = run_cli("tools.rrd", "merge", str(target), str(footered), timeout=120)
    lines = (r.stdout + r.stderr).strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "not a regular file" in lines[0] and str(target) in lines[0]
    after = os.stat(target)
    assert stat.S_IFMT(after.st_mode) == stat.S_IFMT(before.st_mode) and after.st_rdev == before.st_rdev
    assert not (tmp_path / f"{kind}.sha256").exists()


def test_merge_writes_the_digest_of_what_it_wrote(tmp_path, footered):
    out = tmp_path / "m.rrd"
    r = run_cli("tools.rrd", "merge", str(out), str(footered), timeout=120)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "m.rrd.sha256").read_text().split()[0] == hashlib.sha256(out.read_bytes()).hexdigest()
