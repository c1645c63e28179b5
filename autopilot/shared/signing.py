"""MAVLink 2 message signing: key files, signing outgoing packets, checking incoming ones.

The signature is MAVLink 2's (incompat flag 0x01, 13 bytes after the CRC): link id (1 byte), timestamp
(6 bytes, units of 10 us since 2015-01-01 00:00 UTC) and the first 6 bytes of
SHA-256(secret key + header + payload + CRC + link id + timestamp).
``tests/autopilot/shared/test_signing.py`` checks the bytes against pymavlink's own ``MAVLink.signing``.

A key file holds the 32-byte secret as 64 hexadecimal digits (``python -m tools.flight.keygen FILE`` writes one
with mode 0600).  ``load_key`` refuses a missing, unreadable, group- or world-accessible or short key
with a one-line :class:`KeyFileError`.

Checking (``Verifier.check``): the signature must match (``bad_signature``), and per stream (link id,
system, component) the timestamp must grow (``replay``); a new stream must not be older than one minute
(the MAVLink rule), so a packet recorded earlier cannot be replayed once its stream has moved on or
after a restart of the receiver more than a minute later.  The stream's timestamp is updated only after the
signature matched, so a forged packet cannot move it.
"""

from __future__ import annotations

import hashlib
import os
import secrets
import stat
import time

KEY_BYTES = 32
SIGNING_EPOCH_S = 1420070400  # 2015-01-01 00:00:00 UTC
NEW_STREAM_WINDOW = 60 * 100_000  # 1 min in 10 us units
# The link id each link signs with (a receiver keeps one timestamp stream per link id, system and component).
SIGNING_LINK_SITL = 1  # the autopilot's SITL link
SIGNING_LINK_GCS = 2  # the autopilot's GCS link
SIGNING_LINK_SIM = 3  # the SITL's link
SIGNING_LINK_GROUND = 4  # the GCS script's link
_STAMP_MASK = (1 << 48) - 1  # the timestamp is 6 bytes on the wire
_sha256 = hashlib.sha256


class KeyFileError(ValueError):
    """A signing key file that cannot be used (one-line message naming the file)."""


def now_stamp() -> int:
    """The current time in MAVLink signing units (10 us since 2015-01-01 UTC)."""
    return int((time.time() - SIGNING_EPOCH_S) * 100_000)


def load_key(path: str | os.PathLike) -> bytes:
    """The 32-byte secret from a key file; :class:`KeyFileError` if it is missing, unreadable, accessible to
    group or others, or not 64 hex digits."""
    path = os.fspath(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise KeyFileError(
            f"signing key {path}: no such file (create one with python -m tools.flight.keygen {path})"
        ) from None
    except OSError as exc:
        raise KeyFileError(f"signing key {path}: {exc.strerror}") from None
    if not stat.S_ISREG(st.st_mode):
        raise KeyFileError(f"signing key {path}: not a regular file")
    if st.st_mode & 0o077:
        raise KeyFileError(
            f"signing key {path}: mode {stat.S_IMODE(st.st_mode):04o} lets others read it; use chmod 600 {path}"
        )
    try:
        with open(path, "rb") as f:
            text = f.read(4 * KEY_BYTES + 16)
    except OSError as exc:
        raise KeyFileError(f"signing key {path}: cannot read ({exc.strerror})") from None
    try:
        key = bytes.fromhex(text.decode("ascii").strip())
    except (UnicodeDecodeError, ValueError):
        raise KeyFileError(f"signing key {path}: expected {2 * KEY_BYTES} hexadecimal digits") from None
    if len(key) != KEY_BYTES:
        raise KeyFileError(f"signing key {path}: {len(key)} bytes, expected {KEY_BYTES} ({2 * KEY_BYTES} hex digits)")
    return key


def write_key(path: str | os.PathLike, key: bytes | None = None) -> bytes:
    """Create ``path`` (it must not exist) with a new random key (or ``key``), mode 0600; returns the key."""
    key = secrets.token_bytes(KEY_BYTES) if key is None else key
    if len(key) != KEY_BYTES:
        raise KeyFileError(f"a signing key has {KEY_BYTES} bytes, got {len(key)}")
    fd = os.open(os.fspath(path), os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(key.hex() + "\n")
    except OSError:  # a full disk: no empty or half key file is left to be read later
        os.unlink(path)
        raise
    return key


class Signing:
    """One link's signing state: the key, the outgoing link id and timestamp, the incoming streams."""

    def __init__(self, key: bytes, link_id: int = 0):
        if len(key) != KEY_BYTES:
            raise KeyFileError(f"a signing key has {KEY_BYTES} bytes, got {len(key)}")
        self.key = key
        self.link_id = link_id & 0xFF
        self._link_byte = bytes((self.link_id,))
        self._ts = 0
        self.streams: dict = {}  # (link_id, sysid, compid) -> newest accepted timestamp

    def next_stamp(self) -> int:
        """The timestamp for the next outgoing packet: the clock, strictly growing."""
        ts = now_stamp()
        if ts <= self._ts:
            ts = self._ts + 1
        self._ts = ts
        return ts

    def signature(self, signed_part: bytes) -> bytes:
        """The 13 bytes appended to an (already flagged and CRC'd) packet: link id, the 6-byte timestamp
        (``next_stamp``), the first 6 bytes of SHA-256(key + packet + link id + timestamp)."""
        ts = now_stamp()
        if ts <= self._ts:
            ts = self._ts + 1
        self._ts = ts  # next_stamp, spelled out: every packet sent is signed here
        tail = self._link_byte + (ts & _STAMP_MASK).to_bytes(6, "little")
        return tail + _sha256(self.key + signed_part + tail).digest()[:6]

    def resign(self, packet: bytes) -> bytes:
        """``packet`` (one whole signed packet of ours) signed again with a fresh timestamp: a resend that the peer
        can tell from a replay (the same bytes twice are one, by the MAVLink signing rule)."""
        signed_part = packet[:-13]
        return signed_part + self.signature(signed_part)

    def check(self, packet: bytes, sysid: int, compid: int) -> str | None:
        """None if ``packet`` (one whole signed MAVLink 2 packet) is authentic and fresh, else the reason."""
        if _sha256(self.key + packet[:-6]).digest()[:6] != packet[-6:]:
            return "bad_signature"
        link_id = packet[-13]
        ts = int.from_bytes(packet[-12:-6], "little")
        key = (link_id, sysid, compid)
        last = self.streams.get(key)
        if last is None:
            if ts + NEW_STREAM_WINDOW < now_stamp():
                return "replay"
        elif ts <= last:
            return "replay"
        self.streams[key] = ts
        return None
