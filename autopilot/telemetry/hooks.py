"""Ready-made hooks for the two processes' loops, and their command-line flags.

``autopilot.loop.Autopilot.hooks`` and ``sitl.endpoint.Sitl.hooks`` call their hooks once per step /
frame, after the servo command went out (outside the critical path).  The hooks here turn those
records into telemetry rows (one ``push`` of a tuple per step, ~1 us) and state changes.  They only
read attributes (duck typing), so they do not import the loops::

    tel = telemetry.from_args(args, "autopilot")          # --rrd, --recording-id, --connect, --viewer
    hook = telemetry.AutopilotHook(tel)
    autopilot.hooks.append(hook)
    autopilot.event_hooks.append(hook.event)
    with tel:
        autopilot.run()

    tel = telemetry.from_args(args, "sitl")
    sitl.hooks.append(telemetry.SitlHook(tel))
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Sequence

from autopilot.telemetry import layout as L
from autopilot.telemetry.flags import add_arguments  # noqa: F401  (re-exported)
from autopilot.telemetry.writer import Telemetry

_NAN = float("nan")


def _f(v) -> float:
    return _NAN if v is None else float(v)


class AutopilotHook:
    """``Autopilot.hooks`` callable: the controller row every step, link counters at ``link_rate_hz``,
    mode (``ADAPTIVE`` / ``HOLD`` while the controller is frozen) and failsafe (``OK`` or the reason)."""

    def __init__(self, tel: Telemetry, links: Sequence[str] = ("sitl", "gcs"), link_rate_hz: float = 10.0,
                 control_rate_hz: float | None = None):
        self.tel = tel
        self.table, self.links, self.mode, self.failsafe = tel.autopilot_tables(links)
        self._push = self.table.push
        self._link_names = tuple(links)
        self._link_rate_hz = link_rate_hz
        self._link_every = (max(1, int(round(control_rate_hz / link_rate_hz))) if control_rate_hz else None)
        self._next_link_t = -math.inf
        self._last_t = 0.0
        self._missed = 0

    def __call__(self, rec) -> None:
        wall = time.time()
        t = rec.t_sim
        self._last_t = t
        if rec.missed:
            self._missed += 1
        ap = rec.ap
        missed = getattr(getattr(ap, "timing", None), "missed", self._missed)
        self._push((t, wall, rec.ctrl.telemetry() + (
            _f(rec.p), _f(rec.pwm), _f(rec.period), _f(rec.compute), _f(rec.lateness), float(missed))))
        state = "HOLD" if rec.ctrl.frozen else "ADAPTIVE"
        if state != self.mode.last:
            self.mode.set(t, wall, state)
        fs = rec.failsafe
        fs_state = "OK" if fs is None else str(fs).upper().replace(" ", "_")
        if fs_state != self.failsafe.last:
            self.failsafe.set(t, wall, fs_state, "" if fs is None else str(fs))
        due = (rec.step % self._link_every == 0) if self._link_every else (t >= self._next_link_t)
        if due:
            self._next_link_t = t + 1.0 / self._link_rate_hz
            for name, table in self.links.items():
                link = getattr(ap, name, None)
                if link is None:
                    continue
                rejected = getattr(link, "rejected", None)
                if rejected is not None:
                    # The three numbers straight from the link's attributes: counters() builds whole
                    # dicts (~3.5 us a link) for the same values.
                    row = (float(link.rx_packets), float(link.tx_packets), float(sum(rejected.values())))
                else:
                    c = link.counters()
                    row = (float(c.get("rx_packets", 0)), float(c.get("tx_packets", 0)),
                           float(sum(c.get("rejected", {}).values())))
                table.push((t, wall, row))

    def event(self, severity, text: str) -> None:
        """``Autopilot.event_hooks`` callable: a status text in ``/autopilot/events`` at the last step's sim time."""
        level = "ERROR" if isinstance(severity, int) and severity <= 3 else (
            "WARN" if isinstance(severity, int) and severity <= 4 else "INFO")
        self.tel.log_event(self._last_t, time.time(), str(text), level)


class SitlHook:
    """``Sitl.hooks`` callable: the truth state, the applied servo command (rad) and its PWM, per frame."""

    def __init__(self, tel: Telemetry):
        self.tel = tel
        self.table = tel.table(L.SITL_TABLE)
        self._push = self.table.push
        self._last_t = 0.0

    def __call__(self, rec) -> None:
        self._last_t = rec.t_sim
        self._push((rec.t_sim, time.time(), tuple(rec.x.tolist()) + (_f(rec.u), _f(rec.pwm))))

    def event(self, severity, text: str) -> None:
        level = "WARN" if isinstance(severity, int) and severity <= 4 else "INFO"
        self.tel.log_event(self._last_t, time.time(), str(text), level)


# ------------------------------------------------------------------------------------------ flags
def from_args(args: argparse.Namespace, process: str, **kwargs) -> Telemetry:
    """A ``Telemetry`` from the flags of ``add_arguments`` (disabled when none is given)."""
    return Telemetry(process, getattr(args, "recording_id", None), getattr(args, "rrd", None),
                     connect_url=getattr(args, "connect", None), spawn_viewer=bool(getattr(args, "viewer", False)),
                     **kwargs)
