"""The autopilot loop's plain parts: its options, the per-step record its hooks get, the timing statistics,
the attitude it holds, and the message ids and constants the schedulers share.
"""

from __future__ import annotations

import math
import random
import time
from array import array
from dataclasses import dataclass, field

from autopilot.clsac import ClSac
from autopilot.envelope import Envelope
from autopilot.params import ATTITUDE_TIMEOUT_S
from autopilot.shared.link import ANY_COMPONENT
from autopilot.shared.mavlink import (
    GCS_SYSTEMS,
    mavlink,
)
from autopilot.step import StepResult

M = mavlink


ATTITUDE = M.MAVLINK_MSG_ID_ATTITUDE


HEARTBEAT = M.MAVLINK_MSG_ID_HEARTBEAT


STATUSTEXT = M.MAVLINK_MSG_ID_STATUSTEXT


SET_ATTITUDE_TARGET = M.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET


SERVO_OUTPUT_RAW = M.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW


COMMAND_ACK = M.MAVLINK_MSG_ID_COMMAND_ACK  # from the SITL: its answer to a relayed MAV_CMD_INJECT_FAILURE


_TELEMETRY_IDS = (ATTITUDE, M.MAVLINK_MSG_ID_ATTITUDE_TARGET, SERVO_OUTPUT_RAW)


# Real time: the last stretch before a deadline is a pure spin (no syscalls), so an input handled while
# spinning cannot make the step late.
_SPIN_TIGHT_S = 50e-6


SITL_RESTART_MS = 1000  # real time: an ATTITUDE this far behind the one held is a restarted SITL's clock


ATTITUDE_AHEAD_MS = 50.0  # real time: an ATTITUDE this far ahead of the held one's clock is rejected


SELF_STALL_S = 1.0  # lockstep: a pass of the loop this long means the autopilot itself did not run


# HEARTBEAT: 1 Hz once the SITL and a ground station have answered.  Until then the autopilot announces itself
# every ANNOUNCE_FAST_S for its first ANNOUNCE_FAST_FOR_S, then every ANNOUNCE_SLOW_S.  The launcher starts the three
# processes together, so the autopilot's first HEARTBEAT often goes out before the SITL's socket is bound and is
# lost; a lockstep flight cannot start before the next one (with a 1 s period, 3 of 8 launches waited a whole
# second for it).  Twenty a second for two seconds costs nothing, and a peer that never comes is not flooded.
HEARTBEAT_PERIOD_S = 1.0
ANNOUNCE_FAST_S = 0.05
ANNOUNCE_FAST_FOR_S = 2.0
ANNOUNCE_SLOW_S = 0.25


# The control loop first (docs/security.md, "A ground station that holds the key"): every peer's datagrams are
# checked within a budget per control period of wall time, the rest read and dropped (``over_budget``): each
# admitted ground station PEER_BUDGET (PEER_BURST at once), all other addresses together OTHERS_BUDGET (as many at
# once); the real-time SITL link at least SITL_PEER_RATE a second (five times the highest sensor rate).  The lockstep
# SITL is not limited: its frames are the run.  At a low control rate a station still gets PEER_RATE_MIN a second
# (the GCS script alone sends 21 a second in real time).
PEER_BUDGET = 16
PEER_BURST = 256
PEER_RATE_MIN = 1000.0
OTHERS_BUDGET = 256
SITL_PEER_RATE = 5000.0
# A ground station admitted by its signature that sent no HEARTBEAT for this long loses its slot (MAVLink's heartbeat
# protocol: disconnected after four or five missed 1 Hz heartbeats); its next signed packet takes a free one again.
GCS_SLOT_EXPIRE_S = 5.0


TIMING_SAMPLES_MAX = 100_000  # per timing series: a uniform sample of all steps (reservoir), for the percentiles


@dataclass
class AutopilotOptions:
    rate_hz: float = 100.0
    lockstep: bool = False
    duration_s: float = (
        0.0  # 0 = until stopped; lockstep: sim seconds from the first frame; real time: seconds of control
    )
    telemetry_rate_hz: float = 50.0
    attitude_timeout_s: float = ATTITUDE_TIMEOUT_S
    setpoint_timeout_s: float = 1.0
    max_roll_rad: float = math.radians(45.0)
    setpoint_ahead_s: float = 10.0  # a SET_ATTITUDE_TARGET scheduled further ahead of sim time is rejected
    # SET_ATTITUDE_TARGET.time_boot_ms: "sim" = a schedule on sim time (0 or past = now; the GCS script's lockstep
    # schedule); "now" = ignored, every setpoint flies on arrival (as ArduPilot and PX4 do), for ground stations
    # that stamp their own clock (MAVSDK stamps its host's uptime)
    setpoint_time: str = "sim"
    pace: bool = True  # lockstep: wait for the GCS schedule horizon
    spin_s: float = 0.0003  # real time: busy-wait (serving the links) this long before each deadline; inf = never sleep
    sitl: tuple = ("127.0.0.1", 14560)
    sitl_bind: tuple = ("127.0.0.1", 0)
    gcs: tuple = ("127.0.0.1", 14550)
    gcs_bind: tuple = ("127.0.0.1", 0)
    sysid: int = 1  # the vehicle's MAVLink system id (--sysid): 1:1 to the ground stations, 1:140 to the SITL
    gcs_ids: tuple = tuple((s, ANY_COMPONENT) for s in GCS_SYSTEMS)  # (sys, comp); comp ANY_COMPONENT = any
    learn_gcs: bool = True  # also take any system that sends a MAV_TYPE_GCS HEARTBEAT (off with --gcs-id)
    gcs_peers: tuple = ()  # ground-station addresses admitted from the start (--gcs-peer)
    max_gcs: int = 8  # admitted ground-station addresses at most (docs/spec.md, "Trust model")
    signing_key: bytes | None = None  # MAVLink 2 signing on both links (autopilot.shared.signing); None = off
    # SYS_FAILURE_EN: 1 = MAV_CMD_INJECT_FAILURE from a ground station is relayed to the SITL (autopilot.injection)
    failure_injection: float = 0.0
    lockstep_spin_s: float = 0.0  # lockstep: busy-poll this long for the next frame before sleeping in select
    lockstep_idle_exit_s: float = (
        0.0  # lockstep: exit after the last frame if the SITL stays silent this long (0 = never)
    )
    name: str = "clsac"
    verbose: bool = True
    envelope: Envelope = Envelope()  # the limits of a controlled flight (autopilot.envelope), judged every step


@dataclass(slots=True, kw_only=True)
class StepRecord:
    """What one control step did, handed to every ``Autopilot.hooks`` callable after the servo went out.

    ``result``: the :class:`autopilot.step.StepResult` (sim time ``t``, ``um``, ``phi``, ``u``, ``pwm``,
    ``failsafe`` ...).  The scheduler adds: ``frame`` (lockstep frame index, None in real time), ``wall``
    (``time.perf_counter()`` at the start of the step), the measured rates ``p``, ``r`` (rad/s), and timing in
    s: ``period`` since the previous step's start, ``lateness`` start minus deadline (0 in lockstep),
    ``compute`` start to servo sent, ``latency`` attitude (or unblocking setpoint) received to servo sent (in
    real time that is the attitude's age, including the wait for the deadline), ``missed`` (a deadline was
    missed).  ``ctrl`` is the ``ClSac`` (``ctrl.telemetry()``), ``ap`` the Autopilot (links, counters).
    """

    result: StepResult
    frame: int | None
    wall: float
    p: float
    r: float
    period: float | None
    lateness: float
    compute: float
    latency: float | None
    missed: bool
    ctrl: ClSac
    ap: object  # the autopilot.loop.Autopilot that flew the step (its vehicle, control step, links)


@dataclass
class _Attitude:
    ms: int = -1
    roll: float = 0.0
    yaw: float = 0.0  # heading (ATTITUDE.yaw), relayed to the GCS
    p: float = 0.0
    r: float = 0.0
    t_rx: float = -1.0  # perf_counter when received
    valid: bool = False


@dataclass
class TimingStats:
    """Per-step timing (seconds) and summary percentiles, in bounded memory whatever the flight's length: each
    series keeps a uniform random sample of at most TIMING_SAMPLES_MAX of its values (reservoir sampling,
    Vitter's algorithm R) and its exact maximum; ``last_compute`` is the newest step's compute time."""

    period: array = field(default_factory=lambda: array("d"))
    lateness: array = field(default_factory=lambda: array("d"))
    compute: array = field(default_factory=lambda: array("d"))
    latency: array = field(default_factory=lambda: array("d"))
    missed: int = 0
    last_compute: float = 0.0
    seen: dict = field(default_factory=dict)  # series name -> values offered so far
    maxima: dict = field(default_factory=dict)  # series name -> exact maximum
    minima: dict = field(default_factory=dict)  # series name -> exact minimum
    _rng: random.Random = field(default_factory=lambda: random.Random(0), repr=False)

    def _sample(self, name: str, values: array, v: float) -> None:
        n = self.seen.get(name, 0) + 1
        self.seen[name] = n
        if v > self.maxima.get(name, -math.inf):
            self.maxima[name] = v
        if v < self.minima.get(name, math.inf):
            self.minima[name] = v
        if len(values) < TIMING_SAMPLES_MAX:
            values.append(v)
        else:
            j = int(self._rng.random() * n)
            if j < TIMING_SAMPLES_MAX:
                values[j] = v

    def add(self, period, lateness, compute, latency):
        self.last_compute = compute
        if period is not None:
            self._sample("period", self.period, period)
        if lateness is not None:
            self._sample("lateness", self.lateness, lateness)
        self._sample("compute", self.compute, compute)
        if latency is not None:
            self._sample("latency", self.latency, latency)

    def summary(self, nominal_period: float) -> dict:
        def pct(values, name=None, top=None, scale=1e3):
            if not values:
                return None
            s = sorted(values)
            n = len(s)

            def q(p):
                return s[min(n - 1, int(math.ceil(p / 100.0 * n)) - 1 if p > 0 else 0)] * scale

            top = self.maxima[name] if top is None else top  # exact, not the sample's
            return {"p50": q(50), "p99": q(99), "max": top * scale, "n": self.seen.get(name, n)}

        jitter = [abs(p - nominal_period) for p in self.period]
        jitter_max = (
            max(self.maxima["period"] - nominal_period, nominal_period - self.minima["period"]) if jitter else None
        )
        return {
            "period_ms": nominal_period * 1e3,
            "period_jitter_ms": pct(jitter, "period", jitter_max),
            "lateness_ms": pct(self.lateness, "lateness"),
            "compute_ms": pct(self.compute, "compute"),
            "latency_ms": pct(self.latency, "latency"),
            "missed_deadlines": self.missed,
        }


def _wall_usec() -> int:
    """Real-time SERVO_OUTPUT_RAW.time_usec: Unix microseconds mod 2**32 (monotonic across restarts)."""
    return (time.time_ns() // 1000) & 0xFFFFFFFF
