"""KH2013A lateral model and rudder servo, as printed in the paper (Jana & Bhat 2017, section 5).

Pure data and plain functions, no I/O.  States of the augmented plant (paper section 5):

    x_p = [v, p, r, phi, delta_r, delta_r_dot]      (m/s, rad/s, rad/s, rad, rad, rad/s)
    u_p = delta_command                              (rad)
    y_p = phi                                        (rad)
"""

from __future__ import annotations

import numpy as np

STATE_NAMES = ("v", "p", "r", "phi", "delta_r", "delta_r_dot")
PHI = 3  # index of the roll angle in x_p
P = 1  # index of the roll rate
R = 2  # index of the yaw rate
DELTA_R = 4
DELTA_R_DOT = 5

# Lateral model of the 150 mm KH2013A MAV, states [v, p, r, phi], input delta_r (paper section 5, A_lp, B_lp, C_lp).
A_LP = np.array(
    [
        [-3.34, 1.93, -7.55, 7.82],
        [-40.5, -2.22, 2.48, 0.0],
        [234.0, -2.84, -27.0, 0.0],
        [0.0, 1.0, 0.268, 0.0],
    ]
)
B_LP = np.array([[-8.41], [59.7], [793.0], [0.0]])
C_LP = np.array([[0.0, 0.0, 0.0, 1.0]])

# Rudder servo (paper sec. 5.1, eq. (65)): delta_r'' = -wn^2 delta_r - 2 zeta wn delta_r' + wn^2 delta_command.
SERVO_WN2 = 2367.0
SERVO_2ZETA_WN = 72.22


def servo_matrices() -> tuple[np.ndarray, np.ndarray]:
    """State-space (A_s, B_s) of the rudder servo, states [delta_r, delta_r_dot] (paper sec. 5.1, eq. (65))."""
    a_s = np.array([[0.0, 1.0], [-SERVO_WN2, -SERVO_2ZETA_WN]])
    b_s = np.array([[0.0], [SERVO_WN2]])
    return a_s, b_s


def augmented_matrices() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Build the 6-state plant (A_p, B_p, C_p) from (A_lp, B_lp) and the servo (paper section 5).

    The servo's delta_r drives the airframe through B_lp; the servo command is the plant input.
    """
    a_s, b_s = servo_matrices()
    a_p = np.zeros((6, 6))
    a_p[:4, :4] = A_LP
    a_p[:4, 4:5] = B_LP
    a_p[4:, 4:] = a_s
    b_p = np.zeros((6, 1))
    b_p[4:, :] = b_s
    c_p = np.hstack([C_LP, np.zeros((1, 2))])
    return a_p, b_p, c_p


A_P, B_P, C_P = augmented_matrices()
for _m in (A_LP, B_LP, C_LP, A_P, B_P, C_P):
    _m.setflags(write=False)

# The matrices as printed in the paper (section 5), kept verbatim for tests that check the construction above.
A_P_PRINTED = (
    (-3.34, 1.93, -7.55, 7.82, -8.41, 0),
    (-40.5, -2.22, 2.48, 0.0, 59.7, 0),
    (234.0, -2.84, -27.0, 0.0, 793.0, 0),
    (0.0, 1.0, 0.268, 0.0, 0, 0),
    (0.0, 0, 0, 0.0, 0, 1),
    (0.0, 0, 0, 0.0, -2367, -72.22),
)
B_P_PRINTED = (0, 0, 0, 0, 0, 2367)
C_P_PRINTED = (0, 0, 0, 1, 0, 0)


def plant_rhs(t: float, x: np.ndarray, u: np.ndarray | float, params: dict | None = None) -> np.ndarray:  # noqa: ARG001
    """Continuous-time dynamics x_p' = A_p x_p + B_p u_p (paper eq. (1)), python-control's (t, x, u, params) form.

    ``params`` may hold ``A``/``B`` to fly a perturbed airframe; by default the paper's matrices.
    """
    params = params or {}
    a = params.get("A", A_P)
    b = params.get("B", B_P)
    return a @ np.asarray(x, dtype=float) + (b * np.asarray(u, dtype=float).reshape(1, -1)).sum(axis=1)
