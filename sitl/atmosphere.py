"""Lateral atmospheric disturbances for the KH2013A: Dryden turbulence, 1-cosine gusts, steady crosswind.

Pure, seeded, I/O-free; numpy in, numpy out.  The disturbance vector is ``d = [v_g, p_g, r_g]``
(side gust m/s, roll gust rad/s, yaw gust rad/s, body axes), held over each sample (zero-order hold).

Dryden forms (MIL-F-8785C, section 3.7; the low-altitude scales of MIL-HDBK-1797 appendix), each filter
driven by unit-intensity white noise w (E[w(t) w(t+tau)] = delta(tau)), so the output's one-sided PSD in
rad/s is Phi(omega) = |H(j omega)|^2 / pi, the MIL-F-8785C spectrum, and sigma^2 = int_0^inf Phi:

    H_v(s) = sigma_v sqrt(L_v/V) (1 + sqrt(3) L_v s/V) / (1 + L_v s/V)^2
    H_p(s) = sigma_p sqrt(2 T_p) / (1 + T_p s),   T_p = 4b/(pi V),
             sigma_p^2 = 0.8 sigma_w^2 (pi L_w/(4b))^(1/3) pi^2 / (8 b L_w)   (the integral of Phi_p)
    H_r(s) = (s/V) / (1 + 3b s/(pi V)) * H_v(s)        (r_g = dv_g/dx, driven by the same noise as v_g)

The filters are discretised exactly: x[k+1] = A_d x[k] + e[k], e[k] ~ N(0, Q_d) with
Q_d = int_0^h e^{A s} B B^T e^{A^T s} ds = P - A_d P A_d^T (P the stationary covariance), and the state
starts in the stationary distribution, so every sample has exactly the continuous-time variance whatever
the step h.

Assumptions (docs/spec.md, "Atmosphere, sensors, link faults, uncertainty"): airspeed V = |(U0, W0)|
from A_lp's v row (r coefficient -7.55 ~ -U0, p coefficient 1.93 ~ W0), 7.79 m/s; wing span b = 0.15 m;
altitude 10 m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sitl import model

FT = 0.3048  # m
KNOT = 0.514444  # m/s
U0 = -model.A_LP[0, 2]  # 7.55 m/s: the v row's r coefficient is Y_r - U0 with Y_r ~ 0 (paper sec. 5.1)
W0 = model.A_LP[0, 1]  # 1.93 m/s: the v row's p coefficient is Y_p + W0 with Y_p ~ 0
AIRSPEED = math.hypot(U0, W0)  # 7.79 m/s
SPAN = 0.15  # m, the 150 mm KH2013A
ALTITUDE = 10.0  # m
# MIL-HDBK-1797 low-altitude turbulence: wind speed at 20 ft, W20 (light 15 kt, moderate 30 kt, severe 45 kt).
W20 = {"light": 15.0 * KNOT, "moderate": 30.0 * KNOT, "severe": 45.0 * KNOT}
V_G, P_G, R_G = 0, 1, 2  # indices in d
_CHUNK = 50  # Atmosphere.sample advances the filter this many steps per matrix product


class AtmosphereConfigError(ValueError):
    """A turbulence, gust or crosswind value is out of range."""


def _positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        raise AtmosphereConfigError(f"{name} must be positive and finite, got {value!r}")


@dataclass(frozen=True)
class DrydenConfig:
    """Dryden parameters: sigmas (m/s) of the side and vertical gusts, scale lengths (m), airspeed (m/s), span (m).

    sigma_w and length_w set the roll gust p_g (it comes from the spanwise gradient of the vertical gust).
    """

    sigma_v: float
    sigma_w: float
    length_v: float
    length_w: float
    airspeed: float = AIRSPEED
    span: float = SPAN

    def __post_init__(self) -> None:
        for name in ("length_v", "length_w", "airspeed", "span"):
            _positive(name, getattr(self, name))
        for name in ("sigma_v", "sigma_w"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise AtmosphereConfigError(f"{name} must be >= 0 and finite, got {value!r}")

    @classmethod
    def intensity(cls, name: str, altitude: float = ALTITUDE, airspeed: float = AIRSPEED) -> DrydenConfig:
        """Low-altitude model (MIL-HDBK-1797, 10 ft < h < 1000 ft): L_w = h, L_v = h/(0.177 + 0.000823 h)^1.2,
        sigma_w = 0.1 W20, sigma_v = sigma_w/(0.177 + 0.000823 h)^0.4 (h in ft); ``name`` light|moderate|severe."""
        if name not in W20:
            raise AtmosphereConfigError(f"turbulence intensity must be one of {', '.join(W20)}, got {name!r}")
        h_ft = altitude / FT
        if not 10.0 <= h_ft <= 1000.0:
            raise AtmosphereConfigError(f"altitude must be within 3.05..304.8 m (10..1000 ft), got {altitude!r}")
        k = 0.177 + 0.000823 * h_ft
        sigma_w = 0.1 * W20[name]
        return cls(sigma_w / k**0.4, sigma_w, h_ft / k**1.2 * FT, altitude, airspeed)

    @property
    def sigma_p(self) -> float:
        """Standard deviation (rad/s) of the roll gust p_g, the integral of the MIL-F-8785C Phi_p."""
        lw, b = self.length_w, self.span
        return self.sigma_w * math.sqrt(0.8 * (math.pi * lw / (4 * b)) ** (1 / 3) * math.pi**2 / (8 * b * lw))

    def state_space(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Continuous (A, B, C) of [H_v, H_p, H_r] driven by w = [w_v, w_p]: states [x_v1, x_v2, x_p, z_r]."""
        vel = self.airspeed
        a = self.length_v / vel
        k = self.sigma_v * math.sqrt(a)
        tp = 4 * self.span / (math.pi * vel)
        tr = 3 * self.span / (math.pi * vel)
        cv = np.array([k / a**2, k * math.sqrt(3) / a, 0.0, 0.0])  # v_g = C_v x
        am = np.zeros((4, 4))
        am[0, 1] = 1.0
        am[1, 0], am[1, 1] = -1 / a**2, -2 / a
        am[2, 2] = -1 / tp
        am[3, :] = cv / tr  # z' = (v_g - z)/T_r, r_g = (v_g - z)/(V T_r) = (s/V)/(1 + T_r s) v_g
        am[3, 3] -= 1 / tr
        bm = np.zeros((4, 2))
        bm[1, 0] = 1.0
        bm[2, 1] = self.sigma_p * math.sqrt(2 * tp) / tp
        cm = np.zeros((3, 4))
        cm[V_G] = cv
        cm[P_G, 2] = 1.0
        cm[R_G] = cv / (vel * tr)
        cm[R_G, 3] -= 1 / (vel * tr)
        return am, bm, cm

    def psd(self, omega: np.ndarray) -> np.ndarray:
        """Analytic one-sided PSDs Phi(omega) = |H(j omega)|^2/pi of [v_g, p_g, r_g], shape (3, len(omega))."""
        w = np.asarray(omega, dtype=float)
        vel = self.airspeed
        a = self.length_v / vel
        tp = 4 * self.span / (math.pi * vel)
        tr = 3 * self.span / (math.pi * vel)
        hv2 = self.sigma_v**2 * a * (1 + 3 * (a * w) ** 2) / (1 + (a * w) ** 2) ** 2
        hp2 = self.sigma_p**2 * 2 * tp / (1 + (tp * w) ** 2)
        hr2 = (w / vel) ** 2 / (1 + (tr * w) ** 2) * hv2
        return np.vstack([hv2, hp2, hr2]) / math.pi


def noise_zoh(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact discretisation of x' = A x + B w (A stable, w unit-intensity white noise): (A_d, Q_d, P).

    Q_d = int_0^dt e^{As} B B^T e^{A^T s} ds = P - A_d P A_d^T with P the stationary covariance
    (A P + P A^T + B B^T = 0); unlike Van Loan's block exponential this keeps its precision when dt is
    many time constants long.
    """
    from scipy.linalg import expm, solve_continuous_lyapunov  # here: scipy costs ~0.2 s, only turbulence needs it

    ad = expm(a * dt)
    p = solve_continuous_lyapunov(a, -b @ b.T)
    p = (p + p.T) / 2
    qd = p - ad @ p @ ad.T
    return ad, (qd + qd.T) / 2, p


def _sqrtm_psd(q: np.ndarray) -> np.ndarray:
    """L with L L^T = q for a symmetric positive semi-definite q (eigen-decomposition: tolerates rank loss)."""
    lam, vec = np.linalg.eigh(q)
    return vec * np.sqrt(np.clip(lam, 0.0, None))


@dataclass(frozen=True)
class DrydenFilter:
    """The exactly discretised Dryden filters at step ``dt``: x[k+1] = ad x[k] + ld z[k], d[k] = c x[k], z ~ N(0, I).

    Works on one aircraft (x shape (4,)) or a batch (x shape (N, 4)): see :meth:`initial` and :meth:`step`.
    """

    ad: np.ndarray
    ld: np.ndarray
    c: np.ndarray
    l0: np.ndarray  # stationary covariance factor

    @classmethod
    def build(cls, cfg: DrydenConfig, dt: float) -> DrydenFilter:
        _positive("dt", dt)
        a, b, c = cfg.state_space()
        ad, qd, p = noise_zoh(a, b, dt)
        return cls(ad, _sqrtm_psd(qd), c, _sqrtm_psd(p))

    def initial(self, rng: np.random.Generator, batch: tuple = ()) -> np.ndarray:
        """A state drawn from the stationary distribution (shape batch + (4,))."""
        return rng.standard_normal(batch + (4,)) @ self.l0.T

    def step(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The next state(s)."""
        return x @ self.ad.T + rng.standard_normal(x.shape) @ self.ld.T

    def output(self, x: np.ndarray) -> np.ndarray:
        """d = [v_g, p_g, r_g] of the state(s)."""
        return x @ self.c.T


@dataclass(frozen=True)
class Gust:
    """A 1-cosine side gust: v_g = A/2 (1 - cos(2 pi (t - start) V / length)) for start <= t <= start + length/V.

    ``amplitude`` (m/s) is the peak, reached half-way; ``length`` (m) is the gust's length along the flight path,
    so it lasts length/airspeed seconds.
    """

    amplitude: float
    length: float
    start: float
    airspeed: float = AIRSPEED

    def __post_init__(self) -> None:
        if not math.isfinite(self.amplitude):
            raise AtmosphereConfigError(f"gust amplitude must be finite, got {self.amplitude!r}")
        _positive("gust length", self.length)
        _positive("gust airspeed", self.airspeed)
        if not (math.isfinite(self.start) and self.start >= 0):
            raise AtmosphereConfigError(f"gust start must be >= 0 s, got {self.start!r}")

    @property
    def duration(self) -> float:
        return self.length / self.airspeed

    def __call__(self, t: np.ndarray | float) -> np.ndarray:
        """v_g (m/s) at time(s) t (s)."""
        tau = (np.asarray(t, dtype=float) - self.start) / self.duration
        inside = (tau >= 0.0) & (tau <= 1.0)
        return np.where(inside, 0.5 * self.amplitude * (1.0 - np.cos(2.0 * np.pi * tau)), 0.0)


@dataclass(frozen=True)
class AtmosphereConfig:
    """Everything the air does: Dryden turbulence (or None), 1-cosine gusts, steady crosswind (m/s, body y)."""

    turbulence: DrydenConfig | None = None
    gusts: tuple[Gust, ...] = field(default_factory=tuple)
    crosswind: float = 0.0

    def __post_init__(self) -> None:
        if not math.isfinite(self.crosswind):
            raise AtmosphereConfigError(f"crosswind must be finite, got {self.crosswind!r}")

    @property
    def active(self) -> bool:
        return self.turbulence is not None or bool(self.gusts) or self.crosswind != 0.0


class Atmosphere:
    """Samples d = [v_g, p_g, r_g] every ``dt`` seconds from time ``t0``, seeded.

    Example::

        atm = Atmosphere(AtmosphereConfig(DrydenConfig.intensity("moderate")), 1e-3, np.random.default_rng(1))
        d = atm.sample(10)       # (10, 3): the next 10 physics steps
    """

    def __init__(self, cfg: AtmosphereConfig, dt: float, rng: np.random.Generator, t0: float = 0.0):
        self.cfg = cfg
        self.dt = dt
        self.t0 = t0
        self.k = 0
        self.rng = rng
        self.filter = DrydenFilter.build(cfg.turbulence, dt) if cfg.turbulence is not None else None
        self.x = self.filter.initial(rng) if self.filter is not None else None
        self._cache: dict[int, tuple] = {}

    def _blocks(self, m: int) -> tuple:
        """m steps of the filter at once: d[0..m) = G0 x0 + H z, x[m] = A_d^m x0 + K z (z: the m x 4 unit normals,
        flattened), with G0 = [C A_d^i], H[i, j] = C A_d^(i-1-j) L_d (j < i), K[j] = A_d^(m-1-j) L_d; cached per m."""
        blk = self._cache.get(m)
        if blk is None:
            f = self.filter
            powers = [np.eye(4)]
            for _ in range(m):
                powers.append(f.ad @ powers[-1])
            g0 = np.vstack([f.c @ powers[i] for i in range(m)])
            h = np.zeros((3 * m, 4 * m))
            for i in range(m):
                for j in range(i):
                    h[3 * i : 3 * i + 3, 4 * j : 4 * j + 4] = f.c @ powers[i - 1 - j] @ f.ld
            k = np.hstack([powers[m - 1 - j] @ f.ld for j in range(m)])
            blk = self._cache[m] = (g0, h, powers[m], k)
        return blk

    def sample(self, n: int) -> np.ndarray:
        """The disturbance for the next ``n`` steps, shape (n, 3); advances the clock by n dt."""
        d = np.zeros((n, 3))
        if self.filter is not None:
            z = self.rng.standard_normal((n, 4))
            for i in range(0, n, _CHUNK):
                m = min(_CHUNK, n - i)
                g0, h, an, k = self._blocks(m)
                zi = z[i : i + m].ravel()
                d[i : i + m] = (g0 @ self.x + h @ zi).reshape(m, 3)
                self.x = an @ self.x + k @ zi
        if self.cfg.gusts:
            t = self.t0 + (self.k + np.arange(n)) * self.dt
            for g in self.cfg.gusts:
                d[:, V_G] += g(t)
        d[:, V_G] += self.cfg.crosswind
        self.k += n
        return d


def disturbance_matrix(a_p: np.ndarray) -> np.ndarray:
    """E (6x3) with x_p' = A_p x_p + B_p u + E d, d = [v_g, p_g, r_g].

    The aerodynamic forces and moments act on the air-relative velocities v - v_g, p - p_g, r - r_g, so d
    enters through the aerodynamic part of A_p's v, p, r columns with a minus sign.  Aerodynamic: the whole v
    column (Y_v, L_v, N_v) and the p and r columns' L and N rows (L_p, N_p, L_r, N_r).  Kinematic, no gust term:
    the v row's W0 p and -U0 r (Y_p, Y_r ~ 0 for this airframe), the gravity term g cos(theta0) phi, the phi
    row (phi' = p + tan(theta0) r) and the servo rows.
    """
    e = np.zeros((6, 3))
    e[:3, V_G] = -a_p[:3, 0]
    e[1:3, P_G] = -a_p[1:3, 1]
    e[1:3, R_G] = -a_p[1:3, 2]
    return e
