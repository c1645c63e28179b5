"""One batch of the study flown as numpy arrays (``simulate``), and one run replayed alone (``replay``): each run's
random draws, its law, its plant (``inputs``), its disturbances, sensor and link, flown step by step in C
(``kernel_steps``) or numpy (``numpy_steps``), the same numbers whichever, and the metrics of the flight."""

from __future__ import annotations

import argparse
import math

import numpy as np

from autopilot.envelope import within
from tools.experiment.study import faults as study_faults
from tools.experiment.study import native
from tools.experiment.study.inputs import airspeed, dryden, per_run, square_command, zoh_plants
from tools.experiment.study.kernel_steps import fly_kernel
from tools.experiment.study.numpy_steps import fly_numpy
from tools.experiment.study.sampling import (
    DEG,
    ENVELOPE,
    METRICS,
    STATIC,
    StudyError,
    Task,
    get_condition,
    get_controller,
)


def simulate(task: Task, engine: str | None = None) -> dict:
    """Fly ``task``: returns per-run arrays (``METRICS``, ``bounded``, ``pfc_paper``, the draws) in task order,
    and with ``record`` the per-step series of every run.  ``engine``: "kernel" (the C kernel, ``native``),
    "numpy" (the numpy loop) or None (the kernel when it loads, else numpy); the same numbers whichever."""
    from scipy.special import ndtri

    from sitl.atmosphere import Gust

    ctrl = get_controller(task.controller)
    conds = [get_condition(c) for c, _ in task.runs]
    n = len(task.runs)
    rate = 100.0
    dt = 1.0 / rate
    steps = int(round(task.duration_s * rate))
    umax = 30.0 * DEG
    gens = [np.random.default_rng([task.seed, i]) for _, i in task.runs]
    static = np.array([g.random(STATIC) for g in gens])  # (n, STATIC) standard uniforms, fixed order
    turb0 = np.array([g.standard_normal(4) for g in gens])  # stationary initial Dryden state (standard)
    spread = np.array([c.scale_spread for c in conds])
    scales = 1.0 + spread[:, None] * (2.0 * static[:, :6] - 1.0)
    pfc_paper = static[:, 6] < np.array([c.pfc_paper_share for c in conds])
    gust_amp = np.array([c.gust for c in conds]) * (2.0 * static[:, 7] - 1.0)
    gust_len = 5.0 + 15.0 * static[:, 8]
    gust_start = static[:, 9] * max(task.duration_s - 3.0, 0.0)
    crosswind = np.array([c.crosswind for c in conds]) * (2.0 * static[:, 10] - 1.0)
    bias = np.array([c.roll_bias for c in conds]) * (2.0 * static[:, 11] - 1.0)
    noise = np.array([c.roll_noise for c in conds])
    turb = np.array([c.turbulence for c in conds])
    delay = np.array([c.delay for c in conds], dtype=int)
    loss = np.array([c.loss for c in conds])
    thr = ndtri(loss)  # lost when the standard normal draw is below it (-inf: never)

    # Law, one config per run (the PFC is drawn per run): its record's batch form (autopilot.controllers.Law.batch)
    record = ctrl.kind  # its law's record (autopilot.controllers.Law)
    if record.batch_class() is None:
        raise StudyError(f"{ctrl.name}: its law {record.name} has no batch form (the generic loop flies it)")
    by_pfc = {True: ctrl.study_config("paper", rate, umax), False: ctrl.study_config("robust", rate, umax)}
    law = record.batch_class().of([by_pfc[bool(p)] for p in pfc_paper])

    # Plant, one per distinct scale vector (nominal: one for all).
    phis, gams = zoh_plants(scales, dt)
    PHI = [[per_run(phis[:, i, j]) for j in range(6)] for i in range(6)]
    GAM = [[per_run(gams[:, i, j]) for j in range(4)] for i in range(6)]
    # Faults (tools.experiment.study.faults): the phases on the control-step grid and each matrix set they fly
    fplan = study_faults.plan(task.faults, steps, dt)
    mats = [(phis, gams)]
    if fplan is not None:
        mats += [study_faults.matrices(scales, dt, key) for key in fplan.keys[1:]]
    fine = [study_faults.fine_matrices(scales, dt, key) for key in (fplan.fine if fplan is not None else ())]
    MATS1 = [tuple([[per_run(m[:, i, j]) for j in range(m.shape[2])] for i in range(6)] for m in f) for f in fine]
    MATS = [
        (
            [[per_run(p[:, i, j]) for j in range(6)] for i in range(6)],
            [[per_run(g[:, i, j]) for j in range(4)] for i in range(6)],
        )
        for p, g in mats
    ]

    # Disturbances: Dryden at T, scaled per run; gust samples; crosswind.
    dist = bool(np.any(turb > 0) or np.any(gust_amp != 0) or np.any(crosswind != 0))
    noisy = bool(np.any(turb > 0) or np.any(noise > 0) or np.any(loss > 0))
    dry = dryden(dt)
    xt = [np.zeros(n) for _ in range(4)]
    if np.any(turb > 0):
        l0 = dry.l0  # x0 = L0 z per run (so independent of the batch), as explicit sums in a fixed order
        x0 = np.array(
            [[l0[r, 0] * z[0] + l0[r, 1] * z[1] + l0[r, 2] * z[2] + l0[r, 3] * z[3] for r in range(4)] for z in turb0]
        )
        xt = [np.ascontiguousarray(x0[:, j]) for j in range(4)]
    gust_k = np.zeros((n, 0))
    g_first = np.zeros(n, dtype=int)
    if np.any(gust_amp != 0):
        width = int(math.ceil(20.0 / airspeed() * rate)) + 2  # the longest gust, 20 m
        g_first = np.ceil(gust_start * rate - 1e-9).astype(int)
        gust_k = np.zeros((n, width))
        for i in range(n):
            if gust_amp[i] != 0:
                g = Gust(float(gust_amp[i]), float(gust_len[i]), float(gust_start[i]))
                gust_k[i] = g((g_first[i] + np.arange(width)) * dt)  # per run: independent of the batch
    um_all = square_command(steps, dt)

    # Everything the steps read: the batch, its law, its plants and its disturbances, each run's generator.
    b = argparse.Namespace(
        kernel_form=record.kernel_form(),  # its C-kernel form (Law.kernel), None: numpy only
        n=n,
        steps=steps,
        rate=rate,
        dt=dt,
        umax=umax,
        law=law,
        gens=gens,
        noisy=noisy,
        dist=dist,
        turb=turb,
        noise=noise,
        bias=bias,
        thr=thr,
        delay=delay,
        crosswind=crosswind,
        gust_k=gust_k,
        g_first=g_first,
        um_all=um_all,
        PHI=PHI,
        GAM=GAM,
        fplan=fplan,
        MATS=MATS,
        MATS1=MATS1,
        dry=dry,
        xt=xt,
        record=task.record,
    )
    if engine not in (None, "kernel", "numpy"):
        raise StudyError(f"engine must be 'kernel' or 'numpy', got {engine!r}")
    lib = None if engine == "numpy" or b.kernel_form is None else native.load()
    if engine == "kernel" and lib is None:
        raise StudyError(f"no C kernel: {native.reason() if b.kernel_form else f'{record.name} has no kernel form'}")
    acc, peaks, track, rec = fly_numpy(b) if lib is None else fly_kernel(lib, b)
    out = {
        "ise_ref": acc["ise_ref"] * dt,
        "ise_crm": acc["ise_crm"] * dt,
        "energy": acc["energy"] * dt,
        "tv": acc["tv"],
        "max_abs_u": acc["max_abs_u"],
        "max_abs_roll": acc["max_abs_roll"],
        "sat_fraction": acc["sat"] / steps,
    }
    for key in METRICS:
        v = out[key]
        out[key] = np.where(np.isfinite(v), v, np.inf)  # a diverged run scores +inf, never NaN
    # inside the envelope (autopilot.envelope): |roll| and saturation, and tracking in every 20 s window
    out["oscillating"], out["not_following"] = track[0].copy(), track[1].copy()
    out["bounded"] = within(out["max_abs_roll"], out["sat_fraction"], ENVELOPE) & ~track[0] & ~track[1]
    out["pfc_paper"] = pfc_paper
    out["window_peak_roll"] = np.where(np.isfinite(peaks), peaks, np.inf)
    out["draws"] = {
        "scales": scales,
        "gust_amplitude_m_s": gust_amp,
        "gust_length_m": gust_len,
        "gust_start_s": gust_start,
        "crosswind_m_s": crosswind,
        "roll_bias_rad": bias,
    }
    if rec is not None:
        out["series"] = rec
    return out


def replay(
    controller: str, condition: str, seed: int, run: int, duration_s: float = 30.0, record: bool = True, faults=()
):
    """Run ``run`` of the study alone (a batch of one: bit for bit the study's numbers), with ``faults``
    (``sitl.damage.Fault``) if given."""
    return simulate(Task(controller, ((condition, run),), seed, duration_s, record, tuple(faults)))
