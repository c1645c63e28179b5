"""The autopilot's part of a flight recording: entity paths, its row layouts, legend names and colours.

Plain data, no rerun import.  One table per control step (the controller's ``TELEMETRY_FIELDS``, then the
measured roll rate, the rudder PWM and the loop timing), one table of counters per MAVLink link, and two
state channels: the mode (``ADAPTIVE``, or ``HOLD`` while the controller is frozen) and the failsafe
(``OK`` for ``Failsafe.NONE``, else the ``autopilot.step.Failsafe`` member's name).  Units are SI (rad,
rad/s, s); PWM in us, counters.  ``sim_time`` is the ATTITUDE's ``time_boot_ms``.
"""

from __future__ import annotations

from autopilot.clsac import TELEMETRY_FIELDS
from autopilot.shared.telemetry.layout import (
    BLUE,
    GREEN,
    GREY,
    ORANGE,
    PURPLE,
    SKY,
    VERMILLION,
    WHITE,
    YELLOW,
    Plot,
    Rgb,
    TableLayout,
)
from autopilot.step import Failsafe

AP = "/autopilot"
AP_ROLL = f"{AP}/roll"  # um, ym, ym_ol, y (measured phi)                 rad
AP_ROLL_RATE = f"{AP}/roll_rate"  # p measured (ATTITUDE rollspeed)       rad/s
AP_ERROR = f"{AP}/error"  # e = ym - ya                                   rad
AP_AUGMENTED = f"{AP}/augmented"  # ya = y + y_pfc, y_pfc                 rad
AP_RUDDER = f"{AP}/rudder"  # u (limited), u_raw                          rad
AP_RUDDER_PWM = f"{AP}/rudder_pwm"  # SERVO_OUTPUT_RAW rudder channel      us
AP_SATURATED = f"{AP}/saturated"  # 1 while |u_raw| > limit
AP_GAINS = f"{AP}/gains"
AP_GAIN_KE = f"{AP_GAINS}/ke"  # kpe, kie, ke
AP_GAIN_KX = f"{AP_GAINS}/kx"  # kpx, kix, kx
AP_GAIN_KU = f"{AP_GAINS}/ku"  # kpu, kiu, ku
AP_TIMING = f"{AP}/timing"
AP_TIMING_LOOP = f"{AP_TIMING}/loop"  # period, compute, jitter          s
AP_TIMING_MISSED = f"{AP_TIMING}/missed"  # missed deadlines (cumulative count)
AP_LINK = f"{AP}/link"  # /autopilot/link/<name>: rx, tx, rejected (cumulative counts)
AP_STATUS = f"{AP}/status"
AP_MODE = f"{AP_STATUS}/mode"  # StateChange
AP_FAILSAFE = f"{AP_STATUS}/failsafe"  # StateChange
AP_EVENTS = f"{AP}/events"  # TextLog: status events and every state change as a readable line

# The autopilot's row: the controller's telemetry tuple (ClSac.telemetry(), TELEMETRY_FIELDS order),
# then what the loop knows: measured roll rate, rudder PWM and the loop timing of this step.
AUTOPILOT_EXTRA_FIELDS = ("p", "pwm", "period", "compute", "jitter", "missed")
AUTOPILOT_FIELDS = tuple(TELEMETRY_FIELDS) + AUTOPILOT_EXTRA_FIELDS

AUTOPILOT = TableLayout(
    "autopilot",
    AUTOPILOT_FIELDS,
    (
        Plot(
            AP_ROLL,
            ("um", "ym", "ym_ol", "y"),
            ("roll command um", "reference ym (closed loop)", "reference ym_ol (open loop)", "roll phi (measured)"),
            (GREY, ORANGE, SKY, YELLOW),
        ),
        Plot(AP_ROLL_RATE, ("p",), ("roll rate p (measured)",), (YELLOW,)),
        Plot(AP_ERROR, ("e",), ("error e = ym - ya",), (VERMILLION,)),
        Plot(AP_AUGMENTED, ("ya", "y_pfc"), ("augmented output ya", "PFC output y_pfc"), (GREEN, PURPLE)),
        Plot(
            AP_RUDDER, ("u", "u_raw"), ("rudder command u (limited)", "rudder command u_raw (unlimited)"), (BLUE, SKY)
        ),
        Plot(AP_RUDDER_PWM, ("pwm",), ("rudder PWM [us]",), (BLUE,), step=True),
        Plot(AP_SATURATED, ("saturated",), ("rudder saturated",), (VERMILLION,), step=True),
        Plot(AP_GAIN_KE, ("kpe", "kie", "ke"), ("Kpe", "KIe", "Ke"), (SKY, ORANGE, WHITE)),
        Plot(AP_GAIN_KX, ("kpx", "kix", "kx"), ("Kpx", "KIx", "Kx"), (SKY, ORANGE, WHITE)),
        Plot(AP_GAIN_KU, ("kpu", "kiu", "ku"), ("Kpu", "KIu", "Ku"), (SKY, ORANGE, WHITE)),
        Plot(
            AP_TIMING_LOOP,
            ("period", "compute", "jitter"),
            ("period [s]", "compute [s]", "jitter [s]"),
            (GREY, GREEN, VERMILLION),
        ),
        Plot(AP_TIMING_MISSED, ("missed",), ("missed deadlines",), (VERMILLION,), step=True),
    ),
)

LINKS = ("sitl", "gcs")  # the autopilot's MAVLink links (attributes of the Autopilot)
LINK_FIELDS = ("rx", "tx", "rejected")

# received, sent, rejected: one colour family per link so that several links stay apart in one plot
LINK_COLORS: tuple[tuple[Rgb, Rgb, Rgb], ...] = (
    (GREEN, BLUE, VERMILLION),
    (YELLOW, SKY, PURPLE),
    (WHITE, GREY, ORANGE),
)


def link_layout(name: str, index: int = 0) -> TableLayout:
    """Counters of one MAVLink link (``"sitl"``, ``"gcs"``) at ``/autopilot/link/<name>``.

    ``index`` picks the colour family (give each link of a process its own).
    """
    if not name or "/" in name:
        raise ValueError(f"link name must be a non-empty path component, got {name!r}")
    return TableLayout(
        f"link_{name}",
        LINK_FIELDS,
        (
            Plot(
                f"{AP_LINK}/{name}",
                LINK_FIELDS,
                (f"{name} received", f"{name} sent", f"{name} rejected"),
                LINK_COLORS[index % len(LINK_COLORS)],
                step=True,
            ),
        ),
    )


# The states the hook emits, each with its colour in the state timeline view (and nothing else).
MODE_ADAPTIVE = "ADAPTIVE"
MODE_HOLD = "HOLD"  # the controller is frozen (ClSac.hold: failsafe steps)
MODE_COLORS: dict[str, Rgb] = {MODE_ADAPTIVE: GREEN, MODE_HOLD: ORANGE}
FAILSAFE_OK = "OK"


def failsafe_state(failsafe: Failsafe) -> str:
    """The failsafe channel's state: ``OK`` for ``Failsafe.NONE``, else the member's name."""
    return FAILSAFE_OK if failsafe is Failsafe.NONE else failsafe.name


FAILSAFE_COLORS: dict[str, Rgb] = {
    failsafe_state(Failsafe.NONE): GREEN,
    failsafe_state(Failsafe.NO_ATTITUDE): VERMILLION,
    failsafe_state(Failsafe.NO_SETPOINT): ORANGE,
}
FAILSAFE_WARN = frozenset(s for s in FAILSAFE_COLORS if s != FAILSAFE_OK)  # logged at WARN in the event log
