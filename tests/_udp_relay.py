"""A lossy UDP relay between a ground station and the autopilot, for the tests that lose its messages on purpose.

``DroppingRelay(ap_port, gcs_port, msgid, drop, seed)`` forwards every datagram both ways and drops, with
probability ``drop`` (seeded), the ground station's datagrams whose first packet is the MAVLink 2 message ``msgid``:
the lockstep schedule's setpoints (``tests/autopilot/test_ground_station_bounds.py``) or the MIMO schedule's
sideslip (``tests/tools/flight/test_e2e_mimo_schedule.py``).  The autopilot talks to ``a``, the ground station to
``b``; ``matched`` counts the datagrams of that message and ``dropped`` those dropped.
"""

from __future__ import annotations

import random
import select
import socket
import threading


class DroppingRelay:
    def __init__(self, ap_port: int, gcs_port: int, msgid: int, drop: float, seed: int):
        self.to_ap, self.to_gcs = ("127.0.0.1", ap_port), ("127.0.0.1", gcs_port)
        self.a = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.b = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.a.bind(("127.0.0.1", 0))  # the autopilot's peer
        self.b.bind(("127.0.0.1", 0))  # the ground station's vehicle
        self.msgid = msgid.to_bytes(3, "little")  # MAVLink 2: bytes 7-9 of a packet
        self.rng, self.drop = random.Random(seed), drop
        self.matched = self.dropped = 0
        self._stop = False
        self._thread = threading.Thread(target=self._pump, daemon=True)
        self._thread.start()

    def _pump(self) -> None:
        while not self._stop:
            for s in select.select([self.a, self.b], [], [], 0.1)[0]:
                data = s.recv(65535)
                if s is self.a:
                    self.b.sendto(data, self.to_gcs)
                    continue
                if len(data) > 10 and data[0] == 0xFD and data[7:10] == self.msgid:
                    self.matched += 1
                    if self.rng.random() < self.drop:
                        self.dropped += 1
                        continue
                self.a.sendto(data, self.to_ap)

    def close(self) -> None:
        self._stop = True
        self._thread.join(2)
        self.a.close()
        self.b.close()
