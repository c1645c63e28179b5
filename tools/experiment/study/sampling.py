"""What the study flies: the conditions (and their one-factor sweeps), and the chunks (``Task``) the runs are cut
into; its controllers are the registry's (``autopilot.controllers``: ``ROBUSTNESS``, ``studied``, the ``VARIANTS``
of CL-SAC).  Plain data; no simulation."""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

from autopilot import controllers as registry
from autopilot.envelope import Envelope
from autopilot.shared import cli

DEG = math.pi / 180.0


ENVELOPE = Envelope()  # "bounded" = inside the default envelope (autopilot.envelope.within)


BOUND_ROLL_RAD = ENVELOPE.max_roll_rad


BOUND_SAT_FRACTION = ENVELOPE.max_saturated_share


METRICS = ("ise_ref", "ise_crm", "energy", "tv", "max_abs_u", "max_abs_roll", "sat_fraction")


WINDOW_S = 30.0  # the long flight reports the peak |roll| of each such window


BLOCK = 100  # control steps of noise drawn per run at a time


CHANNELS = 7  # standard normals per run and step: 4 Dryden, 1 roll noise, 2 link loss (up, down)


STATIC = 13  # static draws per run: 6 scales, pfc, gust amplitude, length, start, crosswind, bias (uniforms) + 1 spare


class StudyError(ValueError):
    """Bad study input; one line naming the value."""


# ---------------------------------------------------------------------------------------- conditions
@dataclass(frozen=True)
class Condition:
    """How the standard draws of a run become disturbances.  Ranges are symmetric: a value v means U(-v, v)."""

    name: str
    scale_spread: float = 0.0  # every plant scale factor U(1 - s, 1 + s)
    turbulence: float = 0.0  # Dryden sigmas as a multiple of MIL-HDBK-1797 "severe" (moderate = 2/3, light = 1/3)
    gust: float = 0.0  # 1-cosine side gust amplitude U(-g, g) m/s, length U(5, 20) m, start U(0, duration - 3) s
    crosswind: float = 0.0  # m/s
    roll_noise: float = 0.0  # rad (white, per sample)
    roll_bias: float = 0.0  # rad
    delay: int = 0  # samples of sensor delay
    loss: float = 0.0  # probability per message, each direction
    pfc_paper_share: float = 0.5  # the PFC is drawn per run: paper with this probability, else robust


CONDITIONS: dict[str, Condition] = {
    c.name: c
    for c in (
        Condition("nominal"),
        Condition(
            "moderate",
            scale_spread=0.2,
            turbulence=2 / 3,
            gust=2.0,
            crosswind=1.0,
            roll_noise=0.2 * DEG,
            roll_bias=0.5 * DEG,
            delay=1,
            loss=0.02,
        ),
        Condition(
            "severe",
            scale_spread=0.4,
            turbulence=1.0,
            gust=4.0,
            crosswind=2.0,
            roll_noise=0.5 * DEG,
            roll_bias=1.0 * DEG,
            delay=3,
            loss=0.1,
        ),
    )
}


# One factor at a time from nominal: where does each controller stop being bounded?
SWEEPS: dict[str, tuple[str, tuple[float, ...]]] = {
    "loss": ("loss", (0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 0.9)),
    "delay": ("delay", (1, 2, 4, 8, 16, 32)),
    "turbulence": ("turbulence", (1 / 3, 2 / 3, 1.0, 2.0, 4.0, 8.0)),
}


def sweep_conditions() -> dict[str, Condition]:
    out = {}
    for label, (field_name, values) in SWEEPS.items():
        for v in values:
            name = f"{label}={v:.3g}"
            out[name] = dataclasses.replace(CONDITIONS["nominal"], name=name, **{field_name: v})
    return out


@functools.lru_cache(maxsize=1)
def _sweeps() -> dict[str, Condition]:
    return sweep_conditions()  # once per process: get_condition is called per run (a Condition is frozen)


def get_condition(name: str) -> Condition:
    cond = CONDITIONS.get(name) or _sweeps().get(name)
    if cond is None:
        raise StudyError(f"unknown condition {name!r} (known: {', '.join([*CONDITIONS, *sweep_conditions()])})")
    return cond


def get_controller(name: str) -> registry.Controller:
    """The robustness study's controller ``name`` (``autopilot.controllers.studied``: the registry's); StudyError."""
    try:
        return registry.studied(name)
    except ValueError as exc:
        raise StudyError(str(exc)) from None


# ---------------------------------------------------------------------------------------- one batch
@dataclass(frozen=True)
class Task:
    """One chunk: a controller and the (condition, run index) pairs it flies, all with the same seed."""

    controller: str
    runs: tuple[tuple[str, int], ...]
    seed: int
    duration_s: float = 30.0
    record: bool = False
    faults: tuple = ()  # sitl.damage.Fault, flown in every run (tools.experiment.study.faults)


# ---------------------------------------------------------------------------------------- many batches
def make_tasks(
    controllers: Sequence[str], pairs: Sequence[tuple[str, int]], seed: int, chunk: int, duration_s: float = 30.0
) -> list[Task]:
    """Every controller's runs cut into chunks of at most ``chunk`` runs (the results do not depend on it)."""
    if chunk < 1:
        raise StudyError(f"--chunk must be >= 1, got {chunk}")
    return [
        Task(c, tuple(pairs[i : i + chunk]), seed, duration_s) for c in controllers for i in range(0, len(pairs), chunk)
    ]


@dataclass(frozen=True)
class StudyOptions:
    runs: int = 1000
    seed: int = 0
    controllers: tuple[str, ...] = registry.ROBUSTNESS
    conditions: tuple[str, ...] = tuple(CONDITIONS)
    sweep_runs: int = 100
    long_runs: int = 10
    chunk: int = 2500
    scheduler: str | None = None
    workers: int = 1  # local processes (ignored with a scheduler)
    faults: tuple = ()  # sitl.damage.Fault, flown in every run (--fault; tools.experiment.study.faults)

    def __post_init__(self) -> None:
        for name in ("runs", "sweep_runs", "long_runs"):
            if getattr(self, name) < 0:
                raise StudyError(f"--{name.replace('_', '-')} must be >= 0, got {getattr(self, name)}")
        if not 0 <= self.seed <= cli.MAX_SEED:
            raise StudyError(f"--seed must be in [0, 2^63-1], got {self.seed}")
        if self.runs < 1:
            raise StudyError(f"--runs must be >= 1, got {self.runs}")
        if self.chunk < 1:
            raise StudyError(f"--chunk must be >= 1, got {self.chunk}")
        if self.workers < 1:
            raise StudyError(f"--workers must be >= 1, got {self.workers}")
        for c in self.controllers:
            get_controller(c)
        for c in self.conditions:
            get_condition(c)
        if self.scheduler is not None and not self.scheduler.startswith(("tcp://", "tls://", "inproc://")):
            raise StudyError(f"--scheduler must look like tcp://HOST:PORT, got {self.scheduler!r}")
