"""Who a link hears and how much of them: its peers' addresses, the ground-station systems it learns, the budgets
that keep a flood from taking the loop's time, and the slots of the ground stations admitted by signature.  The
mixin ``Admission`` of ``autopilot.shared.link.UdpLink`` (its state is the link's; see ``UdpLink.__init__``).

**Peers.**  A link talks to fixed addresses, never to whoever sent last:

* pinned to ``remote`` (``remote`` given, ``learn_remote`` False): only that address is heard;
* learned once (``learn_remote``): the first address whose packet passes every check up to the IDs becomes
  the one peer and ``remote``; any other address is ``not_peer`` from then on;
* admitting (``admit=N``, the autopilot's ground-station link): ``remote`` is the default destination
  (e.g. 127.0.0.1:14550) and stays so; the addresses in ``peer_addrs`` are admitted from the start; without
  signing and without ``peer_addrs`` the first address that talks with a peer's IDs is admitted (with
  ``peer_addrs``, nobody else); with signing every address whose packet carries a valid signature is
  admitted, up to N in all (more are ``not_peer``).
  ``broadcast``/``send`` reach every admitted peer and ``remote``, each once.

**Ground-station systems.**  ``peers`` lists the source (sysid, compid) pairs taken.  With ``learn_gcs=N`` a packet
from another system is still taken if it is a HEARTBEAT of type MAV_TYPE_GCS that passes every other check (from
an admitted or admissible address): its system joins the peers with any component, up to N systems.  A refused
packet (``wrong_id``, ``not_peer``, ``unsigned`` or ``bad_signature``) whose IDs look like a ground station's
(``looks_like_gcs``) is counted per source in ``refused_gcs`` (at most ``REFUSED_GCS_KEYS`` sources, the rest
together as system and component -1) and handed once per (reason, system) to ``on_refused_gcs(reason, sysid,
compid, addr)`` (at most ``REFUSED_GCS_REPORTS`` calls), so the owner can say why.

**Floods.**  ``poll(handler, budget)`` feeds a datagram from an admitted address; those from every other address
share ``budget`` per poll and the rest of them are ``over_budget``, so a flood from elsewhere costs a bounded amount
of CPU and never makes the link drop a peer's datagram.  With ``peer_rate`` (datagrams per wall second, for each
admitted address, ``peer_burst`` at once) and ``others_rate`` (for all other addresses together) the budgets are per
time instead, token buckets refilled at each poll: a peer that holds the key but floods (a ground station sending
65,000 requests a second) gets its share checked and the rest read and dropped as ``over_budget``, so the control
loop keeps its time (the autopilot sets them per control period: ``autopilot.loop.common``).  A poll reads at most
``16 * budget`` datagrams (what is left waits in the socket for the next poll), and the socket asks for a 4 MiB
receive buffer (the kernel caps it at ``net.core.rmem_max``) so a flood queued ahead of the peer's datagrams does
not make the kernel drop them before they are read.

**Slots.**  With ``expire_s``, an address admitted by its signature (not a listed ``peer_addrs`` one, not the
pinned ``remote``) from which no HEARTBEAT has come for ``expire_s`` (MAVLink's heartbeat protocol: a system is
disconnected after about five missed 1 Hz heartbeats) loses its slot, at ``expire(now)`` or when a new signed
address finds every slot taken; ``on_expired(addr, silent_s)`` says so.  It is admitted again by its next signed
packet if a slot is free.

**Datagram boundaries.**  While the handler runs, ``rx_packet_index`` is the packet's place in its datagram (0 for
the first) and ``rx_more`` whether more bytes follow it; ``rx_datagrams`` numbers the datagram.  The autopilot's
lockstep schedule (``autopilot.schedule``) links a ground station's setpoints by them.
"""

from __future__ import annotations

import time

from autopilot.shared.mavlink import mavlink

_HEARTBEAT = mavlink.MAVLINK_MSG_ID_HEARTBEAT
_MAV_TYPE_GCS = mavlink.MAV_TYPE_GCS
GCS_COMPONENT = mavlink.MAV_COMP_ID_MISSIONPLANNER  # 190: the component QGroundControl, MAVSDK, the GCS script use
REFUSED_GCS_REPORTS = 8  # on_refused_gcs calls at most, per link (the packets are counted whatever their number)
REFUSED_GCS_KEYS = 64  # distinct (reason, sysid, compid) counted in refused_gcs; more share (reason, -1, -1)


def heartbeat_type(raw: bytes) -> int:
    """HEARTBEAT.type of a framed, CRC-checked MAVLink 2 HEARTBEAT packet: payload byte 4 (after the uint32
    custom_mode); MAVLink 2 trims trailing zero bytes, so a payload of 4 bytes or less has type 0."""
    return raw[10 + 4] if raw[1] > 4 else 0


def looks_like_gcs(raw: bytes, sysid: int, compid: int, gcs_systems=()) -> bool:
    """Whether a packet's IDs look like a ground station's: a MAV_TYPE_GCS HEARTBEAT, a system of ``gcs_systems``
    (255, 245) or component 190 (MAV_COMP_ID_MISSIONPLANNER, the ground stations' usual one)."""
    msgid = raw[7] | (raw[8] << 8) | (raw[9] << 16)
    if msgid == _HEARTBEAT and heartbeat_type(raw) == _MAV_TYPE_GCS:
        return True
    return sysid in gcs_systems or compid == GCS_COMPONENT


class Admission:
    """The admission, budget and slot rules of ``UdpLink`` (module docstring)."""

    def _refill(self) -> None:
        """The token buckets, refilled for the wall time since the last poll (capped at their bursts)."""
        now = time.perf_counter()
        dt = now - self._refilled
        self._refilled = now
        if self.peer_rate is not None:
            add, top = self.peer_rate * dt, self.peer_burst
            tokens = self._peer_tokens
            for addr, left in tokens.items():
                tokens[addr] = min(top, left + add)
        if self.others_rate is not None:
            self._others_tokens = min(self.others_burst, self._others_tokens + self.others_rate * dt)

    def expire(self, now: float | None = None) -> list:
        """Free the slots of the addresses admitted by signature that sent no HEARTBEAT for ``expire_s``
        (``now``: ``time.perf_counter()``); the (address, silent s) freed."""
        if self.expire_s is None or not self._signed_slots:
            return []
        now = time.perf_counter() if now is None else now
        gone = [(a, now - t) for a, t in self._signed_slots.items() if now - t > self.expire_s]
        for addr, silent in gone:
            del self._signed_slots[addr]
            self.admitted.remove(addr)
            self._admitted_set.discard(addr)
            self._peer_tokens.pop(addr, None)
            self.expired.append((f"{addr[0]}:{addr[1]}", round(silent, 3)))
            if self.on_expired is not None:
                self.on_expired(addr, silent)
        return gone

    def _admit(self, addr, signed: bool) -> bool:
        """Whether a packet with a peer's IDs from the new address ``addr`` may make it a peer."""
        if self.admit:
            # signed: any address, up to the bound; unsigned: the first one, unless the peers were listed
            if not (signed or not (self._learned or self._listed)):
                return False
            if len(self.admitted) >= self.admit and not (signed and self.expire()):
                return False
            if signed and self.expire_s is not None:
                self._signed_slots[addr] = time.perf_counter()
        elif not self.learn_remote or self._learned:
            return False
        self._learned = True
        self.admitted.append(addr)
        self._admitted_set.add(addr)
        if not self.admit:
            self.remote = addr
        return True

    def _learnable(self, raw: bytes, msgid: int, sysid: int) -> bool:
        """A new system's MAV_TYPE_GCS HEARTBEAT, while ``learn_gcs`` has room (never the vehicle's own system or
        the broadcast id 0)."""
        return (
            msgid == _HEARTBEAT
            and len(self.learned_systems) < self.learn_gcs
            and sysid not in (0, self.mav.srcSystem)
            and heartbeat_type(raw) == _MAV_TYPE_GCS
        )

    def _learn_system(self, sysid: int) -> None:
        self.learned_systems.append(sysid)
        self._any_comp = self._any_comp | {sysid}

    def _refused(self, reason: str, raw: bytes, sysid: int, compid: int, addr) -> None:
        """Count a refused packet that looks like a ground station's; report the first of each (reason, system)."""
        if not looks_like_gcs(raw, sysid, compid, self.gcs_systems):
            return
        key = (reason, sysid, compid)
        if key not in self.refused_gcs and len(self.refused_gcs) >= REFUSED_GCS_KEYS:
            key = (reason, -1, -1)  # a spoofer cycling through ids cannot grow the counter without bound
        self.refused_gcs[key] += 1
        report = (reason, sysid)
        if report in self._refusals_reported or len(self._refusals_reported) >= REFUSED_GCS_REPORTS:
            return
        self._refusals_reported.add(report)
        if self.on_refused_gcs is not None:
            self.on_refused_gcs(reason, sysid, compid, addr)
