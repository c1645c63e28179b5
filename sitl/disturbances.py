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

from sitl.atmosphere import ALTITUDE, AtmosphereConfig, AtmosphereConfigError, DrydenConfig, Gust
from sitl.faults import FaultConfig, FaultConfigError
from sitl.sensors import SensorConfig, SensorConfigError
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
        dict(type=float, metavar="M", help=f"altitude for the turbulence scales (default {ALTITUDE:g})"),
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
    "crosswind": ("--crosswind", dict(type=float, metavar="M/S", help="steady side wind, m/s")),
    "roll_noise": ("--roll-noise", dict(type=float, metavar="DEG", help="white noise sigma on the reported roll")),
    "roll_bias": ("--roll-bias", dict(type=float, metavar="DEG", help="bias on the reported roll")),
    "rate_noise": (
        "--rate-noise",
        dict(type=float, metavar="DEG/S", help="white noise sigma on the reported roll rate"),
    ),
    "rate_bias": ("--rate-bias", dict(type=float, metavar="DEG/S", help="bias on the reported roll rate")),
    "sensor_delay": ("--sensor-delay", dict(type=int, metavar="N", help="delay of the reported attitude, in samples")),
    "loss": (
        "--loss",
        dict(type=probability_arg, metavar="P", help="link: loss probability per packet, each direction"),
    ),
    "delay": (
        "--delay",
        dict(type=float, metavar="S", help="link: one-way delay (sim s in lockstep, wall s in real time)"),
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
    "seed": ("--seed", dict(type=int, metavar="N", help="seed of every disturbance (default 0)")),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The disturbance flags (all default to None: an ideal flight)."""
    g = parser.add_argument_group("disturbances (atmosphere, sensors, link faults, plant uncertainty)")
    for dest, (flag, kw) in FLAGS.items():
        g.add_argument(flag, dest=dest, default=None, **kw)


def from_values(values: dict) -> Disturbances:
    """Disturbances from the flags' values (``{dest: value}``, missing or None = not given).

    Raises one of ERRORS with a one-line message naming the bad value.
    """
    v = {k: values.get(k) for k in FLAGS}
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
