"""The autopilot's part of a flight recording: entity paths, its row layouts, legend names and colours.

Plain data, no rerun import.  One table per control step (the controller's ``TELEMETRY_FIELDS``, then the
measured roll rate, the rudder PWM and the loop timing), one table of counters per MAVLink link, one row per
PARAM_SET (a marker on each gain plot at the gain's value then: accepted or refused), and two state channels:
the vehicle's mode (``autopilot.vehicle.Mode``: MANUAL, SAC, CLSAC, BASELINE, FAILSAFE) and the failsafe (``OK``
for ``Failsafe.NONE``, else the ``autopilot.step.Failsafe`` member's name).  The rows are SI; the plots of angles
are sent in degrees and of angular rates in deg/s (``scale=DEG_PER_RAD``), times in s, PWM in us, counters.  The
reference model's roll ym is drawn in 3D as a ghost aircraft (``AP_REFERENCE_ATTITUDE``).  ``sim_time`` is the
ATTITUDE's ``time_boot_ms``.
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
    Pose,
    Rgb,
    TableLayout,
)
from autopilot.shared.telemetry.layout import DEG_PER_RAD as DEG
from autopilot.step import Failsafe
from autopilot.vehicle import Mode

AP = "/autopilot"
AP_ROLL = f"{AP}/roll"  # um, ym, ym_ol, y (measured phi)                 deg
AP_ROLL_RATE = f"{AP}/roll_rate"  # p measured (ATTITUDE rollspeed)       deg/s
AP_ERROR = f"{AP}/error"  # e = ym - ya                                   deg
AP_AUGMENTED = f"{AP}/augmented"  # ya = y + y_pfc, y_pfc                 deg
AP_RUDDER = f"{AP}/rudder"  # u (limited), u_raw                          deg
AP_REFERENCE_ATTITUDE = f"{AP}/reference_attitude"  # Transform3D at roll ym + the aircraft shape (ghost)
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
AP_PARAM_SET = f"{AP}/param_set"  # /autopilot/param_set/ke|kx|ku: a marker per PARAM_SET at that gain's value
AP_PARAM_SET_KE = f"{AP_PARAM_SET}/ke"
AP_PARAM_SET_KX = f"{AP_PARAM_SET}/kx"
AP_PARAM_SET_KU = f"{AP_PARAM_SET}/ku"

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
            scale=DEG,
        ),
        Plot(AP_ROLL_RATE, ("p",), ("roll rate p (measured)",), (YELLOW,), scale=DEG),
        Plot(AP_ERROR, ("e",), ("error e = ym - ya",), (VERMILLION,), scale=DEG),
        Plot(AP_AUGMENTED, ("ya", "y_pfc"), ("augmented output ya", "PFC output y_pfc"), (GREEN, PURPLE), scale=DEG),
        Plot(
            AP_RUDDER,
            ("u", "u_raw"),
            ("rudder command u (limited)", "rudder command u_raw (unlimited)"),
            (BLUE, SKY),
            scale=DEG,
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
    poses=(Pose(AP_REFERENCE_ATTITUDE, "ym", "reference ym (ghost)", (*ORANGE, 110)),),
)

AP_LAW = f"{AP}/law"  # /autopilot/law/<field>: a law's own telemetry (autopilot.law: its TELEMETRY_FIELDS)


def law_layout(fields: tuple[str, ...]) -> TableLayout:
    """A law's own telemetry (``autopilot.law.Flown.law_row``), one plot per field at ``/autopilot/law/<field>``, in
    the law's own units (SI)."""
    colors = (BLUE, ORANGE, GREEN, VERMILLION, PURPLE, SKY, YELLOW, WHITE, GREY)
    return TableLayout(
        "law",
        tuple(fields),
        tuple(Plot(f"{AP_LAW}/{f}", (f,), (f,), (colors[i % len(colors)],)) for i, f in enumerate(fields)),
    )


# A square MIMO flight's second channel and matrix gain (autopilot.mimo.MIMO_FIELDS, one row per step beside the
# autopilot's): the sideslip, its references and error, the rudder command, and the entries of K_e.
AP_MIMO = f"{AP}/mimo"
AP_SIDESLIP = f"{AP_MIMO}/sideslip"  # beta (AOA_SSA), um2, ym2, ym_ol2, e2     deg
AP_RUDDER2 = f"{AP_MIMO}/rudder"  # u2 (limited), sat2                       deg
AP_GAIN_KE_MATRIX = f"{AP_MIMO}/ke"  # ke11, ke12, ke21, ke22
MIMO = TableLayout(
    "mimo",
    ("beta", "um2", "u2", "e2", "ym2", "ym_ol2", "sat2", "ke11", "ke12", "ke21", "ke22"),
    (
        Plot(
            AP_SIDESLIP,
            ("um2", "ym2", "ym_ol2", "beta", "e2"),
            ("sideslip command", "reference (closed loop)", "reference (open loop)", "sideslip beta", "error e2"),
            (GREY, ORANGE, SKY, YELLOW, VERMILLION),
            scale=DEG,
        ),
        Plot(AP_RUDDER2, ("u2",), ("rudder command u2 (limited)",), (BLUE,), scale=DEG),
        Plot(
            AP_GAIN_KE_MATRIX,
            ("ke11", "ke12", "ke21", "ke22"),
            ("Ke11", "Ke12", "Ke21", "Ke22"),
            (WHITE, SKY, PURPLE, ORANGE),
        ),
    ),
)

# One row per PARAM_SET a ground station sent: each gain's value at that moment, in the series of the outcome
# (the other one NaN, not drawn), so a marker sits on every gain plot where the tuning happened.
PARAM_SET_FIELDS = ("ke_accepted", "ke_refused", "kx_accepted", "kx_refused", "ku_accepted", "ku_refused")
PARAM_SET_LABELS = ("PARAM_SET accepted", "PARAM_SET refused")
PARAM_SETS = TableLayout(
    "param_sets",
    PARAM_SET_FIELDS,
    tuple(
        Plot(path, (f"{k}_accepted", f"{k}_refused"), PARAM_SET_LABELS, (GREEN, VERMILLION), points=True)
        for k, path in (("ke", AP_PARAM_SET_KE), ("kx", AP_PARAM_SET_KX), ("ku", AP_PARAM_SET_KU))
    ),
)


def param_set_row(gains: tuple[float, float, float], accepted: bool) -> tuple[float, ...]:
    """The PARAM_SETS row of one PARAM_SET: the gains (Ke, Kx, Ku) in the outcome's series, NaN in the other."""
    nan = float("nan")
    return tuple(v for g in gains for v in ((g, nan) if accepted else (nan, g)))


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


# The states the hook emits, each with its colour in the state timeline view (and nothing else): the vehicle's
# own modes (what its HEARTBEAT's custom_mode says; FAILSAFE while the attitude or the setpoints are lost).
MODE_COLORS: dict[str, Rgb] = {
    Mode.MANUAL.name: GREY,
    Mode.SAC.name: SKY,
    Mode.CLSAC.name: GREEN,
    Mode.BASELINE.name: BLUE,
    Mode.MRAC.name: PURPLE,
    Mode.CRM_MRAC.name: ORANGE,
    Mode.L1.name: YELLOW,
    Mode.INDI.name: WHITE,
    Mode.LAW.name: SKY,
    Mode.FAILSAFE.name: VERMILLION,
}
MODE_WARN = frozenset({Mode.FAILSAFE.name})  # logged at WARN in the event log
FAILSAFE_OK = "OK"


def failsafe_state(failsafe: Failsafe) -> str:
    """The failsafe channel's state: ``OK`` for ``Failsafe.NONE``, else the member's name."""
    return FAILSAFE_OK if failsafe is Failsafe.NONE else failsafe.name


FAILSAFE_COLORS: dict[str, Rgb] = {
    failsafe_state(Failsafe.NONE): GREEN,
    failsafe_state(Failsafe.LAW_ERROR): PURPLE,
    failsafe_state(Failsafe.NO_ATTITUDE): VERMILLION,
    failsafe_state(Failsafe.NO_SETPOINT): ORANGE,
}
FAILSAFE_WARN = frozenset(s for s in FAILSAFE_COLORS if s != FAILSAFE_OK)  # logged at WARN in the event log
