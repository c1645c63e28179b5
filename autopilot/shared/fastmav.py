"""Fast paths for the few MAVLink messages on the per-frame hot path, built from pymavlink's own tables.

pymavlink's generic ``pack``/``decode`` cost about 11-12 us each in Python; the lockstep loop sends and
receives a handful per frame.  These helpers use the same dialect data (the message class's
``unpacker`` struct, ``crc_extra``, field ``orders``) and the same CRC (fastcrc's MCRF4XX, what
pymavlink uses), and produce byte-identical packets (``tests/test_mavlink_units.py`` checks this
against ``msg.pack(mav)`` and ``mav.decode``).  Anything else goes through pymavlink unchanged.
"""

from __future__ import annotations

import struct

from autopilot.shared.mavlink import mavlink

try:
    import fastcrc

    _crc = fastcrc.crc16.mcrf4xx
except Exception:  # noqa: BLE001  (no fastcrc: use pymavlink's x25crc)
    _crc = None

_HDR = struct.Struct("<BBBBBBBHB")


def crc16(data: bytes) -> int:
    if _crc is not None:
        return _crc(data, 0xFFFF)
    return mavlink.x25crc(data).crc


class FastPacker:
    """``packer(seq, *wire_values) -> bytes`` for one message class, MAVLink 2, signed when ``signing`` is given
    (an ``autopilot.shared.signing.Signing``).

    ``wire_values`` in the order of the class's ``unpacker`` struct (pymavlink's ``pack`` argument order).
    """

    def __init__(self, cls, src_system: int, src_component: int, signing=None):
        self.cls = cls
        self.msgid = cls.id if isinstance(getattr(cls, "id", None), int) else cls.msgid
        self._payload = cls.unpacker.pack
        self._crc_extra = bytes([cls.crc_extra])
        self._sys = src_system
        self._comp = src_component
        self._signing = signing

    def __call__(self, seq: int, *values) -> bytes:
        payload = self._payload(*values)
        p = payload.rstrip(b"\x00") or payload[:1]  # MAVLink 2 trims trailing zero bytes (keeps one)
        mid = self.msgid
        signing = self._signing
        hdr = _HDR.pack(0xFD, len(p), 1 if signing else 0, 0, seq, self._sys, self._comp, mid & 0xFFFF, mid >> 16)
        body = hdr[1:] + p
        c = crc16(body + self._crc_extra)
        packet = hdr[:1] + body + bytes((c & 0xFF, c >> 8))
        return packet + signing.signature(packet) if signing else packet


class FastDecoder:
    """Decode one message class without arrays or strings: CRC check, zero-pad, unpack, reorder, construct.

    Returns the pymavlink message object (same class and fields as ``mav.decode``) or raises
    ``mavlink.MAVError`` on a CRC or length error.
    """

    def __init__(self, cls):
        if sum(cls.lengths) != len(cls.lengths):
            raise ValueError(f"{cls.msgname} has arrays: use pymavlink's decode")
        self.cls = cls
        self._unpack = cls.unpacker.unpack
        self._size = cls.unpacker.size
        self._orders = tuple(cls.orders)
        self._crc_extra = bytes([cls.crc_extra])

    def __call__(self, raw: bytes):
        if raw[0] != 0xFD:
            raise mavlink.MAVError("fast path is for MAVLink 2 only")
        plen = raw[1]
        if len(raw) != (25 if raw[2] & 1 else 12) + plen:  # a signature (checked by the link) follows the CRC
            raise mavlink.MAVError("invalid MAVLink message length")
        c = crc16(raw[1 : 10 + plen] + self._crc_extra)
        if raw[10 + plen] != (c & 0xFF) or raw[11 + plen] != (c >> 8):
            raise mavlink.MAVError("invalid MAVLink CRC")
        payload = raw[10 : 10 + plen]
        size = self._size
        if plen < size:
            payload = payload + bytes(size - plen)
        elif plen > size:
            payload = payload[:size]
        t = self._unpack(payload)
        m = self.cls(*[t[i] for i in self._orders])
        m._msgbuf = bytearray(raw)
        m._payload = raw[6 : 10 + plen]
        m._crc = c
        m._header = mavlink.MAVLink_header(
            raw[7] | (raw[8] << 8) | (raw[9] << 16), raw[2], raw[3], plen, raw[4], raw[5], raw[6]
        )
        return m


FAST_DECODE_IDS = (mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW)
FAST_DECODERS = {mid: FastDecoder(mavlink.mavlink_map[mid]) for mid in FAST_DECODE_IDS}
