"""One batch of the study flown as numpy arrays (``simulate``), and one run replayed alone (``replay``): the
random draws, the plant, the disturbances, the sensor and the link, the law and the metrics of each step."""

from __future__ import annotations

import argparse
import functools
import math

import numpy as np

from autopilot import swings as sw  # the oscillation rule's swing counter
from autopilot.envelope import (
    DEV_FLOOR2,
    DEV_MAX2,
    DEV_RATIO2,
    FOLLOW_GAIN_MIN,
    HIT_REARM,
    REF_FLOOR2,
    SAT_RTOL,
    STOP_HITS_MIN,
    TRACK_BLOCK_S,
    TRACK_BLOCKS,
    saturated,
    stop_hit,
    window_flags,
    within,
)
from tools.experiment.study import faults as study_faults
from tools.experiment.study import native
from tools.experiment.study.sampling import (
    BLOCK,
    CHANNELS,
    DEG,
    ENVELOPE,
    METRICS,
    STATIC,
    WINDOW_S,
    StudyError,
    Task,
    get_condition,
    get_controller,
)


def _square(t: np.ndarray, amplitude: float = 10.0 * DEG, period: float = 10.0) -> np.ndarray:
    """The paper's command (tools.flight.profiles.square: +amplitude first, switching every period/2)."""
    from tools.flight.profiles import square

    return np.array([square(float(x), amplitude, period) for x in t])


@functools.lru_cache(maxsize=8)
def _command(steps: int, dt: float) -> np.ndarray:
    """``_square`` at t = k dt, k < steps, computed once per process and length (a 600 s flight's 60,000 calls of
    ``square`` cost as much as its steps in C); read-only, shared by every batch of that length."""
    um = _square(np.arange(steps) * dt)
    um.flags.writeable = False
    return um


# The study's numbers must not depend on the CPU.  BLAS and LAPACK (scipy's expm, the Lyapunov solve) leave last
# bits that depend on the kernel OpenBLAS picks for the CPU (measured: 29 of 66 entries of a plant's [Phi, Gamma]
# differ between its SkylakeX and Haswell kernels, structural zeros coming out as +-1e-17), and over a 600 s
# saturated limit cycle such a difference grows into degrees: the long flight's clsac / moderate / robust median
# peak of 570-600 s read 63.1 deg on one kernel and 70.7 deg on the other.  So the plant and the law are discretised
# without BLAS (``autopilot.shared.numerics.expm``) and the one Dryden filter, which needs LAPACK (a Lyapunov solve,
# eigen-decompositions), is rounded to a grid (``canonical``) with its factors' column signs fixed.
CANONICAL_BITS = 32


def canonical(a) -> np.ndarray:
    """``a`` rounded to the grid 2**(e - CANONICAL_BITS), 2**e > max |a| (about 1e-10 of its largest entry),
    exactly.  A difference of a few ulp of max |a| changes an entry only if it straddles a grid point
    (probability about 1e-7 per entry); entries that should be zero and come out as +-1e-17 become 0."""
    a = np.asarray(a, dtype=float)
    top = float(np.max(np.abs(a))) if a.size else 0.0
    if top == 0.0:
        return a.copy()
    q = math.ldexp(1.0, math.frexp(top)[1] - CANONICAL_BITS)  # a power of two: a / q and its product are exact
    return np.round(a / q) * q + 0.0  # + 0.0: a -0.0 (rounded from -1e-17) becomes +0.0


def _plant(scales: np.ndarray, dt: float):
    """Per-run ZOH matrices of the scaled plant with inputs [u, v_g, p_g, r_g] held over dt (the same bits on any
    CPU: ``autopilot.shared.numerics.expm``)."""
    from autopilot.shared.numerics import zoh

    return zoh(*_continuous(scales), dt)


def _continuous(scales: np.ndarray):
    """(A_p, [B_p, E]) of the scaled plant."""
    from sitl.atmosphere import disturbance_matrix
    from sitl.uncertainty import PlantScales

    a, b = PlantScales(*scales).matrices()
    return a, np.hstack([b, disturbance_matrix(a)])


def _plants(scales: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``_plant`` of every run, (n, 6, 6) and (n, 6, 4): each distinct scale vector discretised once, all of them
    at once (``zoh_many``: bit for bit ``zoh`` of each)."""
    from autopilot.shared.numerics import zoh_many

    keys = [s.tobytes() for s in scales]
    first = {}
    for i, key in enumerate(keys):
        first.setdefault(key, i)
    pairs = [_continuous(scales[i]) for i in first.values()]
    phi, gam = zoh_many(np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs]), dt)
    where = {key: j for j, key in enumerate(first)}
    index = np.array([where[key] for key in keys])
    return phi[index], gam[index]


# The sign of each column's largest entry in the Dryden filter's square-root factors: LAPACK's choice on the machine
# the published numbers were computed on, now fixed for every machine (an eigen-decomposition may return either
# sign of each eigenvector, and LAPACK's choice depends on its kernel; both give the same covariance, but another
# turbulence sequence from the same draws).
DRYDEN_COLUMN_SIGNS = {"ld": (1.0, 1.0, 1.0, -1.0), "l0": (1.0, -1.0, 1.0, -1.0)}


def _signed_columns(a: np.ndarray, signs) -> np.ndarray:
    """The columns of a square-root factor (L L^T = Q, unique up to each column's sign) with the sign that gives
    each one's largest entry the sign in ``signs``."""
    top = a[np.argmax(np.abs(a), axis=0), np.arange(a.shape[1])]
    return a * np.where(np.sign(top) == np.asarray(signs), 1.0, -1.0) + 0.0  # + 0.0: no -0.0 from a flip


def _dryden(dt: float):
    """The Dryden filter at the control period (MIL-HDBK-1797 "severe", scaled per run): its coefficients
    ``ad``, ``ld``, ``c``, ``l0`` rounded by ``canonical``, the factors' column signs fixed
    (``DRYDEN_COLUMN_SIGNS``)."""
    from sitl.atmosphere import DrydenConfig, DrydenFilter

    dry = DrydenFilter.build(DrydenConfig.intensity("severe"), dt)
    out = {k: canonical(getattr(dry, k)) for k in ("ad", "ld", "c", "l0")}
    for k, signs in DRYDEN_COLUMN_SIGNS.items():
        out[k] = _signed_columns(out[k], signs)
    return argparse.Namespace(**out)


def _columns(values: np.ndarray):
    """(k, ...) entries as Python floats when equal across runs (cheaper, and the same IEEE operation)."""
    first = values[0]
    if np.all(values == first):
        return float(first)
    return np.ascontiguousarray(values)


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
    phis, gams = _plants(scales, dt)
    PHI = [[_columns(phis[:, i, j]) for j in range(6)] for i in range(6)]
    GAM = [[_columns(gams[:, i, j]) for j in range(4)] for i in range(6)]
    # Faults (tools.experiment.study.faults): the phases on the control-step grid and each matrix set they fly
    fplan = study_faults.plan(task.faults, steps, dt)
    mats = [(phis, gams)]
    if fplan is not None:
        mats += [study_faults.matrices(scales, dt, key) for key in fplan.keys[1:]]
    fine = [study_faults.fine_matrices(scales, dt, key) for key in (fplan.fine if fplan is not None else ())]
    MATS1 = [tuple([[_columns(m[:, i, j]) for j in range(m.shape[2])] for i in range(6)] for m in f) for f in fine]
    MATS = [
        (
            [[_columns(p[:, i, j]) for j in range(6)] for i in range(6)],
            [[_columns(g[:, i, j]) for j in range(4)] for i in range(6)],
        )
        for p, g in mats
    ]

    # Disturbances: Dryden at T, scaled per run; gust samples; crosswind.
    dist = bool(np.any(turb > 0) or np.any(gust_amp != 0) or np.any(crosswind != 0))
    noisy = bool(np.any(turb > 0) or np.any(noise > 0) or np.any(loss > 0))
    dry = _dryden(dt)
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
        width = int(math.ceil(20.0 / _airspeed() * rate)) + 2  # the longest gust, 20 m
        g_first = np.ceil(gust_start * rate - 1e-9).astype(int)
        gust_k = np.zeros((n, width))
        for i in range(n):
            if gust_amp[i] != 0:
                g = Gust(float(gust_amp[i]), float(gust_len[i]), float(gust_start[i]))
                gust_k[i] = g((g_first[i] + np.arange(width)) * dt)  # per run: independent of the batch
    um_all = _command(steps, dt)

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
    acc, peaks, track, rec = _fly_numpy(b) if lib is None else _fly_kernel(lib, b)
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


COEF_ROWS = 21  # kernel.c's law coefficients per aircraft (CL-SAC's C_*, B_*: autopilot.batch.clsac_kernel)
_SERIES = ("t", "um", "phi", "ym", "ym_ol", "ya", "y_pfc", "e", "u", "kpe", "kie", "ke", "kpx", "kix", "kx", "kpu")
_SERIES += ("kiu", "ku", "v", "p", "r", "delta_r")  # _record's keys, in its order


def _rows(values, n: int) -> np.ndarray:
    """(k, n) float64, C order: each entry (a Python float the same for every run, or an (n,) array) per run."""
    out = np.empty((len(values), n))
    for j, v in enumerate(values):
        out[j] = v  # a float broadcast: scalar * array and array * array are the same IEEE operation
    return out


def _ptr(a: np.ndarray, ctype=None):
    import ctypes

    return a.ctypes.data_as(ctypes.POINTER(ctype or ctypes.c_double))


def _fly_kernel(lib, b) -> tuple[dict, np.ndarray, np.ndarray, dict | None]:
    """The steps in C (``kernel.c``, ``native``): ``_fly_numpy``'s numbers, bit for bit, without its per-step
    overhead.  The noise is drawn here, block by block from each run's generator, exactly as ``_fly_numpy``
    draws it."""
    import ctypes

    n, steps = b.n, b.steps
    form = b.kernel_form(b.law)  # the law's C-kernel form (autopilot.batch.KernelForm): kernel.c's law and arrays
    kind, state = form.kind, _rows(form.state, n)
    coef = _rows(form.coef, n)
    coef = np.vstack([coef, np.zeros((COEF_ROWS - coef.shape[0], n))])
    aw, dz, kmax, freeze = form.anti_windup, form.dead_zone, form.ki_max, form.freeze
    window = int(round(WINDOW_S * b.rate))
    npeaks = max(steps // window, 1)
    keep = {  # every array the kernel reads or writes, kept alive (and C-contiguous) for the calls
        "coef": coef,
        "law": state,
        "phi": _rows([v for row in b.PHI for v in row], n),
        "gam": _rows([v for row in b.GAM for v in row], n),
        "x": np.zeros((6, n)),
        "dry": np.concatenate([np.ravel(b.dry.c), np.ravel(b.dry.ad), np.ravel(b.dry.ld)]).astype(float),
        "xt": _rows(b.xt, n),
        "turb": np.ascontiguousarray(b.turb, dtype=float),
        "bias": np.ascontiguousarray(b.bias, dtype=float),
        "noise": np.ascontiguousarray(b.noise, dtype=float),
        "thr": np.ascontiguousarray(b.thr, dtype=float),
        "crosswind": np.ascontiguousarray(b.crosswind, dtype=float),
        "delay": np.ascontiguousarray(b.delay, dtype=np.int64),
        "g_first": np.ascontiguousarray(b.g_first, dtype=np.int64),
        "gust_k": np.ascontiguousarray(b.gust_k, dtype=float),
        "um_all": np.ascontiguousarray(b.um_all, dtype=float),
        "hist": np.zeros((int(b.delay.max()) + 1, n)),
        "y_prev": np.zeros(n),
        "u_fly": np.zeros(n),
        "u_prev": np.zeros(n),
        "acc": np.zeros((7, n)),
        "wmax": np.zeros(n),
        "peaks": np.zeros((n, npeaks)),
        "rec": np.zeros((len(_SERIES), steps, n)) if b.record else None,
        "tblk": np.zeros((5, n)),
        "tring": np.zeros((TRACK_BLOCKS * 5, n)),
        "track": np.zeros((2, n)),
        "hit_armed": np.ones(n),
        "swing": np.zeros((7, n)),  # autopilot.swings' state, set at step 0
        **_fault_arrays(b),
    }
    tblock = int(round(TRACK_BLOCK_S * b.rate))
    if keep["dry"].shape != (44,):  # kernel.c reads c (3 x 4), ad (4 x 4), ld (4 x 4)
        raise ValueError(f"the Dryden filter's coefficients: {keep['dry'].shape[0]} values, kernel.c reads 44")
    ints = {"delay", "g_first", "ph_start", "ph_mat", "ph_jump", "ph_off", "ph_delay", "ph_reset", "ph_fine"}
    batch = native.Batch(
        n=n,
        steps=steps,
        hist_len=keep["hist"].shape[0],
        window=window,
        npeaks=npeaks,
        gust_width=keep["gust_k"].shape[1],
        kind=kind,
        noisy=int(b.noisy),
        dist=int(b.dist),
        turb_any=int(np.any(b.turb > 0)),
        gust_any=int(keep["gust_k"].shape[1] > 0),
        aw=int(bool(aw)),
        freeze=int(bool(freeze)),
        has_kmax=int(kmax is not None),
        umax=b.umax,
        sat_lim=(1.0 - SAT_RTOL) * b.umax,  # autopilot.envelope.saturated: not |u| < (1 - SAT_RTOL) u_limit
        dz=float(dz),
        kmax=float(kmax) if kmax is not None else 0.0,
        dt=b.dt,
        tblock=tblock,
        tblocks=TRACK_BLOCKS,
        dev_ratio2=DEV_RATIO2,  # autopilot.envelope.window_flags' constants
        dev_floor2=DEV_FLOOR2,
        ref_floor2=REF_FLOOR2,
        follow_min=FOLLOW_GAIN_MIN,
        hits_min=float(STOP_HITS_MIN),
        rearm_lim=HIT_REARM * b.umax,
        swing_h=sw.OSC_SWING_RAD,  # autopilot.swings' constants
        swing_tol=sw.OSC_REGULAR_TOL,
        swings_min=float(sw.OSC_SWINGS_MIN),
        dev_max2=DEV_MAX2,
        nw=float(TRACK_BLOCKS * tblock),
        nphase=0 if b.fplan is None else len(b.fplan.phases),
        ring_len=keep["ring"].shape[0],
        nsub=study_faults.SUBSTEPS,
        sub_h=b.dt / study_faults.SUBSTEPS,
        **{k: (_ptr(v, ctypes.c_int64) if k in ints else _ptr(v)) for k, v in keep.items() if v is not None},
    )
    ref = ctypes.byref(batch)
    buf = None
    for k0 in range(0, steps, BLOCK):
        m = min(BLOCK, steps - k0)
        z = None
        if b.noisy:  # each run's next block of standard normals, as _fly_numpy draws it
            buf = np.empty((n, m * CHANNELS))
            for i, g in enumerate(b.gens):
                g.standard_normal(out=buf[i])
            z = _ptr(buf)
        lib.study_steps(ref, k0, m, z)
    names = ("ise_ref", "ise_crm", "energy", "tv", "max_abs_u", "max_abs_roll", "sat")
    acc = {name: keep["acc"][j].copy() for j, name in enumerate(names)}
    series = {name: keep["rec"][j] for j, name in enumerate(_SERIES)} if b.record else None
    return acc, keep["peaks"], keep["track"] != 0.0, series


def _fault_arrays(b) -> dict:
    """kernel.c's fault fields (``faults.Phase`` column by column, the matrix sets (nmat * 36, n) and
    (nmat * 24, n), the delay line and its head); none of them read without phases."""
    n, fp = b.n, b.fplan
    phases = fp.phases if fp is not None else ()
    col = {
        f"ph_{k}": np.ascontiguousarray([int(getattr(p, k)) for p in phases] or [0], dtype=np.int64)
        for k in ("start", "mat", "jump", "off", "delay", "reset", "fine")
    }
    col["ph_at"] = np.ascontiguousarray([p.at for p in phases] or [0.0], dtype=float)
    col["ph_rate"] = np.ascontiguousarray([p.rate for p in phases] or [0.0], dtype=float)
    for name, q in (("mphi1", 0), ("mgam1", 1), ("mphic1", 2)):
        sets = [_rows([v for row in f[q] for v in row], n) for f in b.MATS1]
        col[name] = np.concatenate(sets) if sets else np.zeros((1, n))
    mphi = np.concatenate([_rows([v for row in p for v in row], n) for p, _g in b.MATS])
    mgam = np.concatenate([_rows([v for row in g for v in row], n) for _p, g in b.MATS])
    ring = np.zeros((max(fp.max_delay if fp is not None else 0, 1), n))
    return {**col, "mphi": mphi, "mgam": mgam, "ring": ring, "ring_pos": np.zeros(n)}


def _fly_numpy(b) -> tuple[dict, np.ndarray, np.ndarray, dict | None]:
    """The steps in numpy, every run at once (the reference the C kernel equals): the sums of the metrics, the peak
    |roll| per window, the tracking flags (oscillating, not following: (2, n)) and, with ``record``, the series."""
    n, steps, rate, dt, umax, law, gens = b.n, b.steps, b.rate, b.dt, b.umax, b.law, b.gens
    noisy, dist = b.noisy, b.dist
    turb, noise, bias, thr, delay, crosswind = b.turb, b.noise, b.bias, b.thr, b.delay, b.crosswind
    gust_k, g_first, um_all, PHI, GAM, dry, xt = b.gust_k, b.g_first, b.um_all, b.PHI, b.GAM, b.dry, b.xt
    x = [np.zeros(n) for _ in range(6)]
    hist = np.zeros((int(delay.max()) + 1, n))
    cols = np.arange(n)
    y_prev = np.zeros(n)
    u_fly = np.zeros(n)
    acc = {k: np.zeros(n) for k in ("ise_ref", "ise_crm", "energy", "tv", "max_abs_u", "max_abs_roll", "sat")}
    window = int(round(WINDOW_S * rate))
    peaks = np.zeros((n, max(steps // window, 1)))  # peak |roll| (truth) per 30 s window
    wmax = np.zeros(n)
    # tracking (autopilot.envelope.window_flags) over windows of TRACK_BLOCKS blocks: the open block's sums of
    # y_r^2, phi y_r, (phi - y_r)^2 and the stop hits (phi the truth, y_r the law's y_m,ol), the last blocks'
    tblock = int(round(TRACK_BLOCK_S * rate))
    blk = [np.zeros(n) for _ in range(5)]
    ring = np.zeros((TRACK_BLOCKS, 5, n))
    swing = None  # the swing counter of phi - y_r (autopilot.swings), from the first step
    track = np.zeros((2, n), dtype=bool)  # oscillating, not following (in any window)
    hit_armed = np.ones(n, dtype=bool)
    nw = float(TRACK_BLOCKS * tblock)
    u_prev = None
    rec = {} if b.record else None
    block = None
    phases = b.fplan.phases if b.fplan is not None else ()
    nxt, off, dline, pos = 0, False, None, 0  # the next phase; the servo driven with 0; the delay line and its head
    rate, fine = 0.0, None  # a rate limit (rad/s, 0: none) and its physics-step matrices (faults.SUBSTEPS)
    with np.errstate(all="ignore"):
        for k in range(steps):
            while nxt < len(phases) and phases[nxt].start == k:  # a fault starts or ends (faults.Phase)
                ph = phases[nxt]
                PHI, GAM = b.MATS[ph.mat]
                if ph.jump != study_faults.JUMP_NONE:  # sitl.damage.jammed: the surface jams, delta_dot = 0
                    if ph.jump == study_faults.JUMP_AT:
                        x[4] = np.full(n, ph.at)
                    x[5] = np.zeros(n)
                off = ph.off
                rate, fine = ph.rate, (b.MATS1[ph.fine] if ph.rate else None)
                if rate:  # Aircraft.set_effect: delta_dot within the limit
                    x[5] = np.minimum(rate, np.maximum(-rate, x[5]))
                if ph.reset:  # a new delay line, full of the command held (sitl.damage.Actuator)
                    dline = np.tile(u_fly, (ph.delay, 1)) if ph.delay else None
                    pos = 0
                elif not ph.delay:
                    dline = None
                nxt += 1
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
            sat = saturated(u, umax)
            acc["sat"] += sat  # the command at its limit (autopilot.envelope)
            hit, hit_armed = stop_hit(sat, u, umax, hit_armed)
            blk[3] = blk[3] + hit
            ref = law.ym_ol
            dv = phi_true - ref
            blk[0] = blk[0] + ref * ref
            blk[1] = blk[1] + phi_true * ref
            blk[2] = blk[2] + dv * dv
            swing = sw.swing_start(dv) if swing is None else swing
            blk[4] = blk[4] + sw.swing_step(swing, dv, float(k))
            if (k + 1) % tblock == 0:
                _close_block(blk, ring, track, (k + 1) // tblock, nw)
                blk = [np.zeros(n) for _ in range(5)]
            if rec is not None:
                _record(rec, k * dt, um, y, law, u, x)
            u_s = u_fly  # what drives the servo: u_fly, through the delay line, 0 when off
            if dline is not None:
                u_s = dline[pos].copy()
                dline[pos] = u_fly
                pos = (pos + 1) % dline.shape[0]
            if off:
                u_s = np.zeros(n)
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
                if fine is not None:
                    x = study_faults.rate_limited(x, u_s, dd, fine, rate, dt)
                else:
                    x = [
                        PHI[r][0] * x[0]
                        + PHI[r][1] * x[1]
                        + PHI[r][2] * x[2]
                        + PHI[r][3] * x[3]
                        + PHI[r][4] * x[4]
                        + PHI[r][5] * x[5]
                        + GAM[r][0] * u_s
                        + (GAM[r][1] * dd[0] + GAM[r][2] * dd[1] + GAM[r][3] * dd[2])
                        for r in range(6)
                    ]
            elif fine is not None:
                x = study_faults.rate_limited(x, u_s, None, fine, rate, dt)
            else:
                x = [
                    PHI[r][0] * x[0]
                    + PHI[r][1] * x[1]
                    + PHI[r][2] * x[2]
                    + PHI[r][3] * x[3]
                    + PHI[r][4] * x[4]
                    + PHI[r][5] * x[5]
                    + GAM[r][0] * u_s
                    for r in range(6)
                ]
    series = {key: np.array(v) for key, v in rec.items()} if rec is not None else None
    return acc, peaks, track, series


def _close_block(blk: list, ring: np.ndarray, track: np.ndarray, closed: int, nw: float) -> None:
    """Block ``closed`` (counted from 1) ends: its sums go to the ring (slot (closed - 1) % TRACK_BLOCKS) and, from
    the TRACK_BLOCKS-th block on, the window of the last TRACK_BLOCKS blocks is judged (``window_flags``; the
    ring summed slot by slot from slot 0, as kernel.c sums it)."""
    slot = (closed - 1) % TRACK_BLOCKS
    for q in range(5):
        ring[slot, q] = blk[q]
    if closed < TRACK_BLOCKS:
        return
    tot = [ring[0, q].copy() for q in range(5)]
    for j in range(1, TRACK_BLOCKS):
        for q in range(5):
            tot[q] = tot[q] + ring[j, q]
    osc, lag = window_flags(nw, tot[0], tot[1], tot[2], tot[3], tot[4])
    track[0] |= osc
    track[1] |= lag


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


def replay(
    controller: str, condition: str, seed: int, run: int, duration_s: float = 30.0, record: bool = True, faults=()
):
    """Run ``run`` of the study alone (a batch of one: bit for bit the study's numbers), with ``faults``
    (``sitl.damage.Fault``) if given."""
    return simulate(Task(controller, ((condition, run),), seed, duration_s, record, tuple(faults)))
