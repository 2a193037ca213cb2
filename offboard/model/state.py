"""The vehicle state an autopilot reports, in NED/FRD."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class VehicleState:
    """The vehicle's state as an autopilot reports it: local NED position, FRD body.

    Attributes
    ----------
    time_s : float
        Simulation time.
    pos_ned_m, vel_ned_m_s, acc_ned_m_s2 : ndarray (3,)
        Kinematic position, velocity, acceleration (not specific force) in NED.
    euler_rad : ndarray (3,)
        (roll, pitch, yaw). For the rigid body: ZYX angles of the attitude. For the paper model:
        its generalised coordinates (phi, theta, psi).
    euler_rate_rad_s : ndarray (3,)
        Time derivatives of ``euler_rad``.
    body_rate_frd_rad_s : ndarray (3,)
        Body angular velocity (p, q, r) = W_eta @ euler rates (eq. 3).
    quat_wxyz : ndarray (4,)
        Attitude quaternion, body FRD to NED (from the ZYX angles for the paper model).
    motor_speeds_rad_s : ndarray (4,)
        Rotor speeds f1..f4 order (zeros for the paper model, which has no rotors).
    on_ground : bool
        Resting on the ground plane (down = 0).
    """

    time_s: float
    pos_ned_m: np.ndarray
    vel_ned_m_s: np.ndarray
    acc_ned_m_s2: np.ndarray
    euler_rad: np.ndarray
    euler_rate_rad_s: np.ndarray
    body_rate_frd_rad_s: np.ndarray
    quat_wxyz: np.ndarray
    motor_speeds_rad_s: np.ndarray = field(default_factory=lambda: np.zeros(4))
    on_ground: bool = False
