"""One recording from several processes: recording ids, part files, joining them, ``rerun rrd verify``.

Each process of a flight writes its own part (``DIR/.parts/<process>.rrd``) with the same application id
and recording id, without rerun's footer (the footer's index grows with the number of chunks, about 0.5 kB
each, measured, so a writer that keeps one grows with the flight's length).  At the end the launcher joins
the parts and the viewer layout into ONE file in one of two ways:

* ``merge_recordings`` runs ``rerun rrd merge``: it decodes everything, compacts the chunks and writes a
  footer (the index the viewer uses for random access).  Its memory is about twice the parts' size, so it
  is for short flights.
* ``concatenate_recordings`` copies the parts' messages, framed but not decoded, into one stream (the
  layout written beside them without a footer first), a buffer at a time: constant memory whatever the
  flight's length, and as fast as the disk.  The file holds the same recording (one store id, every chunk,
  the layout) without a footer: the viewer and ``rerun.chunk.RrdReader`` load it by scanning, ``rerun rrd
  verify`` needs ``--check-footers=false``.  (``rerun rrd route`` would also stream, but in rerun 0.41 it
  writes an empty footer that makes ``RrdReader`` see no recording, and panics on a footered input.)

A flight whose processes spool their rows (the default) has no parts to join: the launcher records the spools
straight into its one file, layout and footer included (``rerun_sink.record_spools``), and moves it into place
with its digest (``install_recording``).

A part left without footer by a SIGKILL is still joined: every complete message is kept and the torn tail is
dropped.  rerun itself is imported only to write the layout for a concatenation; ``rerun rrd`` does the rest.
"""

from __future__ import annotations

import errno
import hashlib
import os
import struct
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path

from autopilot.shared.telemetry.integrity import not_regular, remove_digest, sha256_file, write_digest
from autopilot.shared.telemetry.layout import APPLICATION_ID, new_recording_id  # noqa: F401  (part of this module's API)
from autopilot.shared.telemetry.viewer import rerun_cli_path


class RrdError(RuntimeError):
    """A rerun CLI operation on .rrd files failed; the message carries rerun's own last lines."""


def part_paths(out_dir: str | os.PathLike, processes: Sequence[str] = ("autopilot", "sitl")) -> dict[str, Path]:
    """Where each process of a flight writes its part: ``OUT/.parts/<process>.rrd``."""
    base = Path(out_dir) / ".parts"
    return {p: base / f"{p}.rrd" for p in processes}


def _cli_env() -> dict[str, str]:
    env = dict(os.environ)
    env.setdefault("RUST_LOG", "warn")  # rrd merge is chatty at INFO
    return env


def _tail(text: str, n: int = 6) -> str:
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    return "\n".join(lines[-n:])


def merge_recordings(
    parts: Sequence[str | os.PathLike],
    out_path: str | os.PathLike,
    *,
    blueprint=None,
    blueprint_file: str | os.PathLike | None = None,
    application_id: str = APPLICATION_ID,
    remove_parts: bool = False,
    timeout_s: float = 120.0,
) -> Path:
    """Merge part files into ``out_path`` with ``rerun rrd merge`` (compacted, with a footer); the output path.

    ``blueprint``: a ``rerun.blueprint.Blueprint`` to add (saved for ``application_id``), or None to keep
    whatever the parts carry; ``blueprint_file``: one already saved (a ``.rbl``, e.g. ``tools.view.layout_cache``'s),
    added as it is (no rerun import here).  Missing or empty parts are skipped (a process that never started); if no
    part is left, RrdError.  ``remove_parts`` deletes the parts after a successful merge.  ``out_path`` gets its
    digest beside it (``OUT.sha256``, ``autopilot.shared.telemetry.integrity``); an ``out_path`` that exists and is
    not a regular file (``/dev/null``) is an RrdError: a rename would replace it.
    """
    if blueprint is not None and blueprint_file is not None:
        raise ValueError("merge_recordings: give blueprint or blueprint_file, not both")
    out = Path(out_path)
    _check_target(out)
    present = [Path(p) for p in parts if Path(p).is_file() and Path(p).stat().st_size > 0]
    if not present:
        raise RrdError(f"no recording to merge: none of {[str(p) for p in parts]} exists or has data")
    out.parent.mkdir(parents=True, exist_ok=True)
    # in the output's folder: the move is a rename, not a copy of a large file
    with tempfile.TemporaryDirectory(prefix=".rrd-merge-", dir=out.parent) as tmp:
        inputs = [str(p) for p in present]
        if blueprint is not None:
            rbl = Path(tmp) / "blueprint.rbl"
            check_room(rbl, RRD_FIXED_BYTES, "the layout")  # blueprint.save writes with rerun's FileSink
            blueprint.save(application_id, str(rbl))
            inputs.append(str(rbl))
        elif blueprint_file is not None:
            inputs.append(str(blueprint_file))
        tmp_out = Path(tmp) / "joined.rrd"
        cmd = [rerun_cli_path(), "rrd", "merge", "--continue-on-error", "-o", str(tmp_out), *inputs]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, env=_cli_env())
        if proc.returncode != 0 or not tmp_out.is_file():
            raise RrdError(f"rerun rrd merge failed (exit {proc.returncode}): {_tail(proc.stderr)}")
        digest = sha256_file(tmp_out)
        remove_digest(out)
        os.replace(tmp_out, out)
        write_digest(out, digest)
    if remove_parts:
        for p in present:
            p.unlink(missing_ok=True)
    return out


# RRD stream framing (rerun 0.41 ``re_log_encoding``): a 12-byte stream header (magic b"RRF2", version, options),
# then messages, each a little-endian (kind u64, length u64) header and ``length`` bytes of payload; kind 0 ends
# the stream (a footer may follow).  Kinds 1-3: SetStoreInfo, ArrowMsg, BlueprintActivationCommand.
_RRD_MAGIC = b"RRF2"
_RRD_HEADER = 12
_MSG_KINDS = (1, 2, 3)
_COPY = 1 << 20  # bytes copied at a time


def concatenate_recordings(
    parts: Sequence[str | os.PathLike],
    out_path: str | os.PathLike,
    *,
    blueprint=None,
    recording_id: str | None = None,
    application_id: str = APPLICATION_ID,
    remove_parts: bool = False,
) -> Path:
    """Join part files into ``out_path`` as one stream, in constant memory (no footer); the output path.

    ``blueprint``, with the parts' ``recording_id``, is written first (footerless) so the viewer shows the
    layout.  Every part must carry the same stream header (rerun version and encoding options) as the first,
    else RrdError.  A torn last message (a part cut by SIGKILL) is dropped; an unknown message kind is an
    RrdError (a rerun format this code does not know).  Missing or empty parts are skipped.  The digest and the
    rule on a target that is not a regular file are those of :func:`merge_recordings`.
    """
    out = Path(out_path)
    _check_target(out)
    present = [Path(p) for p in parts if Path(p).is_file() and Path(p).stat().st_size > _RRD_HEADER]
    if not present:
        raise RrdError(f"no recording to join: none of {[str(p) for p in parts]} exists or has data")
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=".rrd-join-", dir=out.parent) as tmp:
        inputs = list(present)
        if blueprint is not None:
            if recording_id is None:
                raise ValueError("concatenate_recordings: a blueprint needs the parts' recording_id")
            rbl = Path(tmp) / "blueprint.rbl"
            _save_blueprint_unindexed(blueprint, rbl, application_id, recording_id)
            inputs.insert(0, rbl)
        tmp_out = Path(tmp) / "joined.rrd"
        header = None
        with open(tmp_out, "wb") as raw:
            dst = _Hashing(raw)
            for path in inputs:
                with open(path, "rb") as src:
                    head = src.read(_RRD_HEADER)
                    if not head.startswith(_RRD_MAGIC):
                        raise RrdError(f"{path}: not an RRD stream (header {head[:4]!r})")
                    if header is None:
                        header = head
                        dst.write(head)
                    elif head != header:
                        raise RrdError(f"{path}: stream header {head.hex()} is not the first part's {header.hex()}")
                    _copy_messages(src, dst, path)
        remove_digest(out)
        os.replace(tmp_out, out)  # same folder: a rename
        write_digest(out, dst.sha.hexdigest())
    if remove_parts:
        for p in present:
            p.unlink(missing_ok=True)
    return out


def _check_target(out: Path) -> None:
    what = not_regular(out)
    if what:
        raise RrdError(f"{out} is {what}, not a regular file: a recording is never written over it")


# rerun 0.41's FileSink writes from a thread of its own.  When a write fails for want of space, a flush can wait for
# that thread's answer for ever: reproduced in 5 of 9 recordings (``record_spools`` without the guard below) of a
# 30 s flight's spools onto a tmpfs with 1.2 or 1.6 MB free, three busy loops on the 2-core machine.  A flush with a
# timeout does not help: the interpreter's exit then waits for ever instead (rerun flushes every recording there;
# 12 of 24).  Other runs print the error and raise, or return as if the recording were whole although its end is
# missing (1.8 MB free).  So no recording is started on a disk that cannot hold it (``check_room``), and a recording
# said to have a footer is checked for it (``has_footer``).  A file size limit (RLIMIT_FSIZE) fails the write the same
# way (EFBIG): a launcher limited to 300 kB files hung in that flush for 300 s in one whole run of the suite, so
# ``check_room`` refuses a recording larger than the limit too.
RRD_PER_SPOOL_BYTE = 4  # a recording's bytes per byte of its spools: measured 2.5 (a 600 s flight) to 3.0 (30 s)
RRD_FIXED_BYTES = 1 << 20  # and its fixed part (the layout, the properties): 0.42 MB measured for a 2 s flight
FOOTER_MAGIC = b"RRF2FOOT"  # the last bytes but four (the version) of a recording rerun 0.41 ended with a footer


def check_room(path: str | os.PathLike, need_bytes: int, what: str = "the recording") -> None:
    """OSError (ENOSPC, naming ``path``) if the file system ``path`` is written on has fewer than ``need_bytes``
    free for this user, or (EFBIG) if this process may not write a file of ``need_bytes`` (``ulimit -f``): what is
    about to be written there would not fit (``path``'s folder must exist)."""
    st = os.statvfs(Path(path).parent)
    free = st.f_bavail * st.f_frsize
    if free < need_bytes:
        raise OSError(
            errno.ENOSPC,
            f"No space left on device for {what}: it needs about {need_bytes / 1e6:.1f} MB, "
            f"{free / 1e6:.1f} MB are free",
            os.fspath(path),
        )
    largest = _largest_file()
    if largest is not None and largest < need_bytes:  # a write past it fails as on a full disk (EFBIG): same hang
        raise OSError(
            errno.EFBIG,
            f"File too large for {what}: it needs about {need_bytes / 1e6:.1f} MB, and this process may write "
            f"files of {largest / 1e6:.1f} MB at most (RLIMIT_FSIZE, ulimit -f)",
            os.fspath(path),
        )


def _largest_file() -> int | None:
    """The largest file this process may write (its RLIMIT_FSIZE soft limit, ``ulimit -f``), in bytes; None if
    unlimited or unknown (not POSIX)."""
    try:
        import resource
    except ImportError:
        return None
    soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    return None if soft == resource.RLIM_INFINITY else soft


def has_footer(path: str | os.PathLike) -> bool:
    """Whether the recording at ``path`` ends with rerun's footer (``FOOTER_MAGIC`` and a 4-byte version)."""
    with open(path, "rb") as f:
        f.seek(0, os.SEEK_END)
        if f.tell() < len(FOOTER_MAGIC) + 4:
            return False
        f.seek(-(len(FOOTER_MAGIC) + 4), os.SEEK_END)
        return f.read(len(FOOTER_MAGIC)) == FOOTER_MAGIC


def check_recording_target(out_path: str | os.PathLike) -> None:
    """RrdError if ``out_path`` exists and is not a regular file (``/dev/null``): a rename would replace it."""
    _check_target(Path(out_path))


def install_recording(written: str | os.PathLike, out_path: str | os.PathLike) -> Path:
    """Move a finished recording ``written`` (in ``out_path``'s file system) to ``out_path``, with its digest beside
    it (``OUT.sha256``), as :func:`merge_recordings` does with its output; the output path."""
    out = Path(out_path)
    _check_target(out)
    digest = sha256_file(written)
    remove_digest(out)
    os.replace(written, out)
    write_digest(out, digest)
    return out


class _Hashing:
    """A file's ``write`` that also feeds SHA-256 (the digest of what was written, without reading it back)."""

    def __init__(self, f):
        self.f = f
        self.sha = hashlib.sha256()

    def write(self, buf) -> None:
        self.sha.update(buf)
        self.f.write(buf)


def _copy_messages(src, dst, path) -> None:
    """Copy framed messages from ``src`` (after its header) to ``dst`` up to the end marker, EOF or a torn tail."""
    size = os.fstat(src.fileno()).st_size
    while True:
        head = src.read(16)
        if len(head) < 16:
            return  # EOF (or a torn message header)
        kind, length = struct.unpack("<QQ", head)
        if kind == 0:
            return  # end of stream: a footer may follow, not copied
        if kind not in _MSG_KINDS:
            raise RrdError(f"{path}: unknown RRD message kind {kind} at byte {src.tell() - 16}")
        if size - src.tell() < length:
            return  # a torn last message: dropped
        dst.write(head)
        left = length
        while left:
            buf = src.read(min(left, _COPY))
            dst.write(buf)
            left -= len(buf)


def _save_blueprint_unindexed(blueprint, path: Path, application_id: str, recording_id: str) -> None:
    """``blueprint`` for ``recording_id`` as a footerless .rbl (no recording properties, no data)."""
    import rerun as rr

    check_room(path, RRD_FIXED_BYTES, "the layout")
    rec = rr.RecordingStream(application_id, recording_id=recording_id, send_properties=False)
    try:
        rec.set_sinks(rr.FileSink(str(path), write_footer=False))
        rec.send_blueprint(blueprint)
        rec.flush()
    finally:
        rec.disconnect()


def verify_rrd(path: str | os.PathLike, *, check_footers: bool = True, timeout_s: float = 120.0) -> tuple[bool, str]:
    """Run ``rerun rrd verify`` on ``path``: (ok, rerun's output).  Footers are required by default."""
    cmd = [rerun_cli_path(), "rrd", "verify", f"--check-footers={'true' if check_footers else 'false'}", str(path)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, env=_cli_env())
    return proc.returncode == 0, _tail(proc.stdout + "\n" + proc.stderr)
