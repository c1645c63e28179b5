"""Whether an .rrd file is whole: its framing walked to the last byte, and its content against a SHA-256 digest.

``rerun rrd verify`` (rerun-sdk 0.41) decodes every message, but it passes a file cut inside its footer's trailer
(the last 1 to 32 bytes missing: it then reads the file as a footerless "legacy" stream) and it cannot see a change
inside a message that still decodes: rerun's format checksums only the footer, not the data messages, so 64
bytes flipped in the middle of a Scalars column decode to other numbers.  Two checks close that:

* :func:`stream_problem` walks the framing of rerun 0.41's stream (``re_log_encoding``): a 12-byte stream header
  (``b"RRF2"``, version, options), then messages, each a little-endian (kind u64, length u64) header and
  ``length`` bytes; kind 0 ends the stream, its payload is the footer (the index, rerun's ``RrdFooter``), and a
  32-byte trailer follows it: the footer's offset in its stream (u64) and length (u64), its checksum (u32),
  ``b"RRF2FOOT"`` and a version (u32).  A file cut anywhere, the trailer included, has fewer bytes than its
  framing says.  Several streams may follow each other (``cat a.rrd b.rrd`` frames whole; rerun judges what they
  hold).
* :func:`write_digest` writes ``FILE.rrd.sha256`` beside every recording the product writes (the launcher's
  ``flight.rrd``, ``tools.rrd merge|record``, an experiment's ``paper.rrd``), in ``sha256sum``'s format
  (``<64 hex>  <name>``, so ``sha256sum -c FILE.rrd.sha256`` checks it too), and :func:`digest_problem` compares.
  A flipped byte anywhere changes the digest (SHA-256, FIPS 180-4).

No I/O beyond reading the file (and writing the digest); nothing here imports rerun.  ``not_regular`` is
``autopilot.shared.process.not_regular``, re-exported.
"""

from __future__ import annotations

import hashlib
import os
import struct
from pathlib import Path

from autopilot.shared.process import not_regular  # noqa: F401  (re-exported)

STREAM_MAGIC = b"RRF2"
STREAM_HEADER = 12
MESSAGE_HEADER = struct.Struct("<QQ")  # kind, length
MESSAGE_KINDS = (0, 1, 2, 3)  # end of stream (then the footer), SetStoreInfo, ArrowMsg, BlueprintActivationCommand
FOOTER_TRAILER = struct.Struct("<QQI8sI")  # footer offset, footer length, checksum, magic, version
FOOTER_MAGIC = b"RRF2FOOT"
DIGEST_SUFFIX = ".sha256"
_READ = 1 << 20


def stream_problem(path: str | os.PathLike, *, footers: bool = True) -> str | None:
    """Why the framing of ``path`` is not whole (one line), or None.  ``footers``: every stream must end with a
    footer and its trailer (rerun's index); without, a stream may also end at a message boundary (a part file
    written without footer), but never inside a message or inside a footer's trailer."""
    size = os.path.getsize(path)
    with open(path, "rb") as f:
        pos = 0
        while pos < size or pos == 0:
            f.seek(pos)
            head = f.read(STREAM_HEADER)
            if len(head) < STREAM_HEADER or not head.startswith(STREAM_MAGIC):
                where = "the file" if pos == 0 else f"the data after the stream that ended at byte {pos}"
                return f"{where} does not start with an RRD stream header (RRF2): {head[:4]!r}"
            start = pos  # the trailer's offsets count from the stream's start
            pos += STREAM_HEADER
            footer = None  # (offset, length) of the footer of this stream, once its end marker is read
            while pos < size:
                if size - pos < MESSAGE_HEADER.size:
                    return f"cut off: {size - pos} bytes of a message header at byte {pos} (of {MESSAGE_HEADER.size})"
                f.seek(pos)
                kind, length = MESSAGE_HEADER.unpack(f.read(MESSAGE_HEADER.size))
                if kind not in MESSAGE_KINDS:
                    return f"unknown message kind {kind} at byte {pos}"
                body = pos + MESSAGE_HEADER.size
                if size - body < length:
                    return f"cut off: the message at byte {pos} has {length} bytes, the file only {size - body} more"
                pos = body + length
                if kind == 0:
                    footer = (body, length)
                    break
            if footer is None:
                if footers:
                    return "no footer (rerun's index) at the end of the stream: cut off, or written without one"
                return None
            offset, length = footer
            if length == 0:
                if footers:
                    return f"the stream ends at byte {offset} without a footer (rerun's index)"
                continue
            if size - pos < FOOTER_TRAILER.size:
                missing = FOOTER_TRAILER.size - (size - pos)
                return (
                    f"cut off: the last {missing} of the {FOOTER_TRAILER.size} bytes of the footer's trailer are "
                    f"missing (the footer at byte {offset} has {length} bytes; the file ends at byte {size}, not "
                    f"{pos + FOOTER_TRAILER.size})"
                )
            f.seek(pos)
            t_offset, t_length, _checksum, magic, _version = FOOTER_TRAILER.unpack(f.read(FOOTER_TRAILER.size))
            if magic != FOOTER_MAGIC or (t_offset, t_length) != (offset - start, length):
                return (
                    f"the footer's trailer at byte {pos} does not match its footer (magic {magic!r}, footer at "
                    f"{t_offset} of {t_length} bytes; the stream's is at {offset - start} of {length})"
                )
            pos += FOOTER_TRAILER.size
            if pos >= size:
                return None
    return None


def digest_path(path: str | os.PathLike) -> Path:
    """Where the digest of ``path`` is: ``path`` + ``.sha256``."""
    return Path(os.fspath(path) + DIGEST_SUFFIX)


def sha256_file(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while True:
            buf = f.read(_READ)
            if not buf:
                return h.hexdigest()
            h.update(buf)


def write_digest(path: str | os.PathLike, hexdigest: str | None = None) -> Path:
    """Write ``path``'s SHA-256 (or ``hexdigest``, computed while it was written) to ``path.sha256`` in
    ``sha256sum``'s format, by a rename in the same folder; never over something that is not a regular file."""
    target = digest_path(path)
    what = not_regular(target)
    if what:
        raise OSError(f"{target}: {what}, not a regular file: the digest is not written over it")
    hexdigest = hexdigest or sha256_file(path)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(f"{hexdigest}  {Path(path).name}\n")
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)
    return target


def remove_digest(path: str | os.PathLike) -> None:
    """Remove ``path.sha256`` (before ``path`` is replaced: an old digest never stands beside a new file)."""
    target = digest_path(path)
    if not_regular(target) is None:
        target.unlink(missing_ok=True)


def digest_problem(path: str | os.PathLike) -> tuple[bool, str | None]:
    """(has a digest, why it does not match or None).  No ``path.sha256``: (False, None)."""
    target = digest_path(path)
    if not target.exists():
        return False, None
    what = not_regular(target)
    if what:
        return True, f"{target} is {what}"
    try:
        text = target.read_text(errors="replace").split()
    except OSError as exc:
        return True, f"{target}: {exc.strerror}"
    want = text[0].lower() if text else ""
    if len(want) != 64 or any(c not in "0123456789abcdef" for c in want):
        return True, f"{target} holds no SHA-256 digest"
    got = sha256_file(path)
    if got != want:
        return True, f"content changed: its SHA-256 is {got[:16]}..., {target.name} says {want[:16]}..."
    return True, None
