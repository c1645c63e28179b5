"""The Monte Carlo robustness study (issue 13): many aircraft and controllers stepped at once as numpy arrays.

    python -m tools.study run --runs N --seed S --out DIR [--scheduler tcp://HOST:PORT] [--controllers a,b]
                              [--conditions nominal,moderate,severe] [--sweep-runs M] [--long-runs L] [--chunk C]
    python -m tools.study replay --controller NAME --condition NAME --seed S --run I
    python -m tools.experiment robustness ...        (the same as ``python -m tools.study run ...``)

Per controller (``CONTROLLERS``: SAC, CL-SAC at L_v 10/20/50, the fixed-gain baseline, CL-SAC with each robustness
modification) and condition (``CONDITIONS``: nominal, moderate, severe, plus one-factor sweeps of link loss, sensor
delay and turbulence from nominal), N runs of the paper's 30 s square wave; a separate 600 s long-flight scenario
(``--long-runs``) measures the drift of the integral gains.  Writes ``DIR/summary.json`` (per controller and
condition: share of bounded runs, p50/p95 of every metric, the worst run and the commands that replay it),
``DIR/robustness.png`` (metric distributions per controller), ``DIR/worst.rrd`` (the worst runs side by side) and
prints the table.

**Randomness.**  Run i draws everything from ``numpy.random.default_rng([seed, i])``: first the static draws (plant
scale factors, PFC, gust, crosswind, bias, turbulence initial state) as standard uniforms/normals, then, in blocks,
7 standard normals per control step (4 for the Dryden filter, 1 roll noise, 2 link-loss draws).  A condition only
maps these standard draws to values, so run i sees the same underlying draws under every controller and condition
(common random numbers), and a run's result depends on (seed, i, controller, condition) only: never on the chunk
it was computed in or the worker that computed it.  Every per-step operation is elementwise (the law:
``autopilot.batch``; the plant: explicit sums in a fixed order, not BLAS), so element i of a batch is the same
whatever N.

**Models.**  Plant: the 6-state KH2013A + servo (``sitl.model``) scaled by ``sitl.uncertainty.PlantScales``,
advanced one control period T with the command and the disturbance held (exact ZOH of [B_p, E],
``sitl.atmosphere.disturbance_matrix``).  Turbulence: ``sitl.atmosphere.DrydenFilter`` built at T (the disturbance
is sampled and held at the control rate, 100 Hz, rather than the SITL's 1 kHz physics rate), intensity as a
multiple of MIL-HDBK-1797 "severe"; 1-cosine side gust (``sitl.atmosphere.Gust``); steady crosswind.  Sensor:
roll delayed by D samples, plus bias and white noise (``sitl.sensors`` semantics).  Link: each ATTITUDE is lost
with probability p (the law steps on the last roll received, as the real-time autopilot does before its 100 ms
failsafe), each SERVO_OUTPUT_RAW with probability p (the servo keeps the last command).

**Bounded**: max |roll| (truth) < 60 deg and the command saturated in < 20 % of the steps.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as _dt
import math
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from autopilot.shared.cli import OneLineArgumentParser
from autopilot.shared.process import write_json_atomic

DEG = math.pi / 180.0
BOUND_ROLL_RAD = 60.0 * DEG
BOUND_SAT_FRACTION = 0.2
METRICS = ("ise_ref", "ise_crm", "energy", "tv", "max_abs_u", "max_abs_roll", "sat_fraction")
WINDOW_S = 30.0  # the long flight reports the peak |roll| of each such window
BLOCK = 100  # control steps of noise drawn per run at a time
CHANNELS = 7  # standard normals per run and step: 4 Dryden, 1 roll noise, 2 link loss (up, down)
STATIC = 13  # static draws per run: 6 scales, pfc, gust amplitude, length, start, crosswind, bias (uniforms) + 1 spare


class StudyError(ValueError):
    """Bad study input; one line naming the value."""


# ---------------------------------------------------------------------------------------- controllers
@dataclass(frozen=True)
class Controller:
    """A controller of the study: ``kind`` "clsac" (SAC is L_v = 0) or "baseline", and ClSacConfig changes."""

    name: str
    kind: str = "clsac"
    lv: float = 20.0
    changes: tuple[tuple[str, object], ...] = ()
    label: str = ""

    def config(self, pfc: str, control_rate_hz: float, u_limit_rad: float):
        if self.kind == "baseline":
            from autopilot.baseline import BaselineConfig

            return BaselineConfig(control_rate_hz=control_rate_hz, u_limit_rad=u_limit_rad)
        from autopilot.config import ClSacConfig

        return (
            ClSacConfig(control_rate_hz=control_rate_hz, u_limit_rad=u_limit_rad, lv=self.lv)
            .with_pfc(pfc)
            .with_(**dict(self.changes))
        )


DEAD_ZONE_RAD = 0.25 * DEG  # about the roll noise of "moderate"
KI_MAX = 0.2  # rad/rad: 2.6 times the largest |K_I| of the nominal 30 s CL-SAC run (0.076)
CONTROLLERS: dict[str, Controller] = {
    c.name: c
    for c in (
        Controller("sac", lv=0.0, label="SAC"),
        Controller("clsac_lv10", lv=10.0, label="CL-SAC Lv 10"),
        Controller("clsac", lv=20.0, label="CL-SAC Lv 20 (paper)"),
        Controller("clsac_lv50", lv=50.0, label="CL-SAC Lv 50"),
        Controller("baseline", kind="baseline", lv=0.0, label="fixed-gain PID"),
        Controller("clsac_leak", changes=(("sigma_x", 0.1), ("sigma_u", 0.1)), label="CL-SAC + leakage 0.1"),
        Controller("clsac_deadzone", changes=(("dead_zone_rad", DEAD_ZONE_RAD),), label="CL-SAC + dead-zone 0.25 deg"),
        Controller("clsac_projection", changes=(("ki_max", KI_MAX),), label="CL-SAC + projection |K_I| <= 0.2"),
        Controller("clsac_freeze", changes=(("freeze_when_saturated", True),), label="CL-SAC + freeze when saturated"),
    )
}


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


def get_condition(name: str) -> Condition:
    cond = CONDITIONS.get(name) or sweep_conditions().get(name)
    if cond is None:
        raise StudyError(f"unknown condition {name!r} (known: {', '.join([*CONDITIONS, *sweep_conditions()])})")
    return cond


def get_controller(name: str) -> Controller:
    try:
        return CONTROLLERS[name]
    except KeyError:
        raise StudyError(f"unknown controller {name!r} (known: {', '.join(CONTROLLERS)})") from None


# ---------------------------------------------------------------------------------------- one batch
@dataclass(frozen=True)
class Task:
    """One chunk: a controller and the (condition, run index) pairs it flies, all with the same seed."""

    controller: str
    runs: tuple[tuple[str, int], ...]
    seed: int
    duration_s: float = 30.0
    record: bool = False


def _square(t: np.ndarray, amplitude: float = 10.0 * DEG, period: float = 10.0) -> np.ndarray:
    """The paper's command (tools.profiles.square: +amplitude first, switching every period/2)."""
    from tools.profiles import square

    return np.array([square(float(x), amplitude, period) for x in t])


def _plant(scales: np.ndarray, dt: float):
    """Per-run ZOH matrices of the scaled plant with inputs [u, v_g, p_g, r_g] held over dt."""
    from autopilot.shared.numerics import zoh
    from sitl.atmosphere import disturbance_matrix
    from sitl.uncertainty import PlantScales

    a, b = PlantScales(*scales).matrices()
    phi, gam = zoh(a, np.hstack([b, disturbance_matrix(a)]), dt)
    return phi, gam


def _columns(values: np.ndarray):
    """(k, ...) entries as Python floats when equal across runs (cheaper, and the same IEEE operation)."""
    first = values[0]
    if np.all(values == first):
        return float(first)
    return np.ascontiguousarray(values)


def simulate(task: Task) -> dict:
    """Fly ``task``: returns per-run arrays (``METRICS``, ``bounded``, ``pfc_paper``, the draws) in task order,
    and with ``record`` the per-step series of every run."""
    from scipy.special import ndtri

    from autopilot.batch import BatchBaseline, BatchClSac
    from sitl.atmosphere import DrydenConfig, DrydenFilter, Gust

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

    # Law, one config per run (the PFC is drawn per run).
    if ctrl.kind == "baseline":
        law = BatchBaseline(ctrl.config("paper", rate, umax), n)
    else:
        by_pfc = {True: ctrl.config("paper", rate, umax), False: ctrl.config("robust", rate, umax)}
        law = BatchClSac([by_pfc[bool(p)] for p in pfc_paper])

    # Plant, one per distinct scale vector (nominal: one for all).
    cache: dict[bytes, tuple] = {}
    mats = []
    for s in scales:
        key = s.tobytes()
        if key not in cache:
            cache[key] = _plant(s, dt)
        mats.append(cache[key])
    PHI = [[_columns(np.array([m[0][i, j] for m in mats])) for j in range(6)] for i in range(6)]
    GAM = [[_columns(np.array([m[1][i, j] for m in mats])) for j in range(4)] for i in range(6)]

    # Disturbances: Dryden at T, scaled per run; gust samples; crosswind.
    dist = bool(np.any(turb > 0) or np.any(gust_amp != 0) or np.any(crosswind != 0))
    noisy = bool(np.any(turb > 0) or np.any(noise > 0) or np.any(loss > 0))
    dry = DrydenFilter.build(DrydenConfig.intensity("severe"), dt)
    xt = [np.zeros(n) for _ in range(4)]
    if np.any(turb > 0):
        x0 = np.array([dry.l0 @ z for z in turb0])  # per run, so independent of the batch
        xt = [np.ascontiguousarray(x0[:, j]) for j in range(4)]
    t_all = np.arange(steps) * dt
    gust_k = np.zeros((n, 0))
    g_first = np.zeros(n, dtype=int)
    if np.any(gust_amp != 0):
        width = int(math.ceil(20.0 / _airspeed() * rate)) + 2  # the longest gust, 20 m
        g_first = np.ceil(gust_start * rate - 1e-9).astype(int)
        gust_k = np.zeros((n, width))
        for i in range(n):
            if gust_amp[i] != 0:
                g = Gust(float(gust_amp[i]), float(gust_len[i]), float(gust_start[i]))
                gust_k[i] = g((g_first[i] + np.arange(width)) * dt)  # per run: independent of the batch
    um_all = _square(t_all)

    x = [np.zeros(n) for _ in range(6)]
    hist = np.zeros((int(delay.max()) + 1, n))
    cols = np.arange(n)
    y_prev = np.zeros(n)
    u_fly = np.zeros(n)
    acc = {k: np.zeros(n) for k in ("ise_ref", "ise_crm", "energy", "tv", "max_abs_u", "max_abs_roll", "sat")}
    window = int(round(WINDOW_S * rate))
    peaks = np.zeros((n, max(steps // window, 1)))  # peak |roll| (truth) per 30 s window
    wmax = np.zeros(n)
    u_prev = None
    rec = {} if task.record else None
    block = None
    with np.errstate(all="ignore"):
        for k in range(steps):
            if noisy and k % BLOCK == 0:
                m = min(BLOCK, steps - k)
                buf = np.empty((n, m * CHANNELS))
                for i, g in enumerate(gens):
                    g.standard_normal(out=buf[i])
                block = np.ascontiguousarray(buf.reshape(n, m, CHANNELS).transpose(1, 2, 0))
            z = block[k % BLOCK] if noisy else None
            phi_true = x[3]
            # sensor: delay, bias, noise (sitl.sensors semantics: the first sample repeats for k < D)
            hist[k % hist.shape[0]] = phi_true
            y = hist[np.maximum(k - delay, 0) % hist.shape[0], cols] if hist.shape[0] > 1 else phi_true
            y = y + bias
            if noisy:
                y = y + noise * z[4]
                y = np.where(z[5] < thr, y_prev if k else y, y)  # ATTITUDE lost: the last roll received
            y_prev = y
            um = np.full(n, um_all[k])
            u = law(y, um)
            if noisy:
                u_fly = np.where(z[6] < thr, u_fly, u) if k else u  # SERVO_OUTPUT_RAW lost: servo keeps the last
            else:
                u_fly = u
            # metrics of what the law commanded (autopilot.metrics.MetricsAccumulator, same operation order)
            d = y - law.ym_ol
            acc["ise_ref"] += d * d
            acc["ise_crm"] += law.e * law.e
            acc["energy"] += u * u
            if u_prev is not None:
                acc["tv"] += np.abs(u - u_prev)
            u_prev = u
            acc["max_abs_u"] = np.maximum(acc["max_abs_u"], np.abs(u))
            acc["max_abs_roll"] = np.maximum(acc["max_abs_roll"], np.abs(phi_true))
            wmax = np.maximum(wmax, np.abs(phi_true))
            if (k + 1) % window == 0 and (k + 1) // window <= peaks.shape[1]:
                peaks[:, (k + 1) // window - 1] = wmax
                wmax = np.zeros(n)
            acc["sat"] += law.saturated
            if rec is not None:
                _record(rec, k * dt, um, y, law, u, x)
            # disturbance d = [v_g, p_g, r_g], held over the period
            if dist:
                if np.any(turb > 0):
                    dd = [
                        turb * (dry.c[r, 0] * xt[0] + dry.c[r, 1] * xt[1] + dry.c[r, 2] * xt[2] + dry.c[r, 3] * xt[3])
                        for r in range(3)
                    ]
                    if noisy:
                        xt = [
                            dry.ad[r, 0] * xt[0]
                            + dry.ad[r, 1] * xt[1]
                            + dry.ad[r, 2] * xt[2]
                            + dry.ad[r, 3] * xt[3]
                            + (dry.ld[r, 0] * z[0] + dry.ld[r, 1] * z[1] + dry.ld[r, 2] * z[2] + dry.ld[r, 3] * z[3])
                            for r in range(4)
                        ]
                else:
                    dd = [np.zeros(n), np.zeros(n), np.zeros(n)]
                if gust_k.shape[1]:
                    j = k - g_first
                    inside = (j >= 0) & (j < gust_k.shape[1])
                    dd[0] = dd[0] + np.where(inside, gust_k[cols, np.clip(j, 0, gust_k.shape[1] - 1)], 0.0)
                dd[0] = dd[0] + crosswind
                x = [
                    PHI[r][0] * x[0]
                    + PHI[r][1] * x[1]
                    + PHI[r][2] * x[2]
                    + PHI[r][3] * x[3]
                    + PHI[r][4] * x[4]
                    + PHI[r][5] * x[5]
                    + GAM[r][0] * u_fly
                    + (GAM[r][1] * dd[0] + GAM[r][2] * dd[1] + GAM[r][3] * dd[2])
                    for r in range(6)
                ]
            else:
                x = [
                    PHI[r][0] * x[0]
                    + PHI[r][1] * x[1]
                    + PHI[r][2] * x[2]
                    + PHI[r][3] * x[3]
                    + PHI[r][4] * x[4]
                    + PHI[r][5] * x[5]
                    + GAM[r][0] * u_fly
                    for r in range(6)
                ]
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
    out["bounded"] = (out["max_abs_roll"] < BOUND_ROLL_RAD) & (out["sat_fraction"] < BOUND_SAT_FRACTION)
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
        out["series"] = {key: np.array(v) for key, v in rec.items()}
    return out


def _airspeed() -> float:
    from sitl.atmosphere import AIRSPEED

    return AIRSPEED


def _record(rec: dict, t: float, um, y, law, u, x) -> None:
    zero = np.zeros_like(u)
    row = {
        "t": np.full_like(u, t),
        "um": um,
        "phi": y,
        "ym": getattr(law, "ym", law.ym_ol),
        "ym_ol": law.ym_ol,
        "ya": getattr(law, "ya", y),
        "y_pfc": getattr(law, "y_pfc", zero),
        "e": law.e,
        "u": u,
    }
    for key in ("kpe", "kie", "ke", "kpx", "kix", "kx", "kpu", "kiu", "ku"):
        row[key] = getattr(law, key, zero)
    row.update(v=x[0], p=x[1], r=x[2], delta_r=x[4])
    for key, v in row.items():
        rec.setdefault(key, []).append(np.array(v, dtype=float))


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


class Progress:
    """A one-line progress bar on stderr: runs done, runs/s, estimated time left."""

    def __init__(self, total: int, label: str, stream=None, enabled: bool = True):
        self.total, self.label, self.done = total, label, 0
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.t0 = time.perf_counter()

    def add(self, runs: int) -> None:
        self.done += runs
        if not self.enabled:
            return
        el = time.perf_counter() - self.t0
        rate = self.done / el if el > 0 else 0.0
        left = (self.total - self.done) / rate if rate > 0 else float("nan")
        width = 30
        fill = int(width * self.done / max(self.total, 1))
        self.stream.write(
            f"\r{self.label} [{'#' * fill}{'.' * (width - fill)}] {self.done}/{self.total} runs "
            f"{rate:,.0f} runs/s, {left:4.0f} s left "
        )
        if self.done >= self.total:
            self.stream.write("\n")
        self.stream.flush()


def execute(
    tasks: Sequence[Task],
    scheduler: str | None = None,
    progress: Progress | None = None,
    workers: int = 1,
    simulate=simulate,
) -> list[dict]:
    """Run every task: locally, one after the other (``workers`` 1) or in a pool of ``workers`` processes, or on
    the Dask cluster at ``scheduler`` (``tcp://HOST:PORT``); results in task order whichever.  ``simulate``: the
    task function (a picklable module-level function of a task with ``runs``; ``tools.jsbsim_study`` passes its
    own)."""
    results: list[dict | None] = [None] * len(tasks)
    if scheduler is None and workers <= 1:
        for i, t in enumerate(tasks):
            results[i] = simulate(t)
            if progress:
                progress.add(len(t.runs))
        return results  # type: ignore[return-value]
    if scheduler is None:
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(max_workers=workers) as pool:
            index = {pool.submit(simulate, t): i for i, t in enumerate(tasks)}
            for fut in as_completed(index):
                i = index[fut]
                results[i] = fut.result()
                if progress:
                    progress.add(len(tasks[i].runs))
        return results  # type: ignore[return-value]
    try:
        from distributed import Client, as_completed  # lazy: dask is an optional (dev) dependency
    except ImportError as exc:
        raise StudyError(f"--scheduler needs dask.distributed (pip install 'dask[distributed]'): {exc}") from None
    try:
        client = Client(scheduler, timeout="10s")
    except (OSError, TimeoutError) as exc:
        raise StudyError(f"cannot connect to the Dask scheduler at {scheduler}: {exc}") from None
    with client:
        futures = client.map(simulate, list(tasks), pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        for fut in as_completed(futures):
            i = index[fut.key]
            results[i] = fut.result()
            if progress:
                progress.add(len(tasks[i].runs))
    return results  # type: ignore[return-value]


def merge(tasks: Sequence[Task], results: Sequence[dict]) -> dict[str, dict[tuple[str, int], dict]]:
    """{controller: {(condition, run): per-run record}} from the chunks."""
    out: dict[str, dict[tuple[str, int], dict]] = {}
    for t, r in zip(tasks, results):
        d = out.setdefault(t.controller, {})
        for j, pair in enumerate(t.runs):
            rec = {m: float(r[m][j]) for m in METRICS}
            rec["bounded"] = bool(r["bounded"][j])
            rec["pfc"] = "paper" if r["pfc_paper"][j] else "robust"
            rec["window_peak_roll"] = r["window_peak_roll"][j]
            rec["draws"] = {k: (v[j].tolist() if np.ndim(v[j]) else float(v[j])) for k, v in r["draws"].items()}
            d[pair] = rec
    return out


def _pct(values: list[float], q: float) -> float:
    """Nearest-rank percentile (a diverged run's +inf stays +inf instead of making the interpolation NaN)."""
    return float(np.percentile(np.asarray(values, dtype=float), q, method="inverted_cdf"))


def aggregate(records: dict[tuple[str, int], dict], condition: str, controller: str, seed: int) -> dict:
    """summary.json's entry of one controller under one condition."""
    runs = sorted((i, r) for (c, i), r in records.items() if c == condition)
    if not runs:
        return {}
    rs = [r for _, r in runs]
    out: dict = {
        "runs": len(rs),
        "bounded_share": sum(r["bounded"] for r in rs) / len(rs),
        "bounded_share_by_pfc": {},
        "p50": {m: _finite(_pct([r[m] for r in rs], 50)) for m in METRICS},
        "p95": {m: _finite(_pct([r[m] for r in rs], 95)) for m in METRICS},
    }
    for pfc in ("paper", "robust"):
        sub = [r for r in rs if r["pfc"] == pfc]
        if sub and controller != "baseline":
            out["bounded_share_by_pfc"][pfc] = sum(r["bounded"] for r in sub) / len(sub)
    i, worst = min(runs, key=lambda ir: (ir[1]["bounded"], -ir[1]["max_abs_roll"], -ir[1]["ise_ref"]))
    out["worst"] = {
        "run": i,
        "seed": seed,
        "bounded": worst["bounded"],
        "pfc": worst["pfc"],
        "metrics": {m: _finite(worst[m]) for m in METRICS},
        "draws": worst["draws"],
        "replay_inprocess": replay_command(controller, condition, seed, i),
        "replay_mavlink": mavlink_command(controller, condition, seed, i, worst),
    }
    return out


def _finite(x: float):
    return x if math.isfinite(x) else None


def replay_command(controller: str, condition: str, seed: int, run: int) -> str:
    return f"python -m tools.study replay --controller {controller} --condition {condition} --seed {seed} --run {run}"


def mavlink_command(controller: str, condition: str, seed: int, run: int, rec: dict, duration: float = 30.0) -> str:
    """The same run as one lockstep flight over MAVLink (``python -m tools.launch``, the SITL's disturbance flags):
    the same plant, PFC, gust, crosswind, bias, delay, loss and turbulence intensity; the SITL draws its own noise
    sequences from --seed, so the flight is an equivalent replay, not a bit-identical one."""
    from sitl.atmosphere import DrydenConfig
    from sitl.uncertainty import SCALE_NAMES

    ctrl = get_controller(controller)
    cond = get_condition(condition)
    d = rec["draws"]
    argv = ["python -m tools.launch --lockstep", f"--duration {duration:g}"]
    if ctrl.kind == "baseline":
        argv.append("--controller baseline")
    else:
        argv += [f"--controller {'sac' if ctrl.lv == 0 else 'clsac'}", f"--lv {ctrl.lv:g}", f"--pfc {rec['pfc']}"]
        changes = dict(ctrl.changes)
        if "sigma_x" in changes:
            argv.append(f"--sigma-xu {changes['sigma_x']:g}")
        if "dead_zone_rad" in changes:
            argv.append(f"--dead-zone-deg {changes['dead_zone_rad'] / DEG:.6g}")
        if "ki_max" in changes:
            argv.append(f"--ki-max {changes['ki_max']:g}")
        if changes.get("freeze_when_saturated"):
            argv.append("--freeze-when-saturated")
    for name, f in zip(SCALE_NAMES, d["scales"]):
        if f != 1.0:
            argv.append(f"--scale {name}={f:.6g}")
    if cond.turbulence:
        sev = DrydenConfig.intensity("severe")
        argv.append(f"--turbulence-sigma {sev.sigma_v * cond.turbulence:.6g},{sev.sigma_w * cond.turbulence:.6g}")
    if d["gust_amplitude_m_s"]:
        argv.append(f"--gust {d['gust_amplitude_m_s']:.6g},{d['gust_length_m']:.6g},{d['gust_start_s']:.6g}")
    if d["crosswind_m_s"]:
        argv.append(f"--crosswind {d['crosswind_m_s']:.6g}")
    if cond.roll_noise:
        argv.append(f"--roll-noise {cond.roll_noise / DEG:.6g}")
    if d["roll_bias_rad"]:
        argv.append(f"--roll-bias {d['roll_bias_rad'] / DEG:.6g}")
    if cond.delay:
        argv.append(f"--sensor-delay {cond.delay}")
    if cond.loss:
        argv.append(f"--loss {cond.loss:g}")
    argv.append(f"--seed {seed * 1_000_000 + run}")
    return " ".join(argv)


LONG_CONTROLLERS = ("clsac", "clsac_leak", "clsac_deadzone", "clsac_projection", "clsac_freeze", "baseline")
LONG_DURATION_S = 600.0
LONG_CONDITIONS = ("nominal", "moderate")


def long_flight_summary(records: dict[tuple[str, int], dict], condition: str) -> dict:
    """The drift of a 600 s flight: median peak |roll| (deg) of each 30 s window, per PFC."""
    out = {}
    for pfc in ("paper", "robust"):
        rs = [r for (c, _), r in records.items() if r["pfc"] == pfc and c == condition]
        if not rs:
            continue
        peaks = np.array([r["window_peak_roll"] for r in rs]) / DEG
        med = np.median(peaks, axis=0)
        out[pfc] = {
            "runs": len(rs),
            "bounded_share": sum(r["bounded"] for r in rs) / len(rs),
            "median_window_peak_roll_deg": [_finite(round(float(v), 3)) for v in med],
            "peak_first_window_deg": _finite(float(med[0])),
            "peak_180_210_s_deg": _finite(float(med[6])) if len(med) > 6 else None,
            "peak_last_window_deg": _finite(float(med[-1])),
            "first_window_over_60_deg_s": next((WINDOW_S * (j + 1) for j, v in enumerate(med) if v >= 60.0), None),
        }
    return out


@dataclass(frozen=True)
class StudyOptions:
    runs: int = 1000
    seed: int = 0
    controllers: tuple[str, ...] = tuple(CONTROLLERS)
    conditions: tuple[str, ...] = tuple(CONDITIONS)
    sweep_runs: int = 100
    long_runs: int = 10
    chunk: int = 2500
    scheduler: str | None = None
    workers: int = 1  # local processes (ignored with a scheduler)

    def __post_init__(self) -> None:
        for name in ("runs", "sweep_runs", "long_runs"):
            if getattr(self, name) < 0:
                raise StudyError(f"--{name.replace('_', '-')} must be >= 0, got {getattr(self, name)}")
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


def run_study(opts: StudyOptions, out_dir: str | os.PathLike | None = None, *, log=print, progress: bool = True):
    """The whole study; returns the summary dict (also written to ``out_dir/summary.json`` with the table,
    the figure and the worst runs' ``.rrd`` when ``out_dir`` is given)."""
    t_start = time.perf_counter()
    pairs = [(c, i) for c in opts.conditions for i in range(opts.runs)]
    sweeps = list(sweep_conditions()) if opts.sweep_runs else []
    pairs += [(c, i) for c in sweeps for i in range(opts.sweep_runs)]
    tasks = make_tasks(opts.controllers, pairs, opts.seed, opts.chunk)
    long_ctrls = [c for c in LONG_CONTROLLERS if c in opts.controllers] if opts.long_runs else []
    long_pairs = [(c, i) for c in LONG_CONDITIONS for i in range(opts.long_runs)]
    long_tasks = make_tasks(long_ctrls, long_pairs, opts.seed, opts.chunk, LONG_DURATION_S)
    total = sum(len(t.runs) for t in tasks)
    bar = Progress(total, "30 s runs", enabled=progress)
    where = opts.scheduler or ("this process" if opts.workers == 1 else f"{opts.workers} local processes")
    log(f"study: {len(opts.controllers)} controllers x {len(pairs)} runs = {total} runs of 30 s on {where}")
    results = execute(tasks, opts.scheduler, bar, opts.workers)
    wall = time.perf_counter() - t_start
    merged = merge(tasks, results)
    summary: dict = {
        "study": "robustness",
        "seed": opts.seed,
        "runs_per_condition": opts.runs,
        "sweep_runs": opts.sweep_runs,
        "scheduler": opts.scheduler or "local",
        "bounds": {"max_abs_roll_deg": BOUND_ROLL_RAD / DEG, "sat_fraction": BOUND_SAT_FRACTION},
        "units": {
            "ise_ref": "rad^2 s",
            "ise_crm": "rad^2 s",
            "energy": "rad^2 s",
            "tv": "rad",
            "max_abs_u": "rad",
            "max_abs_roll": "rad",
            "sat_fraction": "1",
        },
        "conditions": {c: dataclasses.asdict(get_condition(c)) for c in (*opts.conditions, *sweeps)},
        "controllers": {
            c: {"label": CONTROLLERS[c].label, "changes": dict(CONTROLLERS[c].changes)} for c in opts.controllers
        },
        "results": {
            c: {cond: aggregate(merged[c], cond, c, opts.seed) for cond in (*opts.conditions, *sweeps)}
            for c in opts.controllers
        },
    }
    summary["breaks"] = breaks(summary)
    summary["timing"] = {"wall_s": wall, "runs": total, "runs_per_s": total / wall if wall > 0 else None}
    if long_tasks:
        n_long = sum(len(t.runs) for t in long_tasks)
        log(f"long flight: {len(long_ctrls)} controllers x {len(long_pairs)} runs of {LONG_DURATION_S:g} s")
        lres = execute(long_tasks, opts.scheduler, Progress(n_long, "600 s runs", enabled=progress), opts.workers)
        lmerged = merge(long_tasks, lres)
        summary["long_flight"] = {
            "duration_s": LONG_DURATION_S,
            "window_s": WINDOW_S,
            "runs_per_condition": opts.long_runs,
            "controllers": {
                c: {cond: long_flight_summary(lmerged[c], cond) for cond in LONG_CONDITIONS} for c in long_ctrls
            },
        }
    summary["created"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        write_json_atomic(out / "summary.json", summary, indent=2, allow_nan=False)
        tables = [format_table(summary)]
        if summary["sweep_runs"]:
            tables.append(format_breaks(summary))
        if "long_flight" in summary:
            tables.append(format_long(summary))
        (out / "table.md").write_text("\n\n".join(tables) + "\n", encoding="utf-8")
        log(f"wrote {(out / 'summary.json').resolve()} and table.md")
        try:
            png = save_figure(merged, opts, out / "robustness.png")
            log(f"wrote {png.resolve()}")
        except ImportError as exc:
            log(f"no figure: {exc}")
        rrd = save_worst_rrd(summary, opts, out / "worst.rrd")
        if rrd is not None:
            log(f"wrote {rrd.resolve()} (open it with: rerun {rrd.resolve()})")
    return summary


def breaks(summary: dict, share: float = 0.9) -> dict:
    """Per controller and sweep: the smallest swept value at which fewer than ``share`` of the runs stay bounded
    (None: bounded at every value tried), over all runs and per PFC (``by_pfc``)."""
    out: dict = {}
    for ctrl, by_cond in summary["results"].items():
        out[ctrl] = {"by_pfc": {"paper": {}, "robust": {}}}
        for label, (_field, values) in SWEEPS.items():
            aggs = [(v, by_cond.get(f"{label}={v:.3g}")) for v in values]
            aggs = [(v, a) for v, a in aggs if a]
            if not aggs:
                continue
            out[ctrl][label] = next((v for v, a in aggs if a["bounded_share"] < share), None)
            for pfc in ("paper", "robust"):
                if all(pfc in a["bounded_share_by_pfc"] for _, a in aggs):
                    out[ctrl]["by_pfc"][pfc][label] = next(
                        (v for v, a in aggs if a["bounded_share_by_pfc"][pfc] < share), None
                    )
    return out


def format_table(summary: dict, conditions: Sequence[str] = ("nominal", "moderate", "severe")) -> str:
    """Markdown: bounded share and p95 of ise_ref and energy per controller and condition (README, "Robustness")."""
    conds = [c for c in conditions if any(c in v for v in summary["results"].values())]
    head = "| controller | " + " | ".join(f"{c}: bounded / p95 ise_ref / p95 energy" for c in conds) + " |"
    lines = [head, "|---|" + "---|" * len(conds)]
    for ctrl, by_cond in summary["results"].items():
        cells = []
        for c in conds:
            a = by_cond.get(c) or {}
            if not a:
                cells.append("")
                continue
            cells.append(f"{100 * a['bounded_share']:.1f} % / {_fmt(a['p95']['ise_ref'])} / {_fmt(a['p95']['energy'])}")
        lines.append(f"| {ctrl} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def format_breaks(summary: dict) -> str:
    """Markdown: per controller, the loss probability, sensor delay (samples of 10 ms) and turbulence (x severe)
    at which it stops being bounded, with the paper's PFC / the robust PFC ("-": bounded at every value tried)."""
    head = "| controller | " + " | ".join(f"{k}: paper PFC / robust PFC" for k in SWEEPS) + " |"
    lines = [head, "|---|" + "---|" * len(SWEEPS)]
    for ctrl, b in summary["breaks"].items():
        cells = []
        for k in SWEEPS:
            if ctrl == "baseline":
                v = b.get(k)
                cells.append(f"{'-' if v is None else f'{v:.3g}'} (no PFC)")
                continue
            pair = [b["by_pfc"][p].get(k) for p in ("paper", "robust")]
            cells.append(" / ".join("-" if v is None else f"{v:.3g}" for v in pair))
        lines.append(f"| {ctrl} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def format_long(summary: dict) -> str:
    """Markdown: the long flight's median peak |roll| (deg) in the first window, at 180-210 s and in the last
    window, per controller, condition and PFC."""
    lf = summary.get("long_flight")
    if not lf:
        return ""
    lines = [
        "| controller | condition | PFC | peak 0-30 s | peak 180-210 s | peak 570-600 s | bounded |",
        "|---|---|---|---|---|---|---|",
    ]
    for ctrl, by_cond in lf["controllers"].items():
        for cond, by_pfc in by_cond.items():
            for pfc, d in by_pfc.items():
                if ctrl == "baseline" and pfc == "robust":
                    continue
                cells = [d["peak_first_window_deg"], d["peak_180_210_s_deg"], d["peak_last_window_deg"]]
                lines.append(
                    f"| {ctrl} | {cond} | {'-' if ctrl == 'baseline' else pfc} | "
                    + " | ".join("diverged" if v is None else f"{v:.1f} deg" for v in cells)
                    + f" | {100 * d['bounded_share']:.0f} % |"
                )
    return "\n".join(lines)


def _fmt(v) -> str:
    return "diverged" if v is None else f"{v:.3g}"


def save_figure(merged: dict, opts: StudyOptions, path: Path) -> Path:
    """Box plots of ise_ref and energy per controller, one column per condition (log scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    conds = list(opts.conditions)
    fig, axes = plt.subplots(2, len(conds), figsize=(4.2 * len(conds), 7), squeeze=False, sharey="row")
    for j, cond in enumerate(conds):
        for i, metric in enumerate(("ise_ref", "energy")):
            ax = axes[i][j]
            data = []
            for ctrl in opts.controllers:
                v = np.array([r[metric] for (c, _), r in merged[ctrl].items() if c == cond])
                v = v[np.isfinite(v) & (v > 0)]
                data.append(v if v.size else np.array([np.nan]))
            ax.boxplot(data, whis=(5, 95), showfliers=False)
            ax.set_xticks(range(1, len(opts.controllers) + 1), opts.controllers, rotation=60, fontsize=7)
            ax.set_yscale("log")
            ax.grid(True, alpha=0.3)
            if i == 0:
                ax.set_title(cond)
            if j == 0:
                ax.set_ylabel(f"{metric} [rad^2 s]")
    fig.suptitle(f"Monte Carlo: {opts.runs} runs per condition, seed {opts.seed} (whiskers p5-p95)")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def replay(controller: str, condition: str, seed: int, run: int, duration_s: float = 30.0, record: bool = True):
    """Run ``run`` of the study alone (a batch of one: bit for bit the study's numbers)."""
    return simulate(Task(controller, ((condition, run),), seed, duration_s, record))


def save_worst_rrd(summary: dict, opts: StudyOptions, path: Path, condition: str = "severe") -> Path | None:
    """The worst run of each controller under ``condition`` (else the last condition), side by side in Rerun."""
    from tools.scenario import RunResult

    cond = condition if condition in opts.conditions else opts.conditions[-1]
    results = []
    for ctrl in opts.controllers:
        w = summary["results"][ctrl][cond].get("worst")
        if not w:
            continue
        r = replay(ctrl, cond, opts.seed, w["run"])
        series = {k: v[:, 0] for k, v in r["series"].items()}
        metrics = {m: float(r[m][0]) for m in ("ise_ref", "ise_crm", "energy", "tv", "max_abs_u")}
        results.append(RunResult(f"{ctrl}_{cond}_run{w['run']}", CONTROLLERS[ctrl].lv, metrics, series))
    if not results:
        return None
    try:
        from tools.recording import log_experiment
    except ImportError:
        return None
    return Path(log_experiment(results, path))


# ---------------------------------------------------------------------------------------- command line
def build_parser(prog: str = "python -m tools.study") -> argparse.ArgumentParser:
    p = OneLineArgumentParser(prog=prog, description="Monte Carlo robustness study (issue 13); see the module doc.")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="the study")
    add_run_arguments(r)
    q = sub.add_parser("replay", help="one run of the study, alone, with its metrics")
    q.add_argument("--controller", required=True, choices=tuple(CONTROLLERS))
    q.add_argument("--condition", required=True)
    q.add_argument("--seed", type=int, required=True)
    q.add_argument("--run", type=int, required=True)
    q.add_argument("--duration", type=float, default=30.0)
    return p


def add_run_arguments(r: argparse.ArgumentParser) -> None:
    r.add_argument("--runs", type=int, default=1000, help="runs per controller and condition (default 1000)")
    r.add_argument("--seed", type=int, default=0, help="run i draws from numpy default_rng([seed, i]) (default 0)")
    r.add_argument("--out", metavar="DIR", help="output folder (default: a new runs/robustness-<timestamp>/)")
    r.add_argument("--controllers", metavar="A,B", help=f"subset of: {','.join(CONTROLLERS)} (default all)")
    r.add_argument("--conditions", metavar="A,B", help="subset of: nominal,moderate,severe (default all)")
    r.add_argument(
        "--sweep-runs", type=int, default=100, help="runs per sweep point (loss, delay, turbulence; 0: none)"
    )
    r.add_argument("--long-runs", type=int, default=10, help="runs of the 600 s long flight (0: none; default 10)")
    r.add_argument("--chunk", type=int, default=2500, help="runs per batch (results do not depend on it)")
    r.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="a Dask scheduler (default: run here)")
    r.add_argument(
        "--workers", type=int, default=1, help="local processes when no --scheduler (default 1; results do not change)"
    )
    r.add_argument("--no-progress", action="store_true", help="no progress bar")


def options_from_args(args) -> StudyOptions:
    def names(text):
        if text is None:
            return None
        items = tuple(s.strip() for s in text.split(","))
        if not all(items):
            raise StudyError(f"empty name in {text!r}")
        return items

    kw = dict(
        runs=args.runs,
        seed=args.seed,
        sweep_runs=args.sweep_runs,
        long_runs=args.long_runs,
        chunk=args.chunk,
        scheduler=args.scheduler,
        workers=args.workers,
    )
    if args.controllers:
        kw["controllers"] = names(args.controllers)
    if args.conditions:
        kw["conditions"] = names(args.conditions)
    return StudyOptions(**kw)


def main_run(args, prog: str) -> int:
    try:
        opts = options_from_args(args)
        from tools.experiment import check_out_dir, default_out_dir, prepare_out_dir

        out = Path(args.out) if args.out else default_out_dir("robustness")
        check_out_dir(out)
        out = prepare_out_dir(out)
        summary = run_study(opts, out, progress=not args.no_progress)
    except (StudyError, ValueError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    print()
    print(format_table(summary))
    print()
    if summary["sweep_runs"]:
        print("where each controller stops being bounded (< 90 % of runs), one factor at a time from nominal:")
        print(format_breaks(summary))
    for ctrl, by_cond in summary["results"].items():
        w = by_cond.get(opts.conditions[-1], {}).get("worst")
        if w:
            print(f"worst {ctrl} run under {opts.conditions[-1]}: {w['replay_inprocess']}")
    if "long_flight" in summary:
        print(f"\nlong flight ({LONG_DURATION_S:g} s), median peak |roll| per 30 s window:")
        print(format_long(summary))
    t = summary["timing"]
    print(f"\n{t['runs']} runs in {t['wall_s']:.1f} s ({t['runs_per_s']:,.0f} runs/s); files in {out.resolve()}")
    return 0


def main_replay(args, prog: str) -> int:
    try:
        get_condition(args.condition)
        r = replay(args.controller, args.condition, args.seed, args.run, args.duration, record=False)
    except StudyError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    print(
        f"{args.controller} under {args.condition}, seed {args.seed}, run {args.run} (PFC "
        f"{'paper' if r['pfc_paper'][0] else 'robust'}): bounded {bool(r['bounded'][0])}"
    )
    for m in METRICS:
        print(f"  {m:<13} {float(r[m][0]):.10g}")
    return 0


def main(argv: Sequence[str] | None = None, prog: str = "python -m tools.study", run_prog: str | None = None) -> int:
    """``run_prog``: the study alone under that name (``python -m tools.experiment robustness`` = ``run``)."""
    if run_prog is not None:
        p = OneLineArgumentParser(prog=run_prog, description="Monte Carlo robustness study (tools.study run).")
        add_run_arguments(p)
        return main_run(p.parse_args(argv), run_prog)
    args = build_parser(prog).parse_args(argv)
    if args.command == "replay":
        return main_replay(args, prog)
    return main_run(args, prog)


if __name__ == "__main__":
    sys.exit(main())
