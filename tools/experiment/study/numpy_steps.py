"""A batch's steps in numpy, every run at once (``fly_numpy``): the sensor and the link, the law, the metrics, the
tracking windows, the faults' phases and the plant, in the order ``kernel.c`` follows: the reference the C kernel
equals bit for bit."""

from __future__ import annotations

import numpy as np

from autopilot import swings as sw  # the oscillation rule's swing counter
from autopilot.envelope import TRACK_BLOCK_S, TRACK_BLOCKS, saturated, stop_hit, window_flags
from tools.experiment.study import faults as study_faults
from tools.experiment.study.faults import zoh_step
from tools.experiment.study.sampling import BLOCK, CHANNELS, WINDOW_S


def fly_numpy(b) -> tuple[dict, np.ndarray, np.ndarray, dict | None]:
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
                    x = zoh_step(PHI, GAM, x, u_s, dd)
            elif fine is not None:
                x = study_faults.rate_limited(x, u_s, None, fine, rate, dt)
            else:
                x = zoh_step(PHI, GAM, x, u_s, None)
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
