"""One MAVLink link over a plain non-blocking UDP socket (no mavutil polling in the hot path).

Receiving: each datagram is framed by hand (MAVLink 2 header, length, signature) and every packet is checked
in this order before anything is decoded: framing, message id known, CRC, signature (when signing is on),
source system:component, source address (the pinned or admitted peers), message id taken.  Only accepted
packets are decoded and handed to the owner, which may still reject one (``reject(reason)``).

**Exact counters.**  Every datagram read is counted exactly once: in ``rx_accepted`` if at least one of its
packets was accepted, otherwise in ``rejected`` under the reason of its first packet that failed:

    empty          a 0-byte datagram
    bad_magic      the datagram (or its remainder) does not start with the MAVLink 2 start byte 0xFD
    mavlink1       a MAVLink 1 packet (0xFE): rejected on every link
    truncated      a packet shorter than its header says
    unknown_msg    message id in none of pymavlink's dialects (``all``: common plus the development and vendor
                   sets; its CRC cannot be checked)
    bad_crc        CRC mismatch
    unsigned       signing is on and the packet carries no signature
    bad_signature  signing is on and the signature does not match the key
    replay         signing is on and the timestamp is not newer than the stream's last (or over a minute old)
    wrong_id       source (sysid, compid) not one this link talks to (a link that learns ground stations,
                   ``learn_gcs``, also takes a new system whose HEARTBEAT says MAV_TYPE_GCS)
    not_peer       the right IDs from an address that is not this link's peer
    ignored_msg    a valid message this link does not use
    decode_error   the payload does not decode
    over_budget    a datagram from a non-admitted address beyond the per-poll budget for such addresses: read and
                   dropped unchecked, so a flood cannot stall the loop (an admitted peer's datagrams are never
                   over_budget: see ``poll``)
    (owner's)      reasons the owner gives with ``reject`` (nonfinite_attitude, bad_pwm, ...)

so ``rx_datagrams == rx_accepted + sum(rejected.values())`` always holds.

**Peers, ground-station systems, floods, slots, datagram boundaries**: ``autopilot.shared.admission``, whose
``Admission`` this class inherits.

**The hot path.**  ``on_hot(msgid, callback)`` takes the accepted packets of one of ``fastmav.HOT_IDS`` (ATTITUDE,
SERVO_OUTPUT_RAW: the two messages of a lockstep frame) as ``callback(t_rx, values)``, the payload as a tuple in
wire order (``fastmav.HotDecoder``), without building a pymavlink message.  It serves only the usual datagram:
one whole MAVLink 2 packet of that id with a good CRC (and, with signing on, a good and fresh signature) from an
admitted address and a peer's IDs; it counts, tlogs and takes the owner's ``reject`` exactly as the checks below
do.  Anything else (several packets, a bad CRC, an unsigned or forged packet, a new address or system) has
changed nothing yet when the hot path lets go, and goes through the checks below, which count it.

Sending: ``send(msg)`` packs with this link's own sequence counter and source IDs (signed when signing is on).
Every packet sent or accepted is written to the tlog (if one is attached) with the raw bytes.  A send error
that means the peer cannot be reached at all (no route, bad address) raises :class:`PeerUnreachable`; a
refused or dropped datagram (peer not started yet, buffer full) is counted in ``tx_errors``.
"""

from __future__ import annotations

import errno
import socket
import struct
import time
from collections import Counter

from autopilot.shared.admission import (  # noqa: F401  (re-exported: part of this module's API)
    _HEARTBEAT,
    GCS_COMPONENT,
    REFUSED_GCS_KEYS,
    REFUSED_GCS_REPORTS,
    Admission,
    heartbeat_type,
    looks_like_gcs,
)
from autopilot.shared.fastmav import FAST_DECODERS, HOT_DECODERS, FastPacker, crc16, fast_decoder
from autopilot.shared.mavlink import OTHER_DIALECT_MESSAGES, all_dialect, mavlink

# CRC extras of every message pymavlink knows, so a valid message of another dialect, e.g. the vehicle's CURRENT_MODE
# (436, development), is a checked ``ignored_msg``, not unknown: common's and the other dialects' messages a flight
# exchanges (``OTHER_DIALECT_MESSAGES``) at once, the rest of pymavlink's ``all`` dialect at the first message of it
# (``_other_extra``: the same extras, without loading that dialect in every process)
_CRC_EXTRA = {mid: bytes([cls.crc_extra]) for mid, cls in mavlink.mavlink_map.items()}
_CRC_EXTRA.update({mid: bytes([extra]) for mid, (_name_, extra) in OTHER_DIALECT_MESSAGES.items()})
_ALL_EXTRAS_LOADED = [False]


def _other_extra(msgid: int) -> bytes | None:
    """The CRC extra of a message not in ``_CRC_EXTRA`` yet: pymavlink's ``all`` dialect's (loaded once), else None."""
    if not _ALL_EXTRAS_LOADED[0]:
        _ALL_EXTRAS_LOADED[0] = True
        _CRC_EXTRA.update({mid: bytes([cls.crc_extra]) for mid, cls in all_dialect().mavlink_map.items()})
    return _CRC_EXTRA.get(msgid)


REJECT_REASONS = (
    "empty",
    "bad_magic",
    "mavlink1",
    "truncated",
    "unknown_msg",
    "bad_crc",
    "unsigned",
    "bad_signature",
    "replay",
    "wrong_id",
    "not_peer",
    "ignored_msg",
    "decode_error",
    "over_budget",
)
# sendto errors after which nothing will ever arrive: fatal (the others are counted and the link goes on)
_FATAL_SEND_ERRNOS = (errno.EHOSTUNREACH, errno.ENETUNREACH, errno.EADDRNOTAVAIL, errno.EAFNOSUPPORT, errno.EINVAL)
_monotonic = time.monotonic
_HEADER = struct.Struct("<BBBBBBBHB").unpack_from  # MAVLink 2: magic, len, incompat, compat, seq, sys, comp, msgid
ANY_COMPONENT = None  # a peer (sysid, ANY_COMPONENT) accepts that system with any component


class LinkError(OSError):
    """A link that cannot work: an unresolvable address (one line naming the link and the address)."""


class PeerUnreachable(LinkError):
    """A send failed in a way that will not heal (no route to the peer, unusable address)."""


def resolve(host_port, what: str) -> tuple[str, int]:
    """``(host, port)`` with the host resolved to an IPv4 address; :class:`LinkError` if it cannot be."""
    host, port = host_port
    try:
        infos = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
    except (socket.gaierror, UnicodeError) as exc:
        raise LinkError(f"{what} {host}:{port}: cannot resolve the host ({exc})") from None
    return infos[0][4][0], int(port)


class SendClock:
    """When a process last sent anything, and the longest time it sent nothing, on ``time.monotonic()``
    (CLOCK_MONOTONIC: one clock for every process of the machine, so the launcher can compare them).

    Shared by the links of one process (``UdpLink(send_clock=...)``): a process that is stopped (SIGSTOP),
    starved or hung sends on none of them, and its own clock shows the gap when it runs again.  That is the
    evidence of who stopped sending first (docs/spec.md, "Honest outcomes")."""

    __slots__ = ("last", "first", "sends", "gap_s", "gap_from", "ended")

    def __init__(self):
        self.last: float | None = None  # monotonic time of the last send attempt
        self.first: float | None = None
        self.sends = 0
        self.gap_s = 0.0  # the longest interval between two sends ...
        self.gap_from: float | None = None  # ... and when it began (monotonic)
        self.ended: float | None = None  # when the process's run loop ended (``end``)

    def tick(self, now: float) -> None:
        last = self.last
        if last is None:
            self.first = now
        elif now - last > self.gap_s:
            self.gap_s, self.gap_from = now - last, last
        self.last = now
        self.sends += 1

    def end(self, now: float) -> None:
        """The run loop ended: the time since the last send counts as a gap too (a process stopped until its end
        may never send again)."""
        self.ended = now
        if self.last is not None and now - self.last > self.gap_s:
            self.gap_s, self.gap_from = now - self.last, self.last

    def summary(self) -> dict:
        return {
            "ended_mono": self.ended,
            "first_mono": self.first,
            "last_mono": self.last,
            "sends": self.sends,
            "longest_gap_s": self.gap_s,
            "longest_gap_from_mono": self.gap_from,
            "stats_mono": time.monotonic(),  # when this was taken: the clock of the process's end
        }


class UdpLink(Admission):
    """A MAVLink endpoint on one UDP socket.

    ``bind``: local (host, port), port 0 for an ephemeral one.  ``remote``: where to send (None until a peer
    talks to us when ``learn_remote``).  ``peers``: accepted source (sysid, compid) pairs; compid
    ``ANY_COMPONENT`` (None) accepts any component of that system.  ``msgids``: accepted message ids (others
    are counted as ``ignored_msg`` without decoding).  ``admit``, ``peer_addrs``: see the module docstring.
    ``signing``: an ``autopilot.shared.signing.Signing``: everything sent is signed and everything received
    must be signed with the same key.  ``learn_gcs``: take up to that many more systems from their MAV_TYPE_GCS
    HEARTBEAT; ``gcs_systems``: the system ids that look like a ground station's in a refused packet (both: see
    the module docstring, "Ground-station systems").
    """

    def __init__(
        self,
        name: str,
        src: tuple[int, int],
        bind: tuple[str, int],
        remote: tuple[str, int] | None,
        peers,
        msgids,
        *,
        learn_remote: bool = False,
        admit: int = 0,
        peer_addrs=(),
        signing=None,
        tlog=None,
        rcvbuf: int = 4 << 20,
        send_clock: SendClock | None = None,
        learn_gcs: int = 0,
        gcs_systems=(),
        peer_rate: float | None = None,
        peer_burst: float = 64.0,
        others_rate: float | None = None,
        others_burst: float = 256.0,
        expire_s: float | None = None,
    ):
        self.name = name
        self.send_clock = send_clock if send_clock is not None else SendClock()
        self.signing = signing
        self.mav = mavlink.MAVLink(None, src[0], src[1])
        if signing is not None:
            self.mav.signing.secret_key = signing.key
            self.mav.signing.link_id = signing.link_id
            self.mav.signing.sign_outgoing = True
        self._decoder = mavlink.MAVLink(None, src[0], src[1])  # never checks signatures itself: we do
        self.remote = resolve(remote, f"{name} link: peer") if remote is not None else None
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:  # a deep queue, so a flood queued ahead of the peer's datagrams does not make the kernel drop them
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)  # Linux: capped at net.core.rmem_max
        except OSError:
            pass
        self.sock.bind(resolve(bind, f"{name} link: local address"))
        self.sock.setblocking(False)
        self.local = self.sock.getsockname()
        self.learn_remote = learn_remote
        self.admit = int(admit)
        self.peers = frozenset(tuple(p) for p in peers)
        self._any_comp = frozenset(s for s, c in self.peers if c is ANY_COMPONENT)
        self.msgids = frozenset(msgids)
        self.tlog = tlog
        fixed = [resolve(a, f"{name} link: peer") for a in peer_addrs]
        if not learn_remote and not admit and self.remote is not None:
            fixed.append(self.remote)  # pinned to the one address we talk to
        self.admitted: list = list(dict.fromkeys(fixed))  # addresses we accept packets from
        self._admitted_set = set(self.admitted)
        self._learned = False
        self._listed = bool(peer_addrs)
        self.rx_datagrams = 0
        self.rx_accepted = 0  # datagrams with at least one accepted packet
        self.rx_packets = 0  # packets accepted and decoded
        self.tx_packets = 0
        self.tx_errors = 0
        self.rx_by_type: Counter = Counter()
        self.tx_by_type: Counter = Counter()
        self.rejected: Counter = Counter()
        self.learn_gcs = int(learn_gcs)
        self.gcs_systems = frozenset(gcs_systems)
        self.learned_systems: list = []  # systems taken from their MAV_TYPE_GCS HEARTBEAT (learn_gcs)
        self.refused_gcs: Counter = Counter()  # (reason, sysid, compid) -> refused packets that look like a GCS's
        self._refusals_reported: set = set()  # (reason, sysid) handed to on_refused_gcs
        self.on_refused_gcs = None  # callable(reason, sysid, compid, addr), once per (reason, system)
        self.last_rx_wall = 0.0  # perf_counter of the last accepted packet
        self.peer_addr = None  # address of the last accepted packet
        self.rx_packet_index = 0  # while the handler runs: the packet's place in its datagram (0: the first) ...
        self.rx_more = False  # ... and whether more bytes follow it there (see "Datagram boundaries")
        # budgets per wall time (None: per poll, the peers' unlimited); see "Floods"
        self.peer_rate = peer_rate
        self.peer_burst = float(peer_burst)
        self.others_rate = others_rate
        self.others_burst = float(others_burst)
        self._peer_tokens: dict = {}  # admitted address -> tokens left
        self._others_tokens = float(others_burst)
        self._refilled = time.perf_counter()
        self.over_budget_peers: Counter = Counter()  # admitted address -> its datagrams dropped over its budget
        # slots of the addresses admitted by signature: address -> perf_counter of its admission or last HEARTBEAT
        self.expire_s = expire_s
        self._signed_slots: dict = {}
        self.expired: list = []  # (address, silent s) of each slot that expired
        self.on_expired = None  # callable(addr, silent_s)
        self._verdict = None  # the owner's rejection of the packet being handled
        self._hot: dict = {}  # msgid -> (HotDecoder, CRC extra, callback(t_rx, values)): see ``on_hot``

    # ------------------------------------------------------------------ send
    def pack(self, msg) -> bytes:
        mav = self.mav
        if self.signing is not None:
            mav.signing.timestamp = self.signing.next_stamp()
        buf = msg.pack(mav)
        mav.seq = (mav.seq + 1) & 0xFF
        return buf

    def _targets(self) -> list:
        if not self.admit:
            return [self.remote] if self.remote is not None else []
        return list(dict.fromkeys([*self.admitted, *([self.remote] if self.remote is not None else [])]))

    def send(self, msg) -> bytes | None:
        """Pack and send one message to the peer (an admitting link: to every admitted peer and ``remote``);
        returns the raw bytes (None if there is no peer yet)."""
        targets = self._targets()
        if not targets:
            return None
        buf = self.pack(msg)
        self._sendto(targets, buf, (msg.get_msgId(),), (buf,))
        return buf

    def send_fast(self, packer: FastPacker, *wire_values) -> bytes | None:
        """``send`` for a message packed by a fast packer (``wire_values`` in struct order): the same bytes, sequence
        number, counters and tlog as ``send`` of the pymavlink message; None if there is no peer yet."""
        targets = self._targets()
        if not targets:
            return None
        buf = self.pack_fast(packer, *wire_values)
        self._sendto(targets, buf, (packer.msgid,), (buf,))
        return buf

    def fast_packer(self, cls) -> FastPacker:
        """A byte-identical fast encoder for a hot message class (see ``autopilot.shared.fastmav``)."""
        return FastPacker(cls, self.mav.srcSystem, self.mav.srcComponent, self.signing)

    def pack_fast(self, packer: FastPacker, *wire_values) -> bytes:
        """Encode with a fast packer and this link's sequence number (``wire_values`` in struct order)."""
        mav = self.mav
        buf = packer(mav.seq, *wire_values)
        mav.seq = (mav.seq + 1) & 0xFF
        return buf

    def frame_fast(self, packer: FastPacker, payload: bytes) -> bytes:
        """``pack_fast`` for a payload already in the struct layout (``FastPacker.frame``)."""
        mav = self.mav
        buf = packer.frame(mav.seq, payload)
        mav.seq = (mav.seq + 1) & 0xFF
        return buf

    def send_batch(self, bufs: list, msgids: list) -> bool:
        """Send several packets in one datagram (a UDP MAVLink stream may carry several) to the peer (an
        admitting link: to every admitted peer and ``remote``); tlog each one."""
        targets = self._targets()
        return bool(targets) and self._sendto(targets, b"".join(bufs), msgids, bufs)

    def broadcast(self, bufs: list, msgids: list) -> bool:
        """One datagram of ``bufs`` to every admitted peer plus the default ``remote``, each address once."""
        targets = list(dict.fromkeys([*self.admitted, *([self.remote] if self.remote is not None else [])]))
        return bool(targets) and self._sendto(targets, b"".join(bufs), msgids, bufs)

    def send_raw(self, buf: bytes, msgid: int | None = None) -> bool:
        """Send one packet this link packed to the peer; counted and tlogged.  False if there is no peer yet or
        the datagram was refused (counted in ``tx_errors``)."""
        if self.remote is None:
            return False
        self.send_clock.tick(_monotonic())  # an attempt counts: the process is alive and sending
        return self._count_sent(buf, msgid, self.send_now(buf))

    def send_now(self, buf: bytes) -> bool | None:
        """``send_raw`` in two halves, for the lockstep answer: the ``sendto`` now (None: no peer yet, False:
        refused, counted in ``tx_errors``), ``account_sent`` right after, once the peer has it: the send clock,
        the counters and the tlog, as ``send_raw`` keeps them."""
        remote = self.remote
        if remote is None:
            return None
        try:
            self.sock.sendto(buf, remote)
        except OSError as exc:
            self._send_failed(exc, remote, 1)
            return False
        return True

    def account_sent(self, buf: bytes, msgid: int | None, sent: bool | None) -> bool:
        """The second half of ``send_raw`` after ``send_now`` (``sent``: what it returned); whether it went."""
        if sent is None:
            return False
        self.send_clock.tick(_monotonic())  # an attempt counts: the process is alive and sending
        return self._count_sent(buf, msgid, sent)

    def _count_sent(self, buf: bytes, msgid: int | None, sent: bool) -> bool:
        if not sent:
            return False
        self.tx_packets += 1
        if msgid is not None:
            self.tx_by_type[msgid] += 1
        if self.tlog is not None:
            self.tlog.write(buf)
        return True

    def resend(self, buf: bytes, msgid: int | None = None) -> bool:
        """Send again a packet this link sent before (lockstep recovery of a lost datagram).  With signing on it is
        signed again with a fresh timestamp, else the peer would rightly reject it as a ``replay``."""
        if self.signing is not None and len(buf) > 13 and buf[2] & 1:
            buf = self.signing.resign(buf)
        return self.send_raw(buf, msgid)

    def _sendto(self, targets, data: bytes, msgids, bufs) -> bool:
        ok = False
        self.send_clock.tick(_monotonic())  # an attempt counts: the process is alive and sending
        for addr in targets:
            try:
                self.sock.sendto(data, addr)
            except OSError as exc:
                self._send_failed(exc, addr, len(bufs))
                continue
            ok = True
            self.tx_packets += len(bufs)
            for mid in msgids:
                self.tx_by_type[mid] += 1
        if ok and self.tlog is not None:
            for b in bufs:
                self.tlog.write(b)
        return ok

    def _send_failed(self, exc: OSError, addr, packets: int) -> None:
        """A sendto that failed: :class:`PeerUnreachable` if it never will work, else ``packets`` send errors."""
        if exc.errno in _FATAL_SEND_ERRNOS:
            raise PeerUnreachable(f"{self.name} link: cannot send to {addr[0]}:{addr[1]}: {exc.strerror}") from None
        # ECONNREFUSED from a previous ICMP port-unreachable (peer not up yet), ENOBUFS: count, go on.
        self.tx_errors += packets

    # --------------------------------------------------------------- receive
    def on_hot(self, msgid: int, callback) -> None:
        """Hand the accepted packets of ``msgid`` (one of ``fastmav.HOT_IDS``, taken by this link) to
        ``callback(t_rx, values)`` instead of the poll's handler: ``values`` is the payload in wire order
        (``HOT_DECODERS[msgid].index(name)`` says where a field is).  Only the usual datagram goes this way (see
        the module docstring, "The hot path"); anything else still reaches the handler as a message."""
        dec = HOT_DECODERS.get(msgid)
        if dec is None or msgid not in self.msgids:
            raise ValueError(f"{self.name} link: message {msgid} has no hot path here")
        self._hot[msgid] = (dec, dec.crc_extra, callback)

    def poll(self, handler, budget: int = 256, most: int | None = None) -> int:
        """Read the datagrams waiting, calling ``handler(msg, t_rx)`` for each accepted message; returns the number
        of datagrams read.

        A datagram from an admitted address (pinned, learned or admitted peer) is fed, within its own budget
        when ``peer_rate`` is set.  Datagrams from any other address share ``budget`` per poll (or the
        ``others_rate`` bucket): that many are fed (checked, counted under their reason), the rest are read and
        counted ``over_budget``, so a flood can neither stall the loop nor crowd out the peer.  At most ``16 *
        budget`` datagrams are read per poll (``most``: at most that many, e.g. 1 for the lockstep SITL, which goes
        on with the answer it waited for without first finding the socket empty); the rest wait in the socket for
        the next one."""
        sock = self.sock
        admitted = self._admitted_set  # updated in place when an address is learned or admitted
        n = 0
        others = 0  # datagrams from non-admitted addresses fed in this poll
        cap = 16 * budget if most is None else min(16 * budget, most)
        timed = self.peer_rate is not None or self.others_rate is not None
        if timed:
            self._refill()
            tokens = self._peer_tokens
            limit_peers = self.peer_rate is not None
            if self.others_rate is not None:
                budget = min(budget, int(self._others_tokens))
        while n < cap:
            try:
                data, addr = sock.recvfrom(4096)
            except BlockingIOError:
                break
            except OSError as exc:  # ECONNREFUSED after an ICMP error on a sendto: not data, keep going
                if exc.errno in (errno.ECONNREFUSED, errno.ECONNRESET, errno.EHOSTUNREACH, errno.ENETUNREACH):
                    continue
                raise
            n += 1
            if addr not in admitted:
                if others >= budget:
                    self.rx_datagrams += 1
                    self.rejected["over_budget"] += 1
                    continue
                others += 1
            elif timed and limit_peers:
                left = tokens.get(addr, self.peer_burst)
                if left < 1.0:
                    self.rx_datagrams += 1
                    self.rejected["over_budget"] += 1
                    self.over_budget_peers[addr] += 1
                    continue
                tokens[addr] = left - 1.0
            self.feed(data, addr, handler)
        if timed and self.others_rate is not None:
            self._others_tokens -= others
        return n

    def reject(self, reason: str) -> None:
        """Called by the owner's handler: the packet being handled is rejected for ``reason``."""
        if self._verdict is None:
            self._verdict = reason

    def feed(self, data: bytes, addr, handler) -> None:
        """Frame, check and decode one datagram; count it once (``rx_accepted`` or one reason)."""
        t_rx = time.perf_counter()
        self.rx_datagrams += 1
        if self._hot and self._feed_hot(data, addr, t_rx):
            return
        end = len(data)
        reason = None if end else "empty"
        accepted = False
        signing = self.signing
        slots = self._signed_slots
        i = 0
        index = -1
        while i < end:
            index += 1
            magic = data[i]
            if magic != 0xFD:
                reason = reason or ("mavlink1" if magic == 0xFE else "bad_magic")
                break
            if end - i < 12:
                reason = reason or "truncated"
                break
            plen = data[i + 1]
            signed = data[i + 2] & 1
            total = 12 + plen + (13 if signed else 0)
            if end - i < total:
                reason = reason or "truncated"
                break
            j = i
            i += total
            msgid = data[j + 7] | (data[j + 8] << 8) | (data[j + 9] << 16)
            extra = _CRC_EXTRA.get(msgid)
            if extra is None:
                extra = _other_extra(msgid)
            if extra is None:
                reason = reason or "unknown_msg"
                continue
            c = crc16(data[j + 1 : j + 10 + plen] + extra)
            if data[j + 10 + plen] != (c & 0xFF) or data[j + 11 + plen] != (c >> 8):
                reason = reason or "bad_crc"
                continue
            raw = data[j:i]
            sysid = data[j + 5]
            compid = data[j + 6]
            if signing is not None:
                why = signing.check(raw, sysid, compid) if signed else "unsigned"
                if why is not None:
                    if why != "replay":  # a ground station without the key (a replay is nobody's mistake)
                        self._refused(why, raw, sysid, compid, addr)
                    reason = reason or why
                    continue
            learn = False
            if (sysid, compid) not in self.peers and sysid not in self._any_comp:
                learn = self.learn_gcs and self._learnable(raw, msgid, sysid)
                if not learn:
                    self._refused("wrong_id", raw, sysid, compid, addr)
                    reason = reason or "wrong_id"
                    continue
            if addr not in self._admitted_set and not self._admit(addr, signing is not None):
                self._refused("not_peer", raw, sysid, compid, addr)
                reason = reason or "not_peer"
                continue
            if learn:
                self._learn_system(sysid)
            if msgid not in self.msgids:
                reason = reason or "ignored_msg"
                continue
            try:
                fast = FAST_DECODERS.get(msgid) or fast_decoder(msgid)
                msg = fast(raw) if fast is not None else self._decoder.decode(bytearray(raw))
            except Exception:  # noqa: BLE001  (any decoder failure is a rejected packet, never a crash)
                reason = reason or "decode_error"
                continue
            self.last_rx_wall = t_rx
            self.peer_addr = addr
            if slots and msgid == _HEARTBEAT and addr in slots:
                slots[addr] = t_rx  # a signed station's slot lives on its heartbeats
            if self.tlog is not None:
                self.tlog.write(raw)
            self._verdict = None
            self.rx_packet_index = index
            self.rx_more = i < end
            handler(msg, t_rx)
            if self._verdict is not None:
                reason = reason or self._verdict
                continue
            accepted = True
            self.rx_packets += 1
            self.rx_by_type[msgid] += 1
        if accepted:
            self.rx_accepted += 1
        else:
            self.rejected[reason] += 1

    def _feed_hot(self, data: bytes, addr, t_rx: float) -> bool:
        """The hot path (module docstring): True if ``data`` was one packet of a hot id that passed every check
        and was handed to its callback (and counted); False, with nothing changed, for anything else."""
        end = len(data)
        if end < 12:
            return False
        magic, plen, flags, _compat, _seq, sysid, compid, mid16, mid8 = _HEADER(data)
        signed = flags & 1
        if magic != 0xFD or end != 12 + plen + (13 if signed else 0):
            return False  # not MAVLink 2, several packets, or a truncated one
        hot = self._hot.get(mid16 | (mid8 << 16))
        if hot is None or addr not in self._admitted_set:
            return False
        if (sysid, compid) not in self.peers and sysid not in self._any_comp:
            return False
        dec, extra, callback = hot
        c = crc16(data[1 : 10 + plen] + extra)
        if data[10 + plen] != (c & 0xFF) or data[11 + plen] != (c >> 8):
            return False
        signing = self.signing
        if signing is not None and (not signed or signing.check(data, sysid, compid) is not None):
            return False  # Signing.check changes nothing on a refusal: the checks below give the same verdict
        values = dec(data, plen)
        self.last_rx_wall = t_rx
        self.peer_addr = addr
        if self.tlog is not None:
            self.tlog.write(data)
        self._verdict = None
        callback(t_rx, values)
        if self._verdict is not None:
            self.rejected[self._verdict] += 1
            return True
        self.rx_packets += 1
        self.rx_by_type[dec.msgid] += 1
        self.rx_accepted += 1
        return True

    # ----------------------------------------------------------------- misc
    def fileno(self) -> int:
        return self.sock.fileno()

    def close(self) -> None:
        self.sock.close()

    def counters(self) -> dict:
        return {
            "rx_datagrams": self.rx_datagrams,
            "rx_accepted": self.rx_accepted,
            "rx_packets": self.rx_packets,
            "tx_packets": self.tx_packets,
            "tx_errors": self.tx_errors,
            # monotonic time of the last packet accepted from the peer (perf_counter is CLOCK_MONOTONIC on Linux)
            "last_rx_mono": self.last_rx_wall if self.rx_accepted else None,
            "admitted": [f"{a[0]}:{a[1]}" for a in self.admitted],
            **({"learned_gcs_systems": list(self.learned_systems)} if self.learn_gcs else {}),
            **({"expired": list(self.expired)} if self.expired else {}),
            **(
                {"over_budget_peers": {f"{a[0]}:{a[1]}": v for a, v in self.over_budget_peers.items()}}
                if self.over_budget_peers
                else {}
            ),
            **(
                {"refused_gcs": {f"{r} {s}:{c}": n for (r, s, c), n in sorted(self.refused_gcs.items())}}
                if self.refused_gcs
                else {}
            ),
            "rx_by_type": {_name(k): v for k, v in sorted(self.rx_by_type.items())},
            "tx_by_type": {_name(k): v for k, v in sorted(self.tx_by_type.items())},
            # the link's own reasons first, then those the owner adds (nonfinite_attitude, bad_pwm, ...)
            "rejected": {
                **{r: self.rejected[r] for r in REJECT_REASONS if self.rejected.get(r)},
                **{r: v for r, v in sorted(self.rejected.items()) if r not in REJECT_REASONS and v},
            },
        }


def _name(msgid: int) -> str:
    cls = mavlink.mavlink_map.get(msgid)
    if cls is not None:
        return cls.msgname
    if msgid in OTHER_DIALECT_MESSAGES:
        return OTHER_DIALECT_MESSAGES[msgid][0]
    cls = all_dialect().mavlink_map.get(msgid)
    return cls.msgname if cls is not None else str(msgid)


def format_counters(name: str, c: dict, extra: dict | None = None) -> str:
    """One line: ``name: received N messages (ATTITUDE=.., ...) in D datagrams; sent N (...); rejected: ...``.

    Messages and datagrams differ: a peer may pack several messages into one datagram (N > D), and a rejected
    datagram carries none (N < D)."""
    rx = ", ".join(f"{k}={v}" for k, v in c["rx_by_type"].items())
    tx = ", ".join(f"{k}={v}" for k, v in c["tx_by_type"].items())
    rej = ", ".join(f"{k}={v}" for k, v in c["rejected"].items()) or "none"
    s = (
        f"{name}: received {c['rx_packets']} messages ({rx}) in {c['rx_datagrams']} datagrams; "
        f"sent {c['tx_packets']} messages ({tx})"
        f"{'; send errors ' + str(c['tx_errors']) if c['tx_errors'] else ''}; rejected: {rej}"
    )
    if extra:
        s += "; " + ", ".join(f"{k}={v}" for k, v in extra.items())
    return s
