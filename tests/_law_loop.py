"""The KH2013A closed loop the adaptive-law tests fly, written here from sitl.model's printed matrices (paper sec. 5),
independently of the laws and of the project's discretisation (scipy's expm, solve_ivp).

* ``ivp_flight``: the continuous 6-state plant integrated by solve_ivp over each control period with the surface
  held (ZOH at 100 Hz); the law is the test's own, a function of the samples returning (u, ode): ``ode(t, s)`` the
  law's continuous states over the period with its inputs held (integrated with the plant in the same solve_ivp).
* ``lockstep``: the law class flying the exact ZOH discretisation of the same plant (e^{A T} by scipy).
* ``product_flight``: the product's own lockstep flight of a registered law, in process
  (``tools.experiment.scenario.run_inprocess``: ``autopilot.step.ControlStep`` with the law's shipped design for the
  KH2013A, ``sitl``'s aircraft at 1 kHz physics, the fault as ``--fault`` flies it), still air, no sensor noise.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from sitl.model import A_P, B_P

T = 0.01
PHI, P, R = 3, 1, 2
N = 3000  # 30 s
SERVO = 4  # the deflection's column in A_P


def command(k: int) -> float:
    """The paper's +-10 deg square wave, period 10 s, + first."""
    return math.radians(10.0) if ((k * T) % 10.0) < 5.0 else -math.radians(10.0)


def plant(effectiveness=None, k: int = 0):
    """(A, B) of the KH2013A with the deflection's effect on the airframe scaled by effectiveness = (k_onset, f)
    from step k_onset on."""
    a = np.array(A_P, dtype=float)
    if effectiveness is not None and k >= effectiveness[0]:
        a[:4, SERVO] *= effectiveness[1]
    return a, np.array(B_P, dtype=float)[:, 0]


def zoh_exact(a, b):
    """(e^{A T}, int_0^T e^{A s} ds b) by the block exponential (scipy)."""
    n = a.shape[0]
    m = np.zeros((n + 1, n + 1))
    m[:n, :n], m[:n, n] = a, b
    e = expm(m * T)
    return e[:n, :n], e[:n, n]


def lockstep(law, n: int = N, effectiveness=None):
    """The law class's ``step`` flying the ZOH plant; (roll, surface) arrays."""
    x = np.zeros(6)
    phis, us = np.zeros(n), np.zeros(n)
    disc = {}
    for k in range(n):
        u = law.step(x[PHI], x[P], x[R], command(k))
        phis[k], us[k] = x[PHI], u
        key = effectiveness is not None and k >= effectiveness[0]
        if key not in disc:
            disc[key] = zoh_exact(*plant(effectiveness, k))
        ad, bd = disc[key]
        x = ad @ x + bd * u
    return phis, us


def ivp_flight(law_sample, law_state0, n: int = N, effectiveness=None):
    """Continuous plant + the test's own law.  ``law_sample(k, phi, p, r, cmd, s)`` -> (u, ode, s) where ``s`` is the
    law's state at the sample (possibly updated by the sample), ``ode(s) -> s'`` the law's continuous states'
    derivative over the period, inputs held.  Returns (roll, surface) arrays."""
    x = np.zeros(6)
    s = np.asarray(law_state0, dtype=float)
    m = s.size
    phis, us = np.zeros(n), np.zeros(n)
    for k in range(n):
        u, ode, s = law_sample(k, x[PHI], x[P], x[R], command(k), s)
        phis[k], us[k] = x[PHI], u
        a, b = plant(effectiveness, k)

        def rhs(_t, y, a=a, b=b, u=u, ode=ode):
            return np.concatenate([a @ y[:6] + b * u, ode(y[6:]) if m else []])

        sol = solve_ivp(rhs, (0.0, T), np.concatenate([x, s]), method="DOP853", rtol=1e-11, atol=1e-13)
        x, s = sol.y[:6, -1], sol.y[6:, -1]
    return phis, us


def late_error_deg(phis, ref) -> float:
    """max |phi - ref| over the last second of every 5 s half-period (deg)."""
    t = np.arange(len(phis)) * T
    late = (t % 5.0) >= 4.0
    return float(np.degrees(np.max(np.abs(phis - ref)[late])))


def reference(n: int = N, pole: float = 5.0) -> np.ndarray:
    """The paper's reference 5 / (s + 5) of the command, exact for the held command."""
    out, y, a = np.zeros(n), 0.0, math.exp(-pole * T)
    for k in range(n):
        out[k] = y
        y = a * y + (1 - a) * command(k)
    return out


def product_flight(controller: str, n: int = N, effectiveness=None):
    """The product's lockstep flight of ``controller`` on the KH2013A for n control steps, in process, with the
    effectiveness fault (k_onset, factor) flown as ``--fault effectiveness=F@T``: (roll, surface, the law's config as
    the product built it from its shipped design)."""
    from tools.experiment.scenario import Scenario, controller_config, run_inprocess, run_of

    faults = () if effectiveness is None else (f"effectiveness={effectiveness[1]!r}@{effectiveness[0] * T!r}",)
    sc = Scenario(duration_s=n * T, faults=faults)
    run = run_of(controller)
    series = run_inprocess(sc, run).series
    return series["phi"], series["u"], controller_config(sc, run)


CHECK_N, CHECK_FAULT = 1500, (1000, 0.3)  # the checks' flight: 15 s, the effectiveness at 0.3 from 10 s


def flown_against(controller: str, independent):
    """The check's two flights of ``controller``'s shipped design: (config, the independent loop's (roll, surface),
    the product's lockstep flight's), ``independent(config)`` giving ``ivp_flight``'s (law_sample, state0)."""
    phi, u, cfg = product_flight(controller, n=CHECK_N, effectiveness=CHECK_FAULT)
    return cfg, ivp_flight(*independent(cfg), n=CHECK_N, effectiveness=CHECK_FAULT), (phi, u)


def assert_agree(flight, independent, tol: float = 1e-7) -> None:
    """Roll and surface of two (roll, surface) flights within ``tol`` rad at every sample."""
    for a, b in zip(flight, independent, strict=True):
        assert np.max(np.abs(a - b)) < tol
