"""A square MIMO plant's flight in one process (issue 32): ``run_mimo``, the MIMO form of
``tools.experiment.scenario.run_inprocess`` for ``jsbsim:MODEL:surface=aileron+rudder``.

Per control step k, as the lockstep flight over MAVLink does: the SITL's sideslip (AOA_SSA: deg as float32) and roll
(ATTITUDE: float32) at t_k are measured, ``autopilot.step.ControlStep`` flies ``autopilot.mimo.MimoLaw`` (the roll's
command through the PWM map, ``law.u2`` the rudder's through its own), and the aircraft advances one control period
with both held; the faults fly as the SITL flies ``--fault`` (``sitl.damage.ScheduledEffects``: the aileron's, the
first surface's).  With ``wire`` (the launcher's PWM calibration) the numbers are the MAVLink flight's: the test
(tests/tools/experiment/test_mimo_inprocess.py) compares them with ``python -m tools.launch``'s.  The damage sweep of
docs/jsbsim.md (``sweep``: the aileron's effectiveness F, the rudder's channel as designed) is flown this way.
"""

from __future__ import annotations

import math

import numpy as np

from autopilot.mimo import ChannelMetrics, from_values
from autopilot.params import load_file
from autopilot.shared.mavlink import quaternion_to_roll, roll_to_quaternion
from autopilot.shared.pwm import PwmMap
from autopilot.step import ControlStep, ProfileSetpoints
from sitl import plant as plants
from tools.flight.profiles import Profile


def launcher_pwm(u_limit_deg: float) -> tuple[PwmMap, PwmMap]:
    """The two PWM maps a MIMO launch gives its processes (``tools.flight.command_lines.child_argvs``: aileron on 1,
    rudder on 4, ``--rudder-max-deg max(30, limit)``)."""
    from tools.flight.command_lines import MIMO_CHANNELS, RUDDER_MAX_DEG

    span = math.radians(max(RUDDER_MAX_DEG, u_limit_deg))
    return PwmMap(1000, 2000, 1500, span, MIMO_CHANNELS[0]), PwmMap(1000, 2000, 1500, span, MIMO_CHANNELS[1])


def run_mimo(
    plant: str,
    controller: str = "clsac",
    params=None,
    *,
    duration_s: float = 30.0,
    rate_hz: float = 100.0,
    physics_rate_hz: float = 1000.0,
    faults=(),
    profile: Profile | None = None,
    wire: bool = True,
    disturbances=(),
) -> dict:
    """One flight of ``plant`` (a MIMO JSBSim spec) by ``controller`` ("clsac", "sac", "baseline") with the design
    ``params`` (default the plant's, ``tools.design.linearise.designed_params``); returns {"metrics": the roll's five
    metrics, "sideslip": ``ChannelMetrics.result()``, "series": t, phi, beta, u, u2, ym_ol, um (the roll command in
    force)}; ``disturbances``: what a
    JSBSim plant flies by itself, ((name, value), ...) of ``sitl.disturbances`` (``turbulence``, ``seed``,
    ``crosswind``), as the SITL's flags."""
    from sitl import damage
    from sitl.jsbsim_plant import parse_spec
    from tools.design.linearise import designed_params
    from tools.experiment.scenario import scheduled_faults

    spec = parse_spec(plant)
    if not spec.is_mimo:
        raise ValueError(f"{plant}: not a square MIMO plant (jsbsim:MODEL:surface=aileron+rudder)")
    values = load_file(params or designed_params(plant))
    limits = spec.surface_limits_rad
    law = from_values(controller, values, control_rate_hz=rate_hz, limits=limits)
    profile = profile or Profile.square(10.0, 10.0)

    def command(t: float) -> float:
        v = profile.value(t)
        return quaternion_to_roll(np.float32(roll_to_quaternion(v))) if wire else v  # SET_ATTITUDE_TARGET.q

    pwm1, pwm2 = launcher_pwm(math.degrees(limits[0])) if wire else (None, None)
    step = ControlStep(law=law, pwm=pwm1, setpoints=ProfileSetpoints(command))
    faults = tuple(damage.parse(f) if isinstance(f, str) else f for f in faults)
    if faults:
        plants.check_faults(plant, faults)
    dist = None
    if disturbances:
        from sitl import disturbances as _dist

        dist = _dist.from_values(dict(disturbances))
    ac = plants.build(plant, physics_rate_hz, None, dist, plants.needs_damaged_model(faults))
    faulted = scheduled_faults(ac, faults, physics_rate_hz, ac.advance)
    advance = ac.advance if faulted is None else faulted.advance
    channels = ChannelMetrics(1.0 / rate_hz, limits)
    n, nphys = int(round(duration_s * rate_hz)), int(round(physics_rate_hz / rate_hz))
    rows = np.empty((n, 7))
    for k in range(n):
        t = k / rate_hz
        beta = ac.sideslip()[1]
        phi = ac.attitude()[0]
        if wire:  # AOA_SSA carries deg as float32, ATTITUDE the roll as float32
            beta, phi = math.radians(float(np.float32(math.degrees(beta)))), float(np.float32(phi))
        law.y2 = beta
        law.um2 = profile.sideslip(t)
        res = step(t, phi)
        u2 = pwm2.to_rad(pwm2.to_pwm(law.u2)) if wire else law.u2
        ac.u2 = u2
        channels(_Record(res, law))
        rows[k] = (t, phi, beta, res.u, u2, law.ym_ol, res.um)
        advance(res.u, nphys)
    series = {name: rows[:, i].copy() for i, name in enumerate(("t", "phi", "beta", "u", "u2", "ym_ol", "um"))}
    return {"metrics": step.metrics.result(), "sideslip": channels.result(), "series": series}


class _Record:
    """What ``ChannelMetrics`` reads of a step (the loop's ``StepRecord``): the result and the law."""

    __slots__ = ("result", "ctrl")

    def __init__(self, result, law):
        self.result, self.ctrl = result, law


EFFECTIVENESS = (1.0, 0.5, 0.3, 0.2)


def aileron_only(faults=(), plant: str = "jsbsim:c172x") -> dict:
    """The aileron-only CL-SAC (the rudder held at trim) in-process (``run_inprocess``, its design, limited to the
    aileron's stop), its sideslip from the truth: asin(v / V), V the trim's true airspeed (JSBSim's vt-fps)."""
    from dataclasses import replace

    from sitl.jsbsim_models import quiet_stdio
    from sitl.jsbsim_plant import FT, parse_spec, trimmed_fdm
    from tools.experiment.scenario import PAPER, PAPER_RUNS, run_inprocess

    scenario = replace(PAPER, plant=plant, u_limit_rad=plants.surface_limit_rad(plant), faults=tuple(faults))
    r = run_inprocess(scenario, PAPER_RUNS[1])
    with quiet_stdio():
        speed = float(trimmed_fdm(parse_spec(plant), 0.001)["velocities/vt-fps"]) * FT
    beta = np.arcsin(np.clip(r.series["v"] / speed, -1.0, 1.0))
    u = r.series["u"]
    return {
        "ise_ref": r.metrics["ise_ref"],
        "max_abs_roll_deg": math.degrees(float(np.max(np.abs(r.series["phi"])))),
        "max_abs_sideslip_deg": math.degrees(float(np.max(np.abs(beta)))),
        "aileron_saturated": float(np.mean(np.abs(u) >= scenario.u_limit_rad * (1 - 1e-9))),
        "rudder_saturated": 0.0,
    }


def sweep(plant: str = "jsbsim:c172x:surface=aileron+rudder", effectiveness=EFFECTIVENESS) -> list[dict]:
    """The damage sweep: the aileron's effectiveness F for the whole flight; MIMO CL-SAC, the aileron-only CL-SAC
    and the MIMO baseline."""
    rows = []
    for f in effectiveness:
        faults = () if f == 1.0 else (f"effectiveness={f:g}@0",)
        rows.append({"effectiveness": f, "controller": "MIMO CL-SAC", **_row(run_mimo(plant, "clsac", faults=faults))})
        rows.append({"effectiveness": f, "controller": "aileron-only CL-SAC", **aileron_only(faults)})
        rows.append(
            {"effectiveness": f, "controller": "MIMO baseline", **_row(run_mimo(plant, "baseline", faults=faults))}
        )
    return rows


def _row(r: dict) -> dict:
    side = r["sideslip"]
    return {
        "ise_ref": r["metrics"]["ise_ref"],
        "max_abs_roll_deg": side["channels"][0]["max_abs_deg"],
        "max_abs_sideslip_deg": side["max_abs_sideslip_deg"],
        "aileron_saturated": side["saturated_fraction"]["aileron"],
        "rudder_saturated": side["saturated_fraction"]["rudder"],
    }
