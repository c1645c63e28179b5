"""The flight envelope: what "controlled" means, defined once (docs/spec.md, section 5, "Three outcomes").

A flight is **controlled** when it stayed inside the envelope for the whole flight:

* max |roll| < ``Envelope.max_roll_deg`` (default 60 deg),
* the rudder command was saturated in < ``Envelope.max_saturated_share`` of the control steps (default 20 %), and
* it **tracked** the command in every window of ``TRACK_WINDOW_S`` (20 s, sliding by 1 s; judged when a reference
  response is given: the autopilot's and the study's law's y_m,ol): no sustained oscillation and the roll
  following the command (:func:`window_flags`, below), and
* the **law flew it**: a ground station had the loop (disarmed, or in MANUAL) for < ``GROUND_STATION_SHARE_MAX``
  (half) of the control steps, when they are counted (the autopilot's monitor): a flight the law did not fly for
  most of its length says nothing of the law (issue 35: a DISARM for 97 % of a 300 s flight ended OK).

Both inequalities are strict: a flight exactly at a limit has left the envelope.  A step's command is
**saturated** when it is at the rudder limit, |u| >= (1 - ``SAT_RTOL``) u_limit, or not finite (:func:`saturated`).
The laws clip their command to exactly +-u_limit (``autopilot.clsac``: u = sat(u_raw)), so with the relative
tolerance of 1e-9 this is the laws' own flag ``|u_raw| > u_limit`` (a command closer than 1e-9 u_limit to the limit
without being clipped counts too); a NaN command counts as saturated, as ``u != u_raw`` does.

One definition, three forms on the same code, each giving a :class:`Controlled`: :func:`within` (accumulated
statistics, elementwise: the robustness study's ``bounded``), :class:`EnvelopeMonitor` (one sample per control step,
constant memory: the autopilot, which announces each excursion once) and :func:`judge_series` / :func:`verdict` (a
recorded flight: every other route).

**Tracking** (docs/spec.md, section 5, "Three outcomes").  The deviation d = phi - y_r from the commanded
response y_r (the law's reference model y_m,ol driven by the command: the response the loop was designed to give,
the reference of the ise_ref metric, so a step's designed rise is not an error) is judged over each window of
``TRACK_WINDOW_S`` = 20 s (two periods of the reference square wave, four of its steps: a sustained oscillation
must last that long), sliding by ``TRACK_BLOCK_S`` = 1 s, from its sums (:func:`window_flags`):

* **sustained oscillation**, whether or not the surface reaches its stops: at least ``OSC_SWINGS_MIN`` (16)
  **regular swings** of d in the window (``autopilot.swings``: d moving ``OSC_SWING_DEG``, 4 deg, back from its last
  extreme, a hysteresis below which noise counts nothing; regular when its size and duration are within
  ``OSC_REGULAR_TOL``, 15 %, of the previous swing's; the measured counts that set the limits: docs/spec.md,
  section 5).  Also (issue 29's rule, kept): rms(d) >= ``DEVIATION_RATIO`` (1) x max(rms(y_r), ``REF_FLOOR_DEG``,
  2 deg: a command near level) *and* at least ``STOP_HITS_MIN`` (10) hits of the stops (a hit: the command at a
  stop after it was back within ``HIT_REARM``, half, of the limit): no better than holding the wings level
  (phi = 0 gives rms(d) = rms(y_r)), banging the surface from stop to stop.
* **not following**: where rms(y_r) >= ``REF_FLOOR_DEG``, the in-phase response g = sum(phi y_r) / sum(y_r^2) (the
  least-squares gain of y_r in phi: 1 when phi follows y_r, 0 when it ignores it or lags 90 deg) below
  ``FOLLOW_GAIN_MIN`` = 0.5, or the deviation at least ``DEVIATION_MAX`` (1.5) x rms(y_r): half as bad again as
  holding the wings level, whatever its shape (a slow swing or a drift makes neither 16 swings nor 10 hits).

Flights shorter than one window are not judged on tracking (the reason says so).  A window's numbers are
:class:`TrackWindow`'s (amplitude sqrt(2) std(d); mean frequency by Rice's formula).

**Recovery** after a fault is ``autopilot.recovery``.  No I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from autopilot.swings import (  # the swing counter of the oscillation rule (module docstring, "Tracking")
    _UP,
    OSC_REGULAR_TOL,
    OSC_SWING_DEG,
    OSC_SWINGS_MIN,
    _swing_step_float,
    swing_start,
)

MAX_ROLL_DEG = 60.0  # default roll limit of the envelope
MAX_SATURATED_SHARE = 0.20  # default share of the flight's control steps with the rudder at its limit
SAT_RTOL = 1e-9  # relative tolerance of "at the limit": |u| >= (1 - SAT_RTOL) u_limit
SHARE_MIN_S = 5.0  # the running saturated share is judged (and announced) from this flight time on
ROLL_REARM_DEG = 5.0  # a roll excursion is announced again only after |roll| came back this far inside the limit
SHARE_REARM = 0.9  # a saturation excursion is announced again only after the running share fell below 0.9 x limit
GROUND_STATION_SHARE_MAX = 0.5  # steps disarmed or in MANUAL, as a share of the flight: at or past it, not controlled

# Tracking (module docstring, "Tracking"): windows of TRACK_BLOCKS blocks of TRACK_BLOCK_S of flight time.
TRACK_WINDOW_S = 20.0  # the window a sustained oscillation or a failure to follow is judged over
TRACK_BLOCK_S = 1.0  # the windows slide by one block
TRACK_BLOCKS = 20  # TRACK_WINDOW_S / TRACK_BLOCK_S
DEVIATION_RATIO = 1.0  # rms(phi - y_r) >= this x max(rms(y_r), REF_FLOOR_DEG): no better than wings level
REF_FLOOR_DEG = 2.0  # RMS of the commanded response below which the command counts as level
STOP_HITS_MIN = 10  # hits of the rudder's stops in a window that make a deviation an oscillation
HIT_REARM = 0.5  # a hit counts again only after the command came back within this fraction of the limit
FOLLOW_GAIN_MIN = 0.5  # the roll's in-phase response below this fraction of the commanded one: not following
DEVIATION_MAX = 1.5  # rms(phi - y_r) >= this x rms(y_r) (a command not level): not following, whatever its shape
DEV_MAX2 = DEVIATION_MAX * DEVIATION_MAX
REF_FLOOR2 = math.radians(REF_FLOOR_DEG) ** 2  # per sample, rad^2
DEV_RATIO2 = DEVIATION_RATIO * DEVIATION_RATIO
DEV_FLOOR2 = DEV_RATIO2 * REF_FLOOR2  # per sample, rad^2


class EnvelopeError(ValueError):
    """A limit of the envelope out of its range; the one-line message names the limit and gives the value."""


@dataclass(frozen=True)
class Envelope:
    """The limits of a controlled flight.  ``check=False`` turns the check off: every flight is then judged
    controlled (the numbers are still measured and reported)."""

    max_roll_deg: float = MAX_ROLL_DEG  # (0, 180]
    max_saturated_share: float = MAX_SATURATED_SHARE  # (0, 1]
    check: bool = True
    surface: str = "rudder"  # the surface the command drives, as the reasons name it (the plant's: aileron, rudder)

    def __post_init__(self) -> None:
        r, s = self.max_roll_deg, self.max_saturated_share
        if not (isinstance(r, (int, float)) and math.isfinite(r) and 0.0 < r <= 180.0):
            raise EnvelopeError(f"max_roll_deg must be in (0, 180] deg, got {r!r}")
        if not (isinstance(s, (int, float)) and math.isfinite(s) and 0.0 < s <= 1.0):
            raise EnvelopeError(f"max_saturated_share must be in (0, 1], got {s!r}")

    @property
    def max_roll_rad(self) -> float:
        return math.radians(self.max_roll_deg)

    def limits(self) -> dict:
        return {"max_abs_roll_deg": self.max_roll_deg, "max_saturated_share": self.max_saturated_share}


def saturated(u, u_limit_rad: float):
    """Whether the command ``u`` (rad; a float or an array, elementwise) is at the limit ``u_limit_rad``:
    |u| >= (1 - SAT_RTOL) u_limit, or u is not finite."""
    inside = abs(u) < (1.0 - SAT_RTOL) * u_limit_rad  # False for NaN
    return not inside if isinstance(inside, bool) else ~inside  # numpy bools and arrays: elementwise


def within(max_abs_roll_rad, saturated_share, envelope: Envelope = Envelope()):
    """The envelope's inequalities (check on or off aside): max |roll| < limit and saturated share < limit.
    Elementwise on numpy arrays (a batch of flights); NaN statistics are outside."""
    return (max_abs_roll_rad < envelope.max_roll_rad) & (saturated_share < envelope.max_saturated_share)


def window_flags(n, s_rr, s_pr, s_dd, hits, swings):
    """(oscillating, not_following) of windows from their sums over ``n`` samples (module docstring, "Tracking"):
    ``s_rr`` = sum y_r^2, ``s_pr`` = sum phi y_r, ``s_dd`` = sum (phi - y_r)^2 (rad^2), ``hits`` = the rudder
    command's stop hits (:func:`stop_hit`), ``swings`` = the regular swings of phi - y_r (:func:`swing_step`).
    Elementwise on numpy arrays (the study's batch; its C kernel evaluates the same inequalities in the same
    order); NaN sums are neither (a diverged run leaves the envelope by its roll)::

        oscillating   = swings >= OSC_SWINGS_MIN  or  (s_dd >= DEVIATION_RATIO^2 s_rr
                        and  s_dd >= DEVIATION_RATIO^2 REF_FLOOR^2 n  and  hits >= STOP_HITS_MIN)
        not_following = s_rr >= REF_FLOOR^2 n  and  (s_pr < FOLLOW_GAIN_MIN s_rr  or  s_dd >= DEVIATION_MAX^2 s_rr)
    """
    banging = (s_dd >= DEV_RATIO2 * s_rr) & (s_dd >= DEV_FLOOR2 * n) & (hits >= STOP_HITS_MIN)
    oscillating = (swings >= OSC_SWINGS_MIN) | banging
    not_following = (s_rr >= REF_FLOOR2 * n) & ((s_pr < FOLLOW_GAIN_MIN * s_rr) | (s_dd >= DEV_MAX2 * s_rr))
    return oscillating, not_following


def stop_hit(sat, u, u_limit_rad, armed):
    """(hit, armed after): this step's command ``u`` (``sat``: ``saturated(u, u_limit)``) hits a stop when it is
    saturated and ``armed`` (it came back within ``HIT_REARM`` x the limit since the last hit; True at the start).
    Elementwise on numpy bool arrays."""
    hit = sat & armed
    return hit, (hit ^ True) & (armed | (abs(u) <= HIT_REARM * u_limit_rad))


def tracking_limits() -> dict:
    """The tracking definition's constants, as ``summary.json`` gives them."""
    return dict(
        window_s=TRACK_WINDOW_S, step_s=TRACK_BLOCK_S, deviation_ratio=DEVIATION_RATIO, ref_floor_deg=REF_FLOOR_DEG,
        stop_hits_min=STOP_HITS_MIN, hit_rearm=HIT_REARM, follow_gain_min=FOLLOW_GAIN_MIN, deviation_max=DEVIATION_MAX,
        swing_deg=OSC_SWING_DEG, regular_tol=OSC_REGULAR_TOL, swings_min=OSC_SWINGS_MIN,
    )  # fmt: skip


# A block's sums, in this order: samples, y_r^2, phi y_r, d^2, d, (d')^2, derivative samples, stop hits, saturated,
# the flight time of its first and last sample, and the regular swings.
_N, _RR, _PR, _DD, _D, _DOT2, _NDOT, _HITS, _SAT, _T0, _T1, _SW = range(12)
BLOCK_FIELDS = _SW + 1  # the width of a block of sums
WINDOW_SUMS = (_N, _RR, _PR, _DD, _HITS, _SW)  # the fields window_flags judges a window's summed blocks by


def block_add(b, roll, ref, d, hit, swing, sat):
    """One tracked sample (d = phi - y_r, ``hit`` of :func:`stop_hit`, ``swing`` of ``swing_step``, ``sat``) into its
    block's sums ``b``: one block (a list) or, elementwise, many (numpy arrays: an (N, BLOCK_FIELDS) array's ``.T``)."""
    sums = (_N, 1), (_RR, ref * ref), (_PR, roll * ref), (_DD, d * d), (_D, d), (_HITS, hit), (_SW, swing), (_SAT, sat)
    for j, x in sums:
        b[j] += x


def _empty_block() -> list:
    return [0, 0.0, 0.0, 0.0, 0.0, 0.0, 0, 0, 0, math.nan, math.nan, 0]


@dataclass(frozen=True)
class TrackWindow:
    """One window's verdict and numbers (angles in deg at this edge, as in ``summary.json``)."""

    start_s: float  # flight time of the window's first block
    end_s: float  # and of its end
    samples: int
    oscillating: bool
    not_following: bool
    deviation_ratio: float  # rms(phi - y_r) / max(rms(y_r), REF_FLOOR_DEG)
    amplitude_deg: float  # sqrt(2) std(phi - y_r)
    frequency_hz: float  # Rice's mean frequency of phi - y_r (nan when it does not vary)
    gain: float  # sum(phi y_r) / sum(y_r^2) (nan when the command is level)
    stop_hits: int  # the rudder command's hits of its stops (``stop_hit``)
    on_stops: float  # share of the window's samples with the command saturated
    swings: int = 0  # regular swings of phi - y_r (``swing_step``)

    def to_dict(self) -> dict:
        return {k: _finite_or_none(v) if isinstance(v, float) else v for k, v in self.__dict__.items()}

    def oscillation_text(self) -> str:
        f = self.frequency_hz
        at = f" at {f:.2f} Hz" if math.isfinite(f) else ""
        return f"+-{self.amplitude_deg:.1f} deg{at}"


def _window(blocks: list, end_s: float) -> TrackWindow:
    """The window made of ``blocks`` (chronological), ending at flight time ``end_s``."""
    tot = [0, 0.0, 0.0, 0.0, 0.0, 0.0, 0, 0, 0]
    for b in blocks:
        for j in range(9):
            tot[j] += b[j]
    n, rr, pr, dd, ds, dot2, ndot, hits, sat = tot
    swings = sum(b[_SW] for b in blocks)
    osc, lag = window_flags(n, rr, pr, dd, hits, swings)
    mean = ds / n
    var = max(dd / n - mean * mean, 0.0)
    sd = math.sqrt(var)
    freq = math.nan
    t_first = next((b[_T0] for b in blocks if b[_N]), math.nan)
    t_last = next((b[_T1] for b in reversed(blocks) if b[_N]), math.nan)
    if ndot and sd > 0.0 and math.isfinite(dot2):
        dt = (t_last - t_first) / max(n - 1, 1)  # the mean sample interval
        x = dt * math.sqrt(dot2 / ndot) / (2.0 * sd)  # = sin(pi f dt) for a sampled sinusoid
        freq = math.asin(min(x, 1.0)) / (math.pi * dt) if dt > 0.0 else math.nan
    ratio = math.sqrt(dd / max(rr, REF_FLOOR2 * n)) if n else math.nan
    gain = pr / rr if rr >= REF_FLOOR2 * n and rr > 0.0 else math.nan
    start = end_s - len(blocks) * TRACK_BLOCK_S
    return TrackWindow(
        max(start, 0.0), end_s, n, bool(osc), bool(lag), ratio, math.degrees(math.sqrt(2.0) * sd), freq, gain,
        hits, sat / n if n else math.nan, swings,
    )  # fmt: skip


@dataclass(frozen=True)
class Tracking:
    """The tracking verdict of a flight: every window judged (``windows``), the first and last window that
    oscillated and that did not follow, the flight's last window, the worst deviation ratio and the smallest gain
    of all windows; ``judged`` False for a flight shorter than one window."""

    judged: bool
    windows: int
    oscillating_windows: int
    not_following_windows: int
    first_oscillation: TrackWindow | None
    last_oscillation: TrackWindow | None
    first_not_following: TrackWindow | None
    last_window: TrackWindow | None
    worst_deviation_ratio: float
    min_gain: float
    flown_s: float
    max_swings: int = 0  # the most regular swings of phi - y_r in one window
    worst_following_ratio: float = math.nan  # the largest deviation ratio of a window whose command is not level
    law_s: float = math.nan  # the time the law flew (steps with a reference response), s

    @property
    def ok(self) -> bool:
        return not (self.oscillating_windows or self.not_following_windows)

    def to_dict(self) -> dict:
        out = {k: v.to_dict() if isinstance(v, TrackWindow) else v for k, v in self.__dict__.items()}
        out = {k: _finite_or_none(v) if isinstance(v, float) else v for k, v in out.items()}
        return {**out, "ok": self.ok, "limits": tracking_limits()}

    def parts(self) -> list[str]:
        """The reasons a flight did not track, one per failure, with the numbers."""
        out = []
        w = self.first_oscillation
        if w is not None:
            last = self.last_oscillation
            lw = self.last_window
            tail = (
                f"; still at the end ({lw.start_s:.0f}-{lw.end_s:.0f} s: {lw.oscillation_text()})"
                if lw is not None and lw.oscillating
                else f"; the last oscillating window ended at {last.end_s:.0f} s"
            )
            if w.swings >= OSC_SWINGS_MIN:
                why = f"{w.swings} regular {OSC_SWING_DEG:g} deg swings, limit {OSC_SWINGS_MIN}"
            else:
                why = (
                    f"deviation {w.deviation_ratio:.2f} x the command's, limit {DEVIATION_RATIO:g}; rudder on its "
                    f"stops {w.stop_hits} times, limit {STOP_HITS_MIN}, there {100 * w.on_stops:.0f} % of the window"
                )
            out.append(
                f"sustained oscillation {w.oscillation_text()} about the commanded response in the "
                f"{TRACK_WINDOW_S:g} s window {w.start_s:.0f}-{w.end_s:.0f} s ({why}){tail}"
            )
        w = self.first_not_following
        if w is not None:
            gain = round(w.gain, 2) + 0.0  # no "-0.00"
            what = (
                f"in-phase response {gain:.2f} of the commanded (limit {FOLLOW_GAIN_MIN:g})"
                if w.gain < FOLLOW_GAIN_MIN
                else f"deviation {w.deviation_ratio:.2f} x the command's (limit {DEVIATION_MAX:g})"
            )
            out.append(
                f"the roll did not follow the command: {what} in the {TRACK_WINDOW_S:g} s window "
                f"{w.start_s:.0f}-{w.end_s:.0f} s, {self.not_following_windows} of {self.windows} windows"
            )
        return out

    def summary_text(self) -> str:
        """What an OK reason says of the tracking."""
        if not self.judged and self.flown_s < TRACK_WINDOW_S:
            return f"tracking not judged (flown {self.flown_s:.1f} s, shorter than a {TRACK_WINDOW_S:g} s window)"
        if not self.judged:  # a longer flight in which the law flew less than a window (a ground station had it)
            return (
                f"tracking not judged (the law flew {self.law_s:.1f} s of the {self.flown_s:.1f} s flight, less than "
                f"a {TRACK_WINDOW_S:g} s window)"
            )
        # every number printed here is on the OK side of the limit printed beside it
        gain = (
            f"; in-phase response >= {self.min_gain:.2f}, limit {FOLLOW_GAIN_MIN:g}; deviation <= "
            f"{self.worst_following_ratio:.2f} x the command's, limit {DEVIATION_MAX:g}"
            if math.isfinite(self.min_gain)
            else ""
        )
        return (
            f"tracked in every {TRACK_WINDOW_S:g} s window (regular {OSC_SWING_DEG:g} deg swings about the "
            f"commanded response <= {self.max_swings}, limit {OSC_SWINGS_MIN}{gain})"
        )


@dataclass(frozen=True)
class Controlled:
    """The verdict on one flight against an envelope (see the module docstring)."""

    ok: bool
    max_abs_roll_deg: float
    saturated_share: float
    first_exit_s: float | None
    reason: str
    envelope: Envelope
    samples: int
    tracking: Tracking | None = None  # None: no reference response was given (not judged on tracking)
    ground_station: dict | None = None  # time flown disarmed / in MANUAL (``ground_station_time``)

    def to_dict(self) -> dict:
        """``summary.json``'s ``controlled``."""
        return {
            "ok": self.ok,
            "max_abs_roll_deg": _finite_or_none(self.max_abs_roll_deg),
            "saturated_share": _finite_or_none(self.saturated_share),
            "first_exit_s": self.first_exit_s,
            "reason": self.reason,
            "limits": self.envelope.limits(),
            "checked": self.envelope.check,
            "samples": self.samples,
            "tracking": None if self.tracking is None else self.tracking.to_dict(),
            "ground_station": self.ground_station,
        }


def _finite_or_none(x: float):
    return x if math.isfinite(x) else None


def _deg(rad: float) -> float:
    return math.degrees(rad) if math.isfinite(rad) else math.inf


def ground_station_time(disarmed_steps: int, manual_steps: int, samples: int, period_s: float) -> dict:
    """The time a ground station took the loop from the autopilot: steps flown disarmed (rudder neutral) and in
    MANUAL (the station's rudder), in s and as shares of the flight, and ``note``, the words the verdict adds
    (None when neither happened)."""
    out = {
        "disarmed_s": disarmed_steps * period_s,
        "manual_s": manual_steps * period_s,
        "disarmed_share": disarmed_steps / samples if samples else 0.0,
        "manual_share": manual_steps / samples if samples else 0.0,
    }
    parts = []
    if disarmed_steps:
        parts.append(f"disarmed {out['disarmed_s']:.1f} s = {100 * out['disarmed_share']:.0f} %")
    if manual_steps:
        parts.append(f"in MANUAL {out['manual_s']:.1f} s = {100 * out['manual_share']:.0f} %")
    out["note"] = " and ".join(parts) + " of the flight, by a ground station" if parts else None
    return out


def judge(
    max_abs_roll_rad: float,
    saturated_share: float,
    envelope: Envelope = Envelope(),
    *,
    samples: int,
    roll_exit_s: float | None = None,
    share_exit_s: float | None = None,
    tracking: Tracking | None = None,
    ground_station: dict | None = None,
) -> Controlled:
    """The verdict from a flight's statistics: ``samples`` control steps, of which ``saturated_share`` saturated,
    max |roll| ``max_abs_roll_rad``; ``roll_exit_s`` / ``share_exit_s``: when |roll| first reached its limit and
    when the running share first reached its limit (flight time, s; None if never); ``tracking``: the windows'
    verdict (None: not judged on tracking)."""
    roll_deg = _deg(max_abs_roll_rad)
    pct = 100.0 * saturated_share
    lim_roll, lim_pct = envelope.max_roll_deg, 100.0 * envelope.max_saturated_share
    gs = ground_station
    if samples <= 0:
        return Controlled(False, math.nan, math.nan, None, "no control step was flown", envelope, 0, tracking, gs)
    roll_in = bool(max_abs_roll_rad < envelope.max_roll_rad)
    share_in = bool(saturated_share < envelope.max_saturated_share)
    track_in = tracking is None or tracking.ok
    taken = (gs["disarmed_share"] + gs["manual_share"]) if gs else 0.0  # a ground station had the loop
    law_in = bool(taken < GROUND_STATION_SHARE_MAX)
    numbers = f"max |roll| {roll_deg:.1f} deg, {envelope.surface} saturated {pct:.1f} % of the flight"
    if not envelope.check:
        return Controlled(
            True, roll_deg, saturated_share, None, f"not checked: {numbers}", envelope, samples, tracking, gs
        )
    if roll_in and share_in and track_in and law_in:
        why = f"controlled: {numbers} (limits {lim_roll:g} deg, {lim_pct:g} %)"
        if tracking is not None:
            why += f"; {tracking.summary_text()}"
        return Controlled(True, roll_deg, saturated_share, None, why, envelope, samples, tracking, gs)
    parts, exits = [], []
    if not roll_in:
        # the peak and when the limit was first passed are two instants: say which is which
        at = "" if roll_exit_s is None else f"; first past it at {roll_exit_s:.1f} s"
        parts.append(f"|roll| reached {roll_deg:.1f} deg (limit {lim_roll:g}{at})")
        exits.append(roll_exit_s)
    if not share_in:
        parts.append(f"{envelope.surface} saturated {pct:.1f} % of the flight (limit {lim_pct:g} %)")
        exits.append(share_exit_s)
    if not track_in:
        parts += tracking.parts()
        exits += [w.end_s for w in (tracking.first_oscillation, tracking.first_not_following) if w is not None]
    if not law_in:
        law = 100.0 * (1.0 - taken)
        lim = 100.0 * (1.0 - GROUND_STATION_SHARE_MAX)
        parts.append(
            f"the law flew only {law:.1f} % of the flight (limit: more than {lim:g} %; a ground station had the rest)"
        )
    known = [t for t in exits if t is not None]
    first_exit = min(known) if known else None
    return Controlled(False, roll_deg, saturated_share, first_exit, "; ".join(parts), envelope, samples, tracking, gs)


class EnvelopeMonitor:
    """The envelope judged online, one sample per control step in constant memory.

    ``add(t, roll, u, u_limit, ref=None, armed=True, manual=False)`` takes the step's sim time (s), measured roll,
    rudder command (rad, after the limit), the limit in force (rad: a parameter may change it in flight), the
    commanded response y_r (rad; None: not judged on tracking) and whether the vehicle was armed and in MANUAL; it
    returns the text of an excursion when this sample leaves the envelope, else None.  Each excursion is announced
    once: |roll| reaching the limit (again only after coming back ``ROLL_REARM_DEG`` inside it), the running
    saturated share reaching its limit from ``SHARE_MIN_S`` of flight time on (again only after falling below
    ``SHARE_REARM`` x the limit), a window that oscillates or does not follow (again only after a window that
    does neither; announced when the window's last block ends).  With the check off nothing is announced.
    ``result()``: the :class:`Controlled` of the samples so far (the whole flight at the end), from the same counts.
    """

    def __init__(self, envelope: Envelope = Envelope()):
        self.envelope = envelope
        self._roll_lim = envelope.max_roll_rad
        self._roll_rearm = max(envelope.max_roll_rad - math.radians(ROLL_REARM_DEG), 0.0)
        self._share_lim = envelope.max_saturated_share
        self.reset()

    def reset(self) -> None:
        self.n = 0
        self.n_saturated = 0
        self.max_abs_roll = 0.0
        self.t0: float | None = None
        self.t_last: float | None = None
        self.roll_exit_s: float | None = None  # first |roll| >= limit
        self.share_exit_s: float | None = None  # first running share >= limit from SHARE_MIN_S on
        self.excursions = 0
        self._roll_out = self._share_out = False
        self.n_disarmed = self.n_manual = 0
        self.n_law = 0  # steps with a reference response: the law flew them
        # tracking: the open block, the last TRACK_BLOCKS - 1 closed ones, what the windows found
        self._block: list | None = None
        self._block_index = -1
        self._ring: list = []
        self._d_prev = self._ft_prev = None
        self._hit_armed = True
        self._windows = self._n_osc = self._n_lag = 0
        self._first_osc = self._last_osc = self._first_lag = self._last_window = None
        self._worst_ratio = 0.0
        self._min_gain = math.inf
        self._max_swings = 0
        self._worst_follow = 0.0
        self._track_out = False
        self._swing: list | None = None  # the swing counter (swing_step), from the first tracked sample
        self._k = 0  # tracked samples so far

    def add(
        self, t: float, roll: float, u: float, u_limit_rad: float, ref: float | None = None, *, armed=True, manual=False
    ) -> str | None:
        if self.t0 is None:
            self.t0 = t
        self.t_last = t
        ft = t - self.t0  # flight time
        self.n += 1
        sat = saturated(u, u_limit_rad)
        if sat:
            self.n_saturated += 1
        if not armed:
            self.n_disarmed += 1
        elif manual:
            self.n_manual += 1
        a = abs(roll) if roll == roll else math.inf  # a NaN roll is outside any envelope
        if a > self.max_abs_roll:
            self.max_abs_roll = a
        text = None
        if a >= self._roll_lim:
            if self.roll_exit_s is None:
                self.roll_exit_s = ft
            if not self._roll_out:
                self._roll_out = True
                text = f"ENVELOPE: |roll| {_deg(a):.1f} deg >= {self.envelope.max_roll_deg:g} at {ft:.1f} s"
        elif a < self._roll_rearm:
            self._roll_out = False
        if ft >= SHARE_MIN_S:
            share = self.n_saturated / self.n
            if share >= self._share_lim:
                if self.share_exit_s is None:
                    self.share_exit_s = ft
                if not self._share_out:
                    self._share_out = True
                    text = text or (
                        f"ENVELOPE: {self.envelope.surface} saturated {100 * share:.0f}% >= "
                        f"{100 * self._share_lim:g}% at {ft:.0f} s"
                    )
            elif share < SHARE_REARM * self._share_lim:
                self._share_out = False
        if ref is not None:
            self.n_law += 1
            said = self._track(ft, roll, ref, u, u_limit_rad, sat)
            text = text or said
        else:
            self._d_prev = None  # the law did not fly this step: no derivative of d across the gap
        if text is not None and self.envelope.check:
            self.excursions += 1
            return text
        return None

    # ------------------------------------------------------------------------------------------- tracking
    def _track(self, ft: float, roll: float, ref: float, u: float, u_limit: float, sat: bool) -> str | None:
        j = int(math.floor(ft / TRACK_BLOCK_S + 1e-6))
        text = None
        if j != self._block_index:
            if self._block is not None:
                text = self._close(j)
            self._block, self._block_index = _empty_block(), j
        b = self._block
        d = roll - ref
        # stop_hit, swing_step and block_add on floats, written out: the same operations in the same order
        sat, armed = bool(sat), self._hit_armed
        hit = sat and armed
        self._hit_armed = not hit and (armed or abs(u) <= HIT_REARM * u_limit)
        st = self._swing
        if st is None:
            st = self._swing = swing_start(float(d))
        swing = _swing_step_float(st, float(d), float(self._k), st[_UP] != 0.0)
        b[_N] += 1
        b[_RR] += ref * ref
        b[_PR] += roll * ref
        b[_DD] += d * d
        b[_D] += d
        b[_HITS] += hit
        b[_SW] += swing
        b[_SAT] += sat
        self._k += 1
        if self._d_prev is not None and ft > self._ft_prev:
            rate = (d - self._d_prev) / (ft - self._ft_prev)
            b[_DOT2] += rate * rate
            b[_NDOT] += 1
        if b[_N] == 1:
            b[_T0] = ft
        b[_T1] = ft
        self._d_prev, self._ft_prev = d, ft
        return text

    def _close(self, j: int) -> str | None:
        """Close the open block (and empty ones up to block ``j``), judging each window that ends with one."""
        text = None
        gap = min(j - self._block_index - 1, TRACK_BLOCKS)  # blocks without a sample (a stall in real time)
        blocks = [self._block] + [_empty_block() for _ in range(max(gap, 0))]
        for k, b in enumerate(blocks):
            self._ring.append(b)
            if len(self._ring) > TRACK_BLOCKS:
                del self._ring[0]
            # a window of no sample is not judged: the law flew none of it (MANUAL, disarmed or a stall longer than
            # a window); its sums would divide by 0 samples (issue 35: re-engaging after 21 s of MANUAL crashed)
            if len(self._ring) == TRACK_BLOCKS and any(r[_N] for r in self._ring):
                end = (self._block_index + 1 + k) * TRACK_BLOCK_S
                said = self._judge(_window(self._ring, end))
                text = text or said
        return text

    def _judge(self, w: TrackWindow) -> str | None:
        if not w.samples:
            return None
        self._note(w)
        if w.oscillating or w.not_following:
            if not self._track_out:
                self._track_out = True
                if w.oscillating:
                    f = f" {w.frequency_hz:.1f} Hz" if math.isfinite(w.frequency_hz) else ""
                    return f"ENVELOPE: oscillation +-{w.amplitude_deg:.0f} deg{f} at {w.end_s:.0f} s"  # <= 50
                if w.gain >= FOLLOW_GAIN_MIN:
                    return f"ENVELOPE: roll deviation {w.deviation_ratio:.2f} x at {w.end_s:.0f} s"
                return f"ENVELOPE: roll not following ({round(w.gain, 2) + 0.0:.2f}) at {w.end_s:.0f} s"
        else:
            self._track_out = False
        return None

    def _note(self, w: TrackWindow) -> None:
        self._windows += 1
        self._last_window = w
        if w.oscillating:
            self._n_osc += 1
            self._first_osc = self._first_osc or w
            self._last_osc = w
        if w.not_following:
            self._n_lag += 1
            self._first_lag = self._first_lag or w
        if w.deviation_ratio > self._worst_ratio:
            self._worst_ratio = w.deviation_ratio
        if w.gain < self._min_gain:
            self._min_gain = w.gain
        if math.isfinite(w.gain) and not w.deviation_ratio <= self._worst_follow:
            self._worst_follow = w.deviation_ratio
        if w.swings > self._max_swings:
            self._max_swings = w.swings

    def tracking(self) -> Tracking | None:
        """The tracking verdict so far: the windows closed, and the one ending with the open block (the flight's
        last window at its end).  None if no sample had a reference response.  Leaves the monitor as it was."""
        if self._block is None:
            return None
        saved = dict(self.__dict__)  # what _note changes: attributes only, restored below
        try:
            ring = (self._ring + [self._block])[-TRACK_BLOCKS:]
            period = (self.t_last - self.t0) / (self.n - 1) if self.n > 1 else 0.0
            if len(ring) == TRACK_BLOCKS and self._block[_N]:
                self._note(_window(ring, min((self._block_index + 1) * TRACK_BLOCK_S, self._block[_T1] + period)))
            flown, law_s = (self.t_last - self.t0) if self.n else 0.0, self.n_law * period
            return Tracking(
                self._windows > 0, self._windows, self._n_osc, self._n_lag, self._first_osc, self._last_osc,
                self._first_lag, self._last_window, self._worst_ratio if self._windows else math.nan,
                self._min_gain if math.isfinite(self._min_gain) else math.nan, flown, self._max_swings,
                self._worst_follow if math.isfinite(self._min_gain) else math.nan, law_s,
            )  # fmt: skip
        finally:
            self.__dict__.update(saved)

    # ------------------------------------------------------------------------------------------- the verdict
    @property
    def saturated_share(self) -> float:
        return self.n_saturated / self.n if self.n else math.nan

    def result(self) -> Controlled:
        share_exit = self.share_exit_s
        if share_exit is None and self.n and self.saturated_share >= self._share_lim:
            share_exit = self.t_last - self.t0  # a flight shorter than SHARE_MIN_S: it ended outside
        period = (self.t_last - self.t0) / (self.n - 1) if self.n > 1 else 0.0
        return judge(
            self.max_abs_roll,
            self.saturated_share,
            self.envelope,
            samples=self.n,
            roll_exit_s=self.roll_exit_s,
            share_exit_s=share_exit,
            tracking=self.tracking(),
            ground_station=ground_station_time(self.n_disarmed, self.n_manual, self.n, period),
        )


def verdict(t, roll, u, u_limit_rad: float, envelope: Envelope = Envelope(), ref=None, *, sideslip=None) -> dict:
    """The one verdict of a recorded flight, as ``summary.json``'s ``controlled`` (the launcher's, the experiments',
    the robustness study's flights and the damage study's): :func:`judge_series`, and on a square MIMO plant its
    second channel (``sideslip``: ``autopilot.mimo.ChannelMetrics.result()``: the rudder's saturation and the
    sideslip against their limits) through ``autopilot.mimo.with_sideslip``, as the autopilot adds it."""
    out = judge_series(t, roll, u, u_limit_rad, envelope, ref).to_dict()
    if sideslip is not None:
        from autopilot.mimo import with_sideslip

        out = with_sideslip(out, sideslip)
    return out


def judge_series(t, roll, u, u_limit_rad: float, envelope: Envelope = Envelope(), ref=None) -> Controlled:
    """The verdict on a recorded flight: its sim times (s), roll and rudder command series (rad), one sample per
    control step, the rudder limit (rad) and the commanded response y_r (rad; None: not judged on tracking), fed
    through :class:`EnvelopeMonitor` (so it is the autopilot's verdict on the same samples)."""
    import numpy as np

    mon = EnvelopeMonitor(envelope)
    lim = float(u_limit_rad)
    cols = [np.asarray(a, dtype=float).tolist() for a in (t, roll, u)]
    refs = [None] * len(cols[0]) if ref is None else np.asarray(ref, dtype=float).tolist()
    for ti, ri, ui, yi in zip(*cols, refs):
        mon.add(ti, ri, ui, lim, yi)
    return mon.result()
