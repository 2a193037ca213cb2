"""Attitude on tuples, for the hot paths (PX4's ControlMath and matrix library, in miniature).

Quaternions are (w, x, y, z), body FRD to NED; 3-vectors are tuples (numpy costs more than the
arithmetic at this size). The plant's PX4 inner loops (``sitl_plant.inner_loops``) and the PX4
cascade baseline (``offboard.baselines.px4``) share them; ``offboard.model.rotations`` has the
numpy forms.
"""

from __future__ import annotations

import math

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]



def qmul(a: Quat, b: Quat) -> Quat:
    """The Hamilton product ``a b`` (``b`` applied first)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def qinv(q: Quat) -> Quat:
    """The inverse of a unit quaternion: its conjugate."""
    return (q[0], -q[1], -q[2], -q[3])


def qnormalize(q: Quat) -> Quat:
    """``q`` scaled to unit norm."""
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def dcm_z(q: Quat) -> Vec3:
    """Third column of R(q): the body z axis in NED."""
    w, x, y, z = q
    return (2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y))


def quat_between(src: Vec3, dst: Vec3) -> Quat:
    """Shortest rotation taking unit vector ``src`` to ``dst`` (PX4 ``Quaternion(src, dst)``)."""
    cx = src[1] * dst[2] - src[2] * dst[1]
    cy = src[2] * dst[0] - src[0] * dst[2]
    cz = src[0] * dst[1] - src[1] * dst[0]
    dot = src[0] * dst[0] + src[1] * dst[1] + src[2] * dst[2]
    if math.sqrt(cx * cx + cy * cy + cz * cz) < 1e-5 and dot < 0:
        a = [abs(v) for v in src]
        axis = (1.0, 0.0, 0.0) if a[0] < a[1] and a[0] < a[2] else ((0.0, 1.0, 0.0) if a[1] < a[2] else (0.0, 0.0, 1.0))
        cx = src[1] * axis[2] - src[2] * axis[1]
        cy = src[2] * axis[0] - src[0] * axis[2]
        cz = src[0] * axis[1] - src[1] * axis[0]
        return qnormalize((0.0, cx, cy, cz))
    return qnormalize((dot + 1.0, cx, cy, cz))


def quat_from_dcm(r: list[list[float]]) -> Quat:
    """The unit quaternion of a rotation matrix (rows of ``r``), by the largest of its diagonal terms
    (Shepperd's method, as PX4's matrix library).
    """
    tr = r[0][0] + r[1][1] + r[2][2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2.0
        return (0.25 * s, (r[2][1] - r[1][2]) / s, (r[0][2] - r[2][0]) / s, (r[1][0] - r[0][1]) / s)
    if r[0][0] > r[1][1] and r[0][0] > r[2][2]:
        s = math.sqrt(1.0 + r[0][0] - r[1][1] - r[2][2]) * 2.0
        return ((r[2][1] - r[1][2]) / s, 0.25 * s, (r[0][1] + r[1][0]) / s, (r[0][2] + r[2][0]) / s)
    if r[1][1] > r[2][2]:
        s = math.sqrt(1.0 + r[1][1] - r[0][0] - r[2][2]) * 2.0
        return ((r[0][2] - r[2][0]) / s, (r[0][1] + r[1][0]) / s, 0.25 * s, (r[1][2] + r[2][1]) / s)
    s = math.sqrt(1.0 + r[2][2] - r[0][0] - r[1][1]) * 2.0
    return ((r[1][0] - r[0][1]) / s, (r[0][2] + r[2][0]) / s, (r[1][2] + r[2][1]) / s, 0.25 * s)


def quat_from_euler(roll: float, pitch: float, yaw: float) -> Quat:
    """The quaternion of ZYX Euler angles (rad): ``Rz(yaw) Ry(pitch) Rx(roll)``, body FRD to NED."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def bodyz_to_attitude(body_z: Vec3, yaw_rad: float) -> Quat:
    """Attitude whose body z axis is ``body_z`` (unit, NED) with heading ``yaw_rad`` (PX4 ControlMath)."""
    y_c = (-math.sin(yaw_rad), math.cos(yaw_rad), 0.0)
    bx = (y_c[1] * body_z[2] - y_c[2] * body_z[1], y_c[2] * body_z[0] - y_c[0] * body_z[2], y_c[0] * body_z[1] - y_c[1] * body_z[0])
    if body_z[2] < 0.0:
        bx = (-bx[0], -bx[1], -bx[2])
    if abs(body_z[2]) < 1e-6:
        bx = (0.0, 0.0, 1.0)
    n = math.sqrt(bx[0] ** 2 + bx[1] ** 2 + bx[2] ** 2)
    bx = (bx[0] / n, bx[1] / n, bx[2] / n)
    by = (body_z[1] * bx[2] - body_z[2] * bx[1], body_z[2] * bx[0] - body_z[0] * bx[2], body_z[0] * bx[1] - body_z[1] * bx[0])
    r = [[bx[0], by[0], body_z[0]], [bx[1], by[1], body_z[1]], [bx[2], by[2], body_z[2]]]
    return qnormalize(quat_from_dcm(r))
