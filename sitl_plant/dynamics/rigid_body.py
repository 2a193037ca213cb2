"""A quadrotor as a rigid body: Newton-Euler in NED/FRD, the default plant for flights.

State vector (17 entries, ``STATE_SIZE``), in this order:

======== ======= ===================================================== =========
slice    name    meaning                                               unit
======== ======= ===================================================== =========
0:3      POS     position, north-east-down                             m
3:6      VEL     velocity, NED                                         m/s
6:10     QUAT    attitude quaternion (w, x, y, z), body FRD -> NED     -
10:13    RATES   body angular velocity (p, q, r), FRD                  rad/s
13:17    ROTORS  rotor speeds, rotors f1 (right), f2 (front), f3       rad/s
                 (left), f4 (rear)
======== ======= ===================================================== =========

Equations (see ``docs/model.md``)::

    f_i       = k w_i^2                                   rotor thrust (eq. 10)
    T         = f1 + f2 + f3 + f4                         collective thrust (eq. 9)
    tau       = (l (f3 - f1), l (f2 - f4), c (f2 + f4 - f1 - f3))    body torque (eq. 11)
    m v_dot   = m g e_down - T R e_z + R (-D (R^T (v - v_wind)))    thrust along body -z
    q_dot     = 1/2 q * (0, omega)
    I w_dot   = tau - omega x I omega                     Euler's rotation equation
    w_i_dot   = (clip(w_cmd_i) - w_i) / tau_motor         first-order motor lag

Thrust acts along body -z, so the horizontal force turns with yaw: the difference from the
paper's eq. 18. No rotor gyroscopic torque, blade flapping or induced drag: the rotor is a
thrust and a reaction torque.

The mixer (``mix_rotor_forces``, ``rotor_speeds_for``) inverts eq. 9-11 with PX4-like
saturation (airmode off); ``rotor_forces`` and ``thrust_torque_from_rotor_forces`` are the one
implementation of eq. 9-11 in the repository, used by the controller side too.

``derivative`` is a pure function of arrays and takes an optional leading batch axis, so many
vehicles can be stepped at once. ``RigidBodyModel`` adapts it to ``simulation.Model``.
"""

from __future__ import annotations

import math

import numpy as np

from offboard.model.euler_lagrange import zyx_body_torque_from_generalized, zyx_euler_rates_from_body_rates, zyx_euler_rates_terms
from offboard.model.mixer import rotor_forces, thrust_torque_from_rotor_forces
from offboard.model.rotations import euler_from_quat, euler_from_quat_floats, quat_from_euler
from offboard.model.state import VehicleState
from offboard.model.vehicle import VehicleParams

STATE_SIZE = 17
POS = slice(0, 3)
VEL = slice(3, 6)
QUAT = slice(6, 10)
RATES = slice(10, 13)
ROTORS = slice(13, 17)

__all__ = [
    "STATE_SIZE",
    "POS",
    "VEL",
    "QUAT",
    "RATES",
    "ROTORS",
    "derivative",
    "normalize",
    "rotor_forces",
    "thrust_torque_from_rotor_forces",
    "mix_rotor_forces",
    "rotor_speeds_for",
    "hover_rotor_speed",
    "RigidBodyModel",
]


def _as_list(values: np.ndarray | list[float]) -> list[float]:
    """Python floats of a short vector (arithmetic on them is faster than on numpy scalars)."""
    return values.tolist() if isinstance(values, np.ndarray) else [float(v) for v in values]


# --- eq. 9-11: rotor forces <-> collective thrust and torques ---------------------------------


def mix_rotor_forces(thrust_n: float, torque_nm: np.ndarray, params: VehicleParams) -> np.ndarray:
    """Rotor forces for ``u`` and ``tau`` within the rotors' limits (PX4-like, airmode off).

    Write the forces as ``f1, f3 = b - y -+ R`` and ``f2, f4 = b + y +- P`` with ``b = u/4``,
    ``R = tau_phi / 2l``, ``P = tau_theta / 2l``, ``y = tau_psi / 4c`` (eq. 9-11 inverted) and
    ``f_min, f_max = k w_min**2, k w_max**2``. When every force is in range the result is exact
    (``rotor_forces``). Otherwise, in order of priority:

    1. **Roll and pitch** are scaled by one factor ``s <= 1`` (the tilt torque keeps its
       direction), the largest for which some thrust at or below the request and some yaw
       between zero and the request fit;
    2. **collective thrust** is then the largest up to the request: it is lowered when a
       rotor would pass ``f_max``, and never raised to make room at the bottom (airmode off,
       as PX4's ``mix_airmode_disabled``); a request below ``4 f_min`` gives ``4 f_min``;
    3. **yaw** gets what room is left: the value nearest the request (never of the other
       sign). It adds to one pair and takes from the other, so it leaves u unchanged.

    Each step is a closed-form bound, so the forces vary continuously with the request.
    (PX4 desaturates roll/pitch before mixing yaw at all, and may lower thrust by up to
    15 % for yaw; this mixer is instead exact whenever the rotors can be exact.)

    Parameters
    ----------
    thrust_n : float
        Requested collective thrust u, N.
    torque_nm : array_like, shape (3,)
        Requested body torque (roll, pitch, yaw), FRD, N m.
    params : VehicleParams
        Arm length, drag-to-thrust ratio, thrust coefficient and speed limits.

    Returns
    -------
    ndarray, shape (4,)
        f1..f4 in ``[f_min, f_max]``, N.
    """
    tau_x, tau_y, tau_z = _as_list(torque_nm)
    return np.array(_mix(float(thrust_n), tau_x, tau_y, tau_z, params))


def _mix(thrust_n: float, tau_x: float, tau_y: float, tau_z: float, params: VehicleParams) -> tuple[float, ...]:
    """``mix_rotor_forces`` on Python floats."""
    return mix_forces(
        thrust_n, tau_x, tau_y, tau_z, params.thrust_coeff_n_s2, params.rotor_speed_min_rad_s,
        params.rotor_speed_max_rad_s, params.arm_length_m, params.drag_to_thrust_m,
    )  # fmt: skip


def mix_forces(
    thrust_n: float, tau_x: float, tau_y: float, tau_z: float,
    k: float, w_min: float, w_max: float, arm: float, drag: float,
) -> tuple[float, float, float, float]:  # fmt: skip
    """The mixer of ``mix_rotor_forces`` on plain floats (no objects: ``dynamics.batch`` compiles it).

    ``k`` is the thrust coefficient (N s^2), ``w_min``/``w_max`` the rotor speed limits (rad/s),
    ``arm`` l (m), ``drag`` c (m). Returns f1..f4, N.
    """
    f_min = k * w_min**2
    f_max = k * w_max**2
    span = f_max - f_min
    base_req = min(max(0.25 * thrust_n, f_min), f_max)
    roll = 0.5 * tau_x / arm  # f3 - f1 = 2 roll
    pitch = 0.5 * tau_y / arm  # f2 - f4 = 2 pitch
    yaw_req = 0.25 * tau_z / drag  # (f2 + f4) - (f1 + f3) = 4 yaw
    yaw_lo, yaw_hi = min(0.0, yaw_req), max(0.0, yaw_req)
    room = base_req - f_min
    # 1. the largest s in [0, 1] with a feasible (b <= base_req, y in [yaw_lo, yaw_hi]);
    #    each bound is s * coef <= rhs (pairs' spans, centres b -+ y within range).
    ar, ap = abs(roll), abs(pitch)
    total = ar + ap
    s = 1.0
    coef, rhs = 2.0 * max(ar, ap), span
    if coef * s > rhs:
        s = rhs / coef
    coef, rhs = total, span
    if coef * s > rhs:
        s = rhs / coef
    coef, rhs = 0.5 * total + ar, room + 0.5 * span
    if coef * s > rhs:
        s = rhs / coef
    coef, rhs = 0.5 * total + ap, room + 0.5 * span
    if coef * s > rhs:
        s = rhs / coef
    coef, rhs = total, 2.0 * room
    if coef * s > rhs:
        s = rhs / coef
    coef, rhs = ap, room + yaw_hi
    if coef * s > rhs:
        s = rhs / coef
    coef, rhs = ar, room - yaw_lo
    if coef * s > rhs:
        s = rhs / coef
    roll, pitch, ar, ap = s * roll, s * pitch, s * ar, s * ap
    half = 0.5 * (span - ar - ap)
    y_lo = max(-half, ap - room, yaw_lo)
    y_hi = min(half, room - ar, yaw_hi)
    # 2. the largest b <= base_req: b <= f_max - ar + y and b <= f_max - ap - y
    top_a, top_b = f_max - ar, f_max - ap
    y_best = min(max(0.5 * (top_b - top_a), y_lo), y_hi)
    base = min(base_req, top_a + y_best, top_b - y_best)
    # 3. the yaw nearest the request that keeps both pairs in range at this b
    y_min = max(y_lo, base - top_a, f_min + ap - base)
    y_max = min(y_hi, top_b - base, base - f_min - ar)
    y = min(max(yaw_req, y_min), y_max)
    # clip: rounding only
    return (
        min(max(base - y - roll, f_min), f_max),
        min(max(base + y + pitch, f_min), f_max),
        min(max(base - y + roll, f_min), f_max),
        min(max(base + y - pitch, f_min), f_max),
    )


def rotor_speeds_for(thrust_n: float, torque_frd_nm: np.ndarray, params: VehicleParams) -> np.ndarray:
    """Rotor speed commands (rad/s, f1..f4) for a thrust and body torque, through the mixer.

    ``w_i = sqrt(f_i / k)`` of the forces of ``mix_rotor_forces``, so within the speed limits.
    """
    k = params.thrust_coeff_n_s2
    tau_x, tau_y, tau_z = _as_list(torque_frd_nm)
    return np.array([math.sqrt(f / k) for f in _mix(float(thrust_n), tau_x, tau_y, tau_z, params)])


def hover_rotor_speed(params: VehicleParams) -> float:
    """``sqrt(m g / (4 k))``: each rotor's speed in hover, rad/s."""
    return math.sqrt(params.mass_kg * params.gravity_m_s2 / (4.0 * params.thrust_coeff_n_s2))


# --- the equations of motion ------------------------------------------------------------------


def _rates(
    vn, ve, vd, qw, qx, qy, qz, p, q, r, f1, f2, f3, f4, wn, we, wd, mass, grav, arm, drag, ixx, iyy, izz, dx, dy, dz
):  # noqa: ANN001, ANN202 - floats or equally shaped arrays
    """Accelerations, quaternion and body-rate derivatives; plain arithmetic on floats or arrays."""
    inv_norm = (qw * qw + qx * qx + qy * qy + qz * qz) ** -0.5  # R of the unit quaternion
    w, x, y, z = qw * inv_norm, qx * inv_norm, qy * inv_norm, qz * inv_norm
    r00, r01, r02 = 1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)
    r10, r11, r12 = 2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)
    r20, r21, r22 = 2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)
    # Force in body FRD: thrust along -z (eq. 9), linear drag of the air-relative velocity.
    un, ue, ud = vn - wn, ve - we, vd - wd
    fx = -dx * (r00 * un + r10 * ue + r20 * ud)
    fy = -dy * (r01 * un + r11 * ue + r21 * ud)
    fz = -dz * (r02 * un + r12 * ue + r22 * ud) - (f1 + f2 + f3 + f4)
    inv_m = 1.0 / mass
    an = (r00 * fx + r01 * fy + r02 * fz) * inv_m
    ae = (r10 * fx + r11 * fy + r12 * fz) * inv_m
    ad = (r20 * fx + r21 * fy + r22 * fz) * inv_m + grav
    # q_dot = 1/2 q * (0, omega)
    qw_dot = -0.5 * (qx * p + qy * q + qz * r)
    qx_dot = 0.5 * (qw * p + qy * r - qz * q)
    qy_dot = 0.5 * (qw * q - qx * r + qz * p)
    qz_dot = 0.5 * (qw * r + qx * q - qy * p)
    # I omega_dot = tau - omega x I omega, torques of eq. 11
    p_dot = (arm * (f3 - f1) - (izz - iyy) * q * r) / ixx
    q_dot = (arm * (f2 - f4) - (ixx - izz) * r * p) / iyy
    r_dot = (drag * (f2 + f4 - f1 - f3) - (iyy - ixx) * p * q) / izz
    return an, ae, ad, qw_dot, qx_dot, qy_dot, qz_dot, p_dot, q_dot, r_dot


def derivative(
    x: np.ndarray, rotor_speed_cmd_rad_s: np.ndarray, wind_ned_m_s: np.ndarray, params: VehicleParams
) -> np.ndarray:
    """x_dot of the rigid-body quadrotor: a pure function of state, inputs and parameters.

    Parameters
    ----------
    x : ndarray, shape (17,) or (N, 17)
        State (see the module docstring for the order); a leading axis steps N vehicles.
    rotor_speed_cmd_rad_s : array_like, shape (4,) or (N, 4)
        Commanded rotor speeds f1..f4, rad/s; clipped to the speed limits.
    wind_ned_m_s : array_like, shape (3,) or (N, 3)
        Air velocity, NED, m/s (enters through the linear drag only).
    params : VehicleParams
        The true vehicle.

    Returns
    -------
    ndarray, same shape as ``x``
        Time derivative of the state. The quaternion part is that of ``x``'s quaternion as
        given; forces use its normalised value, so a slightly non-unit ``q`` does no harm.
        With ``motor_time_constant_s == 0`` the rotors follow the command instantly: thrust
        comes from the (clipped) command and the rotor-speed derivative is zero.
    """
    p = params
    lo, hi = p.rotor_speed_min_rad_s, p.rotor_speed_max_rad_s
    tau_motor = p.motor_time_constant_s
    ixx, iyy, izz = p.inertia_kg_m2
    dx, dy, dz = p.linear_drag_n_s_m
    k = p.thrust_coeff_n_s2
    if x.ndim == 1:
        s = x.tolist()
        cmd = [lo if c < lo else hi if c > hi else c for c in _as_list(rotor_speed_cmd_rad_s)]
        speeds = cmd if tau_motor == 0.0 else s[13:17]
        acc = _rates(*(
            *s[3:13], *[k * w * w for w in speeds], *_as_list(wind_ned_m_s),
            p.mass_kg, p.gravity_m_s2, p.arm_length_m, p.drag_to_thrust_m, ixx, iyy, izz, dx, dy, dz,
        ))  # fmt: skip
        if tau_motor == 0.0:
            return np.array([s[3], s[4], s[5], *acc, 0.0, 0.0, 0.0, 0.0])
        rate = 1.0 / tau_motor
        return np.array([s[3], s[4], s[5], *acc, *[(c - w) * rate for c, w in zip(cmd, speeds)]])
    # batched: columns of an (N, 17) state
    xs = np.asarray(x, dtype=float)
    cmd = np.clip(np.broadcast_to(np.asarray(rotor_speed_cmd_rad_s, dtype=float), (xs.shape[0], 4)), lo, hi)
    speeds = cmd if tau_motor == 0.0 else xs[:, ROTORS]
    wind = np.broadcast_to(np.asarray(wind_ned_m_s, dtype=float), (xs.shape[0], 3))
    forces = k * speeds * speeds
    acc = _rates(*(
        *xs[:, 3:13].T, *forces.T, *wind.T,
        p.mass_kg, p.gravity_m_s2, p.arm_length_m, p.drag_to_thrust_m, ixx, iyy, izz, dx, dy, dz,
    ))  # fmt: skip
    out = np.empty_like(xs)
    out[:, POS] = xs[:, VEL]
    out[:, 3:13] = np.stack(acc, axis=-1)
    out[:, ROTORS] = 0.0 if tau_motor == 0.0 else (cmd - speeds) / tau_motor
    return out


def normalize(x: np.ndarray) -> np.ndarray:
    """A copy of ``x`` with a unit quaternion (call after each integration step)."""
    x = np.array(x, dtype=float)
    if x.ndim == 1:
        qw, qx, qy, qz = x[QUAT].tolist()
        x[QUAT] *= 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        return x
    q = x[..., QUAT]
    x[..., QUAT] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return x


# --- the adapter for VehicleSim ------------------------------------------------------------------


class RigidBodyModel:
    """The rigid body as a ``simulation.Model``: thrust and body torque in, through the mixer.

    Parameters
    ----------
    params : VehicleParams
        The true vehicle.

    Notes
    -----
    ``derivative(x, thrust_n, torque_nm, wind)`` takes the collective thrust and the **body
    FRD** torque, turns them into rotor speed commands with ``rotor_speeds_for`` (cached while
    the inputs do not change, as within one RK4 step) and returns the rigid body's ``x_dot``.
    """

    state_size = STATE_SIZE

    def __init__(self, params: VehicleParams) -> None:
        self.params = params
        self._inputs: tuple[float, float, float, float] | None = None
        self._cmd = np.zeros(4)

    def initial_state(self, pos_ned_m: np.ndarray, yaw_rad: float) -> np.ndarray:
        """At rest at ``pos_ned_m``, level, heading ``yaw_rad``, rotors stopped."""
        x = np.zeros(STATE_SIZE)
        x[POS] = pos_ned_m
        x[QUAT] = quat_from_euler(0.0, 0.0, yaw_rad)
        return x

    def rotor_speed_command(self, thrust_n: float, torque_nm: np.ndarray) -> np.ndarray:
        """The mixer's rotor speed commands (rad/s, f1..f4) for a thrust and body torque."""
        inputs = (float(thrust_n), float(torque_nm[0]), float(torque_nm[1]), float(torque_nm[2]))
        if inputs != self._inputs:
            self._cmd = rotor_speeds_for(inputs[0], np.array(inputs[1:]), self.params)
            self._inputs = inputs
        return self._cmd

    def derivative(self, x: np.ndarray, thrust_n: float, torque_nm: np.ndarray, wind_ned_m_s: np.ndarray) -> np.ndarray:
        """dx/dt (``rigid_body.derivative``) with the rotor speeds that give ``thrust_n`` and ``torque_nm``
        (mixed, clipped to the rotors' range) commanded.
        """
        return derivative(x, self.rotor_speed_command(thrust_n, torque_nm), wind_ned_m_s, self.params)

    def normalize(self, x: np.ndarray) -> np.ndarray:
        """Post-step hook: the state with its quaternion renormalised."""
        return normalize(x)

    def euler(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """ZYX (roll, pitch, yaw) of the quaternion and their rates ``W_zyx^-1 omega``."""
        eta = euler_from_quat(x[QUAT] / np.linalg.norm(x[QUAT]))
        return eta, zyx_euler_rates_from_body_rates(eta, x[RATES])

    def torque_from_generalized(self, x: np.ndarray, tau_generalized: np.ndarray) -> np.ndarray:
        """Body torque exerting ``tau_generalized`` on the ZYX angles (``W_zyx^-T tau``)."""
        eta = euler_from_quat(x[QUAT] / np.linalg.norm(x[QUAT]))
        return zyx_body_torque_from_generalized(eta, tau_generalized)

    def ground_contact(self, x: np.ndarray) -> tuple[np.ndarray, bool]:
        """Contact with the ground plane down = 0 (also renormalises the quaternion).

        Above the ground, or on it and moving up, the vehicle is free. Pressed into it (down > 0,
        or down = 0 and not rising) it rests: down clamped to 0, velocity and body rates zeroed,
        roll and pitch levelled, yaw kept; the rotors keep their speeds.
        """
        x = normalize(x)
        if x[2] < 0.0 or (x[2] == 0.0 and x[5] < 0.0):
            return x, False
        yaw = euler_from_quat(x[QUAT])[2]
        x[2] = 0.0
        x[VEL] = 0.0
        x[QUAT] = quat_from_euler(0.0, 0.0, yaw)
        x[RATES] = 0.0
        return x, True

    def vehicle_state(self, x: np.ndarray, time_s: float, xdot: np.ndarray) -> VehicleState:
        """What the autopilot reports; acceleration is kinematic (``xdot``'s velocity part)."""
        s = x.tolist()  # floats: the arithmetic below is on Python floats, not numpy scalars
        qw, qx, qy, qz = s[6:10]
        norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        qw, qx, qy, qz = qw / norm, qx / norm, qy / norm, qz / norm
        roll, pitch, yaw = euler_from_quat_floats(qw, qx, qy, qz)
        speeds = self._cmd.copy() if self.params.motor_time_constant_s == 0.0 else np.array(s[13:17])
        vn, ve, vd = s[3:6]
        return VehicleState(
            time_s=time_s,
            pos_ned_m=np.array(s[0:3]),
            vel_ned_m_s=np.array(s[3:6]),
            acc_ned_m_s2=np.array(xdot[VEL], dtype=float),
            euler_rad=np.array((roll, pitch, yaw)),
            euler_rate_rad_s=np.array(zyx_euler_rates_terms(roll, pitch, *s[10:13])),
            body_rate_frd_rad_s=np.array(s[10:13]),
            quat_wxyz=np.array((qw, qx, qy, qz)),
            motor_speeds_rad_s=speeds,
            on_ground=bool(s[2] >= 0.0 and not (vn or ve or vd)),
        )
