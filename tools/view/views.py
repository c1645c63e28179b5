"""Viewer layouts (Rerun blueprints): where the autopilot's and the SITL's recordings meet on screen.

``flight_blueprint`` lays out a flight (both processes' entities, ``autopilot.telemetry.layout`` and
``sitl.telemetry``); the launcher adds it when it merges the parts and shows it in a live viewer.
``experiment_blueprint`` lays out ``paper.rrd`` (entities under ``/runs``, ``tools.view.recording``).  Every
time-series and state-timeline view links its time axis to the global one (``TimeAxis(link="LinkToGlobal")``):
zooming or panning one plot moves them all.  The time panel opens on the ``sim_time`` timeline.

Each time-series and state-timeline view shows the span it is given (``span``: the flight's, or the experiment's
runs', in sim seconds) as its visible time range (``VisibleTimeRanges`` on ``sim_time``), so the plots open on the
flight and not on a window past its end.  A live viewer's layout (``trailing_s``) shows the plots over the last
``trailing_s`` seconds before the time cursor instead (what a live viewer draws stays bounded however long the flight);
its state lanes keep the whole span (a lane logs a state only when it changes).
"""

from __future__ import annotations

from collections.abc import Sequence

import rerun as rr
import rerun.blueprint as rrb

from autopilot.shared.telemetry.layout import SIM_TIME, fault_mark_path
from autopilot.telemetry import layout as A
from sitl import telemetry as S

# Every run of an experiment lives under /runs/<name>/... (tools.view.recording writes them).
RUNS = "/runs"
RUN_COMMAND = f"{RUNS}/command"  # um, shared by all runs
RUN_REFERENCE_OL = f"{RUNS}/reference_ol"  # ym_ol, shared by all runs (driven by the same command)
RUN_METRICS = f"{RUNS}/metrics"  # markdown table


def run_path(name: str, what: str) -> str:
    """The entity of one run's signal: ``/runs/<name>/<what>``."""
    return f"{RUNS}/{name}/{what}"


RUDDER_PLOT = "Rudder [deg] (fixed range: 1.25 x the limit; u_raw beyond it in Details)"
RUDDER_RAW_PLOT = "Rudder command u and unlimited u_raw [deg] (autoscaled)"


def _axis() -> rrb.TimeAxis:
    return rrb.TimeAxis(link="LinkToGlobal")


Span = tuple[float, float] | None  # (start, end) sim s; None: the whole timeline (rerun's default)


def time_range(span: Span = None, trailing_s: float | None = None) -> rrb.VisibleTimeRange | None:
    """The visible time range on ``sim_time``: the last ``trailing_s`` s before the cursor, else ``span`` (absolute,
    ns-exact), else None (rerun's default: the whole timeline)."""
    if trailing_s is not None:
        return rrb.VisibleTimeRange(
            SIM_TIME,
            start=rr.TimeRangeBoundary.cursor_relative(seconds=-float(trailing_s)),
            end=rr.TimeRangeBoundary.cursor_relative(),
        )
    if span is None:
        return None
    start, end = (round(float(t) * 1e9) for t in span)
    if not end > start:
        raise ValueError(f"a time span must end after it starts, got {span!r}")
    return rrb.VisibleTimeRange(
        SIM_TIME, start=rr.TimeRangeBoundary.absolute(nanos=start), end=rr.TimeRangeBoundary.absolute(nanos=end)
    )


# The plots a fault's start and end are marked on (autopilot.shared.telemetry.layout.fault_marks_layout).
FAULT_MARKED = frozenset(p.path for t in (A.AUTOPILOT, S.SITL_TABLE, S.SITL_HELD_TABLE) for p in t.plots) | {
    f"{A.AP_LINK}/**"
}


def _with_fault_marks(contents: Sequence[str]) -> list[str]:
    """``contents`` and the fault markers of each of its plots."""
    return list(contents) + [fault_mark_path(c) for c in contents if c in FAULT_MARKED]


def _plot_in(
    name: str,
    contents: Sequence[str],
    *,
    legend: bool = True,
    window: rrb.VisibleTimeRange | None = None,
    y_range: tuple[float, float] | None = None,
) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(
        name=name,
        origin="/",
        contents=_with_fault_marks(contents),
        axis_x=_axis(),
        axis_y=None if y_range is None else rrb.ScalarAxis(range=y_range, zoom_lock=False),
        plot_legend=rrb.PlotLegend(visible=legend),
        time_ranges=window,
    )


RUDDER_MARGIN = 1.25  # the Rudder plot's fixed y range: the surface's limit times this, on each side
DEFAULT_RUDDER_LIMIT_DEG = 30.0  # the KH2013A's rudder limit (the paper's), for a layout built without a flight


def rudder_range(limit_deg: float | None) -> tuple[float, float]:
    """The Rudder plot's y range (deg): +-RUDDER_MARGIN times the surface's limit (30 deg when not given or not a
    positive finite number), so the commanded and true deflections fill the plot whatever the unlimited command
    u_raw does (it can reach 1e5 deg when the law diverges: it is also drawn, autoscaled, in the Details tab)."""
    ok = isinstance(limit_deg, (int, float)) and 0.0 < limit_deg < float("inf")
    half = RUDDER_MARGIN * (float(limit_deg) if ok else DEFAULT_RUDDER_LIMIT_DEG)
    return -half, half


def _attitude_view() -> rrb.Spatial3DView:
    """The aircraft at its true roll (SITL) with the reference model's roll ym as a ghost, seen from behind.

    Body and world axes are FRD (x forward, y right, z down): the eye sits behind and a little above the aircraft,
    looking forward, with -z up, so a positive roll puts the right wing (screen right) down."""
    return rrb.Spatial3DView(
        name="Attitude: aircraft (true roll) and reference ym (ghost)",
        origin="/",
        contents=[S.SITL_ATTITUDE, A.AP_REFERENCE_ATTITUDE],
        eye_controls=rrb.EyeControls3D(position=(-2.1, 0.0, -0.35), look_target=(0.0, 0.0, 0.0), eye_up=(0, 0, -1)),
        line_grid=rrb.LineGrid3D(visible=False),
    )


def flight_blueprint(
    span: Span = None, *, trailing_s: float | None = None, rudder_limit_deg: float | None = None
) -> rrb.Blueprint:
    """The layout of a flight (``flight.rrd``): a "Flight" tab and a "Details" tab, fitting a 1600x1000 browser
    window (the side panels and the streams tree start collapsed; the time bar stays).

    Flight tab, top to bottom (angles in degrees, rates in deg/s):
      1. Roll tracking: command um, closed-loop reference ym, open-loop reference ym_ol, roll measured by the
         autopilot and the SITL's true roll | the aircraft in 3D at its true roll, the reference ym as a ghost.
      2. Error e | rudder (command u, unlimited u_raw, applied servo command, true deflection) on a fixed range,
         +-1.25 times the surface's limit (``rudder_limit_deg``: ``rudder_range``) | rudder PWM.
      3. Adaptive gains Ke | Kx | Ku, each with its proportional and integral parts, and a marker per PARAM_SET
         (accepted green, refused vermillion) at the gain's value then.
      4. Loop timing (period, compute, jitter) | missed deadlines | link counters.
      5. The vehicle's mode (MANUAL, SAC, CLSAC, BASELINE, FAILSAFE) and failsafe state lanes | event log of both
         processes (status texts, state changes, every PARAM_SET).
    Details tab: augmented output and PFC output, roll rate (measured vs truth) and yaw rate, side
    velocity, rudder rate, saturation flag, and the rudder command with its unlimited u_raw, autoscaled.  Held axes
    tab (a JSBSim plant): altitude, airspeed, pitch and the
    safety pilot's elevator and throttle.

    ``span`` (start, end sim s): the flight, every plot's and lane's visible time range; ``trailing_s``: a live
    viewer's plots over the last ``trailing_s`` s instead (the lanes keep ``span``).
    """
    window = time_range(span, trailing_s)
    lanes = time_range(span)

    def _plot(name: str, contents: Sequence[str]) -> rrb.TimeSeriesView:
        return _plot_in(name, contents, window=window)

    def _gains(name: str, gain: str, marks: str) -> rrb.TimeSeriesView:
        return _plot(name, [gain, marks])

    flight = rrb.Vertical(
        rrb.Horizontal(
            _plot("Roll tracking [deg]", [A.AP_ROLL, S.SITL_ROLL]),
            _attitude_view(),
            column_shares=[2.6, 1],
        ),
        rrb.Horizontal(
            _plot("Error e = ym - ya [deg]", [A.AP_ERROR]),
            _plot_in(RUDDER_PLOT, [A.AP_RUDDER, S.SITL_RUDDER], window=window, y_range=rudder_range(rudder_limit_deg)),
            _plot("Rudder PWM [us]", [A.AP_RUDDER_PWM, S.SITL_SERVO_PWM]),
            column_shares=[1, 1.4, 1],
        ),
        rrb.Horizontal(
            _gains("Gain Ke (error), PARAM_SET marks", A.AP_GAIN_KE, A.AP_PARAM_SET_KE),
            _gains("Gain Kx (reference state), PARAM_SET marks", A.AP_GAIN_KX, A.AP_PARAM_SET_KX),
            _gains("Gain Ku (command), PARAM_SET marks", A.AP_GAIN_KU, A.AP_PARAM_SET_KU),
        ),
        rrb.Horizontal(
            _plot("Loop timing [s]", [A.AP_TIMING_LOOP]),
            _plot("Missed deadlines", [A.AP_TIMING_MISSED]),
            _plot("Link counters", [f"{A.AP_LINK}/**"]),
        ),
        rrb.Horizontal(
            rrb.StateTimelineView(name="Mode and failsafe", origin=A.AP_STATUS, time_view=_axis(), time_ranges=lanes),
            rrb.TextLogView(name="Events", origin="/", contents=[A.AP_EVENTS, S.SITL_EVENTS]),
        ),
        row_shares=[2.5, 1.6, 1.6, 1.3, 1.9],
        name="Flight",
    )
    details = rrb.Grid(
        _plot("Augmented output ya and PFC output [deg]", [A.AP_AUGMENTED, A.AP_ROLL]),
        _plot("Roll and yaw rate [deg/s]", [A.AP_ROLL_RATE, S.SITL_RATES]),
        _plot("Side velocity v [m/s]", [S.SITL_SIDE_VELOCITY]),
        _plot("Rudder rate [deg/s]", [S.SITL_RUDDER_RATE]),
        _plot("Rudder saturated", [A.AP_SATURATED]),
        _plot(RUDDER_RAW_PLOT, [A.AP_RUDDER]),
        grid_columns=2,
        name="Details",
    )
    held = rrb.Grid(  # a JSBSim plant only (sitl.telemetry.SITL_HELD_TABLE): what the SITL's safety pilot held
        _plot("Altitude [m]", [S.SITL_ALTITUDE]),
        _plot("Airspeed [m/s]", [S.SITL_AIRSPEED]),
        _plot("Pitch theta [deg]", [S.SITL_PITCH]),
        _plot("Safety pilot: elevator and throttle", [S.SITL_PILOT]),
        grid_columns=2,
        name="Held axes (JSBSim)",
    )
    return rrb.Blueprint(
        rrb.Tabs(flight, details, held, active_tab=0),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(timeline=SIM_TIME, state="collapsed"),
        auto_views=False,
    )


def experiment_blueprint(run_names: Sequence[str], span: Span = None) -> rrb.Blueprint:
    """Every run side by side (``paper.rrd``): overlays of roll, references, error, rudder and gains; a tab per run.
    ``span`` (start, end sim s): the runs', every plot's visible time range."""
    names = list(run_names)
    window = time_range(span)

    def _plot(name: str, contents: Sequence[str]) -> rrb.TimeSeriesView:
        return _plot_in(name, contents, window=window)

    def each(what: str) -> list[str]:
        return [run_path(n, what) for n in names]

    overlay = rrb.Vertical(
        _plot("Roll: command, open-loop reference and every run [deg]", [RUN_COMMAND, RUN_REFERENCE_OL, *each("roll")]),
        rrb.Horizontal(
            _plot("Closed-loop reference ym per run [deg]", [RUN_REFERENCE_OL, *each("reference")]),
            _plot("Error e per run [deg]", each("error")),
        ),
        _plot("Rudder command u per run [deg]", each("rudder")),
        rrb.Horizontal(
            _plot("Ke per run", each("gains/ke")),
            _plot("Kx per run", each("gains/kx")),
            _plot("Ku per run", each("gains/ku")),
        ),
        rrb.TextDocumentView(name="Metrics", origin=RUN_METRICS),
        row_shares=[3, 2, 2, 2, 1.2],
        name="All runs",
    )
    per_run = [
        rrb.Vertical(
            _plot(f"{n}: roll [deg]", [RUN_COMMAND, RUN_REFERENCE_OL, run_path(n, "reference"), run_path(n, "roll")]),
            _plot(f"{n}: rudder [deg]", [run_path(n, "rudder")]),
            _plot(f"{n}: gains, proportional and integral parts", [run_path(n, "gains/parts")]),
            _plot(f"{n}: aircraft state", [run_path(n, "state")]),
            name=n,
        )
        for n in names
    ]
    return rrb.Blueprint(
        rrb.Tabs(overlay, *per_run, active_tab=0),
        rrb.TimePanel(timeline=SIM_TIME),
        auto_views=False,
    )
