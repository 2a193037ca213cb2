"""The one place where MAVLink's NED/FRD meets the paper's frame.

The paper's frame (eq. 18, NOTES.md): x north, y east, z **up**; its angles (phi, theta, psi) are
FRD roll, pitch and yaw. So, at psi = 0, positive pitch accelerates towards -x (south) and
positive roll towards +y (east), as in NED/FRD. Body rates (p, q, r) and Euler-angle rates are
related by ``omega = W_eta @ eta_dot`` (eq. 3) with the W_eta form the controller believes in.
"""

from __future__ import annotations

import numpy as np

from offboard.controller.law import TrackingReference
from offboard.trajectory.base import Reference
from sitl_plant.dynamics.euler_lagrange import euler_rate_matrix


def paper_position_from_ned(pos_ned_m: np.ndarray) -> np.ndarray:
    """(x, y, z_up) from (north, east, down)."""
    return np.array([pos_ned_m[0], pos_ned_m[1], -pos_ned_m[2]])


def ned_from_paper_position(xyz_up_m: np.ndarray) -> np.ndarray:
    """(north, east, down) from the paper's (x, y, z_up)."""
    return np.array([xyz_up_m[0], xyz_up_m[1], -xyz_up_m[2]])


def euler_rates_from_body_rates(euler_rad: np.ndarray, body_rate_frd_rad_s: np.ndarray, form: str) -> np.ndarray:
    """eta_dot = W_eta^-1 omega (eq. 3)."""
    return np.linalg.solve(euler_rate_matrix(np.asarray(euler_rad, dtype=float), form), body_rate_frd_rad_s)


def body_rates_from_euler_rates(euler_rad: np.ndarray, euler_rate_rad_s: np.ndarray, form: str) -> np.ndarray:
    """omega = W_eta eta_dot (eq. 3)."""
    return euler_rate_matrix(np.asarray(euler_rad, dtype=float), form) @ np.asarray(euler_rate_rad_s, dtype=float)


def paper_state(
    pos_ned_m: np.ndarray, vel_ned_m_s: np.ndarray, euler_rad: np.ndarray, euler_rate_rad_s: np.ndarray
) -> tuple[float, ...]:
    """The 12-state of eq. 22 (paper frame) from NED position/velocity and Euler angles/rates."""
    n, e, d = (float(v) for v in pos_ned_m)
    vn, ve, vd = (float(v) for v in vel_ned_m_s)
    phi, theta, psi = (float(v) for v in euler_rad)
    dphi, dtheta, dpsi = (float(v) for v in euler_rate_rad_s)
    return (n, vn, e, ve, -d, -vd, phi, dphi, theta, dtheta, psi, dpsi)


def tracking_reference(reference: Reference) -> TrackingReference:
    """(x1d, x3d, x5d, x11d) in the paper's frame from a NED reference."""
    n, e, d = reference.pos_ned_m
    return TrackingReference(float(n), float(e), float(-d), reference.yaw_rad)
