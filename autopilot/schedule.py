"""A ground station's lockstep schedule that no lost datagram can change: which scheduled setpoints are taken.

In lockstep the autopilot flies frame k only once a ground station has scheduled setpoints up to t_k (pacing,
docs/spec.md, section 4).  If the horizon moved with every setpoint that arrived, a lost one (the kernel drops
datagrams when a flood fills the socket) would leave a hole: the frames after it would fly the point before it,
and a lost last point would leave the run waiting for ever.  So the horizon moves only over points known to be
contiguous with what the autopilot holds, and the ground station sends again what was lost:

* **Linked datagrams** (``tools.gcs``): the schedule goes out in datagrams whose first setpoint is one the
  autopilot already holds (the last point of the datagram before, or for the first datagram the schedule's first
  point, at or before the frame waiting) followed by the next points in order.  UDP delivers a datagram whole or
  not at all, so a datagram whose first point is at or before what is held (the newest linked point H, or, before
  any, the frame the autopilot waits at) continues the schedule without a gap: its points after H are taken and H
  moves to its last.  A datagram whose first point is after H follows a lost one: it is not taken (counted
  ``setpoints_unlinked``); points at or before H are copies of points held (``setpoints_held``, never pushed again:
  a copy arriving late would bring back a point already passed).
* **Resent on evidence** (``tools.gcs``): while it waits for the schedule, the lockstep autopilot sends SYSTEM_TIME
  (20 Hz of wall time) with ``time_boot_ms`` the frame waiting and ``time_unix_usec`` the wall time of its last
  read of the link.  A ground station that had sent a point covering that frame before that read knows the
  autopilot lacks it and sends its schedule again, from the point in force at the last frame it knows was flown.

A station that has never sent a linked datagram of several points and sends one setpoint per datagram (a
third-party scheduler) moves the horizon as before, point by point.  Pure: no I/O, no clock.
"""

from __future__ import annotations

from dataclasses import dataclass

NEW = "new"  # push it: the horizon moves to it (a plain scheduler's: to the newest of its points)
HELD = "held"  # a copy of a point held: drop it
UNLINKED = "unlinked"  # after a lost datagram: drop it (it will be sent again)


@dataclass
class _Source:
    horizon_us: float | None = None  # the newest point taken in order (H)
    datagram: int = -1  # the datagram being read
    linked: bool = False  # whether it continues the schedule
    plain: bool = False  # this datagram is one setpoint from a station that never linked several: taken as it is
    chained: bool = False  # the station sends linked datagrams of several points: single ones must link too


class ScheduleChain:
    """``take(source, datagram, index, more, t_us, frontier_us)`` -> NEW, HELD or UNLINKED for one scheduled
    setpoint: ``source`` its sender (system, component), ``datagram`` a number unique to its datagram, ``index`` its
    place there (0 first) and ``more`` whether packets follow it there (``UdpLink.rx_packet_index``, ``rx_more``),
    ``t_us`` its time, ``frontier_us`` the frame the autopilot waits at or flew last (None before the first)."""

    def __init__(self):
        self.sources: dict = {}

    def horizon_us(self, source) -> float | None:
        s = self.sources.get(source)
        return None if s is None else s.horizon_us

    def take(self, source, datagram: int, index: int, more: bool, t_us: float, frontier_us: float | None) -> str:
        s = self.sources.get(source)
        if s is None:
            s = self.sources[source] = _Source()
        if datagram != s.datagram:
            s.datagram = datagram
            held = s.horizon_us if s.horizon_us is not None else frontier_us
            s.plain = index == 0 and not more and not s.chained  # one point a datagram: a plain scheduler
            s.linked = s.plain or (index == 0 and held is not None and t_us <= held + 1e-3)
        if s.plain:
            s.horizon_us = t_us if s.horizon_us is None else max(s.horizon_us, t_us)
            return NEW  # queued and paced on as before this module: point by point, whatever came before
        if not s.linked:
            return UNLINKED
        if index > 0:
            s.chained = True
        if s.horizon_us is not None and t_us <= s.horizon_us + 1e-3:
            return HELD
        s.horizon_us = t_us
        return NEW
