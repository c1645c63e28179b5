"""The flight envelope: what "controlled" means, defined once (docs/design.md, section 4, "Three outcomes").

A flight is **controlled** when it stayed inside the envelope for the whole flight:

* max |roll| < ``Envelope.max_roll_deg`` (default 60 deg), and
* the rudder command was saturated in < ``Envelope.max_saturated_share`` of the control steps (default 20 %).

Both inequalities are strict: a flight exactly at a limit has left the envelope.  A step's command is
**saturated** when it is at the rudder limit, |u| >= (1 - ``SAT_RTOL``) u_limit, or not finite (:func:`saturated`).
The laws clip their command to exactly +-u_limit (``autopilot.clsac``: u = sat(u_raw)), so with the relative
tolerance of 1e-9 this is the laws' own flag ``|u_raw| > u_limit`` (a command closer than 1e-9 u_limit to the limit
without being clipped counts too); a NaN command counts as saturated, as ``u != u_raw`` does.

One definition, three forms, all calling the same code:

* :func:`within`: the inequalities on accumulated statistics, elementwise on numpy arrays (the robustness study's
  ``bounded``, ``tools.experiment.study``);
* :class:`EnvelopeMonitor`: one sample per control step, in constant memory (the autopilot while flying, which
  announces each excursion once: ``add`` returns its text);
* :func:`judge_series`: a recorded flight's roll and command series fed through the monitor (``tools.experiment``).

Each returns, or :func:`judge` builds, a :class:`Controlled`: ``ok``, ``max_abs_roll_deg``, ``saturated_share``,
``first_exit_s`` (flight time of the first excursion that decided the verdict, None when controlled) and a
one-line ``reason`` with the numbers.  No I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

MAX_ROLL_DEG = 60.0  # default roll limit of the envelope
MAX_SATURATED_SHARE = 0.20  # default share of the flight's control steps with the rudder at its limit
SAT_RTOL = 1e-9  # relative tolerance of "at the limit": |u| >= (1 - SAT_RTOL) u_limit
SHARE_MIN_S = 5.0  # the running saturated share is judged (and announced) from this flight time on
ROLL_REARM_DEG = 5.0  # a roll excursion is announced again only after |roll| came back this far inside the limit
SHARE_REARM = 0.9  # a saturation excursion is announced again only after the running share fell below 0.9 x limit


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
        }


def _finite_or_none(x: float):
    return x if math.isfinite(x) else None


def _deg(rad: float) -> float:
    return math.degrees(rad) if math.isfinite(rad) else math.inf


def judge(
    max_abs_roll_rad: float,
    saturated_share: float,
    envelope: Envelope = Envelope(),
    *,
    samples: int,
    roll_exit_s: float | None = None,
    share_exit_s: float | None = None,
) -> Controlled:
    """The verdict from a flight's statistics: ``samples`` control steps, of which ``saturated_share`` saturated,
    max |roll| ``max_abs_roll_rad``; ``roll_exit_s`` / ``share_exit_s``: when |roll| first reached its limit and
    when the running share first reached its limit (flight time, s; None if never)."""
    roll_deg = _deg(max_abs_roll_rad)
    pct = 100.0 * saturated_share
    lim_roll, lim_pct = envelope.max_roll_deg, 100.0 * envelope.max_saturated_share
    if samples <= 0:
        return Controlled(False, math.nan, math.nan, None, "no control step was flown", envelope, 0)
    roll_in = bool(max_abs_roll_rad < envelope.max_roll_rad)
    share_in = bool(saturated_share < envelope.max_saturated_share)
    numbers = f"max |roll| {roll_deg:.1f} deg, {envelope.surface} saturated {pct:.1f} % of the flight"
    if not envelope.check:
        return Controlled(True, roll_deg, saturated_share, None, f"not checked: {numbers}", envelope, samples)
    if roll_in and share_in:
        why = f"controlled: {numbers} (limits {lim_roll:g} deg, {lim_pct:g} %)"
        return Controlled(True, roll_deg, saturated_share, None, why, envelope, samples)
    parts, exits = [], []
    if not roll_in:
        # the peak and when the limit was first passed are two instants: say which is which
        at = "" if roll_exit_s is None else f"; first past it at {roll_exit_s:.1f} s"
        parts.append(f"|roll| reached {roll_deg:.1f} deg (limit {lim_roll:g}{at})")
        exits.append(roll_exit_s)
    if not share_in:
        parts.append(f"{envelope.surface} saturated {pct:.1f} % of the flight (limit {lim_pct:g} %)")
        exits.append(share_exit_s)
    known = [t for t in exits if t is not None]
    first_exit = min(known) if known else None
    return Controlled(False, roll_deg, saturated_share, first_exit, "; ".join(parts), envelope, samples)


class EnvelopeMonitor:
    """The envelope judged online, one sample per control step in constant memory.

    ``add(t, roll, u, u_limit)`` takes the step's sim time (s), measured roll, rudder command (rad, after the limit)
    and the limit in force (rad: a parameter may change it in flight); it
    returns the text of an excursion when this sample leaves the envelope, else None.  Each excursion is announced
    once: |roll| reaching the limit (again only after coming back ``ROLL_REARM_DEG`` inside it), and the running
    saturated share reaching its limit from ``SHARE_MIN_S`` of flight time on (again only after falling below
    ``SHARE_REARM`` x the limit).  With the check off nothing is announced.  ``result()``: the :class:`Controlled`
    of the samples so far (the whole flight at the end), from the same counts.
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

    def add(self, t: float, roll: float, u: float, u_limit_rad: float) -> str | None:
        if self.t0 is None:
            self.t0 = t
        self.t_last = t
        ft = t - self.t0  # flight time
        self.n += 1
        if saturated(u, u_limit_rad):
            self.n_saturated += 1
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
        if text is not None and self.envelope.check:
            self.excursions += 1
            return text
        return None

    @property
    def saturated_share(self) -> float:
        return self.n_saturated / self.n if self.n else math.nan

    def result(self) -> Controlled:
        share_exit = self.share_exit_s
        if share_exit is None and self.n and self.saturated_share >= self._share_lim:
            share_exit = self.t_last - self.t0  # a flight shorter than SHARE_MIN_S: it ended outside
        return judge(
            self.max_abs_roll,
            self.saturated_share,
            self.envelope,
            samples=self.n,
            roll_exit_s=self.roll_exit_s,
            share_exit_s=share_exit,
        )


def judge_series(t, roll, u, u_limit_rad: float, envelope: Envelope = Envelope()) -> Controlled:
    """The verdict on a recorded flight: its sim times (s), roll and rudder command series (rad), one sample per
    control step, and the rudder limit (rad), fed through :class:`EnvelopeMonitor` (so it is the autopilot's
    verdict on the same samples)."""
    import numpy as np

    mon = EnvelopeMonitor(envelope)
    lim = float(u_limit_rad)
    for ti, ri, ui in zip(*(np.asarray(a, dtype=float).tolist() for a in (t, roll, u))):
        mon.add(ti, ri, ui, lim)
    return mon.result()
