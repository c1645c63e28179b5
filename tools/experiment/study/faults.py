"""Mid-flight faults in the KH2013A study (``--fault`` on ``python -m tools.experiment robustness``): the faults of
``sitl.damage`` that are exact in the study's ZOH form x[k+1] = Phi x[k] + Gamma [u_s, v_g, p_g, r_g]^T at the
control period h, cut into phases on the control-step grid, and each phase's per-run matrices.

A fault starts at the first control step k with k h >= START and ends at the first one >= END
(``sitl.damage.Schedule`` with dt = h); the faults active together combine into one ``sitl.damage.Effect``.  Where
the Effect changes, a phase begins, with what ``sitl.aircraft.Aircraft.set_effect`` does there (the SITL's
semantics with its physics step equal to h):

* effectiveness=F, damping=F: A_p becomes ``sitl.damage.airframe_matrix`` (B_lp's column times F; L_p times F), E
  its ``disturbance_matrix``, and (Phi, Gamma) its exact ZOH, from that step; back to the plant's own at END.
* stuck[=DEG]: the surface jumps to DEG (or stays where it is) with delta_dot = 0, and the servo rows become
  delta' = delta_dot, delta_dot' = 0 (``sitl.damage.coasting_matrix``): Phi is the exact ZOH of that matrix, the
  command's column of Gamma is 0 (the SITL's coasting step ignores the command), the disturbance's is unchanged.
* off: the servo is driven with 0 (``sitl.damage.Actuator.command``).
* delay=S, S a whole number D of control periods: the servo is driven with the command of D steps before, through
  a line that starts full of the command held at the onset (``Actuator``'s deque); a new line starts whenever the
  servo faults change (a new ``Actuator``), none when they end.
* rate=DEG_PER_S: a slew limit decides inside each physics step whether the surface coasts at +-rate or takes its
  free step with delta_dot clipped (``Actuator.surface``), a nonlinearity the ZOH form at h does not have.  So a
  control step under a rate limit is flown as the SITL flies it: ``SUBSTEPS`` physics steps of h / SUBSTEPS (the
  SITL's 1 kHz), each the free step x_f = Phi_1 x + Gamma_1 u_s, its move delta_f - delta against rate h_1; beyond
  it the coasting step Phi_c1 [.., delta, +-rate], else x_f with delta_dot clipped to +-rate; the disturbance held
  over the control step added on each (Gamma_1's columns).  At the phase's start delta_dot is clipped to +-rate
  (``set_effect``).  A stuck surface ignores the rate limit (it coasts at 0).

Everything is a function of the spec and the step index; the numpy loop and the C kernel read the same phases.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sitl.fault_kinds import STUDY_KINDS
from tools.experiment.study.sampling import StudyError

KINDS = STUDY_KINDS  # the kinds whose record says how the study flies them (sitl.fault_kinds.FaultKind.study)
REFUSED: dict = {}
SUBSTEPS = 10  # physics steps per control step under a rate limit (the SITL's 1 kHz at the study's 100 Hz)
JUMP_NONE, JUMP_WHERE, JUMP_AT = 0, 1, 2


@dataclass(frozen=True)
class Phase:
    """From control step ``start`` on: the matrix set ``mat`` (index into ``Faults.keys``), the surface's jump there
    (``JUMP_*``, ``at`` rad for JUMP_AT), the servo driven with 0 (``off``), a delay line of ``delay`` steps
    (``reset``: a new one starts here, full of the command held)."""

    start: int
    mat: int
    jump: int
    at: float
    off: bool
    delay: int
    reset: bool
    rate: float = 0.0  # rad/s; 0: no rate limit (flown in SUBSTEPS physics steps with Faults.fine[fine])
    fine: int = -1


@dataclass(frozen=True)
class Faults:
    """The phases of a flight and the matrix sets they use: ``keys[m]`` = (effectiveness, damping, stuck); key 0 is
    always the plant as built (1, 1, False)."""

    phases: tuple
    keys: tuple
    fine: tuple = ()  # (effectiveness, damping) of each physics-step matrix set a rate limit flies

    @property
    def max_delay(self) -> int:
        return max((p.delay for p in self.phases), default=0)


def check(faults, dt: float = 0.01) -> None:
    """StudyError (one line) for a fault the study cannot fly exactly, or whose value the KH2013A cannot do (a
    stuck angle beyond the rudder's +-30 deg travel: ``sitl.plant.fault_value_refusal``, the SITL's own bound)."""
    from sitl import plant as plants

    for f in faults:
        why = plants.fault_value_refusal(plants.KH2013A, f)
        if why is not None:
            raise StudyError(f"--fault {f.spec}: {why}")
        if f.kind in REFUSED:
            raise StudyError(f"--fault {f.spec}: not in the KH2013A study: {REFUSED[f.kind]}")
        if f.kind not in KINDS:
            raise StudyError(f"--fault {f.spec}: the KH2013A study flies {', '.join(KINDS)} (not {f.kind})")
        if f.kind == "delay":
            d = f.value / dt
            if abs(d - round(d)) > 1e-9 * max(1.0, d):
                raise StudyError(
                    f"--fault {f.spec}: the study's delay is whole control periods of {dt * 1e3:g} ms "
                    f"(e.g. delay={round(d) * dt:g})"
                )


def plan(faults, steps: int, dt: float) -> Faults | None:
    """The phases of ``faults`` over ``steps`` control steps of ``dt`` (None: no fault ever active)."""
    from sitl import damage

    faults = tuple(faults or ())
    if not faults:
        return None
    check(faults, dt)
    sched = damage.Schedule(faults, 0.0, dt)
    marks = sorted({b for _f, s, e in sched.entries for b in (s, e) if b is not None and 0 <= b < steps})
    keys = [(1.0, 1.0, False)]
    fine: list = []
    phases = []
    old = damage.NOMINAL
    for k in marks:
        new = sched.effect(k)
        if new == old:
            continue
        key = (new.effectiveness, new.damping, new.stuck)
        if key not in keys:
            keys.append(key)
        reset = new.servo and (not old.servo or new.servo_differs(old))
        jump, at = JUMP_NONE, 0.0
        if new.stuck and not old.stuck:
            jump, at = (JUMP_WHERE, 0.0) if new.stuck_at is None else (JUMP_AT, new.stuck_at)
        elif new.stuck and new.stuck_at is not None and new.stuck_at != old.stuck_at:
            jump, at = JUMP_AT, new.stuck_at  # sitl.damage.jammed
        delay = int(round(new.delay / dt)) if new.servo else 0
        rate, fi = 0.0, -1
        if new.rate is not None and not new.stuck:
            rate = float(new.rate)
            if key[:2] not in fine:
                fine.append(key[:2])
            fi = fine.index(key[:2])
        phases.append(Phase(k, keys.index(key), jump, float(at), bool(new.off), delay, bool(reset), rate, fi))
        old = new
    if not phases:
        return None
    return Faults(tuple(phases), tuple(keys), tuple(fine))


def matrices(scales: np.ndarray, dt: float, key) -> tuple[np.ndarray, np.ndarray]:
    """Per-run (Phi, Gamma), (n, 6, 6) and (n, 6, 4), of the plant under (effectiveness, damping, stuck): A_p from
    ``sitl.damage.airframe_matrix``, E = ``disturbance_matrix`` of it, the exact ZOH (``zoh_many``, no BLAS); stuck:
    Phi the ZOH of ``coasting_matrix``, the command's column 0."""
    from autopilot.shared.numerics import zoh_many
    from sitl import damage
    from sitl.atmosphere import disturbance_matrix
    from sitl.uncertainty import PlantScales

    eff, damp, stuck = key
    effect = damage.Effect(effectiveness=eff, damping=damp)
    keys = [s.tobytes() for s in scales]
    first: dict = {}
    for i, k in enumerate(keys):
        first.setdefault(k, i)
    a_all, bg_all = [], []
    for i in first.values():
        a0, b = PlantScales(*scales[i]).matrices()
        a = damage.airframe_matrix(a0, effect, 1)  # sitl.model.P: the KH2013A's roll rate
        a_all.append(a)
        bg_all.append(np.hstack([b, disturbance_matrix(a)]))
    phi, gam = zoh_many(np.array(a_all), np.array(bg_all), dt)
    if stuck:
        phi = zoh_many(
            np.array([damage.coasting_matrix(a) for a in a_all]), np.zeros((len(a_all), a_all[0].shape[0], 1)), dt
        )[0]
        gam = gam.copy()
        gam[:, :, 0] = 0.0
    where = {k: j for j, k in enumerate(first)}
    index = np.array([where[k] for k in keys])
    return phi[index], gam[index]


def fine_matrices(scales: np.ndarray, dt: float, key) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-run (Phi_1, Gamma_1, Phi_c1) at the physics step dt / SUBSTEPS under (effectiveness, damping): the free
    step's ZOH and the coasting one's (``coasting_matrix``), as ``matrices``."""
    h = dt / SUBSTEPS
    phi, gam = matrices(scales, h, (*key, False))
    phic, _ = matrices(scales, h, (*key, True))
    return phi, gam, phic


# ---------------------------------------------------------------------------------------------- the rate limit
def slew(delta, delta_free, rate_free, move_max: float, rate: float):
    """The rate limit's rule on arrays, ``sitl.damage.Actuator.surface``'s (and kernel.c's ``rate_limited``): the free
    step's move ``delta_free - delta`` beyond ``move_max`` (rate * h) coasts at +-rate, else the free step is taken
    with its rate clipped to +-rate.  Returns (coast, the coasting rate, the clipped free rate);
    tests/sitl/test_faults.py holds it to the Actuator's bit for bit."""
    move = delta_free - delta
    up, down = move > move_max, move < -move_max
    return up | down, np.where(up, rate, -rate), np.minimum(rate, np.maximum(-rate, rate_free))


def zoh_step(PHI, GAM, x: list, u_s, dd: list | None) -> list:
    """One physics step of the sampled plant, x+ = Phi x + Gamma_u u (+ Gamma_d d with the disturbances ``dd``), row
    by row over the runs (PHI, GAM: per-run columns), left to right as the kernel adds (bit for bit).  The study's
    numpy path (``numpy_steps``) steps the plant with it, and ``rate_limited`` its free sub-steps."""
    out = [
        PHI[r][0] * x[0]
        + PHI[r][1] * x[1]
        + PHI[r][2] * x[2]
        + PHI[r][3] * x[3]
        + PHI[r][4] * x[4]
        + PHI[r][5] * x[5]
        + GAM[r][0] * u_s
        for r in range(6)
    ]
    if dd is None:
        return out
    return [out[r] + (GAM[r][1] * dd[0] + GAM[r][2] * dd[1] + GAM[r][3] * dd[2]) for r in range(6)]


def rate_limited(x: list, u_s, dd, fine, rate: float, dt: float) -> list:
    """One control step under a rate limit, as ``sitl.aircraft.Aircraft._advance_servo_fault`` flies it
    (``faults.SUBSTEPS`` physics steps of dt / SUBSTEPS): the free step, its move against rate * h; beyond it the
    coasting step at +-rate (``damage.coasting_matrix``'s ZOH), else the free step with delta_dot clipped; the
    disturbance ``dd`` (held) added on each step."""
    p1, g1, pc = fine
    move_max = rate * (dt / SUBSTEPS)  # damage.Actuator's max move
    for _ in range(SUBSTEPS):
        xf = zoh_step(p1, g1, x, u_s, None)
        coast, at, xf[5] = slew(x[4], xf[4], xf[5], move_max, rate)
        xc = [
            pc[r][0] * x[0] + pc[r][1] * x[1] + pc[r][2] * x[2] + pc[r][3] * x[3] + pc[r][4] * x[4] + pc[r][5] * at
            for r in range(6)
        ]
        x = [np.where(coast, xc[r], xf[r]) for r in range(6)]
        if dd is not None:
            x = [x[r] + (g1[r][1] * dd[0] + g1[r][2] * dd[1] + g1[r][3] * dd[2]) for r in range(6)]
    return x


__all__ = [
    "rate_limited",
    "slew",
    "JUMP_AT",
    "JUMP_NONE",
    "JUMP_WHERE",
    "KINDS",
    "REFUSED",
    "SUBSTEPS",
    "Faults",
    "Phase",
    "check",
    "matrices",
    "plan",
]
