"""The one place where MAVLink's NED/FRD meets the paper's frame.

The paper's frame (eq. 18; docs/model.md, "Frames and conventions"): x north, y east, z **up**; its angles (phi, theta, psi) are
FRD roll, pitch and yaw. So, at psi = 0, positive pitch accelerates towards -x (south) and
positive roll towards +y (east), as in NED/FRD. Body rates (p, q, r) and Euler-angle rates are
related by ``omega = W_eta @ eta_dot`` (eq. 3) with the W_eta form the controller believes in.
"""

from __future__ import annotations

import math

import numpy as np

from offboard.controller.law import TrackingReference
from offboard.trajectory.base import Reference
from offboard.model.rotations import quat_from_euler
from offboard.model.vehicle import VehicleModel


def paper_position_from_ned(pos_ned_m: np.ndarray) -> np.ndarray:
    """(x, y, z_up) from (north, east, down)."""
    return np.array([pos_ned_m[0], pos_ned_m[1], -pos_ned_m[2]])


def ned_from_paper_position(xyz_up_m: np.ndarray) -> np.ndarray:
    """(north, east, down) from the paper's (x, y, z_up)."""
    return np.array([xyz_up_m[0], xyz_up_m[1], -xyz_up_m[2]])


def floats3(values: np.ndarray | tuple[float, ...] | list[float]) -> tuple[float, float, float]:
    """Three Python floats of a 3-vector (``tolist`` is the cheap way out of a float array, per sample)."""
    out = np.asarray(values, dtype=float).tolist()
    if len(out) != 3:
        raise ValueError(f"expected 3 components, got {len(out)}")
    return out[0], out[1], out[2]


def paper_state(
    pos_ned_m: np.ndarray, vel_ned_m_s: np.ndarray, euler_rad: np.ndarray, euler_rate_rad_s: np.ndarray
) -> tuple[float, ...]:
    """The 12-state of eq. 22 (paper frame) from NED position/velocity and Euler angles/rates."""
    n, e, d = floats3(pos_ned_m)
    vn, ve, vd = floats3(vel_ned_m_s)
    phi, theta, psi = floats3(euler_rad)
    dphi, dtheta, dpsi = floats3(euler_rate_rad_s)
    return (n, vn, e, ve, -d, -vd, phi, dphi, theta, dtheta, psi, dpsi)


def tracking_reference(reference: Reference, lead_s2: tuple[float, float] = (0.0, 0.0)) -> TrackingReference:
    """(x1d, x3d, x5d, x11d) in the paper's frame from a NED reference.

    ``lead_s2`` = (horizontal, vertical) c2 of ``[law] reference_lead_s2``: the position handed
    to the law is ``r - c2 r''`` with the reference's own acceleration (docs/controller-design.md);
    (0, 0), the paper's law, hands ``r`` itself.
    """
    n, e, d = reference.pos_ned_m
    ch, cv = lead_s2
    if ch or cv:
        an, ae, ad = reference.acc_ned_m_s2
        n, e, d = n - ch * an, e - ch * ae, d - cv * ad
    return TrackingReference(float(n), float(e), float(-d), reference.yaw_rad, reference.yaw_rate_rad_s)


def tilt_about_heading(roll_rad: float, pitch_rad: float, heading_from_rad: float, heading_to_rad: float) -> tuple[float, float]:
    """(roll, pitch) that give, at heading ``heading_to``, the thrust axis that (roll, pitch) give
    at heading ``heading_from`` (ZYX angles, rigid body: the thrust axis is body z).

    The body z axis of ``Rz(h) Ry(pitch) Rx(roll)`` is ``Rz(h) (cos r sin p, -sin r, cos r cos p)``;
    the angles are solved for the same axis under ``Rz(heading_to)``. Identity when the headings
    are equal.
    """
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    d = heading_from_rad - heading_to_rad
    cd, sd = math.cos(d), math.sin(d)
    vx0, vy0, vz = cr * sp, -sr, cr * cp  # body z at heading 0
    vx, vy = cd * vx0 - sd * vy0, sd * vx0 + cd * vy0  # ... turned by heading_from - heading_to
    return math.atan2(-vy, math.hypot(vx, vz)), math.atan2(vx, vz)


def setpoint_attitude(
    roll_ref_rad: float, pitch_ref_rad: float, yaw_ref_rad: float, law_heading_rad: float, model: VehicleModel
) -> np.ndarray:
    """The setpoint quaternion (w, x, y, z) for the law's angle references.

    The law computes x7ez and x9ez about a heading: the measured yaw with the yaw-aware option, 0
    without (eq. 18 ignores yaw). On a rigid body, whose thrust turns with yaw, the setpoint keeps
    that thrust axis and asks for the heading ``yaw_ref`` (PX4 tracks the thrust axis first and the
    heading after), so a large yaw step does not swing the thrust round with the reference. On the
    paper's model the thrust direction depends on (phi, theta) only (eq. 18): the plain ZYX
    quaternion of (x7ez, x9ez, yaw_ref).
    """
    roll, pitch = roll_ref_rad, pitch_ref_rad
    if model == VehicleModel.RIGID_BODY:
        roll, pitch = tilt_about_heading(roll_ref_rad, pitch_ref_rad, law_heading_rad, yaw_ref_rad)
    return quat_from_euler(roll, pitch, yaw_ref_rad)
