"""PX4's multicopter position controller (``mc_pos_control``, ``PositionControl.cpp``), NED.

The cascade PX4 flies in offboard position mode with velocity and acceleration feed-forward
(PX4 v1.14 ``PositionControl::_positionControl``, ``_velocityControl``,
``_accelerationControl``; parameter defaults of ``mc_pos_control_params.c``)::

    v_sp  = K_p (x_d - x) + v_d                     P on position, speeds limited (MPC_*_VEL_MAX)
    a_sp  = K_v (v_sp - v) + i + K_d d(v_sp - v)/dt + a_d        PID on velocity
    i    += K_i (v_sp - v) dt                        (frozen while the thrust saturates)
    body_z = normalize(-a_sp_n, -a_sp_e, g)          tilt limited to MPC_TILTMAX_AIR
    T     = m_hat (g - a_sp_d) / body_z_d            collective thrust, N, clipped

and the attitude setpoint is the attitude whose body z axis is ``body_z`` with the reference's
heading (``ControlMath::bodyzToAttitude``, shared with the plant:
``offboard.model.attitude.bodyz_to_attitude``), with the reference's yaw rate as feed-forward.
PX4 works in normalised thrust with a hover-thrust estimate; here ``m_hat g`` is that hover
thrust in newtons, so a wrong believed mass is a wrong hover thrust, as on a real vehicle.

PX4 then flies the attitude setpoint with ``mc_att_control`` and ``mc_rate_control``; in this
repository that is ``sitl_plant.inner_loops.Px4Loop.fly_attitude`` (the plant's ``px4`` inner
loop), so the baseline needs no attitude loop of its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from offboard.baselines.se3 import AttitudeTarget
from offboard.controller.command import Command, StateEstimate
from offboard.trajectory.base import Reference
from offboard.model.attitude import bodyz_to_attitude

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Px4Gains:
    """PX4 parameters of the position and velocity loops (defaults: PX4 v1.14)."""

    xy_p: float = 0.95  # MPC_XY_P, 1/s
    z_p: float = 1.0  # MPC_Z_P, 1/s
    xy_vel_p: float = 1.8  # MPC_XY_VEL_P_ACC, 1/s
    xy_vel_i: float = 0.4  # MPC_XY_VEL_I_ACC, 1/s^2
    xy_vel_d: float = 0.2  # MPC_XY_VEL_D_ACC, 1
    z_vel_p: float = 4.0  # MPC_Z_VEL_P_ACC, 1/s
    z_vel_i: float = 2.0  # MPC_Z_VEL_I_ACC, 1/s^2
    z_vel_d: float = 0.0  # MPC_Z_VEL_D_ACC, 1
    xy_vel_max_m_s: float = 12.0  # MPC_XY_VEL_MAX
    z_vel_max_up_m_s: float = 3.0  # MPC_Z_VEL_MAX_UP
    z_vel_max_dn_m_s: float = 1.5  # MPC_Z_VEL_MAX_DN
    tilt_max_rad: float = math.radians(45.0)  # MPC_TILTMAX_AIR

    def __post_init__(self) -> None:
        if min(self.xy_p, self.z_p, self.xy_vel_p, self.z_vel_p) <= 0:
            raise ValueError("P gains must be > 0")
        if min(self.xy_vel_i, self.z_vel_i, self.xy_vel_d, self.z_vel_d) < 0:
            raise ValueError("I and D gains must be >= 0")
        if not 0.0 < self.tilt_max_rad < math.pi / 2:
            raise ValueError(f"tilt_max_rad must lie in (0, pi/2), got {self.tilt_max_rad}")


class Px4PositionController:
    """P position / PID velocity / thrust vector, once per control sample (``step``).

    Parameters
    ----------
    mass_kg : float
        Mass the controller believes (its hover thrust is ``mass_kg * g``).
    sample_time_s : float
        The sample time of ``step`` (for the integral and the derivative).
    gains : Px4Gains
    thrust_min_n, thrust_max_n : float
        Collective thrust range, N.

    As a ``Controller`` (``step(state, ref_n, ref_n1) -> Command``) it gives the attitude setpoint,
    thrust and yaw-rate feed-forward only: PX4's attitude and rate controllers fly the rest.
    """

    name = "px4"

    def __init__(
        self,
        mass_kg: float,
        sample_time_s: float,
        gains: Px4Gains | None = None,
        *,
        gravity_m_s2: float = 9.81,
        thrust_min_n: float = 0.0,
        thrust_max_n: float = math.inf,
    ) -> None:
        if mass_kg <= 0 or sample_time_s <= 0:
            raise ValueError("mass and sample time must be > 0")
        if not thrust_min_n < thrust_max_n:
            raise ValueError("thrust_min_n must be below thrust_max_n")
        self.mass_kg = float(mass_kg)
        self.dt = float(sample_time_s)
        self.sample_time_s = self.dt
        self.gains = gains or Px4Gains()
        self.gravity_m_s2 = gravity_m_s2
        self.thrust_min_n = thrust_min_n
        self.thrust_max_n = thrust_max_n
        self.reset()

    def reset(self) -> None:
        """Zero the velocity integral and forget the previous velocity error."""
        self._int = [0.0, 0.0, 0.0]
        self._prev_err: list[float] | None = None

    def step(self, state: StateEstimate, ref_n: Reference, ref_n1: Reference) -> Command:
        """The ``Controller`` step: ``target``'s attitude setpoint, thrust and yaw feed-forward."""
        return self.target(state, ref_n).command()

    def target(self, state: StateEstimate, reference: Reference) -> AttitudeTarget:
        """The attitude setpoint and thrust for the measured state (NED) and the reference."""
        k = self.gains
        g = self.gravity_m_s2
        p, v = state.pos_ned_m, state.vel_ned_m_s
        rp, rv, ra = reference.pos_ned_m, reference.vel_ned_m_s, reference.acc_ned_m_s2
        # _positionControl: P with velocity feed-forward, horizontal and vertical speed limits
        vsp = [
            k.xy_p * (float(rp[0]) - float(p[0])) + float(rv[0]),
            k.xy_p * (float(rp[1]) - float(p[1])) + float(rv[1]),
            k.z_p * (float(rp[2]) - float(p[2])) + float(rv[2]),
        ]
        vxy = math.hypot(vsp[0], vsp[1])
        if vxy > k.xy_vel_max_m_s:
            vsp[0] *= k.xy_vel_max_m_s / vxy
            vsp[1] *= k.xy_vel_max_m_s / vxy
        vsp[2] = min(max(vsp[2], -k.z_vel_max_up_m_s), k.z_vel_max_dn_m_s)
        # _velocityControl: PID on the velocity error, acceleration feed-forward
        err = [vsp[i] - float(v[i]) for i in range(3)]
        prev = self._prev_err if self._prev_err is not None else err
        self._prev_err = err
        kp = (k.xy_vel_p, k.xy_vel_p, k.z_vel_p)
        ki = (k.xy_vel_i, k.xy_vel_i, k.z_vel_i)
        kd = (k.xy_vel_d, k.xy_vel_d, k.z_vel_d)
        acc = [kp[i] * err[i] + self._int[i] + kd[i] * (err[i] - prev[i]) / self.dt + float(ra[i]) for i in range(3)]
        # _accelerationControl: the thrust direction from the horizontal acceleration, tilt limited
        body_z = [-acc[0], -acc[1], g]
        n = math.sqrt(body_z[0] ** 2 + body_z[1] ** 2 + body_z[2] ** 2)
        body_z = [c / n for c in body_z]
        tilt = math.acos(min(1.0, body_z[2]))
        if tilt > k.tilt_max_rad:  # ControlMath::limitTilt
            horiz = math.hypot(body_z[0], body_z[1])
            s = math.sin(k.tilt_max_rad) / horiz
            body_z = [body_z[0] * s, body_z[1] * s, math.cos(k.tilt_max_rad)]
        thrust = self.mass_kg * (g - acc[2]) / body_z[2]
        saturated = thrust >= self.thrust_max_n or thrust <= self.thrust_min_n
        thrust = min(max(thrust, self.thrust_min_n), self.thrust_max_n)
        if not saturated:  # PX4's anti-windup: no integration while the thrust saturates
            for i in range(3):
                self._int[i] += ki[i] * err[i] * self.dt
        q = bodyz_to_attitude((body_z[0], body_z[1], body_z[2]), reference.yaw_rad)
        yaw_rate = float(reference.yaw_rate_rad_s)
        return AttitudeTarget(
            thrust_n=thrust,
            quat_wxyz=q,
            body_rate_frd_rad_s=(0.0, 0.0, yaw_rate),
            force_ned_n=(-thrust * body_z[0], -thrust * body_z[1], -thrust * body_z[2]),
        )
