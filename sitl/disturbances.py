"""Everything that makes a flight non-ideal, in one seeded bundle, and its command-line flags.

:class:`Disturbances` groups the atmosphere (``sitl.atmosphere``), the sensor errors (``sitl.sensors``), the
link faults (``sitl.faults``) and the plant scale factors (``sitl.uncertainty``) with one seed.  Each
consumer gets its own independent generator (``numpy.random.SeedSequence(seed).spawn``), so adding a
disturbance never shifts another's random stream.  Degrees appear only in the flags; everything inside is SI.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field

import numpy as np

from autopilot.shared.cli import bounded, count
from autopilot.shared.cli import seed as seed_arg
from sitl.atmosphere import ALTITUDE, Atmosphere, AtmosphereConfig, AtmosphereConfigError, DrydenConfig, Gust
from sitl.faults import FaultChannel, FaultConfig, FaultConfigError
from sitl.sensors import SensorConfig, SensorConfigError, Sensors
from sitl.uncertainty import PlantScales, UncertaintyError, draw_scales, parse_scale

STREAMS = ("atmosphere", "sensors", "uplink", "downlink", "uncertainty")
ERRORS = (AtmosphereConfigError, FaultConfigError, SensorConfigError, UncertaintyError)


@dataclass(frozen=True)
class Disturbances:
    """The non-ideal flight: air, sensors, link, plant, and the seed they draw from."""

    atmosphere: AtmosphereConfig = field(default_factory=AtmosphereConfig)
    sensors: SensorConfig = field(default_factory=SensorConfig)
    faults: FaultConfig = field(default_factory=FaultConfig)
    scales: tuple = ()  # ((name, factor or (lo, hi)), ...) as parse_scale gives them
    seed: int = 0

    def rngs(self) -> dict[str, np.random.Generator]:
        """One independent generator per consumer (STREAMS), from the seed."""
        seqs = np.random.SeedSequence(self.seed).spawn(len(STREAMS))
        return {name: np.random.default_rng(s) for name, s in zip(STREAMS, seqs)}

    def plant_scales(self) -> PlantScales:
        """The scale factors, ranges drawn with the ``uncertainty`` stream."""
        return draw_scales(dict(self.scales), self.rngs()["uncertainty"])


# ---------------------------------------------------------------------------------------------- flags
def _floats(text: str, n: int, what: str) -> tuple[float, ...]:
    parts = str(text).split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return values


def _typed(fn):
    def check(text):
        try:
            return fn(text)
        except ERRORS as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    check.__name__ = fn.__name__.lstrip("_")
    return check


@_typed
def gust_arg(text: str) -> tuple[float, float, float]:
    """``AMP,LEN,START``: m/s, m, s."""
    amp, length, start = _floats(text, 3, "AMP,LEN,START (m/s, m, s)")
    Gust(amp, length, start)  # validates
    return amp, length, start


def pair_arg(text: str) -> tuple[float, float]:
    """``A,B``: two non-negative numbers."""
    a, b = _floats(text, 2, "two numbers A,B")
    if a < 0 or b < 0:
        raise argparse.ArgumentTypeError(f"expected two numbers >= 0, got {text!r}")
    return a, b


def probability_arg(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a probability in [0, 1), got {text!r}") from None
    if not 0.0 <= v < 1.0:
        raise argparse.ArgumentTypeError(f"expected a probability in [0, 1), got {text!r}")
    return v


scale_arg = _typed(parse_scale)

# dest -> (flag, argparse keywords); the same names on python -m sitl, python -m tools.launch and Flight.
FLAGS = {
    "turbulence": ("--turbulence", dict(choices=("light", "moderate", "severe"), help="Dryden turbulence intensity")),
    "turbulence_sigma": (
        "--turbulence-sigma",
        dict(type=pair_arg, metavar="SV,SW", help="Dryden sigmas of the side and vertical gusts, m/s"),
    ),
    "turbulence_length": (
        "--turbulence-length",
        dict(type=pair_arg, metavar="LV,LW", help="Dryden scale lengths L_v, L_w, m (default from --altitude)"),
    ),
    "altitude": (
        "--altitude",
        dict(
            type=bounded(0.0, 10_000.0, "m", lo_open=True),
            metavar="M",
            help=f"altitude for the turbulence scales (default {ALTITUDE:g})",
        ),
    ),
    "gust": (
        "--gust",
        dict(
            type=gust_arg,
            action="append",
            metavar="AMP,LEN,START",
            help="1-cosine side gust: peak m/s, length m, start s (repeatable)",
        ),
    ),
    "crosswind": ("--crosswind", dict(type=bounded(-100.0, 100.0, "m/s"), metavar="M/S", help="steady side wind, m/s")),
    "roll_noise": (
        "--roll-noise",
        dict(type=bounded(0.0, 180.0, "deg"), metavar="DEG", help="white noise sigma on the reported roll"),
    ),
    "roll_bias": (
        "--roll-bias",
        dict(type=bounded(-180.0, 180.0, "deg"), metavar="DEG", help="bias on the reported roll"),
    ),
    "rate_noise": (
        "--rate-noise",
        dict(type=bounded(0.0, 10_000.0, "deg/s"), metavar="DEG/S", help="white noise sigma on the reported roll rate"),
    ),
    "rate_bias": (
        "--rate-bias",
        dict(type=bounded(-10_000.0, 10_000.0, "deg/s"), metavar="DEG/S", help="bias on the reported roll rate"),
    ),
    "sensor_delay": (
        "--sensor-delay",
        dict(type=count(0, 100_000, "samples"), metavar="N", help="delay of the reported attitude, in samples"),
    ),
    "loss": (
        "--loss",
        dict(type=probability_arg, metavar="P", help="link: loss probability per packet, each direction"),
    ),
    "delay": (
        "--delay",
        dict(
            type=bounded(0.0, 60.0, "s"),
            metavar="S",
            help="link: one-way delay (sim s in lockstep, wall s in real time)",
        ),
    ),
    "duplicate": ("--duplicate", dict(type=probability_arg, metavar="P", help="link: duplication probability")),
    "reorder": ("--reorder", dict(type=probability_arg, metavar="P", help="link: reordering probability")),
    "scale": (
        "--scale",
        dict(
            type=scale_arg,
            action="append",
            metavar="NAME=F|NAME=LO:HI",
            help="plant scale factor, or a range drawn with the seed (repeatable)",
        ),
    ),
    "seed": ("--seed", dict(type=seed_arg, metavar="N", help="seed of every disturbance (default 0)")),
}


class DisturbanceValueError(ValueError):
    """A disturbance value given from Python (``Flight`` keywords) is malformed; ``field`` names it."""

    def __init__(self, field_name: str, message: str):
        super().__init__(message)
        self.field = field_name


def parse_values(values: dict) -> dict:
    """Flag values given as text (as on the command line) or already parsed, through the flags' types.

    Repeatable flags (``gust``, ``scale``) take one item or a list of them.  Raises DisturbanceValueError
    naming the field on the first bad one; returns ``{dest: parsed value or None}``.
    """
    out = {}
    for dest, (_flag, kw) in FLAGS.items():
        value = values.get(dest)
        if value is None:
            out[dest] = None
            continue
        check = kw.get("type", str)
        repeat = kw.get("action") == "append"
        items = [value] if not repeat or isinstance(value, str) or _is_item(dest, value) else list(value)
        parsed = []
        for item in items:
            text = to_argv({dest: [item] if repeat else item})[1] if not isinstance(item, str) else item
            try:
                parsed.append(check(text))
            except (argparse.ArgumentTypeError, ValueError) as exc:
                raise DisturbanceValueError(dest, f"{dest}: {exc}") from None
            if "choices" in kw and parsed[-1] not in kw["choices"]:
                raise DisturbanceValueError(dest, f"{dest} must be one of {', '.join(kw['choices'])}, got {item!r}")
        out[dest] = tuple(parsed) if repeat else parsed[0]
    return out


def _is_item(dest: str, value) -> bool:
    """A single parsed item of a repeatable flag: (amp, len, start) for gust, (name, factor) for scale."""
    if not isinstance(value, tuple) or not value:
        return False
    if dest == "scale":
        return len(value) == 2 and isinstance(value[0], str) and "=" not in value[0] and not isinstance(value[1], str)
    return not isinstance(value[0], (str, tuple, list))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The disturbance flags (all default to None: an ideal flight)."""
    g = parser.add_argument_group("disturbances (atmosphere, sensors, link faults, plant uncertainty)")
    for dest, (flag, kw) in FLAGS.items():
        g.add_argument(flag, dest=dest, default=None, **kw)


def from_values(values: dict) -> Disturbances:
    """Disturbances from the flags' values (``{dest: value}`` as text or parsed, missing or None = not given).

    Raises one of ERRORS with a one-line message naming the bad value.
    """
    v = parse_values(values)
    turb = None
    if v["turbulence"] is not None or v["turbulence_sigma"] is not None or v["turbulence_length"] is not None:
        base = DrydenConfig.intensity(v["turbulence"] or "light", ALTITUDE if v["altitude"] is None else v["altitude"])
        sv, sw = v["turbulence_sigma"] if v["turbulence_sigma"] is not None else (base.sigma_v, base.sigma_w)
        lv, lw = v["turbulence_length"] if v["turbulence_length"] is not None else (base.length_v, base.length_w)
        turb = DrydenConfig(sv, sw, lv, lw)
    elif v["altitude"] is not None:
        raise AtmosphereConfigError("--altitude needs --turbulence, --turbulence-sigma or --turbulence-length")
    atm = AtmosphereConfig(turb, tuple(Gust(*g) for g in v["gust"] or ()), v["crosswind"] or 0.0)
    sensors = SensorConfig(
        math.radians(v["roll_noise"] or 0.0),
        math.radians(v["roll_bias"] or 0.0),
        math.radians(v["rate_noise"] or 0.0),
        math.radians(v["rate_bias"] or 0.0),
        v["sensor_delay"] or 0,
    )
    faults = FaultConfig(v["loss"] or 0.0, v["delay"] or 0.0, v["duplicate"] or 0.0, v["reorder"] or 0.0)
    scales = tuple(v["scale"] or ())
    names = [n for n, _ in scales]
    if len(set(names)) != len(names):
        raise UncertaintyError(f"--scale given twice for the same name: {', '.join(names)}")
    d = Disturbances(atm, sensors, faults, scales, v["seed"] or 0)
    d.plant_scales()  # validates the ranges now, not at the first frame
    return d


def to_argv(values: dict) -> list[str]:
    """The flags that reproduce ``values`` (``{dest: value}``, None = not given) on another command line."""
    argv: list[str] = []
    for dest, (flag, kw) in FLAGS.items():
        value = values.get(dest)
        if value is None:
            continue
        items = value if kw.get("action") == "append" else [value]
        for item in items:
            if isinstance(item, tuple) and dest == "scale":
                name, f = item
                text = f"{name}={f[0]!r}:{f[1]!r}" if isinstance(f, tuple) else f"{name}={f!r}"
            elif isinstance(item, tuple):
                text = ",".join(repr(float(x)) for x in item)
            else:
                text = repr(item) if isinstance(item, float) else str(item)
            argv += [flag, text]
    return argv


# ---------------------------------------------------------------------------------------------- runtime
class Injector:
    """What the SITL's endpoint calls to apply a :class:`Disturbances` (see ``sitl.endpoint``).

    Physics: :meth:`advance` feeds the atmosphere, sampled at the physics step, to the aircraft.  Sensors:
    :meth:`measure` once per ATTITUDE.  Link, lockstep (ticks = global frame index, delay rounded to whole
    frames): the handshake stays intact and the faults act on what each frame carries: :meth:`uplink_frame`
    gives the newest sample delivered by this frame (the receiver's hold of the last one when it was lost,
    delayed or overtaken) and how many datagrams arrive (2 for a duplicate); :meth:`downlink_frame` gives the
    newest servo command delivered by this frame or None (hold the last).  Link, real time (wall seconds): the
    datagrams themselves are delayed, dropped, duplicated and reordered (:meth:`uplink_raw`, :meth:`downlink`).
    """

    def __init__(self, dist: Disturbances, physics_dt: float, frame_rate: float, lockstep: bool, t0: float = 0.0):
        self.dist = dist
        rngs = dist.rngs()
        self.scales = dist.plant_scales()
        self.atmosphere = (
            Atmosphere(dist.atmosphere, physics_dt, rngs["atmosphere"], t0) if dist.atmosphere.active else None
        )
        self.sensors = Sensors(dist.sensors, rngs["sensors"]) if dist.sensors.active else None
        self.lockstep = lockstep
        fc = dist.faults
        delay = round(fc.delay * frame_rate) if lockstep else fc.delay
        self.delay_frames = delay if lockstep else None
        self.up = FaultChannel(fc, rngs["uplink"], delay) if fc.active else None
        self.down = FaultChannel(fc, rngs["downlink"], delay) if fc.active else None
        self._up_last = None  # (tick, sample) newest delivered
        self._down_last = -1

    def params(self) -> dict | None:
        """Aircraft params (perturbed A_p, B_p), or None for the paper's plant."""
        if self.scales.nominal:
            return None
        a, b = self.scales.matrices()
        return {"A": a, "B": b}

    def advance(self, aircraft, u: float, n: int):
        if self.atmosphere is None:
            return aircraft.advance(u, n)
        return aircraft.advance(u, n, self.atmosphere.sample(n))

    def measure(self, x) -> tuple[float, float, float]:
        """(roll, roll rate, yaw rate) to report from the truth state x."""
        phi, p, r = float(x[3]), float(x[1]), float(x[2])
        return (phi, p, r) if self.sensors is None else self.sensors.measure(phi, p, r)

    def uplink_frame(self, k: int, sample: tuple) -> tuple[tuple, int]:
        """Lockstep: (the sample the autopilot holds at frame k, datagrams that arrive at frame k)."""
        if self.up is None:
            return sample, 1
        if self._up_last is None:  # before anything arrives the receiver holds the initial sample
            self._up_last = (-1, sample)
        self.up.push(k, (k, sample))
        arrived = self.up.due(k)
        for item in arrived:
            if item[0] > self._up_last[0]:
                self._up_last = item
        return self._up_last[1], len(arrived)

    def downlink_frame(self, k: int, pwm: int) -> int | None:
        """Lockstep: the newest servo PWM delivered by frame k, or None (hold the last one)."""
        if self.down is None:
            return pwm
        self.down.push(k, (k, pwm))
        newest = None
        for tick, value in self.down.due(k):
            if tick > self._down_last:
                self._down_last, newest = tick, value
        return newest

    def uplink_raw(self, now: float, raw: bytes | None) -> list:
        """Real time: push a datagram (if any) at wall time ``now``; the datagrams due now."""
        if self.up is None:
            return [] if raw is None else [raw]
        if raw is not None:
            self.up.push(now, raw)
        return self.up.due(now)

    def downlink(self, now: float, item=None) -> list:
        """Real time: push a received servo message (if any); the ones delivered by ``now``."""
        if self.down is None:
            return [] if item is None else [item]
        if item is not None:
            self.down.push(now, item)
        return self.down.due(now)

    def next_due(self) -> float:
        return min(self.up.next_due(), self.down.next_due()) if self.up is not None else math.inf

    def stats(self) -> dict:
        d = self.dist
        out = {
            "seed": d.seed,
            "scales": self.scales.as_dict(),
            "turbulence": None if d.atmosphere.turbulence is None else vars(d.atmosphere.turbulence),
            "gusts": [vars(g) for g in d.atmosphere.gusts],
            "crosswind": d.atmosphere.crosswind,
            "sensors": vars(d.sensors),
            "faults": vars(d.faults),
        }
        if self.up is not None:
            out["injected"] = {"uplink": dict(self.up.counts), "downlink": dict(self.down.counts)}
            if self.delay_frames is not None:
                out["delay_frames"] = self.delay_frames
        return out
