"""The generic shape of a recording: timelines, tables and plots, colours.  Plain data, no rerun import.

A *table* is what a process appends once per sample: a fixed tuple of numbers (its ``fields``).  The
writer fans every row out to a few *plots*: one Rerun entity each, holding several scalar series that
share a y axis (a multi-instance ``Scalars`` column, with ``SeriesLines`` names and colours logged once as
static data).  Signals that belong in one chart share one entity, so a TimeSeriesView shows them together
without any set-up.  Which tables a process has is its own layout (``autopilot.telemetry.layout``,
``sitl.telemetry``).

Rows are in SI units (rad, rad/s, m/s, s); the only others are PWM pulse widths (us, as on the wire) and
counters.  What the viewer shows may be scaled: a plot's ``scale`` multiplies its series before they are sent, so
angles are recorded and shown in degrees (``DEG_PER_RAD``; rates in deg/s), as the flags, flight.png and the
summaries give them.  A ``Pose`` draws the aircraft shape (``AIRCRAFT_BOXES``) at a row's roll angle in 3D.

Timelines (both on every row):
  ``sim_time``   duration, the simulated time of the sample, rounded to the nanosecond so that every
                 process puts the same instant on exactly the same index value;
  ``wall_time``  timestamp, the host clock (``time.time()``) when the sample was taken.
"""

from __future__ import annotations

import dataclasses
import math
import uuid
from dataclasses import dataclass

APPLICATION_ID = "clsac_autopilot"  # every process of a flight must use it (it is part of the store id)


def new_recording_id() -> str:
    """A fresh recording id for one flight (the other part of the store id); give the same one to every process
    of that flight."""
    return str(uuid.uuid4())


SIM_TIME = "sim_time"
WALL_TIME = "wall_time"

Rgb = tuple[int, int, int]
Rgba = tuple[int, int, int, int]

DEG_PER_RAD = 180.0 / math.pi  # a plot's scale for angles (rad rows shown in deg) and rates (rad/s in deg/s)

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
PALETTE: tuple[Rgb, ...] = (SKY, VERMILLION, GREEN, ORANGE, PURPLE, YELLOW, BLUE, WHITE)  # for series in turn


def wrap_angles(rad):
    """Angles (rad, a numpy array) wrapped to (-pi, pi], as ``autopilot.shared.numerics.wrap_pi`` wraps one: those
    already in it unchanged (to the bit), NaN stays NaN."""
    import numpy as np

    v = np.asarray(rad, dtype=float)
    w = np.remainder(v + math.pi, 2 * math.pi) - math.pi  # in [-pi, pi)
    w = np.where(w == -math.pi, math.pi, w)
    return np.where((v > -math.pi) & (v <= math.pi), v, w)


@dataclass(frozen=True)
class Plot:
    """One entity: the series ``fields`` (names of table fields) drawn with ``labels`` and ``colors``."""

    path: str
    fields: tuple[str, ...]
    labels: tuple[str, ...]
    colors: tuple[Rgb, ...]
    step: bool = False  # staircase lines (counters, 0/1 flags)
    scale: float = 1.0  # the series sent are the row's values times this (DEG_PER_RAD: angles in degrees)
    points: bool = False  # markers at each row (events), no lines
    wrap: bool = False  # angles (rad rows) wrapped to (-pi, pi] before the scale, as ATTITUDE reports the roll

    def shown(self, values):
        """What the viewer gets of the rows' ``values`` (rad, ...): wrapped if ``wrap``, times ``scale``."""
        if self.wrap:
            values = wrap_angles(values)
        return values if self.scale == 1.0 else values * self.scale

    def __post_init__(self) -> None:
        if not (len(self.fields) == len(self.labels) == len(self.colors)) or not self.fields:
            raise ValueError(f"{self.path}: fields, labels and colors must have the same non-zero length")
        if not self.path.startswith("/"):
            raise ValueError(f"entity paths are absolute, got {self.path!r}")
        if not (math.isfinite(self.scale) and self.scale != 0.0):
            raise ValueError(f"{self.path}: scale must be finite and non-zero, got {self.scale!r}")


# The aircraft drawn in 3D: (part, centre, half sizes) in body axes (x forward, y right, z down; a 1 m fuselage).
AIRCRAFT_BOXES: tuple[tuple[str, tuple[float, float, float], tuple[float, float, float]], ...] = (
    ("fuselage", (0.0, 0.0, 0.0), (0.5, 0.05, 0.05)),
    ("wing", (0.08, 0.0, 0.0), (0.12, 0.75, 0.012)),
    ("tailplane", (-0.42, 0.0, 0.0), (0.07, 0.25, 0.01)),
    ("fin", (-0.42, 0.0, -0.13), (0.07, 0.01, 0.13)),
)


@dataclass(frozen=True)
class Pose:
    """The aircraft shape at ``path``, rotated by a row's roll angle ``roll`` (rad, a table field) about the body x
    axis and, with ``pitch`` (a table field, rad), by the pitch angle about the body y axis before it (a
    ``Transform3D`` per row: R = R_y(theta) R_x(phi), the Euler ZYX attitude without the heading, so the aircraft
    stays in front of the camera); ``color`` with alpha below 255 draws it as a translucent ghost."""

    path: str
    roll: str
    label: str
    color: Rgba
    pitch: str | None = None

    def __post_init__(self) -> None:
        if not self.path.startswith("/"):
            raise ValueError(f"entity paths are absolute, got {self.path!r}")


@dataclass(frozen=True)
class TableLayout:
    """The row a process appends (``fields``, in order) and the plots it is split into."""

    name: str
    fields: tuple[str, ...]
    plots: tuple[Plot, ...]
    poses: tuple[Pose, ...] = ()  # 3D attitudes drawn from the same rows

    def __post_init__(self) -> None:
        if len(set(self.fields)) != len(self.fields):
            raise ValueError(f"table {self.name}: duplicate field names")
        for plot in self.plots:
            missing = [f for f in plot.fields if f not in self.fields]
            if missing:
                raise ValueError(f"table {self.name}: plot {plot.path} uses unknown fields {missing}")
        for pose in self.poses:
            if pose.roll not in self.fields:
                raise ValueError(f"table {self.name}: pose {pose.path} uses unknown field {pose.roll!r}")

    def index(self, field: str) -> int:
        return self.fields.index(field)

    def naming(self, word: str, instead: str) -> TableLayout:
        """This layout with ``word`` in its plots' and poses' labels replaced by ``instead`` (the plant's surface:
        "rudder" -> "aileron"); the entity paths, and so the viewer's layout, stay."""
        if word == instead:
            return self
        plots = tuple(
            dataclasses.replace(p, labels=tuple(s.replace(word, instead) for s in p.labels)) for p in self.plots
        )
        poses = tuple(dataclasses.replace(p, label=p.label.replace(word, instead)) for p in self.poses)
        return dataclasses.replace(self, plots=plots, poses=poses)

    @property
    def paths(self) -> tuple[str, ...]:
        return tuple(p.path for p in self.plots)


# A fault's start or end (the SITL's status text ``fault ...``, autopilot.shared.servo_failures.FAULT_PREFIX): a
# marker on each plot of a process at the plotted values then, under /<process>/fault_marks/<the plot's path>.
FAULT_MARKS = "fault_marks"


def fault_mark_path(path: str) -> str:
    """The entity of the fault markers on the plot ``path`` (``/sitl/roll`` -> ``/sitl/fault_marks/roll``)."""
    head, _, rest = path[1:].partition("/")
    return f"/{head}/{FAULT_MARKS}/{rest}"


def fault_marks_layout(table: TableLayout, color: Rgb = VERMILLION) -> TableLayout:
    """The fault markers of ``table``'s plots: a row of the same fields where a fault starts or ends, as points."""
    return TableLayout(
        f"{table.name}_fault_marks",
        table.fields,
        tuple(
            Plot(
                fault_mark_path(p.path),
                p.fields,
                tuple(f"fault: {label}" for label in p.labels),
                (color,) * len(p.fields),
                scale=p.scale,
                points=True,
                wrap=p.wrap,
            )
            for p in table.plots
        ),
    )
