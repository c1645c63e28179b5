"""The generic shape of a recording: timelines, tables and plots, colours.  Plain data, no rerun import.

A *table* is what a process appends once per sample: a fixed tuple of numbers (its ``fields``).  The
writer fans every row out to a few *plots*: one Rerun entity each, holding several scalar series that
share a y axis (a multi-instance ``Scalars`` column, with ``SeriesLines`` names and colours logged once as
static data).  Signals that belong in one chart share one entity, so a TimeSeriesView shows them together
without any set-up.  Which tables a process has is its own layout (``autopilot.telemetry.layout``,
``sitl.telemetry``).

Units are SI everywhere (rad, rad/s, m/s, s); the only others are PWM pulse widths (us, as on the wire)
and counters.

Timelines (both on every row):
  ``sim_time``   duration, the simulated time of the sample, rounded to the nanosecond so that every
                 process puts the same instant on exactly the same index value;
  ``wall_time``  timestamp, the host clock (``time.time()``) when the sample was taken.
"""

from __future__ import annotations

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
