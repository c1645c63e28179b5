"""Link faults the SITL injects, one :class:`FaultChannel` per direction: loss, delay, duplication, reordering.

Pure and seeded: a channel sees ``push(t, item)`` when a packet would be sent and hands it over with
``due(t)`` once it has arrived.  Time ``t`` is whatever clock the caller keeps (lockstep: the frame
index, so the delay is in frames of sim time; real time: wall seconds).  Every packet draws exactly three
uniforms from the channel's own generator, whatever happens to it, so a run's fault pattern is a function of
the seed and the packet order only (in lockstep: of the seed and the frame index).

Per packet, in this order: lost with probability ``loss``; otherwise it arrives ``delay`` later, twice with
probability ``duplicate``; with probability ``reorder`` it is held back and delivered right after the next
packet that is not held (so that one overtakes it).
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass

import numpy as np

FAULT_COUNTS = ("sent", "lost", "duplicated", "reordered", "delivered")


class FaultConfigError(ValueError):
    """A link-fault value is out of range."""


@dataclass(frozen=True)
class FaultConfig:
    """loss, duplicate, reorder: probabilities per packet in [0, 1); delay: one-way delay in seconds (>= 0)."""

    loss: float = 0.0
    delay: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0

    def __post_init__(self) -> None:
        for name in ("loss", "duplicate", "reorder"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0.0 <= v < 1.0):
                raise FaultConfigError(f"{name} must be a probability in [0, 1), got {v!r}")
        if not (math.isfinite(self.delay) and self.delay >= 0):
            raise FaultConfigError(f"delay must be >= 0 s and finite, got {self.delay!r}")

    @property
    def active(self) -> bool:
        return any((self.loss, self.delay, self.duplicate, self.reorder))


class FaultChannel:
    """One direction of the link.

    Example (lockstep, ``delay`` in frames)::

        ch = FaultChannel(FaultConfig(loss=0.1), np.random.default_rng(0), delay=2)
        ch.push(k, payload)
        for item in ch.due(k): ...
    """

    def __init__(self, cfg: FaultConfig, rng: np.random.Generator, delay: float | None = None):
        self.cfg = cfg
        self.rng = rng
        self.delay = cfg.delay if delay is None else delay
        self.counts = Counter({k: 0 for k in FAULT_COUNTS})
        self._queue: deque = deque()  # (arrival, item), arrivals non-decreasing
        self._held: list = []  # reordered packets waiting to be overtaken: (arrival, copies, item)

    def push(self, t: float, item) -> None:
        cfg = self.cfg
        c = self.counts
        u_loss, u_dup, u_reorder = self.rng.random(3)
        c["sent"] += 1
        if u_loss < cfg.loss:
            c["lost"] += 1
            return
        arrival = t + self.delay
        copies = 1
        if u_dup < cfg.duplicate:
            copies = 2
            c["duplicated"] += 1
        if u_reorder < cfg.reorder:
            c["reordered"] += 1
            self._held.append((arrival, copies, item))
            return
        q = self._queue
        if q and q[-1][0] > arrival:  # a released held packet ahead of it: keep arrivals non-decreasing
            arrival = q[-1][0]
        q.extend([(arrival, item)] * copies)
        for _arr, n, held in self._held:  # the overtaken ones arrive right after this one
            q.extend([(arrival, held)] * n)
        self._held.clear()

    def due(self, t: float) -> list:
        """The items that have arrived by ``t``, in arrival order."""
        q = self._queue
        out = []
        while q and q[0][0] <= t:
            out.append(q.popleft()[1])
        self.counts["delivered"] += len(out)
        return out

    def next_due(self) -> float:
        """Arrival time of the next queued item (inf if none)."""
        return self._queue[0][0] if self._queue else math.inf
