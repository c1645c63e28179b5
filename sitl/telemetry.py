"""The SITL's telemetry: its part of a flight recording (truth state, applied servo command, PWM) and its hook.

One row per frame (lockstep) or per ATTITUDE sent (real time): the truth state x_p in ``sitl.model.STATE_NAMES``
order, then the servo command the SITL applied (rad, after the PWM -> angle mapping) and the PWM it received.
``sim_time`` is the SITL's clock (``steps * dt``), the same instant the autopilot logs for that frame.  The rows
are SI (m/s, rad/s, rad); the plots send angles in degrees and angular rates in deg/s (``scale=DEG_PER_RAD``),
PWM in us.  The true roll phi is also drawn as the aircraft in 3D (``SITL_ATTITUDE``).  Imports only
``autopilot.shared`` and ``sitl``.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

from autopilot.shared.servo_failures import FAULT_PREFIX
from autopilot.shared.telemetry.flags import attach as attach_hook
from autopilot.shared.telemetry.hooks import ProcessHook, nan_if_none
from autopilot.shared.telemetry.layout import DEG_PER_RAD as DEG
from autopilot.shared.telemetry.layout import GREEN, GREY, PURPLE, Plot, Pose, TableLayout, fault_marks_layout
from sitl.model import STATE_NAMES

SITL = "/sitl"
SITL_ROLL = f"{SITL}/roll"  # phi truth                                  deg
SITL_RATES = f"{SITL}/rates"  # p, r truth                               deg/s
SITL_SIDE_VELOCITY = f"{SITL}/side_velocity"  # v truth                  m/s
SITL_RUDDER = f"{SITL}/rudder"  # delta_r truth, servo command applied   deg
SITL_RUDDER_RATE = f"{SITL}/rudder_rate"  # delta_r_dot truth            deg/s
SITL_ATTITUDE = f"{SITL}/attitude"  # Transform3D at the true roll phi (and pitch on JSBSim) + the aircraft shape
SITL_SERVO_PWM = f"{SITL}/servo_pwm"  # PWM as received                  us
SITL_EVENTS = f"{SITL}/events"  # TextLog: status events
# A JSBSim plant (sitl.jsbsim_plant): what the safety pilot holds, so a user sees what it did.
SITL_ALTITUDE = f"{SITL}/held/altitude"  # altitude above sea level     m
SITL_AIRSPEED = f"{SITL}/held/airspeed"  # calibrated airspeed            m/s
SITL_PITCH = f"{SITL}/held/pitch"  # pitch theta                          deg
SITL_PILOT = f"{SITL}/held/pilot"  # elevator and throttle commands       normalised

SITL_EXTRA_FIELDS = ("delta_cmd", "pwm")
SITL_FIELDS = tuple(STATE_NAMES) + SITL_EXTRA_FIELDS

SITL_TABLE = TableLayout(
    "sitl",
    SITL_FIELDS,
    (
        Plot(SITL_ROLL, ("phi",), ("roll phi (truth, wrapped to +-180)",), (PURPLE,), scale=DEG, wrap=True),
        Plot(SITL_RATES, ("p", "r"), ("roll rate p (truth)", "yaw rate r (truth)"), (PURPLE, GREEN), scale=DEG),
        Plot(SITL_SIDE_VELOCITY, ("v",), ("side velocity v (truth)",), (GREEN,)),
        Plot(
            SITL_RUDDER,
            ("delta_r", "delta_cmd"),
            ("rudder delta_r (truth)", "servo command applied"),
            (PURPLE, GREY),
            scale=DEG,
        ),
        Plot(SITL_RUDDER_RATE, ("delta_r_dot",), ("rudder rate (truth)",), (PURPLE,), scale=DEG),
        Plot(SITL_SERVO_PWM, ("pwm",), ("servo PWM received [us]",), (PURPLE,), step=True),
    ),
    poses=(Pose(SITL_ATTITUDE, "phi", "aircraft (true roll phi)", (*PURPLE, 255)),),
)


HELD_FIELDS = ("altitude_m", "airspeed_m_s", "theta", "elevator", "throttle")  # sitl.jsbsim_plant.JsbsimPlant.held
# On a JSBSim plant the 3D aircraft flies the full attitude that is not the heading: roll and pitch, from the held
# table's rows (the truth table then draws none).
SITL_TABLE_NO_POSE = dataclasses.replace(SITL_TABLE, poses=())
SITL_HELD_TABLE = TableLayout(
    "sitl_held",
    (*HELD_FIELDS, "phi"),
    (
        Plot(SITL_ALTITUDE, ("altitude_m",), ("altitude [m]",), (PURPLE,)),
        Plot(SITL_AIRSPEED, ("airspeed_m_s",), ("airspeed [m/s]",), (PURPLE,)),
        Plot(SITL_PITCH, ("theta",), ("pitch theta (truth)",), (PURPLE,), scale=DEG),
        Plot(SITL_PILOT, ("elevator", "throttle"), ("safety pilot: elevator", "safety pilot: throttle"), (GREEN, GREY)),
    ),
    poses=(Pose(SITL_ATTITUDE, "phi", "aircraft (true roll phi, pitch theta)", (*PURPLE, 255), pitch="theta"),),
)


class SitlHook(ProcessHook):
    """``Sitl.hooks`` callable: the truth state, the applied servo command (rad) and its PWM, per ``SitlRecord``;
    with ``held`` (a JSBSim plant) also what the safety pilot holds."""

    def __init__(self, tel, held: bool = False, surface: str = "rudder"):
        super().__init__(tel)
        self._layout = SITL_TABLE.naming("rudder", surface)  # the plant's surface in the labels (an aileron...)
        self.table = tel.table((SITL_TABLE_NO_POSE if held else SITL_TABLE).naming("rudder", surface))
        self._push = self.table.push
        self._held = tel.table(SITL_HELD_TABLE).push if held else None
        self._phi = STATE_NAMES.index("phi")
        # the last row of each table: where a fault's markers sit (attributes, not a dict keyed by the layout: hashing
        # the layout every frame cost more than the row)
        self._row: tuple | None = None
        self._held_row: tuple | None = None
        self._marks: dict = {}  # the fault-marker tables, made at the first fault (a flight without none)

    def __call__(self, rec) -> None:
        self.last_t = t = rec.t_sim
        wall = time.time()
        self._row = row = tuple(rec.x.tolist()) + (nan_if_none(rec.u), nan_if_none(rec.pwm))
        self._push((t, wall, row))
        if self._held is not None:
            held = rec.sitl.aircraft.held()
            self._held_row = row = (*(held[k] for k in HELD_FIELDS), float(rec.x[self._phi]))
            self._held((t, wall, row))

    def _last_rows(self) -> list:
        """(layout, its last row) of each table that has one."""
        rows = [] if self._row is None else [(self._layout, self._row)]
        return rows + ([] if self._held_row is None else [(SITL_HELD_TABLE, self._held_row)])

    def event(self, severity, text: str) -> None:
        """A status event in ``/sitl/events``; a fault's start or end also as a marker on every plot."""
        super().event(severity, text)
        if str(text).startswith(FAULT_PREFIX):
            wall = time.time()
            for layout, row in self._last_rows():
                if layout not in self._marks:
                    self._marks[layout] = self.tel.table(fault_marks_layout(layout))
                self._marks[layout].push((self.last_t, wall, row))


def attach(args: argparse.Namespace, sitl):
    """If a telemetry flag was given, build the writer and register a ``SitlHook`` on ``sitl``; the writer or None."""
    from sitl.plant import surface_of

    held = hasattr(getattr(sitl, "aircraft", None), "held")  # a JSBSim plant
    surface = surface_of(getattr(args, "plant", "kh2013a"))
    return attach_hook(args, "sitl", sitl, lambda tel: SitlHook(tel, held, surface))
