"""The autopilot's telemetry hook: one ``StepRecord`` in, one row (and any state change) out.

``Autopilot.hooks`` call it once per step, after the servo command went out (outside the critical path);
it pushes one tuple (~1 us) and sets the mode and failsafe channels.  It only reads the record's
attributes (duck typing), so it does not import the loop.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

from autopilot.shared.servo_failures import FAULT_PREFIX
from autopilot.shared.telemetry.hooks import ProcessHook, nan_if_none
from autopilot.shared.telemetry.layout import fault_marks_layout
from autopilot.telemetry import layout as L

_GAIN_INDEX = tuple(L.AUTOPILOT.index(k) for k in ("ke", "kx", "ku"))  # in the autopilot's row


def autopilot_tables(tel, links: Sequence[str] = L.LINKS, surface: str = "rudder"):
    """Register the autopilot's layout with a writer: (main table, {link: table}, mode channel, failsafe channel);
    ``surface``: the word its labels use for the command (the plant's: rudder, aileron)."""
    return (
        tel.table(L.AUTOPILOT.naming("rudder", surface)),
        {name: tel.table(L.link_layout(name, i)) for i, name in enumerate(links)},
        tel.state_channel(L.AP_MODE, "mode", L.MODE_COLORS, warn=L.MODE_WARN),
        tel.state_channel(L.AP_FAILSAFE, "failsafe", L.FAILSAFE_COLORS, warn=L.FAILSAFE_WARN),
    )


class AutopilotHook(ProcessHook):
    """``Autopilot.hooks`` callable: the controller row every step, link counters at ``link_rate_hz``, the vehicle's
    mode (``autopilot.vehicle.Mode`` name) and the failsafe (``OK`` or the member's name).  ``param_set`` (a
    ``Vehicle.param_hooks`` callable) logs each PARAM_SET and marks it on the gain plots.

    ``control_rate_hz`` paces the link counters on the step count (exact in lockstep); without it, on sim time.
    """

    def __init__(
        self,
        tel,
        links: Sequence[str] = L.LINKS,
        link_rate_hz: float = 10.0,
        control_rate_hz: float | None = None,
        surface: str = "rudder",
    ):
        super().__init__(tel)
        self.table, self.links, self.mode, self.failsafe = autopilot_tables(tel, links, surface)
        self._layout = L.AUTOPILOT.naming("rudder", surface)
        self._push = self.table.push
        self._link_rate_hz = link_rate_hz
        self._link_every = max(1, int(round(control_rate_hz / link_rate_hz))) if control_rate_hz else None
        self._next_link_t = -math.inf
        self._failsafe = None  # the last Failsafe member seen
        self.param_sets = tel.table(L.PARAM_SETS)
        self._row: tuple | None = None  # the last step's row: its Ke, Kx, Ku are where a PARAM_SET's markers sit
        self._link_rows: dict = {}  # the last counters of each link: where a fault's markers sit on their plot
        self._marks: dict = {}  # the fault-marker tables, made at the first fault the SITL reports
        self._mimo = None  # a MIMO law's table (layout.MIMO), made at its first step
        self._law = None  # a law's own telemetry (layout.law_layout), made at its first step

    def __call__(self, rec) -> None:
        wall = time.time()
        res = rec.result
        t = res.t
        self.last_t = t
        ctrl = rec.ctrl
        ap = rec.ap
        self._row = row = ctrl.telemetry() + (
            nan_if_none(rec.p),
            nan_if_none(res.pwm),
            nan_if_none(rec.period),
            nan_if_none(rec.compute),
            nan_if_none(rec.lateness),
            float(ap.timing.missed),
        )
        self._push((t, wall, row))
        mimo_row = getattr(ctrl, "mimo_row", None)
        if mimo_row is not None:  # a square MIMO law (autopilot.mimo): its second channel and K_e, a table beside
            if self._mimo is None:
                self._mimo = self.tel.table(L.MIMO)
            self._mimo.push((t, wall, tuple(float(v) for v in mimo_row())))
        law_row = getattr(ctrl, "law_row", None)
        if law_row is not None and ctrl.fields:  # a law on the interface (autopilot.law.Flown): its own table
            if self._law is None:
                self._law = self.tel.table(L.law_layout(ctrl.fields))
            self._law.push((t, wall, law_row()))
        mode = ap.vehicle.mode.name
        if mode != self.mode.last:
            self.mode.set(t, wall, mode)
        fs = res.failsafe
        if fs is not self._failsafe:
            self._failsafe = fs
            self.failsafe.set(t, wall, L.failsafe_state(fs))
        due = (res.k % self._link_every == 0) if self._link_every else (t >= self._next_link_t)
        if due:
            self._next_link_t = t + 1.0 / self._link_rate_hz
            for name, table in self.links.items():
                link = getattr(ap, name)
                # Straight from the link's attributes: counters() builds whole dicts for the same numbers.
                counts = (float(link.rx_packets), float(link.tx_packets), float(sum(link.rejected.values())))
                self._link_rows[name] = counts
                table.push((t, wall, counts))

    def event(self, severity, text: str) -> None:
        """A status event in ``/autopilot/events``; a fault's start or end the SITL reports (``SITL: fault ...``)
        also as a marker on every plot, at the last step's values."""
        super().event(severity, text)
        if not str(text).startswith("SITL: " + FAULT_PREFIX) or self._row is None:
            return
        wall = time.time()
        layouts = [(self._layout, self._row)]
        layouts += [(L.link_layout(n, i), self._link_rows[n]) for i, n in enumerate(self.links) if n in self._link_rows]
        for layout, row in layouts:
            if layout.name not in self._marks:
                self._marks[layout.name] = self.tel.table(fault_marks_layout(layout))
            self._marks[layout.name].push((self.last_t, wall, row))

    def param_set(self, name: str, value: float, accepted: bool) -> None:
        """A ``Vehicle.param_hooks`` callable: the PARAM_SET as a line in the event log (refused at WARN; the reason
        is the status text logged just before) and a marker on each gain plot at the last step's gains."""
        wall = time.time()
        text = f"PARAM_SET {name} = {value:.6g}: {'accepted' if accepted else 'refused'}"
        self.tel.log_event(self.last_t, wall, text, "INFO" if accepted else "WARN")
        row = self._row
        gains = (0.0, 0.0, 0.0) if row is None else tuple(float(row[i]) for i in _GAIN_INDEX)
        self.param_sets.push((self.last_t, wall, L.param_set_row(gains, accepted)))
