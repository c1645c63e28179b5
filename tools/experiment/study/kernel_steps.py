"""A batch's steps in C (``kernel.c``, loaded by ``native``): ``fly_kernel`` fills the kernel's ``Batch`` with the
law's coefficients and state, the plants, the disturbances and the faults' phases, and draws each run's noise block
by block as the numpy loop (``numpy_steps.fly_numpy``) draws it: the same numbers, bit for bit."""

from __future__ import annotations

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
)
from tools.experiment.study import faults as study_faults
from tools.experiment.study import native
from tools.experiment.study.sampling import BLOCK, CHANNELS, WINDOW_S

COEF_ROWS = 21  # kernel.c's law coefficients per aircraft (CL-SAC's C_*, B_*: autopilot.batch.clsac_kernel)
SERIES = ("t", "um", "phi", "ym", "ym_ol", "ya", "y_pfc", "e", "u", "kpe", "kie", "ke", "kpx", "kix", "kx", "kpu")
SERIES += ("kiu", "ku", "v", "p", "r", "delta_r")  # numpy_steps._record's keys, in its order


def _rows(values, n: int) -> np.ndarray:
    """(k, n) float64, C order: each entry (a Python float the same for every run, or an (n,) array) per run."""
    out = np.empty((len(values), n))
    for j, v in enumerate(values):
        out[j] = v  # a float broadcast: scalar * array and array * array are the same IEEE operation
    return out


def _ptr(a: np.ndarray, ctype=None):
    import ctypes

    return a.ctypes.data_as(ctypes.POINTER(ctype or ctypes.c_double))


def fly_kernel(lib, b) -> tuple[dict, np.ndarray, np.ndarray, dict | None]:
    """The steps in C (``kernel.c``, ``native``): ``fly_numpy``'s numbers, bit for bit, without its per-step
    overhead.  The noise is drawn here, block by block from each run's generator, exactly as ``fly_numpy``
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
        "rec": np.zeros((len(SERIES), steps, n)) if b.record else None,
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
        if b.noisy:  # each run's next block of standard normals, as fly_numpy draws it
            buf = np.empty((n, m * CHANNELS))
            for i, g in enumerate(b.gens):
                g.standard_normal(out=buf[i])
            z = _ptr(buf)
        lib.study_steps(ref, k0, m, z)
    names = ("ise_ref", "ise_crm", "energy", "tv", "max_abs_u", "max_abs_roll", "sat")
    acc = {name: keep["acc"][j].copy() for j, name in enumerate(names)}
    series = {name: keep["rec"][j] for j, name in enumerate(SERIES)} if b.record else None
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
