"""The paper's quadrotor model: translation per eq. 18, rotation per eq. 13.

State (eq. 22), the paper's frame with z **up** (x north, y east, z = -down):

    x = [x, x_dot, y, y_dot, z, z_dot, phi, phi_dot, theta, theta_dot, psi, psi_dot]

Inputs: the collective thrust ``u`` (N, eq. 9) and the generalised torques ``tau`` (N m, eq. 11),
which act on the Euler angles through eq. 13 with the true inertia. Translation ignores yaw
(eq. 18): the thrust direction does not turn with psi; that is the paper's model, exact only at
psi = 0, and the reason the rigid-body model exists.
"""

from __future__ import annotations

import numpy as np

from offboard.model.euler_lagrange import EulerRateForm, euler_acceleration

STATE_SIZE = 12
POSITION = [0, 2, 4]
VELOCITY = [1, 3, 5]
ANGLES = [6, 8, 10]
ANGLE_RATES = [7, 9, 11]


def translational_acceleration(angles: np.ndarray, thrust_n: float, mass_kg: float, gravity_m_s2: float) -> np.ndarray:
    """(x_ddot, y_ddot, z_ddot) of eq. 18, z up."""
    phi, theta = angles[0], angles[1]
    a = thrust_n / mass_kg
    return np.array(
        [
            -a * np.sin(theta),
            a * np.cos(theta) * np.sin(phi),
            a * np.cos(theta) * np.cos(phi) - gravity_m_s2,
        ]
    )


def derivative(
    x: np.ndarray,
    thrust_n: float,
    torque_nm: np.ndarray,
    mass_kg: float,
    inertia: np.ndarray,
    gravity_m_s2: float,
    form: EulerRateForm = EulerRateForm.CASTILLO,
) -> np.ndarray:
    """x_dot for the paper model (eq. 13 and 18): a pure function of state and inputs.

    Parameters
    ----------
    x : ndarray, shape (12,)
        State in the paper's order and frame (eq. 22).
    thrust_n : float
        u, newtons.
    torque_nm : ndarray, shape (3,)
        Generalised torques (tau_phi, tau_theta, tau_psi), N m.
    mass_kg, inertia, gravity_m_s2
        The true vehicle's m, I (3x3), g.
    form : EulerRateForm
        W_eta form, see ``euler_lagrange``.
    """
    xdot = np.empty(STATE_SIZE)
    eta = x[ANGLES]
    eta_dot = x[ANGLE_RATES]
    xdot[POSITION] = x[VELOCITY]
    xdot[VELOCITY] = translational_acceleration(eta, thrust_n, mass_kg, gravity_m_s2)
    xdot[ANGLES] = eta_dot
    xdot[ANGLE_RATES] = euler_acceleration(eta, eta_dot, np.asarray(torque_nm, dtype=float), inertia, form)
    return xdot
