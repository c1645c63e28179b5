/* The study's control steps in C (tools/experiment/study/native.py builds and loads this file, kernel_steps.py fills its
 * Batch; tools/experiment/study/numpy_steps.py is the reference it must equal bit for bit).
 *
 * One call flies steps k0 .. k0 + m - 1 of every run of a batch: the sensor (delay, bias, noise), the link
 * (ATTITUDE and SERVO_OUTPUT_RAW lost with probability p), the law (CL-SAC: ClSac._step_siso, paper eqs. (6),
 * (18)-(21), as autopilot.batch.BatchClSac; or the fixed-gain baseline: Baseline.step, as BatchBaseline), the
 * metrics (MetricsAccumulator's sums in its order), the tracking windows (autopilot.envelope.window_flags and the
 * swing counter of autopilot.swings), the
 * disturbance (Dryden filter, 1-cosine gust, crosswind)
 * and the plant x[k+1] = Phi x[k] + Gamma [u, v_g, p_g, r_g]^T (the exact ZOH of (A_p, [B_p, E])).
 *
 * Why it is the same numbers as the numpy loop: every operation below is the numpy loop's IEEE-754 add,
 * multiply, compare or select, in the same order (a + b + c is (a + b) + c as in Python), on doubles, built with
 * -ffp-contract=off and without -ffast-math (no fused multiply-add, no reassociation).  np.maximum, np.minimum
 * and np.clip are written with numpy's NaN rule (a NaN operand gives NaN), so a diverged run diverges the same
 * way.  The runs of a batch are independent, so the loop is over runs, then steps.  The batch-wide switches
 * (noisy, dist, turb_any, gust_any) are the numpy loop's, so even a zero's sign is the same. */

#include <math.h>
#include <stddef.h>
#include <stdint.h>

typedef struct {
    /* sizes and switches of the batch */
    int64_t n, steps, hist_len, window, npeaks, gust_width;
    int64_t kind;     /* 0: CL-SAC, 1: baseline */
    int64_t noisy, dist, turb_any, gust_any;
    int64_t aw, freeze, has_kmax;
    double umax, sat_lim, dz, kmax, dt;
    /* the law's coefficients, (n,) each: CL-SAC (15 + 6 leaks) or baseline (6, the first ones) */
    const double *coef; /* (21, n) */
    /* the law's states, (n,) each: CL-SAC xm, xm_ol, xd, ki_e, ki_x, ki_u; baseline xm_ol, xi, e_prev */
    double *law;        /* (6, n) */
    /* the plant */
    const double *phi;  /* (36, n): Phi[r][j] */
    const double *gam;  /* (24, n): Gamma[r][j] */
    double *x;          /* (6, n) */
    /* the disturbance */
    const double *dry;  /* c (3x4), ad (4x4), ld (4x4): 44 */
    double *xt;         /* (4, n) */
    const double *turb, *bias, *noise, *thr, *crosswind; /* (n,) */
    const int64_t *delay, *g_first;                       /* (n,) */
    const double *gust_k;                                 /* (n, gust_width) */
    const double *um_all;                                 /* (steps,) */
    /* the sensor and the link */
    double *hist;       /* (hist_len, n) */
    double *y_prev, *u_fly, *u_prev; /* (n,) */
    /* the metrics: ise_ref, ise_crm, energy, tv, max_abs_u, max_abs_roll, sat */
    double *acc;        /* (7, n) */
    double *wmax;       /* (n,) */
    double *peaks;      /* (n, npeaks) */
    /* the series (record), or NULL: (22, steps, n) in numpy_steps._record's order */
    double *rec;
    /* tracking (autopilot.envelope.window_flags): blocks of tblock steps, windows of tblocks blocks; the open
     * block's sums of y_r^2, phi y_r, (phi - y_r)^2, stop hits and regular swings (5, n), the ring of the last
     * blocks' (tblocks * 5, n: slot * 5 + sum), the flags oscillating / not following in any window (2, n: 0.0 or
     * 1.0), whether a stop hit counts (autopilot.envelope.stop_hit; n: 0.0 or 1.0); the swing counter
     * (autopilot.swings.swing_step: its constants, its state (7, n) in swing_start's order) */
    int64_t tblock, tblocks;
    double dev_ratio2, dev_floor2, ref_floor2, follow_min, hits_min, rearm_lim, nw;
    double *tblk, *tring, *track, *hit_armed;
    double swing_h, swing_tol, swings_min, dev_max2;
    double *swing;
    /* faults (tools/experiment/study/faults.py): nphase phases, each from step ph_start on with the matrix set
     * ph_mat (mphi (nmat * 36, n), mgam (nmat * 24, n); set 0 the plant as built), the surface's jump (0 none,
     * 1 where it is, 2 at ph_at; delta_dot = 0), the servo driven with 0 (ph_off), a delay line of ph_delay steps
     * (ph_reset: a new one, full of the command held); ring (ring_len, n) and its head (n,) per run.  nphase 0:
     * none of these is read. */
    int64_t nphase, ring_len;
    const int64_t *ph_start, *ph_mat, *ph_jump, *ph_off, *ph_delay, *ph_reset;
    const double *ph_at, *mphi, *mgam;
    double *ring, *ring_pos;
    /* a rate limit (faults.py, faults.rate_limited): ph_rate rad/s (0: none), flown in nsub physics steps of
     * sub_h with the physics-step set ph_fine: mphi1 (nfine * 36, n), mgam1 (nfine * 24, n), mphic1 (coasting) */
    int64_t nsub;
    double sub_h;
    const int64_t *ph_fine;
    const double *ph_rate, *mphi1, *mgam1, *mphic1;
} Batch;

/* numpy's maximum / minimum: a NaN operand propagates */
static inline double np_max(double a, double b) { return (a >= b || isnan(a)) ? a : b; }
static inline double np_min(double a, double b) { return (a <= b || isnan(a)) ? a : b; }
/* numpy's clip: min(max(x, lo), hi), a NaN x stays NaN */
static inline double np_clip(double x, double lo, double hi) {
    if (isnan(x)) return x;
    double t = x > lo ? x : lo;
    return t < hi ? t : hi;
}

enum { C_PHI_M, C_G_MU, C_G_MY, C_PHI_OL, C_G_OL, C_CM, C_PHI_D, C_G_D, C_CD, C_GPE, C_GIE, C_GPX, C_GIX, C_GPU,
       C_GIU, C_DECAY, C_GAIN_IE, C_DECAY_X, C_GAIN_IX, C_DECAY_U, C_GAIN_IU };
enum { B_PHI_OL, B_G_OL, B_CM, B_KP, B_KI_T, B_KD_T };
enum { R_T, R_UM, R_PHI, R_YM, R_YM_OL, R_YA, R_Y_PFC, R_E, R_U, R_KPE, R_KIE, R_KE, R_KPX, R_KIX, R_KX, R_KPU,
       R_KIU, R_KU, R_V, R_P, R_R, R_DELTA_R, R_COUNT };

/* One control step under a rate limit (faults.rate_limited; sitl.aircraft.Aircraft._advance_servo_fault):
 * nsub physics steps, each the free step, its move against rate * h; beyond it the coasting step at +-rate, else
 * the free step with delta_dot clipped; the held disturbance dd (or none) added on each.  x in, xn out. */
static void rate_limited(const double *x0, double *xn, double u_s, const double *dd, const double *p1,
                         const double *g1, const double *pc, double rate, double sub_h, int64_t nsub) {
    double x[6], xf[6], xc[6];
    for (int r = 0; r < 6; r++) x[r] = x0[r];
    const double move_max = rate * sub_h; /* damage.Actuator's max move */
    for (int64_t s = 0; s < nsub; s++) {
        for (int r = 0; r < 6; r++)
            xf[r] = p1[r * 6 + 0] * x[0] + p1[r * 6 + 1] * x[1] + p1[r * 6 + 2] * x[2] + p1[r * 6 + 3] * x[3] +
                    p1[r * 6 + 4] * x[4] + p1[r * 6 + 5] * x[5] + g1[r * 4 + 0] * u_s;
        const double move = xf[4] - x[4];
        const int up = move > move_max, down = move < -move_max;
        const double at = up ? rate : -rate;
        for (int r = 0; r < 6; r++)
            xc[r] = pc[r * 6 + 0] * x[0] + pc[r * 6 + 1] * x[1] + pc[r * 6 + 2] * x[2] + pc[r * 6 + 3] * x[3] +
                    pc[r * 6 + 4] * x[4] + pc[r * 6 + 5] * at;
        xf[5] = np_min(rate, np_max(-rate, xf[5]));
        const int coast = up | down;
        for (int r = 0; r < 6; r++) x[r] = coast ? xc[r] : xf[r];
        if (dd)
            for (int r = 0; r < 6; r++)
                x[r] = x[r] + (g1[r * 4 + 1] * dd[0] + g1[r * 4 + 2] * dd[1] + g1[r * 4 + 3] * dd[2]);
    }
    for (int r = 0; r < 6; r++) xn[r] = x[r];
}

int study_series_count(void) { return R_COUNT; }
int64_t study_batch_size(void) { return (int64_t)sizeof(Batch); }

/* Steps k0 .. k0 + m - 1 of every run; z: this block's standard normals, (n, m * 7) as each run's generator
 * drew them (step s, channel ch at s * 7 + ch: 4 Dryden, roll noise, ATTITUDE loss, SERVO_OUTPUT_RAW loss), or
 * NULL when the batch is not noisy. */
void study_steps(const Batch *b, int64_t k0, int64_t m, const double *z_all) {
    const int64_t n = b->n;
    const double *C = b->dry, *AD = b->dry + 12, *LD = b->dry + 28;
    for (int64_t i = 0; i < n; i++) {
        double co[21], ph[36], ga[24]; /* this run's coefficients, read once */
        for (int j = 0; j < 21; j++) co[j] = b->coef[j * n + i];
        for (int j = 0; j < 36; j++) ph[j] = b->phi[j * n + i];
        for (int j = 0; j < 24; j++) ga[j] = b->gam[j * n + i];
        /* faults: the phase in force before step k0, its matrices, its servo path */
        int64_t cur = 0, fd = 0, pos = 0;
        int off = 0;
        double rate = 0.0, p1[36], g1[24], pc[36];
#define LOAD_FINE(f)                                                                   \
    do {                                                                              \
        const int64_t fm = (f);                                                       \
        for (int j = 0; j < 36; j++) p1[j] = b->mphi1[(fm * 36 + j) * n + i];         \
        for (int j = 0; j < 24; j++) g1[j] = b->mgam1[(fm * 24 + j) * n + i];         \
        for (int j = 0; j < 36; j++) pc[j] = b->mphic1[(fm * 36 + j) * n + i];        \
    } while (0)
        if (b->nphase) {
            while (cur < b->nphase && b->ph_start[cur] < k0) cur++;
            if (cur > 0) {
                const int64_t mt = b->ph_mat[cur - 1];
                for (int j = 0; j < 36; j++) ph[j] = b->mphi[(mt * 36 + j) * n + i];
                for (int j = 0; j < 24; j++) ga[j] = b->mgam[(mt * 24 + j) * n + i];
                off = b->ph_off[cur - 1] != 0, fd = b->ph_delay[cur - 1];
                rate = b->ph_rate[cur - 1];
                if (rate != 0.0) LOAD_FINE(b->ph_fine[cur - 1]);
            }
            pos = (int64_t)b->ring_pos[i];
        }
#define CO(j) co[j]
#define PHI(r, j) ph[(r) * 6 + (j)]
#define GAM(r, j) ga[(r) * 4 + (j)]
        double x[6], xt[4];
        for (int r = 0; r < 6; r++) x[r] = b->x[r * n + i];
        for (int r = 0; r < 4; r++) xt[r] = b->xt[r * n + i];
        double s0 = b->law[0 * n + i], s1 = b->law[1 * n + i], s2 = b->law[2 * n + i];
        double s3 = b->law[3 * n + i], s4 = b->law[4 * n + i], s5 = b->law[5 * n + i];
        double y_prev = b->y_prev[i], u_fly = b->u_fly[i], u_prev = b->u_prev[i], wmax = b->wmax[i];
        double a_ise_ref = b->acc[0 * n + i], a_ise_crm = b->acc[1 * n + i], a_energy = b->acc[2 * n + i];
        double a_tv = b->acc[3 * n + i], a_max_u = b->acc[4 * n + i], a_max_roll = b->acc[5 * n + i];
        double a_sat = b->acc[6 * n + i];
        double t_rr = b->tblk[0 * n + i], t_pr = b->tblk[1 * n + i], t_dd = b->tblk[2 * n + i];
        double t_hits = b->tblk[3 * n + i], t_sw = b->tblk[4 * n + i];
        double w_up = b->swing[0 * n + i], w_ext = b->swing[1 * n + i], w_kext = b->swing[2 * n + i];
        double w_last = b->swing[3 * n + i], w_klast = b->swing[4 * n + i], w_size = b->swing[5 * n + i];
        double w_dur = b->swing[6 * n + i];
        double f_osc = b->track[0 * n + i], f_lag = b->track[1 * n + i];
        int armed = b->hit_armed[i] != 0.0;
        const double turb = b->turb[i], bias = b->bias[i], noise = b->noise[i], thr = b->thr[i];
        const double crosswind = b->crosswind[i];
        const int64_t delay = b->delay[i], g_first = b->g_first[i];
        for (int64_t s = 0; s < m; s++) {
            const int64_t k = k0 + s;
            const double *z = z_all ? z_all + (i * m + s) * 7 : NULL;
            while (cur < b->nphase && b->ph_start[cur] == k) { /* a fault starts or ends (faults.Phase) */
                const int64_t mt = b->ph_mat[cur];
                for (int j = 0; j < 36; j++) ph[j] = b->mphi[(mt * 36 + j) * n + i];
                for (int j = 0; j < 24; j++) ga[j] = b->mgam[(mt * 24 + j) * n + i];
                if (b->ph_jump[cur] != 0) { /* sitl.damage.jammed: the surface jams, delta_dot = 0 */
                    if (b->ph_jump[cur] == 2) x[4] = b->ph_at[cur];
                    x[5] = 0.0;
                }
                off = b->ph_off[cur] != 0;
                rate = b->ph_rate[cur];
                if (rate != 0.0) { /* Aircraft.set_effect: delta_dot within the limit */
                    LOAD_FINE(b->ph_fine[cur]);
                    x[5] = np_min(rate, np_max(-rate, x[5]));
                }
                if (b->ph_reset[cur]) { /* a new delay line, full of the command held (sitl.damage.Actuator) */
                    fd = b->ph_delay[cur];
                    for (int64_t q = 0; q < fd; q++) b->ring[q * n + i] = u_fly;
                    pos = 0;
                } else if (!b->ph_delay[cur]) {
                    fd = 0;
                }
                cur++;
            }
            const double phi_true = x[3];
            /* sensor: delay, bias, noise (sitl.sensors semantics: the first sample repeats for k < D) */
            b->hist[(k % b->hist_len) * n + i] = phi_true;
            double y;
            if (b->hist_len > 1) {
                int64_t j = k - delay;
                y = b->hist[((j > 0 ? j : 0) % b->hist_len) * n + i];
            } else {
                y = phi_true;
            }
            y = y + bias;
            if (b->noisy) {
                y = y + noise * z[4];
                if (z[5] < thr && k) y = y_prev; /* ATTITUDE lost: the last roll received */
            }
            y_prev = y;
            const double um = b->um_all[k];
            /* the law */
            double u, u_raw, e, ym_ol, ym, ya, y_pfc = 0.0;
            double kpe = 0.0, kie = 0.0, ke = 0.0, kpx = 0.0, kix = 0.0, kx = 0.0, kpu = 0.0, kiu = 0.0, ku = 0.0;
            if (b->kind == 0) { /* CL-SAC, BatchClSac.__call__; states s0..s5 = xm, xm_ol, xd, ki_e, ki_x, ki_u */
                const double xm = s0;
                y_pfc = CO(C_CD) * s2;           /* y_d = C_d x_d */
                ya = y + y_pfc;                  /* y_a = y_p + D(s) u_p */
                ym = CO(C_CM) * xm;              /* y_m = C_m x_m */
                e = ym - ya;                     /* e_my = y_m - y_a  (paper eq. (20)) */
                kpe = e * e * CO(C_GPE);
                kpx = e * xm * CO(C_GPX);
                kpu = e * um * CO(C_GPU);
                kie = s3, kix = s4, kiu = s5;
                ke = kpe + kie;
                kx = kpx + kix;
                ku = kpu + kiu;
                u_raw = ke * e + kx * xm + ku * um; /* paper eqs. (6), (21) */
                u = np_clip(u_raw, -b->umax, b->umax);
                const int sat = u != u_raw;
                double die = CO(C_GAIN_IE) * (e * e * CO(C_GIE));
                double dix = CO(C_GAIN_IX) * (e * xm * CO(C_GIX));
                double diu = CO(C_GAIN_IU) * (e * um * CO(C_GIU));
                int skip = 0, any_skip = 0;
                if (b->dz > 0.0) skip = fabs(e) <= b->dz, any_skip = 1; /* dead-zone on e */
                if (b->freeze) skip = skip | sat, any_skip = 1;
                if (any_skip && skip) die = 0.0, dix = 0.0, diu = 0.0;
                if (b->aw) { /* conditional integration, per channel */
                    if (sat && die * e * u_raw > 0) die = 0.0;
                    if (sat && dix * xm * u_raw > 0) dix = 0.0;
                    if (sat && diu * um * u_raw > 0) diu = 0.0;
                }
                double ki_e = CO(C_DECAY) * kie + die;
                double ki_x = CO(C_DECAY_X) * kix + dix;
                double ki_u = CO(C_DECAY_U) * kiu + diu;
                if (b->has_kmax) { /* projection onto |K_I| <= ki_max */
                    const double km = b->kmax;
                    ki_e = np_min(np_max(ki_e, -km), km);
                    ki_x = np_min(np_max(ki_x, -km), km);
                    ki_u = np_min(np_max(ki_u, -km), km);
                }
                s0 = CO(C_PHI_M) * xm + (CO(C_G_MU) * um + CO(C_G_MY) * ya); /* paper eq. (18), exact ZOH */
                ym_ol = CO(C_CM) * s1;
                s1 = CO(C_PHI_OL) * s1 + CO(C_G_OL) * um;
                s2 = CO(C_PHI_D) * s2 + CO(C_G_D) * u;
                s3 = ki_e, s4 = ki_x, s5 = ki_u;
            } else { /* the baseline, BatchBaseline.__call__; states s0..s2 = xm_ol, xi, e_prev */
                ym_ol = CO(B_CM) * s0;
                e = ym_ol - y;
                u_raw = CO(B_KP) * e + s1 + CO(B_KD_T) * (e - s2);
                u = np_clip(u_raw, -b->umax, b->umax);
                const int sat = u != u_raw;
                const double di = CO(B_KI_T) * e;
                const int keep = b->aw ? (sat && di * u_raw > 0) : 0;
                s1 = keep ? s1 : s1 + di;
                s0 = CO(B_PHI_OL) * s0 + CO(B_G_OL) * um;
                s2 = e;
                ym = ym_ol, ya = y;
            }
            if (b->noisy) {
                u_fly = k ? (z[6] < thr ? u_fly : u) : u; /* SERVO_OUTPUT_RAW lost: the servo keeps the last */
            } else {
                u_fly = u;
            }
            /* metrics of what the law commanded (autopilot.metrics.MetricsAccumulator, same operation order) */
            const double d = y - ym_ol;
            a_ise_ref += d * d;
            a_ise_crm += e * e;
            a_energy += u * u;
            if (k) a_tv += fabs(u - u_prev);
            u_prev = u;
            a_max_u = np_max(a_max_u, fabs(u));
            a_max_roll = np_max(a_max_roll, fabs(phi_true));
            wmax = np_max(wmax, fabs(phi_true));
            if ((k + 1) % b->window == 0 && (k + 1) / b->window <= b->npeaks) {
                b->peaks[i * b->npeaks + (k + 1) / b->window - 1] = wmax;
                wmax = 0.0;
            }
            const int sat_k = !(fabs(u) < b->sat_lim); /* autopilot.envelope.saturated */
            a_sat += sat_k ? 1.0 : 0.0;
            { /* tracking: numpy_steps._close_block, autopilot.envelope.stop_hit and window_flags */
                const int hit = sat_k && armed;
                armed = !hit && (armed || fabs(u) <= b->rearm_lim);
                t_hits = t_hits + (hit ? 1.0 : 0.0);
                const double dv = phi_true - ym_ol;
                t_rr = t_rr + ym_ol * ym_ol;
                t_pr = t_pr + phi_true * ym_ol;
                t_dd = t_dd + dv * dv;
                { /* autopilot.swings.swing_step on dv at step k (swing_start at step 0) */
                    if (k == 0) w_up = 1.0, w_ext = dv, w_kext = 0.0, w_last = dv, w_klast = 0.0, w_size = 0.0,
                                w_dur = 0.0;
                    const int upb = w_up != 0.0;
                    const double kd = (double)k;
                    const int grow = upb ? (dv > w_ext) : (dv < w_ext);
                    const int back = upb ? (dv <= w_ext - b->swing_h) : (dv >= w_ext + b->swing_h);
                    const double ext = grow ? dv : w_ext, kext = grow ? kd : w_kext;
                    const double sz = fabs(ext - w_last), du = kext - w_klast;
                    int reg = back && (w_size > 0.0);
                    reg = reg && (fabs(sz - w_size) <= b->swing_tol * np_max(sz, w_size));
                    reg = reg && (fabs(du - w_dur) <= b->swing_tol * np_max(du, w_dur));
                    if (back) {
                        w_size = sz, w_dur = du, w_last = ext, w_klast = kext, w_up = 1.0 - w_up;
                        w_ext = dv, w_kext = kd;
                    } else {
                        w_ext = ext, w_kext = kext;
                    }
                    t_sw = t_sw + (reg ? 1.0 : 0.0);
                }
                if ((k + 1) % b->tblock == 0) {
                    const int64_t closed = (k + 1) / b->tblock, slot = (closed - 1) % b->tblocks;
                    double *rg = b->tring;
                    rg[(slot * 5 + 0) * n + i] = t_rr, rg[(slot * 5 + 1) * n + i] = t_pr;
                    rg[(slot * 5 + 2) * n + i] = t_dd, rg[(slot * 5 + 3) * n + i] = t_hits;
                    rg[(slot * 5 + 4) * n + i] = t_sw;
                    if (closed >= b->tblocks) {
                        double s_rr = rg[0 * n + i], s_pr = rg[1 * n + i], s_dd = rg[2 * n + i];
                        double s_hits = rg[3 * n + i], s_sw = rg[4 * n + i];
                        for (int64_t j = 1; j < b->tblocks; j++) {
                            s_rr = s_rr + rg[(j * 5 + 0) * n + i], s_pr = s_pr + rg[(j * 5 + 1) * n + i];
                            s_dd = s_dd + rg[(j * 5 + 2) * n + i], s_hits = s_hits + rg[(j * 5 + 3) * n + i];
                            s_sw = s_sw + rg[(j * 5 + 4) * n + i];
                        }
                        const int bang = (s_dd >= b->dev_ratio2 * s_rr) & (s_dd >= b->dev_floor2 * b->nw) &
                                         (s_hits >= b->hits_min);
                        const int osc = (s_sw >= b->swings_min) | bang;
                        const int lag = (s_rr >= b->ref_floor2 * b->nw) &
                                        ((s_pr < b->follow_min * s_rr) | (s_dd >= b->dev_max2 * s_rr));
                        if (osc) f_osc = 1.0;
                        if (lag) f_lag = 1.0;
                    }
                    t_rr = 0.0, t_pr = 0.0, t_dd = 0.0, t_hits = 0.0, t_sw = 0.0;
                }
            }
            if (b->rec) {
                double row[R_COUNT] = {(double)k * b->dt, um, y, ym, ym_ol, ya, y_pfc, e, u, kpe, kie, ke, kpx,
                                       kix, kx, kpu, kiu, ku, x[0], x[1], x[2], x[4]};
                for (int q = 0; q < R_COUNT; q++) b->rec[(q * b->steps + k) * n + i] = row[q];
            }
            /* what drives the servo: u_fly, through the delay line, 0 when off */
            double u_s = u_fly;
            if (fd) {
                u_s = b->ring[pos * n + i];
                b->ring[pos * n + i] = u_fly;
                pos = (pos + 1) % fd;
            }
            if (off) u_s = 0.0;
            /* disturbance d = [v_g, p_g, r_g], held over the period, and the plant */
            double xn[6];
            if (b->dist) {
                double dd[3] = {0.0, 0.0, 0.0};
                if (b->turb_any) {
                    for (int r = 0; r < 3; r++)
                        dd[r] = turb * (C[r * 4 + 0] * xt[0] + C[r * 4 + 1] * xt[1] + C[r * 4 + 2] * xt[2] +
                                        C[r * 4 + 3] * xt[3]);
                    if (b->noisy) {
                        double xtn[4];
                        for (int r = 0; r < 4; r++)
                            xtn[r] = AD[r * 4 + 0] * xt[0] + AD[r * 4 + 1] * xt[1] + AD[r * 4 + 2] * xt[2] +
                                     AD[r * 4 + 3] * xt[3] +
                                     (LD[r * 4 + 0] * z[0] + LD[r * 4 + 1] * z[1] + LD[r * 4 + 2] * z[2] +
                                      LD[r * 4 + 3] * z[3]);
                        for (int r = 0; r < 4; r++) xt[r] = xtn[r];
                    }
                }
                if (b->gust_any) {
                    const int64_t j = k - g_first;
                    dd[0] = dd[0] + ((j >= 0 && j < b->gust_width) ? b->gust_k[i * b->gust_width + j] : 0.0);
                }
                dd[0] = dd[0] + crosswind;
                if (rate != 0.0) {
                    rate_limited(x, xn, u_s, dd, p1, g1, pc, rate, b->sub_h, b->nsub);
                } else {
                    for (int r = 0; r < 6; r++)
                        xn[r] = PHI(r, 0) * x[0] + PHI(r, 1) * x[1] + PHI(r, 2) * x[2] + PHI(r, 3) * x[3] +
                                PHI(r, 4) * x[4] + PHI(r, 5) * x[5] + GAM(r, 0) * u_s +
                                (GAM(r, 1) * dd[0] + GAM(r, 2) * dd[1] + GAM(r, 3) * dd[2]);
                }
            } else if (rate != 0.0) {
                rate_limited(x, xn, u_s, NULL, p1, g1, pc, rate, b->sub_h, b->nsub);
            } else {
                for (int r = 0; r < 6; r++)
                    xn[r] = PHI(r, 0) * x[0] + PHI(r, 1) * x[1] + PHI(r, 2) * x[2] + PHI(r, 3) * x[3] +
                            PHI(r, 4) * x[4] + PHI(r, 5) * x[5] + GAM(r, 0) * u_s;
            }
            for (int r = 0; r < 6; r++) x[r] = xn[r];
        }
        for (int r = 0; r < 6; r++) b->x[r * n + i] = x[r];
        for (int r = 0; r < 4; r++) b->xt[r * n + i] = xt[r];
        b->law[0 * n + i] = s0, b->law[1 * n + i] = s1, b->law[2 * n + i] = s2;
        b->law[3 * n + i] = s3, b->law[4 * n + i] = s4, b->law[5 * n + i] = s5;
        if (b->nphase) b->ring_pos[i] = (double)pos;
        b->y_prev[i] = y_prev, b->u_fly[i] = u_fly, b->u_prev[i] = u_prev, b->wmax[i] = wmax;
        b->acc[0 * n + i] = a_ise_ref, b->acc[1 * n + i] = a_ise_crm, b->acc[2 * n + i] = a_energy;
        b->acc[3 * n + i] = a_tv, b->acc[4 * n + i] = a_max_u, b->acc[5 * n + i] = a_max_roll;
        b->acc[6 * n + i] = a_sat;
        b->tblk[0 * n + i] = t_rr, b->tblk[1 * n + i] = t_pr, b->tblk[2 * n + i] = t_dd, b->tblk[3 * n + i] = t_hits;
        b->tblk[4 * n + i] = t_sw;
        b->swing[0 * n + i] = w_up, b->swing[1 * n + i] = w_ext, b->swing[2 * n + i] = w_kext;
        b->swing[3 * n + i] = w_last, b->swing[4 * n + i] = w_klast, b->swing[5 * n + i] = w_size;
        b->swing[6 * n + i] = w_dur;
        b->track[0 * n + i] = f_osc, b->track[1 * n + i] = f_lag, b->hit_armed[i] = armed ? 1.0 : 0.0;
#undef CO
#undef PHI
#undef GAM
#undef LOAD_FINE
    }
}
