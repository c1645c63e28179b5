"""Fast paths for the few MAVLink messages on the per-frame hot path, built from pymavlink's own tables.

pymavlink's generic ``pack``/``decode`` cost about 11-12 us each in Python; the lockstep loop sends and
receives a handful per frame.  These helpers use the same dialect data (the message class's
``unpacker`` struct, ``crc_extra``, field ``orders``) and the same CRC (fastcrc's MCRF4XX, what
pymavlink uses), and produce byte-identical packets (``tests/autopilot/shared/test_mavlink_units.py`` checks this
against ``msg.pack(mav)`` and ``mav.decode``).  Anything else goes through pymavlink unchanged.

``HotDecoder`` goes one step further for the two messages of a lockstep frame (``HOT_IDS``: ATTITUDE and
SERVO_OUTPUT_RAW): the payload's values as one tuple in wire order, no message object at all, for a link's
``on_hot`` callback (``autopilot.shared.link``; the link has framed and checked the packet before).
"""

from __future__ import annotations

from autopilot.shared.mavlink import OTHER_DIALECT_MESSAGES, all_dialect, mavlink


def _x25crc(data: bytes) -> int:
    return mavlink.x25crc(data).crc


try:
    import fastcrc

    # crc16(data) -> int: MAVLink's X.25 CRC is CRC-16/MCRF4XX (initial 0xFFFF, fastcrc's default for it)
    crc16 = fastcrc.crc16.mcrf4xx
except Exception:  # noqa: BLE001  (no fastcrc: use pymavlink's x25crc)
    crc16 = _x25crc


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
        mid = self.msgid
        self._ids = bytes((src_system, src_component, mid & 0xFF, (mid >> 8) & 0xFF, mid >> 16))
        self._signing = signing

    def __call__(self, seq: int, *values) -> bytes:
        return self.frame(seq, self._payload(*values))

    def frame(self, seq: int, payload: bytes) -> bytes:
        """The packet of a payload already packed in the class's struct layout (``cls.unpacker``; whole, or
        already trimmed): trimmed, framed, CRC'd and signed as ``__call__`` does."""
        p = payload.rstrip(b"\x00") or payload[:1]  # MAVLink 2 trims trailing zero bytes (keeps one)
        signing = self._signing
        # header after the start byte: len, incompat flags (1 = signed), compat flags, seq, sys, comp, msgid (3)
        body = bytes((len(p), 1 if signing else 0, 0, seq)) + self._ids + p
        c = crc16(body + self._crc_extra)
        packet = b"\xfd" + body + bytes((c & 0xFF, c >> 8))
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


class HotDecoder:
    """The payload of one message class as a tuple in wire order (``cls.ordered_fieldnames``), from a packet the
    link has framed and CRC-checked: MAVLink 2 trims trailing zero bytes, so a short payload is zero-padded as
    pymavlink does, and a longer one (a newer dialect's extensions) is read up to the known fields.  No arrays or
    strings (those go through pymavlink).  ``index(name)``: where a field sits in the tuple."""

    def __init__(self, cls):
        if sum(cls.lengths) != len(cls.lengths):
            raise ValueError(f"{cls.msgname} has arrays: use pymavlink's decode")
        self.cls = cls
        self.msgid = cls.id if isinstance(getattr(cls, "id", None), int) else cls.msgid
        self.crc_extra = bytes([cls.crc_extra])
        self._unpack = cls.unpacker.unpack
        self._unpack_from = cls.unpacker.unpack_from
        self._size = cls.unpacker.size

    def index(self, name: str) -> int:
        return self.cls.ordered_fieldnames.index(name)

    def __call__(self, raw: bytes, plen: int) -> tuple:
        size = self._size
        if plen >= size:
            return self._unpack_from(raw, 10)
        return self._unpack(raw[10 : 10 + plen] + bytes(size - plen))


FAST_DECODE_IDS = (mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW)
FAST_DECODERS = {mid: FastDecoder(mavlink.mavlink_map[mid]) for mid in FAST_DECODE_IDS}
# ArduPilot's AOA_SSA (ardupilotmega dialect, id 11020: time_usec, AOA and SSA in deg): the sideslip a square MIMO
# plant's SITL sends beside ATTITUDE (docs/spec.md, "Square MIMO CL-SAC"); decoded here, since the links parse the
# common dialect.  Its class is pymavlink's ``all`` dialect's, loaded at the first use (``AOA_SSA``, or the first
# AOA_SSA a link decodes: ``fast_decoder``), not by every process of a flight (about 35 ms each).
AOA_SSA_ID = next(mid for mid, (name, _extra) in OTHER_DIALECT_MESSAGES.items() if name == "AOA_SSA")
_LAZY_CLASSES = {AOA_SSA_ID: "MAVLink_aoa_ssa_message"}  # msgid -> its class in the all dialect


def _lazy_class(msgid: int):
    """The class of a lazily loaded message (``_LAZY_CLASSES``), its fast decoder registered in ``FAST_DECODERS``."""
    cls = getattr(all_dialect(), _LAZY_CLASSES[msgid])
    if msgid not in FAST_DECODERS:
        FAST_DECODERS[msgid] = FastDecoder(cls)
    return cls


def fast_decoder(msgid: int):
    """``FAST_DECODERS``' decoder of ``msgid`` (None: none, decode with pymavlink), built for a lazily loaded class
    (AOA_SSA) at its first message."""
    fast = FAST_DECODERS.get(msgid)
    if fast is None and msgid in _LAZY_CLASSES:
        _lazy_class(msgid)
        fast = FAST_DECODERS[msgid]
    return fast


def __getattr__(name: str):
    if name == "AOA_SSA":  # the class, loaded at the first use (module docstring)
        return _lazy_class(AOA_SSA_ID)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


HOT_IDS = FAST_DECODE_IDS
HOT_DECODERS = {mid: HotDecoder(mavlink.mavlink_map[mid]) for mid in HOT_IDS}
