"""The geometric tracking controller on SE(3) (Lee, Leok, McClamroch, CDC 2010), NED/FRD.

Lee et al. write the quadrotor with the inertial and body z axes pointing **down** and the thrust
along ``-b3``: exactly MAVLink's NED/FRD, so their equations are used as printed. With the
position and velocity errors ``e_x = x - x_d``, ``e_v = v - v_d`` (NED)::

    F      = m (-K_x e_x - K_v e_v + a_d - g e3)      the force the thrust must give (NED)
    f      = -F . R e3                                collective thrust, N            (Lee eq. 15)
    b3_d   = -F / |F|,  b1_c = (cos psi_d, sin psi_d, 0)
    b2_d   = b3_d x b1_c / |b3_d x b1_c|,  b1_d = b2_d x b3_d,  R_d = [b1_d b2_d b3_d]
    e_R    = 1/2 vee(R_d^T R - R^T R_d),   e_W = W - W_d
    M      = J (-k_R e_R - k_W e_W) + W x J W                                      (Lee eq. 16)

As in RotorPy's ``SE3Control`` (``rotorpy/controllers/quadrotor_control.py``), the attitude
gains are scaled by the inertia (``J k_R``, ``J k_W``), the desired body rate is
``W_d = (0, 0, psi_d_dot)`` and the terms of Lee's eq. 16 in ``W_d_dot`` are left out. The gains
default to RotorPy's for its 0.5 kg Hummingbird, whose mass and inertia are within 4 % of the
paper's vehicle. ``tests/unit/offboard/test_baselines.py`` checks this module against ``SE3Control`` itself
through the NED/FRD <-> ENU/FLU conversion when RotorPy is installed.

Added for a real airframe (the same limits the other controllers get): the tilt of ``b3_d``
is bounded (``tilt_max_rad``) and the thrust clipped to ``[thrust_min_n, thrust_max_n]``.

The outer part (``step``: F, R_d, W_d) runs once per control sample; the attitude law
(``torque``) is meant to run at the physics rate with the latest target, as a flight
controller's attitude loop runs faster than its position loop.
"""

from __future__ import annotations

from collections.abc import Sequence

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from offboard.controller.command import Command, StateEstimate
from offboard.trajectory.base import Reference
from offboard.model.rotations import euler_from_quat

if TYPE_CHECKING:  # the simulator's side of SE3Actuation: offboard fly never loads it
    from sitl_plant.simulation import Model

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class AttitudeTarget:
    """What a position controller hands its attitude loop for one sample.

    Attributes
    ----------
    thrust_n : float
        Collective thrust along body -z, N (at the attitude of the measured state).
    quat_wxyz : tuple of 4 floats
        Desired attitude, body FRD -> NED.
    body_rate_frd_rad_s : tuple of 3 floats
        Desired body rates (feed-forward), FRD.
    force_ned_n : tuple of 3 floats
        The thrust vector wanted, NED, N (``f = -F . R e3`` at any attitude R).
    """

    thrust_n: float
    quat_wxyz: tuple[float, float, float, float]
    body_rate_frd_rad_s: Vec3
    force_ned_n: Vec3

    @property
    def yaw_rate_ff_rad_s(self) -> float:
        """The yaw-rate feed-forward that goes with the attitude: the desired body rate about z, rad/s."""
        return self.body_rate_frd_rad_s[2]

    def command(self, torque_nm: Vec3 | None = None) -> Command:
        """This target as the controller interface's ``Command`` (the attitude form, and a torque
        when the controller computes one)."""
        roll, pitch, yaw = (float(v) for v in euler_from_quat(np.array(self.quat_wxyz)))
        return Command(
            thrust_n=self.thrust_n,
            attitude_wxyz=self.quat_wxyz,
            yaw_rate_ff_rad_s=self.yaw_rate_ff_rad_s,
            attitude_ref_euler_rad=(roll, pitch, yaw),
            torque_nm=torque_nm,
        )


@dataclass(frozen=True)
class SE3Gains:
    """Gains of the SE(3) controller (RotorPy's ``SE3Control`` defaults with Hummingbird's).

    Attributes
    ----------
    kx : position gain per NED axis, 1/s^2 (RotorPy kp_pos, x y z).
    kv : velocity gain per NED axis, 1/s (RotorPy kd_pos).
    k_r : attitude gain, 1/s^2 (RotorPy kp_att, times the inertia).
    k_w : body-rate gain, 1/s (RotorPy kd_att, times the inertia).
    """

    kx: Vec3 = (6.5, 6.5, 15.0)
    kv: Vec3 = (4.0, 4.0, 9.0)
    k_r: float = 544.0
    k_w: float = 46.64

    def __post_init__(self) -> None:
        if min(*self.kx, *self.kv, self.k_r, self.k_w) <= 0:
            raise ValueError("SE(3) gains must be > 0")


def _quat_from_matrix(r: tuple[Vec3, Vec3, Vec3]) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a rotation matrix given by rows (Shepperd's method), w >= 0."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = r
    tr = r00 + r11 + r22
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = (0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s)
    elif r00 > r11 and r00 > r22:
        s = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        q = ((r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s)
    elif r11 > r22:
        s = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)
        q = ((r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)
        q = ((r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s)
    return q if q[0] >= 0.0 else (-q[0], -q[1], -q[2], -q[3])


def _matrix(q: Sequence[float] | np.ndarray) -> tuple[Vec3, Vec3, Vec3]:
    """Rows of R(q), ``v_ned = R v_frd``, for a unit (w, x, y, z)."""
    w, x, y, z = (float(v) for v in q)
    return (
        (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)),
        (2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)),
        (2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)),
    )


class SE3Controller:
    """Lee et al.'s geometric controller: ``step`` at the control rate, ``torque`` at the physics rate.

    Parameters
    ----------
    mass_kg : float
        Mass the controller believes.
    inertia_kg_m2 : (Ixx, Iyy, Izz)
        Inertia it believes, body FRD principal axes.
    gains : SE3Gains
    gravity_m_s2 : float
    thrust_min_n, thrust_max_n : float or None
        Bounds on the collective thrust.
    tilt_max_rad : float or None
        Bound on the angle between ``b3_d`` and the vertical.
    sample_time_s : float
        The control period of ``step`` (the paper's To by default).

    As a ``Controller`` (``step(state, ref_n, ref_n1) -> Command``) it gives the attitude target
    R_d with thrust f and the feed-forward psi_d_dot, and Lee's moment M at the measured attitude
    as the torque command; ``actuation()`` flies M at the physics rate instead.
    """

    name = "se3"

    def __init__(
        self,
        mass_kg: float,
        inertia_kg_m2: Vec3,
        gains: SE3Gains | None = None,
        *,
        gravity_m_s2: float = 9.81,
        thrust_min_n: float | None = None,
        thrust_max_n: float | None = None,
        tilt_max_rad: float | None = None,
        sample_time_s: float = 0.05,
    ) -> None:
        if mass_kg <= 0 or min(inertia_kg_m2) <= 0:
            raise ValueError("mass and inertia must be > 0")
        if tilt_max_rad is not None and not 0.0 < tilt_max_rad < math.pi / 2:
            raise ValueError(f"tilt_max_rad must lie in (0, pi/2), got {tilt_max_rad}")
        self.mass_kg = float(mass_kg)
        self.inertia = tuple(float(v) for v in inertia_kg_m2)
        self.gains = gains or SE3Gains()
        self.gravity_m_s2 = gravity_m_s2
        self.thrust_min_n = thrust_min_n
        self.thrust_max_n = thrust_max_n
        self.tilt_max_rad = tilt_max_rad
        self.sample_time_s = float(sample_time_s)
        self.last_target: AttitudeTarget | None = None

    def reset(self) -> None:
        """The controller keeps no memory between samples but its last target."""
        self.last_target = None

    def step(self, state: StateEstimate, ref_n: Reference, ref_n1: Reference) -> Command:
        """The ``Controller`` step: ``target`` and Lee's moment at the measured attitude."""
        target = self.target(state, ref_n)
        _, torque = self.thrust_and_torque(state.quat_wxyz, state.body_rate_frd_rad_s, target)
        return target.command(torque)

    def _clip_thrust(self, thrust_n: float) -> float:
        if self.thrust_min_n is not None:
            thrust_n = max(thrust_n, self.thrust_min_n)
        if self.thrust_max_n is not None:
            thrust_n = min(thrust_n, self.thrust_max_n)
        return thrust_n

    def target(self, state: StateEstimate, reference: Reference) -> AttitudeTarget:
        """F, R_d and W_d for the measured state (NED/FRD) and the reference (Lee eq. 15)."""
        g = self.gains
        m = self.mass_kg
        p, v = state.pos_ned_m, state.vel_ned_m_s
        rp, rv, ra = reference.pos_ned_m, reference.vel_ned_m_s, reference.acc_ned_m_s2
        f = [
            m * (-g.kx[i] * (float(p[i]) - float(rp[i])) - g.kv[i] * (float(v[i]) - float(rv[i])) + float(ra[i]))
            for i in range(3)
        ]
        f[2] -= m * self.gravity_m_s2  # - m g e3 (e3 points down)
        if self.tilt_max_rad is not None:  # a real airframe: -F within the tilt cone, at least g/10 up
            up = max(-f[2], 0.1 * m * self.gravity_m_s2)
            f[2] = -up
            horiz = math.hypot(f[0], f[1])
            limit = up * math.tan(self.tilt_max_rad)
            if horiz > limit:
                f[0], f[1] = f[0] * limit / horiz, f[1] * limit / horiz
        norm = math.sqrt(f[0] ** 2 + f[1] ** 2 + f[2] ** 2)
        b3 = (-f[0] / norm, -f[1] / norm, -f[2] / norm)
        yaw = reference.yaw_rad
        c1 = (math.cos(yaw), math.sin(yaw), 0.0)
        b2 = (b3[1] * c1[2] - b3[2] * c1[1], b3[2] * c1[0] - b3[0] * c1[2], b3[0] * c1[1] - b3[1] * c1[0])
        n2 = math.sqrt(b2[0] ** 2 + b2[1] ** 2 + b2[2] ** 2)
        b2 = (b2[0] / n2, b2[1] / n2, b2[2] / n2)
        b1 = (b2[1] * b3[2] - b2[2] * b3[1], b2[2] * b3[0] - b2[0] * b3[2], b2[0] * b3[1] - b2[1] * b3[0])
        r_d = ((b1[0], b2[0], b3[0]), (b1[1], b2[1], b3[1]), (b1[2], b2[2], b3[2]))
        r = _matrix(state.quat_wxyz)
        thrust = -(f[0] * r[0][2] + f[1] * r[1][2] + f[2] * r[2][2])  # f = -F . R e3
        self.last_target = AttitudeTarget(
            thrust_n=self._clip_thrust(thrust),
            quat_wxyz=_quat_from_matrix(r_d),
            body_rate_frd_rad_s=(0.0, 0.0, float(reference.yaw_rate_rad_s)),
            force_ned_n=(f[0], f[1], f[2]),
        )
        return self.last_target

    def thrust_and_torque(
        self, quat_wxyz: np.ndarray | tuple[float, ...], body_rate_frd_rad_s: np.ndarray | tuple[float, ...],
        target: AttitudeTarget,
    ) -> tuple[float, Vec3]:  # fmt: skip
        """Collective thrust ``-F . R e3`` (N) and Lee's moment (N m, FRD) at attitude ``quat_wxyz``."""
        g = self.gains
        r = _matrix(quat_wxyz)
        rd = _matrix(target.quat_wxyz)
        f = target.force_ned_n
        thrust = self._clip_thrust(-(f[0] * r[0][2] + f[1] * r[1][2] + f[2] * r[2][2]))
        # e_R = 1/2 vee(R_d^T R - R^T R_d): with A = R_d^T R, vee(A - A^T) / 2
        a = [[sum(rd[k][i] * r[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
        e_r = (0.5 * (a[2][1] - a[1][2]), 0.5 * (a[0][2] - a[2][0]), 0.5 * (a[1][0] - a[0][1]))
        w = tuple(float(v) for v in body_rate_frd_rad_s)
        wd = target.body_rate_frd_rad_s
        ix, iy, iz = self.inertia
        jw = (ix * w[0], iy * w[1], iz * w[2])
        w_x_jw = (w[1] * jw[2] - w[2] * jw[1], w[2] * jw[0] - w[0] * jw[2], w[0] * jw[1] - w[1] * jw[0])
        torque = tuple(
            inertia * (-g.k_r * e_r[i] - g.k_w * (w[i] - wd[i])) + w_x_jw[i]
            for i, inertia in enumerate(self.inertia)
        )
        return thrust, torque  # type: ignore[return-value]

    def actuation(self, target: AttitudeTarget | None = None) -> SE3Actuation:
        """A ``VehicleSim`` actuation running this attitude law at every physics step (rigid body)."""
        return SE3Actuation(self, target if target is not None else self.last_target)


class SE3Actuation:
    """``(model, x) -> (thrust, body torque)`` for ``VehicleSim`` with a ``RigidBodyModel``."""

    def __init__(self, controller: SE3Controller, target: AttitudeTarget | None) -> None:
        if target is None:
            raise ValueError("no target: call SE3Controller.step or .target first")
        self.controller = controller
        self.target = target

    def __call__(self, model: Model, x: np.ndarray) -> tuple[float, np.ndarray]:
        q = x[6:10]
        q = q / math.sqrt(float(q @ q))
        thrust, torque = self.controller.thrust_and_torque(q, x[10:13], self.target)
        return thrust, np.array(torque)
