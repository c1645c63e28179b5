"""One control step, free of I/O: the setpoint at time t, the law, the rudder limit, the PWM map and the metrics.

Three users call :class:`ControlStep` once per control period and get a :class:`StepResult` back:

* the lockstep scheduler and the real-time scheduler of the autopilot process (``autopilot.loop``), which
  only add the MAVLink I/O and the timing around it;
* the in-process runner (``tools.experiment.scenario.run_inprocess``), which adds the simulated aircraft.

So the three can never drift apart: a lockstep flight over MAVLink and the in-process runner with the wire
model give bit-identical metrics (``tests/tools/flight/test_e2e_lockstep.py``).  Example::

    from autopilot import ClSacConfig, ControlStep, PwmMap
    from autopilot.step import ProfileSetpoints

    step = ControlStep(ClSacConfig(), PwmMap(), ProfileSetpoints(lambda t: 0.1745))
    res = step(0.0, phi)          # res.u: the rudder command that flies (rad), res.pwm its pulse (us)
    step.metrics.result()         # the five metrics so far (docs/spec.md, "Metrics")

Like simple-pid's controller object, the clock is injected (``t`` is an argument, never read from the
machine), the internals of each step are exposed for logging (``step.law``: the ``ClSac`` with ``e``,
``ym``, the gains ...), and ``reset()`` returns to the initial conditions.
"""

from __future__ import annotations

import enum
import math
from bisect import insort
from collections.abc import Callable
from dataclasses import dataclass

from autopilot.config import ClSacConfig, NonFiniteInputError
from autopilot.controllers import make_law
from autopilot.law import LawFailure
from autopilot.metrics import MetricsAccumulator
from autopilot.shared.pwm import PwmMap


class Failsafe(enum.Enum):
    """What a step flew on.  ``NONE``: the law on fresh data.  ``NO_ATTITUDE``: no fresh attitude, rudder
    neutral and adaptation frozen (``ClSac.hold``).  ``NO_SETPOINT``: no setpoint for the timeout, the law
    flies wings level (u_m = 0).  Both failsafes are left automatically when the data comes back."""

    NONE = "none"
    NO_ATTITUDE = "no attitude"
    NO_SETPOINT = "no setpoint"
    LAW_ERROR = "law error"  # the law raised or returned NaN/inf (autopilot.law.LawFailure): neutral from then on


@dataclass(slots=True)
class StepResult:
    """What one control step did.  Angles in rad, ``t`` in s of sim time, ``pwm`` in us (None without a map)."""

    k: int  # steps taken so far, this one included (failsafe steps count)
    t: float  # sim time of the measurement used
    um: float  # roll command u_m in force
    phi: float  # measured roll y
    u_cmd: float  # the law's command, limited to +-u_limit (paper eqs. (6), (21) + the limit)
    u: float  # the command that flies: u_cmd after the PWM map's 1 us quantisation (= u_cmd without a map)
    pwm: int | None  # its pulse width
    failsafe: Failsafe
    saturated: bool  # |u_raw| > u_limit this step


class SetpointQueue:
    """Setpoints scheduled on sim time: ``push(t_us, roll)``, then ``at(t)`` makes the last one due the command.

    Times are whole microseconds as the wire carries them (``SET_ATTITUDE_TARGET.time_boot_ms * 1000``); a
    point is due at ``t`` when its time is at most ``t`` (to 1 ns).  Until the first point, the command is 0.
    """

    __slots__ = ("_q", "_seq", "current", "limit", "evicted")

    def __init__(self, limit: int = 100_000):
        self._q: list = []  # sorted (t_us, seq, roll)
        self._seq = 0
        self.evicted = 0
        self.current = 0.0
        self.limit = limit

    def __len__(self) -> int:
        return len(self._q)

    def push(self, t_us: float, roll: float) -> bool:
        """Schedule ``roll`` (rad) at ``t_us``.  When ``limit`` points are waiting, the one furthest in the future
        makes room for an earlier one (counted in ``evicted``); False (nothing queued) if the new point would
        itself be the furthest.  A point due sooner (a "now" point above all) therefore always gets in."""
        q = self._q
        if len(q) >= self.limit:
            if not q or (t_us, self._seq + 1) >= q[-1][:2]:
                return False
            q.pop()
            self.evicted += 1
        self._seq += 1
        item = (t_us, self._seq, roll)
        if not q or item >= q[-1]:
            q.append(item)
        else:
            insort(q, item)
        return True

    def at(self, t: float) -> float:
        """Pop every point due at sim time ``t`` (s); the last one due becomes ``current``, which is returned."""
        q = self._q
        t_us = t * 1e6 + 1e-3
        if q and q[0][0] <= t_us:
            i = 0
            n = len(q)
            while i < n and q[i][0] <= t_us:
                i += 1
            self.current = q[i - 1][2]
            del q[:i]
        return self.current

    def clear(self) -> None:
        self._q.clear()
        self.current = 0.0


class ProfileSetpoints:
    """The command as a function of sim time, ``fn(t) -> rad`` (a ``tools.flight.profiles.Profile.value``, say)."""

    __slots__ = ("fn", "current")

    def __init__(self, fn: Callable[[float], float]):
        self.fn = fn
        self.current = 0.0

    def at(self, t: float) -> float:
        self.current = v = self.fn(t)
        return v


TRANSFER_TAU_S = 0.2  # bumpless mode transfer: time constant of the command's approach to the new source


class ControlStep:
    """The control step: ``step(t, phi) -> StepResult``.

    ``config``: the law (``ClSacConfig``; ``ClSacConfig.sac()`` for SAC; ``BaselineConfig`` for the fixed-gain
    baseline), or ``law=``: a law object (``ClSac``, ``autopilot.baseline.Baseline``).  ``pwm``: the servo
    calibration the command goes through (``None``: the law's command flies unquantised, as in the paper).
    ``setpoints``: any object with ``at(t) -> rad`` and a ``current`` attribute (default: an empty
    :class:`SetpointQueue`).

    ``metrics`` accumulates the five metrics from what flew (the command after the PWM map); with a PWM map,
    ``metrics_commanded`` the same from the law's own command, before quantisation.  A NaN/Inf measurement or
    command is flown as a hold (rudder neutral, adaptation frozen) and counted in ``nonfinite_inputs``.
    """

    def __init__(self, config: ClSacConfig | None = None, pwm: PwmMap | None = None, setpoints=None, *, law=None):
        # ``law``: any object that quacks like ClSac (autopilot.baseline.Baseline); by default the config's law.
        if law is None:
            config = config or ClSacConfig()
            law = make_law(config)  # its registered law (autopilot.controllers)
        self.config = law.config
        self.law = law
        self.pwm = pwm
        self.setpoints = SetpointQueue() if setpoints is None else setpoints
        dt = 1.0 / float(self.config.control_rate_hz)  # a user's Config need not have ``dt`` (autopilot.law)
        self.metrics = MetricsAccumulator(dt)
        self.metrics_commanded = MetricsAccumulator(dt) if pwm is not None else self.metrics
        self.k = 0
        self.nonfinite_inputs = 0  # steps whose measurement or command was NaN/Inf: flown as a hold
        # Ground-station modes (autopilot.vehicle): disarmed = rudder neutral; ``manual`` (rad, None = the law)
        # flies a rudder command from the ground station while the law only follows it (ClSac.hold).
        self.armed = True
        self.manual: float | None = None
        self._offset = 0.0  # bumpless transfer: added to the new source's command, decays with TRANSFER_TAU_S
        self._decay = math.exp(-dt / TRANSFER_TAU_S)
        self._transfer = False
        self.u_last = 0.0  # the last command flown (rad): where a transfer starts
        self._split = callable(getattr(law, "command", None))  # ClSac.command/advance; others step whole
        self._measures = bool(getattr(law, "MEASURES", False))  # a law on autopilot.law's interface: the rates too
        self._pending = None  # between ``command`` and ``finish``
        # A law that raised or returned NaN/inf (autopilot.law.LawFailure): its one-line reason and sim time; every
        # step from then on is a hold (rudder neutral, Failsafe.LAW_ERROR): a failed law's states are not trusted
        self.law_failure: str | None = None
        self.law_failure_t: float | None = None
        self.law_exception: BaseException | None = None

    def transfer(self) -> None:
        """A mode switch (or arming): the next command starts where the last one was and joins the new source
        exponentially (time constant ``TRANSFER_TAU_S``), so the rudder command never steps."""
        self._transfer = True

    def reconfigure(self, config: ClSacConfig) -> None:
        """Fly ``config`` from the next step, keeping the law's states (``ClSac.reconfigure``)."""
        self.law.reconfigure(config)
        self.config = config

    def _source(self, u: float) -> float:
        """The command after the bumpless transfer (the offset is 0.0 and untouched outside a transfer)."""
        if self._transfer:
            self._transfer = False
            self._offset = self.u_last - u
        if self._offset:
            u += self._offset
            self._offset = off = self._offset * self._decay
            if abs(off) < 1e-9:
                self._offset = 0.0
            lim = self.config.u_limit_rad
            u = lim if u > lim else (-lim if u < -lim else u)
        self.u_last = u
        return u

    def reset(self) -> None:
        """Back to the initial conditions (law, metrics, step count); the setpoints are the caller's."""
        self.law.reset()
        self.metrics.reset()
        self.metrics_commanded.reset()
        self.k = 0
        self.nonfinite_inputs = 0
        self.u_last = self._offset = 0.0
        self._transfer = False
        self._pending = None
        self.law_failure = self.law_failure_t = self.law_exception = None

    def __call__(self, t: float, phi: float, *, wings_level: bool = False, p: float = 0.0, r: float = 0.0):
        """One step on the measured roll ``phi`` (rad), roll rate ``p`` and yaw rate ``r`` (rad/s, ATTITUDE's
        rollspeed and yawspeed: read by a law on autopilot.law's interface) at sim time ``t`` (s).

        ``wings_level``: the setpoint stream is lost, fly u_m = 0 (``Failsafe.NO_SETPOINT``).
        """
        self.command(t, phi, wings_level=wings_level, p=p, r=r)
        return self.finish()

    def command(self, t: float, phi: float, *, wings_level: bool = False, p: float = 0.0, r: float = 0.0):
        """The first half of a step (``__call__`` is ``command`` then ``finish``): what flies, as soon as it is
        known, the pulse width (the command in rad without a PWM map).  ``finish()`` must follow before the next
        step: it completes the law's step (``ClSac.advance``) and the metrics and returns the ``StepResult``, with
        exactly the numbers of ``__call__`` (the same operations in the same order).  The lockstep autopilot sends
        the servo command between the two (docs/spec.md, "Lockstep")."""
        setpoints = self.setpoints
        um = setpoints.at(t)
        if wings_level:
            um = setpoints.current = 0.0
        law = self.law
        if not self.armed or self.manual is not None:
            # Disarmed: rudder neutral at once.  MANUAL: the ground station's rudder; the law follows it.
            if not self.armed:
                self.u_last = self._offset = 0.0
            return self._done(self._hold_step(t, phi, um, self._source(self.manual) if self.armed else 0.0))
        split = self._split
        if self.law_failure is not None:  # a failed law is not flown again
            self.u_last = self._offset = 0.0
            return self._done(self._hold_step(t, phi, um, 0.0, Failsafe.LAW_ERROR))
        try:
            # paper eqs. (6), (21), limited to +-u_limit (autopilot.clsac)
            if split:
                u_cmd = law.command(phi, um)
            elif self._measures:
                u_cmd = law(phi, um, p, r)
            else:
                u_cmd = law(phi, um)
        except LawFailure as exc:
            self.law_failure, self.law_failure_t, self.law_exception = str(exc), t, exc
            self.u_last = self._offset = 0.0
            return self._done(self._hold_step(t, phi, um, 0.0, Failsafe.LAW_ERROR))
        except NonFiniteInputError:
            # A NaN/Inf measurement or command never reaches the states or the metrics: a hold step instead.
            self.nonfinite_inputs += 1
            return self._done(self.hold(t, phi, Failsafe.NO_ATTITUDE if phi - phi != 0.0 else Failsafe.NO_SETPOINT))
        flew = False
        if self._transfer or self._offset:
            u_cmd = self._source(u_cmd)
            flew = hasattr(law, "flew")  # the PFC follows the command that flies (after the law's own step)
        else:
            self.u_last = u_cmd
        pwm_map = self.pwm
        pwm = None if pwm_map is None else pwm_map.to_pwm(u_cmd)
        self._pending = (t, um, phi, u_cmd, pwm, wings_level, flew)
        return u_cmd if pwm is None else pwm

    def _done(self, res: StepResult):
        """A step flown whole in ``command`` (a hold): ``finish`` returns it."""
        self._pending = res
        return res.u if res.pwm is None else res.pwm

    def finish(self) -> StepResult:
        """The second half of the step ``command`` began: the law's step completed, the metrics, the result."""
        pending = self._pending
        self._pending = None
        if type(pending) is StepResult:
            return pending
        t, um, phi, u_cmd, pwm, wings_level, flew = pending
        u = u_cmd if pwm is None else self.pwm.to_rad(pwm)  # the command that flew, after the 1 us quantisation
        law = self.law
        if self._split:
            law.advance()
        if flew:
            law.flew(u_cmd)
        if pwm is not None:
            self.metrics_commanded.add(phi, law.ym_ol, law.e, u_cmd)
        self.metrics.add(phi, law.ym_ol, law.e, u)
        self.k += 1
        return StepResult(
            self.k, t, um, phi, u_cmd, u, pwm, Failsafe.NO_SETPOINT if wings_level else Failsafe.NONE, law.saturated
        )

    def hold(self, t: float, phi: float = math.nan, failsafe: Failsafe = Failsafe.NO_ATTITUDE) -> StepResult:
        """A failsafe step: rudder neutral, the PFC follows it, adaptation frozen (``ClSac.hold``); no metrics."""
        self.u_last = 0.0
        self._offset = 0.0
        return self._hold_step(t, phi, self.setpoints.current, 0.0, failsafe)

    def _hold_step(self, t, phi, um, u_cmd: float, failsafe: Failsafe = Failsafe.NONE) -> StepResult:
        """A step flown by someone else's command ``u_cmd`` (failsafe, disarmed, MANUAL): the PFC follows it,
        adaptation frozen (``ClSac.hold``), no metrics.  A law whose hold raises has failed (``law_failure``: not
        called again, the command given flies all the same, a ground station's in MANUAL included)."""
        if self.law_failure is None:
            try:
                self.law.hold(u_cmd)
            except LawFailure as exc:
                self.law_failure, self.law_failure_t, self.law_exception = str(exc), t, exc
        self.k += 1
        pwm_map = self.pwm
        if pwm_map is None:
            return StepResult(self.k, t, um, phi, u_cmd, u_cmd, None, failsafe, False)
        pwm = pwm_map.to_pwm(u_cmd)
        return StepResult(self.k, t, um, phi, u_cmd, pwm_map.to_rad(pwm), pwm, failsafe, False)
