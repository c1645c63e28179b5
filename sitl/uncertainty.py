"""Plant uncertainty: scale factors on the KH2013A model (paper section 5.1), fixed or drawn from ranges.  No I/O.

Each factor multiplies terms of A_p / B_p (paper sec. 5.1 and eq. (65)):

| name | terms |
|---|---|
| control | B_lp, the rudder's column of A_p (control effectiveness) |
| roll_damping | L_p, A_lp[1, 1] |
| dihedral | L_v, A_lp[1, 0] |
| yaw_coupling | L_r and N_p, A_lp[1, 2] and A_lp[2, 1] (the roll-yaw cross terms) |
| servo_wn | the servo's natural frequency: wn^2 by f^2, 2 zeta wn by f |
| servo_zeta | the servo's damping ratio: 2 zeta wn by f |
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from sitl import model


class UncertaintyError(ValueError):
    """A scale factor or range is malformed or out of range."""


@dataclass(frozen=True)
class PlantScales:
    """Multiplicative factors on the model; all 1.0 is the paper's plant."""

    control: float = 1.0
    roll_damping: float = 1.0
    dihedral: float = 1.0
    yaw_coupling: float = 1.0
    servo_wn: float = 1.0
    servo_zeta: float = 1.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not (math.isfinite(v) and v > 0):
                raise UncertaintyError(f"scale {f.name} must be positive and finite, got {v!r}")

    @property
    def nominal(self) -> bool:
        return all(getattr(self, f.name) == 1.0 for f in fields(self))

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """The perturbed (A_p, B_p) (6x6, 6x1)."""
        a = model.A_P.copy()
        b = model.B_P.copy()
        a[:4, model.DELTA_R] *= self.control
        a[1, 1] *= self.roll_damping
        a[1, 0] *= self.dihedral
        a[1, 2] *= self.yaw_coupling
        a[2, 1] *= self.yaw_coupling
        a[model.DELTA_R_DOT, model.DELTA_R] *= self.servo_wn**2
        a[model.DELTA_R_DOT, model.DELTA_R_DOT] *= self.servo_wn * self.servo_zeta
        b[model.DELTA_R_DOT, 0] *= self.servo_wn**2
        return a, b


SCALE_NAMES = tuple(f.name for f in fields(PlantScales))


def parse_scale(text: str) -> tuple[str, float | tuple[float, float]]:
    """``NAME=FACTOR`` or ``NAME=LO:HI`` (a uniform range drawn with the seed) -> (name, value or (lo, hi))."""
    name, sep, value = text.partition("=")
    name = name.strip()
    if not sep or name not in SCALE_NAMES:
        raise UncertaintyError(
            f"expected NAME=FACTOR or NAME=LO:HI with NAME one of {', '.join(SCALE_NAMES)}, got {text!r}"
        )
    try:
        parts = [float(v) for v in value.split(":")]
    except ValueError:
        raise UncertaintyError(f"scale {name}: {value!r} is not a number or LO:HI") from None
    if len(parts) > 2 or not all(math.isfinite(v) and v > 0 for v in parts):
        raise UncertaintyError(f"scale {name}: factors must be positive finite numbers, got {value!r}")
    if len(parts) == 2:
        if parts[0] > parts[1]:
            raise UncertaintyError(f"scale {name}: range LO:HI needs LO <= HI, got {value!r}")
        return name, (parts[0], parts[1])
    return name, parts[0]


def draw_scales(spec: dict, rng: np.random.Generator) -> PlantScales:
    """PlantScales from ``{name: factor or (lo, hi)}``; ranges drawn uniformly, in SCALE_NAMES order (one draw per
    range, so the result depends only on the seed and on which names have ranges)."""
    values = {}
    for name in SCALE_NAMES:
        v = spec.get(name)
        if isinstance(v, tuple):
            values[name] = float(rng.uniform(v[0], v[1]))
        elif v is not None:
            values[name] = float(v)
    unknown = set(spec) - set(SCALE_NAMES)
    if unknown:
        raise UncertaintyError(f"unknown scale(s) {', '.join(sorted(unknown))}; known: {', '.join(SCALE_NAMES)}")
    return replace(PlantScales(), **values)
