"""One task of the damage study, flown or designed in a worker (``run_damage_task``: picklable, a function of the
task only).

A :class:`~tools.experiment.damage.grid.DamageFlight` is the reference scenario's square wave (``PAPER``: +-10 deg,
period 10 s) flown in-process (``tools.experiment.scenario.run_inprocess``: the control step and the plant in one
process, faults flown as the SITL flies ``--fault``) for ``duration`` s on the plant, with the fault from its
onset, in turbulence seeded by the flight's seed.  Its record: the verdict (``autopilot.envelope.judge_series``
with the commanded response y_m,ol: the one definition of a controlled flight, |roll|, saturation and tracking, so
a limit cycle is out), the tracking error after the onset, per period of the square wave, the effort, and the
recovery after the onset (``autopilot.recovery``, as the launcher reports it).

A :class:`~tools.experiment.damage.grid.Design` is ``tools.design.tuning.design_pid_bound`` (the rule of
``design_baseline`` over continuous gains) on the plant's linear model (``tools.design.linearise.linear_model``)
changed as the fault changes it (``tools.design.tuning.faulted_plant``), with the fault's delay in the loop.
A :class:`~tools.experiment.damage.grid.Calibration` finds the factor s on the plant's PID gains whose energy
(``autopilot.metrics``: sum u^2 dt) on the fault-free reference scenario (30 s, still air) equals
CL-SAC's there: Brent's method on log E(s) - log E_CL-SAC over s in [1/30, 30].
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from sitl import plant as plants
from tools.experiment.damage.grid import (
    ENERGY,
    MIMO_CONTROLLERS,
    NONE,
    RETUNED,
    ROBUST,
    Calibration,
    DamageFlight,
    Design,
    effect_of,
    fault_of,
)

PAPER_RATE_HZ = 100.0  # the reference scenario's control rate (tools.experiment.scenario.PAPER)
SCALE_RANGE = (1.0 / 30.0, 30.0)
SCALE_XTOL = 1e-4  # on log s: the energy is matched to about 0.01 %


def _scenario(plant: str, duration: float = 30.0, dist: tuple = (), **kw):
    from sitl import plant as plants
    from tools.experiment.scenario import PAPER

    limit = min(PAPER.u_limit_rad, plants.surface_limit_rad(plant) or math.inf)  # the surface's stop
    return replace(PAPER, plant=plant, duration_s=duration, u_limit_rad=limit, disturbances=dist, **kw)


def _run(controller: str):
    """The scenario's run of a study controller: SAC and CL-SAC with the robust PFC are the registered laws with
    ``pfc="robust"`` (applied after the plant's design file, as the launcher's ``--pfc robust``)."""
    from tools.experiment.scenario import run_of

    if controller in ROBUST:
        return replace(run_of(ROBUST[controller]), name=controller, pfc="robust")
    return run_of("baseline" if controller in (RETUNED, ENERGY) else controller)


def disturbances(turbulence: str, seed: int) -> tuple:
    """The flight's disturbances: the seed, and the turbulence unless "none" (JSBSim flies its own MIL-F-8785C
    turbulence, the KH2013A the SITL's Dryden model, ``sitl.atmosphere``)."""
    return (("seed", int(seed)),) + ((("turbulence", turbulence),) if turbulence != "none" else ())


def fly(task: DamageFlight):
    """The flight's ``RunResult`` and its scenario."""
    from tools.experiment.scenario import run_inprocess

    faults = () if task.kind == NONE else (fault_of(task.kind, task.value, task.onset),)
    scen = _scenario(
        task.plant,
        task.duration,
        disturbances(task.turbulence, task.seed),
        faults=faults,
        baseline_gains=task.gains,
        gain_schedule=task.schedule,
    )
    return run_inprocess(scen, _run(task.controller), atmosphere=True), scen


def record(
    series: dict,
    metrics: dict,
    onset: float,
    period: float,
    u_limit: float,
    dt: float,
    surface: str = "rudder",
    sideslip: dict | None = None,
) -> dict:
    """A flight's record from its series (``t``, ``phi``, ``u``, ``ym_ol``; rad, one sample per control step);
    ``surface``: the roll's surface, as the verdict's reason names it (the plant's: ``sitl.plant.surface_of``);
    ``sideslip``: a square MIMO plant's second channel (``autopilot.mimo.ChannelMetrics.result()``), judged too."""
    from autopilot.envelope import Envelope, saturated, verdict

    t, phi, u, ym, um = (np.asarray(series[k], dtype=float) for k in ("t", "phi", "u", "ym_ol", "um"))
    d2 = (phi - ym) ** 2  # the tracking error of autopilot.metrics' ise_ref, per sample
    after = t >= onset - 1e-9
    # the launcher's verdict: |roll|, saturation, tracking, and a MIMO plant's rudder and sideslip
    judged = verdict(t, phi, u, u_limit, Envelope(surface=surface), ref=ym, sideslip=sideslip)
    tracking = judged["tracking"]
    n_periods = int(math.ceil(round(len(t) * dt / period, 9)))
    periods = [
        float(np.sum(d2[(t >= i * period - 1e-9) & (t < (i + 1) * period - 1e-9)]) * dt) for i in range(n_periods)
    ]
    sat = saturated(u, u_limit)  # autopilot.envelope's one definition: at the stop, or not finite
    return {
        "controlled": bool(judged["ok"]),
        "reason": judged["reason"],
        "first_exit_s": judged["first_exit_s"],
        "oscillating": bool(tracking is not None and tracking["oscillating_windows"]),
        "not_following": bool(tracking is not None and tracking["not_following_windows"]),
        "max_abs_roll_deg": float(np.degrees(np.max(np.abs(phi)))),
        "saturated_share": float(np.mean(sat)),
        "ise_ref": float(metrics["ise_ref"]),
        "energy": float(metrics["energy"]),
        "ise_ref_after": float(np.sum(d2[after]) * dt),
        "ise_ref_before": float(np.sum(d2[~after]) * dt),
        "energy_after": float(np.sum(u[after] ** 2) * dt),
        "ise_ref_periods": periods,
        **recovery_of(t, phi, ym, um, onset),
    }


def recovery_of(t, phi, ym, um, onset: float) -> dict:
    """The recovery after the onset (``autopilot.recovery.recovery``, as the launcher reports it: the roll's
    settled 1 s RMS deviation from y_m,ol back within the command's band, staying there and following the command):
    ``recovered`` (True, False, None when not measured), ``recovery_s``, ``recovery_reason``."""
    from autopilot.recovery import recovery

    r = recovery(t, phi, ym, onset, raw_command=um)
    return {
        "recovered": r.recovered,
        "recovery_s": r.time_s,
        "recovery_band_deg": r.band_deg,
        "recovery_reason": r.reason,
    }


def _roll_surface(plant: str) -> str:
    """The surface that rolls the plant: the first of a square MIMO plant's (``aileron+rudder``: the aileron)."""
    return plants.spec(plant).surfaces[0]


def fly_record(task: DamageFlight) -> dict:
    if plants.spec(task.plant).mimo:
        return fly_record_mimo(task)
    res, scen = fly(task)
    return record(
        res.series, res.metrics, task.onset, scen.period_s, scen.u_limit_rad, 1.0 / scen.control_rate_hz,
        _roll_surface(task.plant),
    )  # fmt: skip


def fly_record_mimo(task: DamageFlight) -> dict:
    """A square MIMO plant's flight (``tools.experiment.mimo_inprocess.run_mimo``, bit for bit the lockstep MAVLink
    flight): the same square wave, fault, onset and turbulence; the fault acts on the first surface, the aileron
    (``sitl.damage.ScheduledEffects`` on the aileron's command, effectiveness on its control derivatives), the
    rudder flies as designed.  The record is a SISO flight's, judged as the launcher judges it (the roll channel, the
    rudder's saturation and the sideslip, ``autopilot.envelope.verdict``), with the sideslip's numbers beside:
    ``max_abs_sideslip_deg`` (|beta| as AOA_SSA carries it) and ``rudder_saturated_share``."""
    from tools.experiment.mimo_inprocess import run_mimo
    from tools.experiment.scenario import PAPER

    if task.controller not in MIMO_CONTROLLERS:
        raise ValueError(
            f"{task.plant}: a square MIMO plant flies {', '.join(MIMO_CONTROLLERS)}, not {task.controller}"
        )
    faults = () if task.kind == NONE else (fault_of(task.kind, task.value, task.onset),)
    r = run_mimo(
        task.plant,
        task.controller,
        duration_s=task.duration,
        rate_hz=PAPER.control_rate_hz,
        faults=faults,
        disturbances=disturbances(task.turbulence, task.seed),
    )
    scen = _scenario(task.plant, task.duration)
    out = record(
        r["series"], r["metrics"], task.onset, scen.period_s, scen.u_limit_rad, 1.0 / scen.control_rate_hz,
        _roll_surface(task.plant), r["sideslip"],
    )  # fmt: skip
    out["max_abs_sideslip_deg"] = float(np.degrees(np.max(np.abs(r["series"]["beta"]))))
    out["rudder_saturated_share"] = float(r["sideslip"]["saturated_fraction"]["rudder"])
    return out


def design(task: Design) -> dict:
    """The retuned PID's gains and margins on the plant's linear model under the fault, the fault's delay (rounded
    to control steps) in the loop."""
    from tools.design.linearise import linear_model
    from tools.design.tuning import design_pid_bound, faulted_plant

    model = linear_model(task.plant)
    if model is None:
        raise ValueError(f"{task.plant}: no linear model to retune the PID on (tools.design.linearise.linear_model)")
    effect = effect_of(task.kind, task.value)
    plant = faulted_plant(model[:3], model[3], effect)
    rate = PAPER_RATE_HZ
    delay_steps = int(round(effect.delay * rate))  # the fault's delay is in the loop it is designed on
    d = design_pid_bound(plant, rate_hz=rate, delay_steps=delay_steps)
    return {"gains": (float(d.kp), float(d.ki), float(d.kd)), "margins": d.margins, "delay_steps": delay_steps}


def _energy(plant: str, controller: str, gains=None) -> float:
    from tools.experiment.scenario import run_inprocess

    return float(run_inprocess(_scenario(plant, baseline_gains=gains), _run(controller)).metrics["energy"])


def calibrate(task: Calibration) -> dict:
    """The factor on the plant's PID gains that matches CL-SAC's energy on the fault-free reference scenario."""
    from scipy.optimize import brentq

    from autopilot.baseline import BaselineConfig
    from tools.design.linearise import flown_baseline_gains

    base = flown_baseline_gains("baseline", task.plant)
    if base is None:
        d = BaselineConfig()
        base = (d.kp, d.ki, d.kd)
    target = _energy(task.plant, "clsac")

    def f(log_s: float) -> float:
        s = math.exp(log_s)
        return math.log(_energy(task.plant, "baseline", tuple(s * g for g in base)) / target)

    lo, hi = (math.log(x) for x in SCALE_RANGE)
    flo, fhi = f(lo), f(hi)
    if not (flo < 0 < fhi):
        raise ValueError(
            f"{task.plant}: no PID gain factor in [{SCALE_RANGE[0]:.3g}, {SCALE_RANGE[1]:g}] matches CL-SAC's energy "
            f"{target:.4g} (log ratio {flo:.3g} .. {fhi:.3g})"
        )
    log_s = brentq(f, lo, hi, xtol=SCALE_XTOL)
    s = math.exp(log_s)
    gains = tuple(s * g for g in base)
    return {
        "scale": s,
        "gains": gains,
        "base_gains": tuple(base),
        "energy_clsac": target,
        "energy": _energy(task.plant, "baseline", gains),
        "energy_base": _energy(task.plant, "baseline", tuple(base)),
    }


def run_damage_task(task) -> dict:
    """The task function of ``tools.experiment.study.execute``: a flight's record, a design or a calibration."""
    if isinstance(task, DamageFlight):
        return fly_record(task)
    if isinstance(task, Design):
        return design(task)
    if isinstance(task, Calibration):
        return calibrate(task)
    raise TypeError(f"not a damage study task: {task!r}")
