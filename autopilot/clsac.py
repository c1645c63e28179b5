"""Closed-loop Reference Model Simple Adaptive Control (CL-SAC), Jana & Bhat 2017, sections 2-3.

Every equation of the control law lives in this file.  Per control step k (period T), with the
measured output y[k] and the command u_m[k]:

    y_d[k] = C_d x_d[k]                         PFC output, D(s) = 1/C(s) (paper sec. 2 and 5)
    y_a    = y[k] + y_d[k]                      augmented output, computed from the controller's own
                                                past (applied) commands (paper sec. 5, Fig. "Details")
    y_m    = C_m x_m[k]                         reference model output (paper eq. (19))
    e      = y_m - y_a                          output error e_my (paper eq. (20))
    K_pe = e e^T G_pe,  K_px = e x_m^T G_px,  K_pu = e u_m^T G_pu           (paper sec. 2-3)
    u_raw  = (K_pe + K_Ie) e + (K_px + K_Ix) x_m + (K_pu + K_Iu) u_m          (paper eqs. (6), (21))
    u      = clip(u_raw, -u_limit, +u_limit)    the command actually applied

then the states move to k+1 (exact zero-order-hold discretisation: the controller only knows its
signals at the samples and holds them, just as the servo holds u, so each update is the exact
solution of the continuous law over one period for held inputs):

    x_d[k+1] = e^{A_d T} x_d + A_d^{-1}(e^{A_d T} - I) B_d u                 PFC driven by applied u
    x_m[k+1] = e^{A_c T} x_m + A_c^{-1}(e^{A_c T} - I)(B_m u_m + L_v y_a),  A_c = A_m - L_v C_m
                                                                             (paper eq. (18))
    K_Ie[k+1] = e^{-sigma T} K_Ie + (1 - e^{-sigma T})/sigma * e e^T G_Ie   (K_Ie' = e e^T G_Ie - sigma K_Ie)
    K_Ix[k+1] = K_Ix + T e x_m^T G_Ix                                          (K_Ix' = e x_m^T G_Ix)
    K_Iu[k+1] = K_Iu + T e u_m^T G_Iu                                          (K_Iu' = e u_m^T G_Iu)

Optional extension (``sigma_x``, ``sigma_u`` > 0, default 0 as in the paper): the same leakage on the
x and u channels, K_Ix' = e x_m^T G_Ix - sigma_x K_Ix, discretised like K_Ie.

Optional robustness modifications (``ClSacConfig``; none is in the paper, each is off by default):
``dead_zone_rad`` > 0 skips every integral increment while |e| <= dead_zone_rad (MIMO: max |e_i|), the
sigma decays still act; ``freeze_when_saturated`` skips every integral increment while the command saturates;
``ki_max`` projects each element of K_Ie, K_Ix, K_Iu onto [-ki_max, ki_max] after its update.

SAC (paper sec. 2) is exactly this with L_v = 0: A_c = A_m and the y_a term vanishes.

Saturation (a choice the paper does not make, documented here): the PFC is always driven by the
clipped command, so y_a describes the plant that is really being driven.  With ``anti_windup`` on,
while |u_raw| > u_limit each integral channel whose increment would push u_raw further past the
limit is not integrated that step (conditional integration); the sigma decay of K_Ie still acts.

The open-loop model x_m,ol' = A_m x_m,ol + B_m u_m is run alongside for telemetry and the
``ise_ref`` metric; it does not feed the law.
"""

from __future__ import annotations

import math
import operator

import numpy as np

from autopilot.config import ClSacConfig, ConfigError, NonFiniteInputError
from autopilot.shared.numerics import zoh

TELEMETRY_FIELDS = (
    "um",
    "y",
    "ym",
    "ym_ol",
    "ya",
    "y_pfc",
    "e",
    "u_raw",
    "u",
    "saturated",
    "kpe",
    "kie",
    "ke",
    "kpx",
    "kix",
    "kx",
    "kpu",
    "kiu",
    "ku",
)
# The internals of any law with these attributes (ClSac, autopilot.baseline.Baseline) as one tuple, built in C.
telemetry_of = operator.attrgetter(*TELEMETRY_FIELDS)
# Two subsets the per-step series record: the reference model and error, and the six gains.
MODEL_FIELDS = ("ym", "ym_ol", "ya", "y_pfc", "e")
GAIN_FIELDS = ("kpe", "kie", "ke", "kpx", "kix", "kx", "kpu", "kiu", "ku")
model_of = operator.attrgetter(*MODEL_FIELDS)
gains_of = operator.attrgetter(*GAIN_FIELDS)


def pfc_state_space(num, den) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Controllable canonical (A_d, B_d, C_d) of the strictly proper PFC D(s) = num(s)/den(s).

    den = a_0 s^n + ... + a_n (a_0 != 0), num of degree < n: with x_1 the highest derivative,
    x' = A x + B u where A's first row is -a_1..a_n / a_0, the subdiagonal is ones, B = e_1,
    and y = C x with C the numerator coefficients / a_0, right-aligned to length n.
    (Hand-coded to keep scipy.signal, ~1 s of imports, out of every process's start-up.)
    """
    den = np.trim_zeros(np.asarray(den, dtype=float).ravel(), "f")
    num = np.trim_zeros(np.asarray(num, dtype=float).ravel(), "f")
    n = den.size - 1
    if num.size > n:
        raise ValueError("PFC must be strictly proper")
    a = np.zeros((n, n))
    a[0, :] = -den[1:] / den[0]
    a[1:, :-1] = np.eye(n - 1)
    b = np.zeros((n, 1))
    b[0, 0] = 1.0
    c = np.zeros((1, n))
    c[0, n - num.size :] = num / den[0]
    return a, b, c


def _block_pfc(channels, T: float):
    """(e^{A_D T}, Gamma_D, C_D) of D(s) = diag(D_1, ..., D_m), D_i = num_i/den_i (``pfc_state_space`` each, blocks
    on the diagonal): a square MIMO plant's PFC, one of its own per channel, discretised exactly (ZOH)."""
    blocks = [pfc_state_space(num, den) for num, den in channels]
    n = sum(a.shape[0] for a, _, _ in blocks)
    m = len(blocks)
    a_d, b_d, c_d = np.zeros((n, n)), np.zeros((n, m)), np.zeros((m, n))
    k = 0
    for i, (a, b, c) in enumerate(blocks):
        j = k + a.shape[0]
        a_d[k:j, k:j], b_d[k:j, i], c_d[i, k:j] = a, b[:, 0], c[0]
        k = j
    phi, gam = zoh(a_d, b_d, T)
    return phi, gam, c_d


class ClSac:
    """The CL-SAC controller: call once per control step with the measured output and the command.

    Example::

        ctrl = ClSac(ClSacConfig())            # the paper's CL-SAC, L_v = 20, 100 Hz
        u = ctrl(phi_measured, phi_command)    # rudder command in rad, already limited

    After each call the internals of that step are attributes (``e``, ``ym``, ``ym_ol``, ``ya``, ``y_pfc``,
    ``u_raw``, ``u``, ``saturated`` and the gains it used, ``kpe``, ``kie``, ``ke`` ... ``ku``, so that
    ``ke == kpe + kie``); the states carried to the next step are ``xm``, ``xm_ol``, ``xd`` and the
    integral gains ``ki_e``, ``ki_x``, ``ki_u``.  For the SISO
    loop they are floats, for MIMO numpy arrays.  ``telemetry()`` returns them as a tuple ordered
    like ``TELEMETRY_FIELDS``.  ``reset()`` returns to the initial conditions; ``hold(u)`` advances
    only the PFC with a command applied by someone else (failsafe), adaptation frozen.
    """

    def __init__(self, config: ClSacConfig | None = None, *, fast: bool | None = None):
        self.config = cfg = config or ClSacConfig()
        m, n_m, m_m = cfg.dims()
        self._m, self._nm, self._mm = m, n_m, m_m
        T = cfg.dt
        self.dt = T
        am = np.atleast_2d(np.asarray(cfg.am, dtype=float))
        bm = np.atleast_2d(np.asarray(cfg.bm, dtype=float))
        cm = np.atleast_2d(np.asarray(cfg.cm, dtype=float))
        lv = np.atleast_2d(np.asarray(cfg.lv, dtype=float))
        if lv.shape == (1, 1) and (n_m, m) != (1, 1):
            lv = lv[0, 0] * np.eye(n_m, m)

        def gam(v, n):
            g = np.atleast_2d(np.asarray(v, dtype=float))
            return g[0, 0] * np.eye(n) if g.shape == (1, 1) else g

        self._G = {
            "pe": gam(cfg.gamma_pe, m),
            "ie": gam(cfg.gamma_ie, m),
            "px": gam(cfg.gamma_px, n_m),
            "ix": gam(cfg.gamma_ix, n_m),
            "pu": gam(cfg.gamma_pu, m_m),
            "iu": gam(cfg.gamma_iu, m_m),
        }
        # Reference models (paper eq. (18); open loop eq. (3)): inputs [u_m, y_a] held over T.
        self._am, self._bm, self._cm, self._lv = am, bm, cm, lv
        # With L_v = 0, A_m - L_v C_m is A_m exactly, so the closed-loop model is discretised by the very same
        # call as the open-loop one and SAC comes out bit-identical; the y_a input column is then exactly zero.
        self._phi_m, self._gam_mu = zoh(am - lv @ cm, bm, T)
        self._gam_my = zoh(am - lv @ cm, lv, T)[1] if np.any(lv) else np.zeros((n_m, m))
        self._phi_ol, self._gam_ol = zoh(am, bm, T)
        # PFC D(s) per output channel (paper sec. 5: D(s) = 10/(4s + 40)).
        ad, bd, cd = pfc_state_space(cfg.pfc_num, cfg.pfc_den)
        self._nd = ad.shape[0]
        self._phi_d, self._gam_d = zoh(ad, bd, T)
        self._cd = cd
        # A PFC of its own per channel (``pfc_channels``): D(s) = diag(D_1, ..., D_m) as one block-diagonal state
        # space (A_D, B_D, C_D), x_d one vector; y_d = C_D x_d, x_d[k+1] = e^{A_D T} x_d + Gamma_D u (exact ZOH).
        self._blk = cfg.pfc_channels is not None
        if self._blk:
            self._phi_d, self._gam_d, self._cd = _block_pfc(cfg.pfc_channels, T)
            self._nd = self._phi_d.shape[0]

        # sigma-modification: K_Ie' = e e^T G_Ie - sigma K_Ie, exact for held e.
        def leak(sig: float) -> tuple[float, float]:
            decay = math.exp(-sig * T)
            return decay, ((1.0 - decay) / sig if sig > 0 else T)

        self._decay, self._gain_ie = leak(cfg.sigma)
        self._decay_x, self._gain_ix = leak(cfg.sigma_x)
        self._decay_u, self._gain_iu = leak(cfg.sigma_u)
        self._umax = float(cfg.u_limit_rad) if cfg.u_limits_rad is None else np.asarray(cfg.u_limits_rad, float)
        self._aw = bool(cfg.anti_windup)
        # Optional robustness modifications (ClSacConfig; all off by default = the paper's law).
        self._dz = float(cfg.dead_zone_rad)
        self._kmax = None if cfg.ki_max is None else float(cfg.ki_max)
        self._freeze = bool(cfg.freeze_when_saturated)
        self._ki0 = (
            np.broadcast_to(np.atleast_2d(np.asarray(cfg.ki_e0, dtype=float)), (m, m)).copy(),
            np.broadcast_to(np.atleast_2d(np.asarray(cfg.ki_x0, dtype=float)), (m, n_m)).copy(),
            np.broadcast_to(np.atleast_2d(np.asarray(cfg.ki_u0, dtype=float)), (m, m_m)).copy(),
        )
        siso = cfg.is_siso and self._nd == 1
        self._fast = siso if fast is None else (bool(fast) and siso)
        if self._fast:
            # Scalar coefficients for the SISO roll loop (same equations, Python floats: ~3 us a step).
            self._s = dict(
                phi_m=float(self._phi_m[0, 0]),
                g_mu=float(self._gam_mu[0, 0]),
                g_my=float(self._gam_my[0, 0]),
                phi_ol=float(self._phi_ol[0, 0]),
                g_ol=float(self._gam_ol[0, 0]),
                cm=float(cm[0, 0]),
                bm=float(bm[0, 0]),
                phi_d=float(self._phi_d[0, 0]),
                g_d=float(self._gam_d[0, 0]),
                cd=float(cd[0, 0]),
                gpe=float(self._G["pe"][0, 0]),
                gie=float(self._G["ie"][0, 0]),
                gpx=float(self._G["px"][0, 0]),
                gix=float(self._G["ix"][0, 0]),
                gpu=float(self._G["pu"][0, 0]),
                giu=float(self._G["iu"][0, 0]),
            )
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Back to the initial conditions: reference models, PFC at zero, K_I = K_I(0)."""
        m, n_m, m_m = self._m, self._nm, self._mm
        self.steps = 0
        self.frozen = False
        self._pending = None  # what ``advance`` needs after a ``command`` (SISO)
        if self._fast:
            self.xm = 0.0
            self.xm_ol = 0.0
            self.xd = 0.0
            self.ki_e = self.kie = float(self._ki0[0][0, 0])
            self.ki_x = self.kix = float(self._ki0[1][0, 0])
            self.ki_u = self.kiu = float(self._ki0[2][0, 0])
            zero = 0.0
            self.um = self.y = self.ym = self.ym_ol = self.ya = self.y_pfc = self.e = zero
            self.u_raw = self.u = zero
            self.kpe = self.kpx = self.kpu = zero
            self.ke, self.kx, self.ku = self.kie, self.kix, self.kiu
        else:
            self.xm = np.zeros(n_m)
            self.xm_ol = np.zeros(n_m)
            self.xd = np.zeros(self._nd) if self._blk else np.zeros((self._nd, m))  # one PFC per output channel
            self.ki_e, self.ki_x, self.ki_u = (k.copy() for k in self._ki0)
            self.kie, self.kix, self.kiu = (k.copy() for k in self._ki0)
            self.um = np.zeros(m_m)
            self.y = self.ym = self.ym_ol = self.ya = self.y_pfc = self.e = np.zeros(m)
            self.u_raw = self.u = np.zeros(m)
            self.kpe, self.kpx, self.kpu = np.zeros((m, m)), np.zeros((m, n_m)), np.zeros((m, m_m))
            self.ke, self.kx, self.ku = self.kie.copy(), self.kix.copy(), self.kiu.copy()
        self.saturated = False

    def telemetry(self) -> tuple:
        """The internals after the last step, ordered like ``TELEMETRY_FIELDS``."""
        return telemetry_of(self)

    # ------------------------------------------------------------------ step
    def __call__(self, y, um):
        return self.step(y, um)

    def step(self, y, um):
        """One control step: measured output ``y`` and command ``um`` in; the applied command out."""
        if self._fast:
            return self._step_siso(y, um)
        return self._step_matrix(y, um)

    def command(self, y, um):
        """The first half of ``step``: this step's command u (eqs. (6), (21), limited), as soon as it is known.
        ``advance()``, the second half (the integral gains, reference models and PFC to step k+1, and the step's
        internals), must follow before anything else reads or steps the law; the two give exactly ``step``'s
        numbers (the same operations in the same order).  The autopilot sends u between the two."""
        if self._fast:
            return self._command_siso(y, um)
        self._pending = None
        return self._step_matrix(y, um)

    def advance(self) -> None:
        """The second half of the step ``command`` began (nothing after a matrix step, done in one)."""
        p = self._pending
        if p is not None:
            self._pending = None
            self._advance_siso(*p)

    def hold(self, u_applied=0.0) -> None:
        """Failsafe step: someone else applies ``u_applied``; only the PFC follows it (adaptation frozen)."""
        if self._fast:
            s = self._s
            self.xd = s["phi_d"] * self.xd + s["g_d"] * float(u_applied)
            self.u = self.u_raw = float(u_applied)
        else:
            u = np.broadcast_to(np.asarray(u_applied, dtype=float), (self._m,))
            self.xd = self._pfc_next(self.xd, u)
            self.u = self.u_raw = u.copy()
        self.frozen = True

    def flew(self, u_applied) -> None:
        """This step's command ``u`` was replaced by ``u_applied`` before it flew (a bumpless transfer): the PFC
        is driven by what flew, as always (y_a describes the plant really driven); ``u`` stays the law's own."""
        if self._fast:
            self.xd += self._s["g_d"] * (float(u_applied) - self.u)
        else:
            u_applied = np.broadcast_to(np.asarray(u_applied, dtype=float), (self._m,))
            du = u_applied - self.u
            self.xd = self.xd + (self._gam_d @ du if self._blk else self._gam_d @ du[None, :])

    def reconfigure(self, config: ClSacConfig) -> None:
        """Fly ``config`` from the next step on, keeping the states (a parameter change or a SAC <-> CL-SAC
        switch in flight): the coefficients are discretised again, x_m, x_m,ol, the integral gains and the last
        step's internals are kept.  A first-order PFC keeps its output y_d = C_d x_d (x_d rescaled), so y_a does
        not jump; a PFC of another order starts from rest.  Raises ``ConfigError`` for other dimensions."""
        if config.dims() != self.config.dims():
            raise ConfigError(f"reconfigure needs the same dimensions {self.config.dims()}, got {config.dims()}")
        kept = {k: v for k, v in vars(self).items() if not k.startswith("_") and k not in ("config", "dt")}
        cd_old, nd_old = self._cd, self._nd
        self.__init__(config, fast=self._fast)
        if self._nd != nd_old:
            del kept["xd"]
        elif self._blk and self._nd == self._m and cd_old.shape == self._cd.shape:  # first-order D_i: y_d kept
            kept["xd"] = kept["xd"] * (np.diag(cd_old) / np.diag(self._cd))
        elif self._nd == 1:
            kept["xd"] = kept["xd"] * float(cd_old[0, 0] / self._cd[0, 0])  # y_d = C_d x_d unchanged
        vars(self).update(kept)

    def _pfc_next(self, xd, u):
        """x_d[k+1] of the matrix step's PFC driven by the applied ``u`` (one D(s) per channel, or the block-diagonal
        D(s) = diag(D_i) of ``pfc_channels``)."""
        if self._blk:
            return self._phi_d @ xd + self._gam_d @ u
        return self._phi_d @ xd + self._gam_d @ u[None, :]

    def _step_siso(self, y, um):
        """One SISO step in floats (paper sections 2-3): ``_command_siso`` then ``_advance_siso``."""
        u = self._command_siso(y, um)
        self._advance_siso(*self._pending)
        self._pending = None
        return u

    def _command_siso(self, y, um):
        """``_step_siso`` up to the command; what the rest needs waits in ``_pending``."""
        y = float(y)
        um = float(um)
        if not (math.isfinite(y) and math.isfinite(um)):
            raise NonFiniteInputError(f"controller inputs must be finite, got y={y!r}, um={um!r}")
        s = self._s
        xm = self.xm
        y_pfc = s["cd"] * self.xd  # y_d = C_d x_d
        ya = y + y_pfc  # y_a = y_p + D(s) u_p
        ym = s["cm"] * xm  # y_m = C_m x_m
        e = ym - ya  # e_my = y_m - y_a
        kpe = e * e * s["gpe"]  # K_pe = e e^T G_pe
        kpx = e * xm * s["gpx"]  # K_px = e x_m^T G_px
        kpu = e * um * s["gpu"]  # K_pu = e u_m^T G_pu
        kie, kix, kiu = self.ki_e, self.ki_x, self.ki_u  # integral gains of this step
        ke = kpe + kie
        kx = kpx + kix
        ku = kpu + kiu
        u_raw = ke * e + kx * xm + ku * um  # u_p = K_e e + K_x x_m + K_u u_m
        umax = self._umax
        u = umax if u_raw > umax else (-umax if u_raw < -umax else u_raw)
        sat = u != u_raw
        self._pending = (y, um, xm, ya, ym, y_pfc, e, kpe, kpx, kpu, kie, kix, kiu, ke, kx, ku, u_raw, u, sat)
        return u

    def _advance_siso(self, y, um, xm, ya, ym, y_pfc, e, kpe, kpx, kpu, kie, kix, kiu, ke, kx, ku, u_raw, u, sat):
        """``_step_siso`` after the command: the adaptation and the models to step k+1."""
        s = self._s
        # Integral gains, exact ZOH updates (module docstring).
        die = self._gain_ie * (e * e * s["gie"])
        dix = self._gain_ix * (e * xm * s["gix"])
        diu = self._gain_iu * (e * um * s["giu"])
        if (self._dz > 0.0 and abs(e) <= self._dz) or (sat and self._freeze):
            die = dix = diu = 0.0  # dead-zone on e / frozen while saturated: no integral adaptation this step
        elif sat and self._aw:
            # Conditional integration: skip channels whose increment pushes u_raw further past the limit.
            if die * e * u_raw > 0:
                die = 0.0
            if dix * xm * u_raw > 0:
                dix = 0.0
            if diu * um * u_raw > 0:
                diu = 0.0
        self.ki_e = self._decay * kie + die
        self.ki_x = self._decay_x * kix + dix  # decay_x = 1 exactly when sigma_x = 0 (the paper)
        self.ki_u = self._decay_u * kiu + diu
        if self._kmax is not None:  # projection onto the box |K_I| <= ki_max
            km = self._kmax
            self.ki_e = min(max(self.ki_e, -km), km)
            self.ki_x = min(max(self.ki_x, -km), km)
            self.ki_u = min(max(self.ki_u, -km), km)
        # Reference models and PFC to k+1 (paper eqs. (18), (3); D(s) driven by the applied u).
        self.xm = s["phi_m"] * xm + (s["g_mu"] * um + s["g_my"] * ya)
        ym_ol = s["cm"] * self.xm_ol  # open-loop y_m,ol at step k (telemetry, ise_ref)
        self.xm_ol = s["phi_ol"] * self.xm_ol + s["g_ol"] * um
        self.xd = s["phi_d"] * self.xd + s["g_d"] * u
        # Expose what this step used.
        self.um, self.y, self.ym, self.ym_ol, self.ya, self.y_pfc, self.e = um, y, ym, ym_ol, ya, y_pfc, e
        self.u_raw, self.u, self.saturated = u_raw, u, sat
        self.kpe, self.kpx, self.kpu, self.ke, self.kx, self.ku = kpe, kpx, kpu, ke, kx, ku
        self.kie, self.kix, self.kiu = kie, kix, kiu
        self.frozen = False
        self.steps += 1

    def _step_matrix(self, y, um):
        m = self._m
        y = np.asarray(y, dtype=float).reshape(m)
        um = np.asarray(um, dtype=float).reshape(self._mm)
        if not (np.all(np.isfinite(y)) and np.all(np.isfinite(um))):
            raise NonFiniteInputError(f"controller inputs must be finite, got y={y!r}, um={um!r}")
        G = self._G
        xm = self.xm
        y_pfc = (self._cd @ self.xd).reshape(m)  # y_d = C_d x_d, per channel (block-diagonal: C_D x_d)
        ya = y + y_pfc  # y_a = y_p + D(s) u_p
        ym = self._cm @ xm  # y_m = C_m x_m
        e = ym - ya  # e_my = y_m - y_a
        kpe = np.outer(e, e) @ G["pe"]  # K_pe = e e^T G_pe
        kpx = np.outer(e, xm) @ G["px"]  # K_px = e x_m^T G_px
        kpu = np.outer(e, um) @ G["pu"]  # K_pu = e u_m^T G_pu
        kie, kix, kiu = self.ki_e, self.ki_x, self.ki_u  # integral gains of this step
        ke, kx, ku = kpe + kie, kpx + kix, kpu + kiu
        u_raw = ke @ e + kx @ xm + ku @ um  # u_p = K_e e + K_x x_m + K_u u_m
        u = np.clip(u_raw, -self._umax, self._umax)
        sat_ch = u != u_raw
        die = self._gain_ie * (np.outer(e, e) @ G["ie"])
        dix = self._gain_ix * (np.outer(e, xm) @ G["ix"])
        diu = self._gain_iu * (np.outer(e, um) @ G["iu"])
        if (self._dz > 0.0 and np.max(np.abs(e)) <= self._dz) or (self._freeze and np.any(sat_ch)):
            die, dix, diu = die * 0.0, dix * 0.0, diu * 0.0  # dead-zone on e / frozen while saturated
        elif self._aw and np.any(sat_ch):
            # Conditional integration per saturated output channel (row of the gain matrices).
            for i in np.flatnonzero(sat_ch):
                if die[i] @ e * u_raw[i] > 0:
                    die[i] = 0.0
                if dix[i] @ xm * u_raw[i] > 0:
                    dix[i] = 0.0
                if diu[i] @ um * u_raw[i] > 0:
                    diu[i] = 0.0
        self.ki_e = self._decay * kie + die
        self.ki_x = self._decay_x * kix + dix
        self.ki_u = self._decay_u * kiu + diu
        if self._kmax is not None:  # projection onto the box |K_I| <= ki_max, element by element
            self.ki_e, self.ki_x, self.ki_u = (
                np.clip(k, -self._kmax, self._kmax) for k in (self.ki_e, self.ki_x, self.ki_u)
            )
        self.xm = self._phi_m @ xm + (self._gam_mu @ um + self._gam_my @ ya)
        ym_ol = self._cm @ self.xm_ol
        self.xm_ol = self._phi_ol @ self.xm_ol + self._gam_ol @ um
        self.xd = self._pfc_next(self.xd, u)
        self.um, self.y, self.ym, self.ym_ol, self.ya, self.y_pfc, self.e = um, y, ym, ym_ol, ya, y_pfc, e
        self.u_raw, self.u, self.saturated = u_raw, u, bool(np.any(sat_ch))
        self.kpe, self.kpx, self.kpu, self.ke, self.kx, self.ku = kpe, kpx, kpu, ke, kx, ku
        self.kie, self.kix, self.kiu = kie, kix, kiu
        self.frozen = False
        self.steps += 1
        return u
