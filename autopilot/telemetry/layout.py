"""What goes where in a flight recording: entity paths, row layouts, legend names and colours.

Plain data, no rerun import.  A *table* is what a process appends once per sample: a fixed tuple of
numbers (its ``fields``).  The writer fans every row out to a few *plots*: one Rerun entity each,
holding several scalar series that share a y axis (a multi-instance ``Scalars`` column, with
``SeriesLines`` names and colours logged once as static data).  Signals that belong in one chart
(command, reference models, measured roll) share one entity, so a TimeSeriesView shows them
together without any set-up.

Units are SI everywhere, as in the rest of the code (DESIGN.md section 1): rad, rad/s, m/s, s.
The only non-SI numbers are PWM pulse widths (microseconds, as on the wire) and counters.

Timelines (both on every row):
  ``sim_time``   duration, the simulated time of the sample (ATTITUDE ``time_boot_ms`` on the
                 autopilot side, ``steps * dt`` in the SITL), rounded to the nanosecond so that
                 both processes put the same instant on exactly the same index value;
  ``wall_time``  timestamp, the host clock (``time.time()``) when the sample was taken.
"""

from __future__ import annotations

from dataclasses import dataclass

from autopilot.clsac import TELEMETRY_FIELDS
from sitl.model import STATE_NAMES

APPLICATION_ID = "clsac_autopilot"  # both flight processes must use the same one (it is part of the store id)
EXPERIMENT_APPLICATION_ID = "clsac_experiment"  # paper.rrd: its own blueprint, never mixed with a flight's
SIM_TIME = "sim_time"
WALL_TIME = "wall_time"

Rgb = tuple[int, int, int]

# Colour-blind-safe palette (Okabe-Ito), readable on the viewer's dark background.
GREY: Rgb = (200, 200, 200)
ORANGE: Rgb = (230, 159, 0)
SKY: Rgb = (86, 180, 233)
GREEN: Rgb = (0, 158, 115)
YELLOW: Rgb = (240, 228, 66)
BLUE: Rgb = (0, 114, 178)
VERMILLION: Rgb = (213, 94, 0)
PURPLE: Rgb = (204, 121, 167)
WHITE: Rgb = (240, 240, 240)


@dataclass(frozen=True)
class Plot:
    """One entity: the series ``fields`` (names of table fields) drawn with ``labels`` and ``colors``."""

    path: str
    fields: tuple[str, ...]
    labels: tuple[str, ...]
    colors: tuple[Rgb, ...]
    step: bool = False  # staircase lines (counters, 0/1 flags)

    def __post_init__(self) -> None:
        if not (len(self.fields) == len(self.labels) == len(self.colors)) or not self.fields:
            raise ValueError(f"{self.path}: fields, labels and colors must have the same non-zero length")
        if not self.path.startswith("/"):
            raise ValueError(f"entity paths are absolute, got {self.path!r}")


@dataclass(frozen=True)
class TableLayout:
    """The row a process appends (``fields``, in order) and the plots it is split into."""

    name: str
    fields: tuple[str, ...]
    plots: tuple[Plot, ...]

    def __post_init__(self) -> None:
        if len(set(self.fields)) != len(self.fields):
            raise ValueError(f"table {self.name}: duplicate field names")
        for plot in self.plots:
            missing = [f for f in plot.fields if f not in self.fields]
            if missing:
                raise ValueError(f"table {self.name}: plot {plot.path} uses unknown fields {missing}")

    def index(self, field: str) -> int:
        return self.fields.index(field)

    @property
    def paths(self) -> tuple[str, ...]:
        return tuple(p.path for p in self.plots)


# ---------------------------------------------------------------------------------------- autopilot
AP = "/autopilot"
AP_ROLL = f"{AP}/roll"  # um, ym, ym_ol, y (measured phi)                 rad
AP_ROLL_RATE = f"{AP}/roll_rate"  # p measured (ATTITUDE rollspeed)       rad/s
AP_ERROR = f"{AP}/error"  # e = ym - ya                                   rad
AP_AUGMENTED = f"{AP}/augmented"  # ya = y + y_pfc, y_pfc                 rad
AP_RUDDER = f"{AP}/rudder"  # u (applied, limited), u_raw                 rad
AP_RUDDER_PWM = f"{AP}/rudder_pwm"  # SERVO_OUTPUT_RAW channel 4           us
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
AP_EVENTS = f"{AP}/events"  # TextLog: every state change as a readable line

# The autopilot's row: the controller's telemetry tuple (ClSac.telemetry(), TELEMETRY_FIELDS order),
# then what the loop knows: measured roll rate, rudder PWM and the loop timing of this step.
AUTOPILOT_EXTRA_FIELDS = ("p", "pwm", "period", "compute", "jitter", "missed")
AUTOPILOT_FIELDS = tuple(TELEMETRY_FIELDS) + AUTOPILOT_EXTRA_FIELDS

AUTOPILOT = TableLayout(
    "autopilot",
    AUTOPILOT_FIELDS,
    (
        Plot(AP_ROLL, ("um", "ym", "ym_ol", "y"),
             ("roll command um", "reference ym (closed loop)", "reference ym_ol (open loop)", "roll phi (measured)"),
             (GREY, ORANGE, SKY, YELLOW)),
        Plot(AP_ROLL_RATE, ("p",), ("roll rate p (measured)",), (YELLOW,)),
        Plot(AP_ERROR, ("e",), ("error e = ym - ya",), (VERMILLION,)),
        Plot(AP_AUGMENTED, ("ya", "y_pfc"), ("augmented output ya", "PFC output y_pfc"), (GREEN, PURPLE)),
        Plot(AP_RUDDER, ("u", "u_raw"), ("rudder command u (limited)", "rudder command u_raw (unlimited)"),
             (BLUE, SKY)),
        Plot(AP_RUDDER_PWM, ("pwm",), ("rudder PWM ch4 [us]",), (BLUE,), step=True),
        Plot(AP_SATURATED, ("saturated",), ("rudder saturated",), (VERMILLION,), step=True),
        Plot(AP_GAIN_KE, ("kpe", "kie", "ke"), ("Kpe", "KIe", "Ke"), (SKY, ORANGE, WHITE)),
        Plot(AP_GAIN_KX, ("kpx", "kix", "kx"), ("Kpx", "KIx", "Kx"), (SKY, ORANGE, WHITE)),
        Plot(AP_GAIN_KU, ("kpu", "kiu", "ku"), ("Kpu", "KIu", "Ku"), (SKY, ORANGE, WHITE)),
        Plot(AP_TIMING_LOOP, ("period", "compute", "jitter"),
             ("period [s]", "compute [s]", "jitter [s]"), (GREY, GREEN, VERMILLION)),
        Plot(AP_TIMING_MISSED, ("missed",), ("missed deadlines",), (VERMILLION,), step=True),
    ),
)

LINK_FIELDS = ("rx", "tx", "rejected")


# received, sent, rejected: one colour family per link so that several links stay apart in one plot
LINK_COLORS: tuple[tuple[Rgb, Rgb, Rgb], ...] = (
    (GREEN, BLUE, VERMILLION),
    (YELLOW, SKY, PURPLE),
    (WHITE, GREY, ORANGE),
)


def link_layout(name: str, index: int = 0) -> TableLayout:
    """Counters of one MAVLink endpoint (e.g. ``"sitl"``, ``"gcs"``) at ``/autopilot/link/<name>``.

    ``index`` picks the colour family (give each link of a process its own).
    """
    if not name or "/" in name:
        raise ValueError(f"link name must be a non-empty path component, got {name!r}")
    return TableLayout(
        f"link_{name}",
        LINK_FIELDS,
        (Plot(f"{AP_LINK}/{name}", LINK_FIELDS,
              (f"{name} received", f"{name} sent", f"{name} rejected"), LINK_COLORS[index % len(LINK_COLORS)],
              step=True),),
    )


# ---------------------------------------------------------------------------------------- SITL
SITL = "/sitl"
SITL_ROLL = f"{SITL}/roll"  # phi truth                                  rad
SITL_RATES = f"{SITL}/rates"  # p, r truth                               rad/s
SITL_SIDE_VELOCITY = f"{SITL}/side_velocity"  # v truth                  m/s
SITL_RUDDER = f"{SITL}/rudder"  # delta_r truth, servo command applied   rad
SITL_RUDDER_RATE = f"{SITL}/rudder_rate"  # delta_r_dot truth            rad/s
SITL_SERVO_PWM = f"{SITL}/servo_pwm"  # PWM as received                  us
SITL_STATUS = f"{SITL}/status"  # StateChange (optional)
SITL_EVENTS = f"{SITL}/events"

# The SITL's row: the truth state x_p (sitl.model.STATE_NAMES order), then the servo command it applied
# (rad, after the PWM -> angle mapping) and the PWM it received.
SITL_EXTRA_FIELDS = ("delta_cmd", "pwm")
SITL_FIELDS = tuple(STATE_NAMES) + SITL_EXTRA_FIELDS

SITL_TABLE = TableLayout(
    "sitl",
    SITL_FIELDS,
    (
        Plot(SITL_ROLL, ("phi",), ("roll phi (truth)",), (PURPLE,)),
        Plot(SITL_RATES, ("p", "r"), ("roll rate p (truth)", "yaw rate r (truth)"), (PURPLE, GREEN)),
        Plot(SITL_SIDE_VELOCITY, ("v",), ("side velocity v (truth)",), (GREEN,)),
        Plot(SITL_RUDDER, ("delta_r", "delta_cmd"), ("rudder delta_r (truth)", "servo command applied"),
             (PURPLE, GREY)),
        Plot(SITL_RUDDER_RATE, ("delta_r_dot",), ("rudder rate (truth)",), (PURPLE,)),
        Plot(SITL_SERVO_PWM, ("pwm",), ("servo PWM received [us]",), (PURPLE,), step=True),
    ),
)

# State colours for the state timeline view (unknown states get the viewer's default colours).
MODE_COLORS: dict[str, Rgb] = {
    "STARTING": GREY, "WAITING": GREY, "MANUAL": SKY, "AUTO": GREEN, "ADAPTIVE": GREEN, "HOLD": ORANGE,
    "FAILSAFE": VERMILLION, "STOPPED": GREY,
}
FAILSAFE_COLORS: dict[str, Rgb] = {
    "OK": GREEN, "NONE": GREEN, "LINK_LOST": VERMILLION, "STALE": ORANGE, "NONFINITE": VERMILLION,
    "ACTIVE": VERMILLION,
}

# Every run of an experiment (log_experiment) lives under /runs/<name>/...
RUNS = "/runs"
RUN_COMMAND = f"{RUNS}/command"  # um, shared by all runs
RUN_REFERENCE_OL = f"{RUNS}/reference_ol"  # ym_ol, shared by all runs (driven by the same command)
RUN_PLOTS = ("roll", "reference", "rudder", "error", "gains", "state")

RUN_COLORS: dict[str, Rgb] = {
    "sac": VERMILLION, "clsac": SKY, "clsac_lv10": GREEN, "clsac_lv50": ORANGE, "clsac_lv100": PURPLE,
}
RUN_PALETTE: tuple[Rgb, ...] = (SKY, VERMILLION, GREEN, ORANGE, PURPLE, YELLOW, BLUE, WHITE)


def run_color(name: str, i: int) -> Rgb:
    return RUN_COLORS.get(name, RUN_PALETTE[i % len(RUN_PALETTE)])
