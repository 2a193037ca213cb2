"""The eq. 9-11 mixer: rotor forces of a collective thrust and body torques, and back (pure).

Rotors f1 right, f2 front, f3 left, f4 rear (the paper's Fig. 1, body FRD): ``u = f1 + f2 + f3 +
f4`` (eq. 9), ``tau_phi = (f3 - f1) l``, ``tau_theta = (f2 - f4) l``, ``tau_psi = c (f2 + f4 -
f1 - f3)`` (eq. 11). The rigid body (``sitl_plant.dynamics.rigid_body``) limits and squares them
into rotor speeds; the law (``offboard.controller.law``) reports them.
"""

from __future__ import annotations

import numpy as np


def rotor_forces(thrust_n: float, torque_nm: np.ndarray, arm_length_m: float, drag_to_thrust_m: float) -> np.ndarray:
    """Rotor forces f1..f4 that give ``u`` and ``tau`` exactly (eq. 9-11 inverted, no limits).

    ``u = f1 + f2 + f3 + f4`` (eq. 9), ``tau_phi = (f3 - f1) l``, ``tau_theta = (f2 - f4) l``,
    ``tau_psi = c (f2 + f4 - f1 - f3)`` (eq. 11), rotors f1 right, f2 front, f3 left, f4 rear.

    Parameters
    ----------
    thrust_n : float
        Collective thrust u, N.
    torque_nm : array_like, shape (3,)
        (tau_phi, tau_theta, tau_psi), N m, body FRD axes.
    arm_length_m : float
        l, rotor to centre of gravity.
    drag_to_thrust_m : float
        c, rotor reaction torque per newton of thrust.

    Returns
    -------
    ndarray, shape (4,)
        f1..f4, N. May be negative or exceed what the rotors can give.
    """
    quarter = 0.25 * thrust_n
    roll = 0.5 * torque_nm[0] / arm_length_m
    pitch = 0.5 * torque_nm[1] / arm_length_m
    yaw = 0.25 * torque_nm[2] / drag_to_thrust_m
    return np.array([quarter - roll - yaw, quarter + pitch + yaw, quarter + roll - yaw, quarter - pitch + yaw])


def thrust_torque_from_rotor_forces(
    forces_n: np.ndarray, arm_length_m: float, drag_to_thrust_m: float
) -> tuple[float, np.ndarray]:
    """Collective thrust and body torques of rotor forces f1..f4 (eq. 9-11).

    Returns
    -------
    thrust_n : float
        u = sum f_i (eq. 9).
    torque_nm : ndarray, shape (3,)
        ((f3 - f1) l, (f2 - f4) l, c (f2 + f4 - f1 - f3)) (eq. 11), body FRD.
    """
    f1, f2, f3, f4 = (float(f) for f in forces_n)
    return f1 + f2 + f3 + f4, np.array(
        [(f3 - f1) * arm_length_m, (f2 - f4) * arm_length_m, drag_to_thrust_m * (f2 + f4 - f1 - f3)]
    )
