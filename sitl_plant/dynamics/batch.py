"""Fast stepping of rigid-body quadrotors: many vehicles at once, or one vehicle's whole sample.

``rigid_body.derivative`` and ``integrate.rk4_step`` are the reference: clear, pure, and slow
(one RK4 step of one vehicle costs some hundred microseconds of interpreted Python). This
module runs the **same equations** (the very same ``rigid_body._rates`` and
``rigid_body.mix_forces`` functions, compiled) in two shapes:

- **many vehicles** (``step_many``, ``derivative_many``): an ``(N, 17)`` state array stepped by
  RK4 with rotor-speed commands and wind held over the step, then the quaternions
  renormalised, exactly as ``VehicleSim`` steps one. Compiled with numba and spread over the
  cores when numba is installed; otherwise vectorised numpy over the batch (the batched path
  of ``rigid_body.derivative``).
- **one vehicle, one control sample** (``FastRigidBodySim``): the drop-in for ``VehicleSim``
  with a ``RigidBodyModel``. For the two actuations a controller hands on each sample
  (``HeldActuation``; ``EulerAccelActuation``: the paper's tau~ with eq. 16 at every physics
  step) the whole sample (inner loop, mixer, RK4, renormalisation, ground contact) is one
  compiled call. Any other actuation (a baseline's attitude loop, say) is called in Python at
  every physics step, as ``VehicleSim`` does, and only the mixer and RK4 are compiled.

Results equal the reference to rounding (``tests/unit/sitl_plant/test_batch.py``: 1e-12). Wind is sampled
once per physics step at the step's start time, as ``VehicleSim`` does; every wind model of
``dynamics.wind`` depends on time only, so a sample's wind is drawn before the sample runs.

Set the environment variable ``SITL_PLANT_NO_NUMBA=1`` (or uninstall numba) to run the same
kernels as plain Python: identical results, for checking, at interpreted speed.

Parameter vector (``param_vector``): ``(m, g, l, c, Ixx, Iyy, Izz, Dx, Dy, Dz, k, w_min,
w_max, tau_motor)``, SI units, as in ``VehicleParams``.
"""

from __future__ import annotations

import math
import os
import pickle
import types
from typing import Any, Protocol

import numpy as np

from offboard.model import euler_lagrange
from offboard.model.euler_lagrange import EULER_FORM_TERMS, EulerRateForm, real_torques_terms
from offboard.model.state import VehicleState
from offboard.model.vehicle import VehicleParams
from sitl_plant.dynamics import rigid_body
from sitl_plant.dynamics.rigid_body import QUAT, STATE_SIZE, RigidBodyModel
from sitl_plant.simulation import EulerAccelActuation, HeldActuation, Model, VehicleSim

__all__ = [
    "NUMBA",
    "param_vector",
    "derivative_many",
    "step_many",
    "step_many_numpy",
    "FastRigidBodySim",
    "advance_many",
]


def _numba_jit():  # noqa: ANN202
    if os.environ.get("SITL_PLANT_NO_NUMBA", "") not in ("", "0"):
        return None
    try:
        import numba
    except ImportError:
        return None
    return numba


_numba = _numba_jit()
#: Whether the kernels are compiled (numba installed and not switched off).
NUMBA = _numba is not None


def _jit(fn):  # noqa: ANN001, ANN202
    return _numba.njit(cache=True)(fn) if NUMBA else fn


def _pjit(fn):  # noqa: ANN001, ANN202
    return _numba.njit(cache=True, parallel=True, fastmath=True)(fn) if NUMBA else fn


def _vjit(fn):  # noqa: ANN001, ANN202
    return _numba.njit(cache=True, fastmath=True, inline="always")(fn) if NUMBA else fn


def _ijit(fn):  # noqa: ANN001, ANN202
    """Compiled and inlined into its callers, with no fast-math (the batch's NaN checks need NaNs)."""
    return _numba.njit(cache=True, inline="always")(fn) if NUMBA else fn


def _bjit(fn):  # noqa: ANN001, ANN202
    return _numba.njit(cache=True, parallel=True)(fn) if NUMBA else fn


_prange = _numba.prange if NUMBA else range

# the same functions as the reference, compiled (and, for the batch, inlined and vectorised)
_rates = _jit(rigid_body._rates)
_rates_v = _vjit(rigid_body._rates)
_mix_forces = _jit(rigid_body.mix_forces)
_rates_i = _ijit(rigid_body._rates)
_mix_forces_i = _ijit(rigid_body.mix_forces)

_M, _G, _L, _C, _IXX, _IYY, _IZZ, _DX, _DY, _DZ, _K, _WMIN, _WMAX, _TAU = range(14)


def param_vector(params: VehicleParams) -> np.ndarray:
    """The vehicle's parameters as the flat float vector the kernels take (module docstring)."""
    return np.array(
        [
            params.mass_kg, params.gravity_m_s2, params.arm_length_m, params.drag_to_thrust_m,
            *params.inertia_kg_m2, *params.linear_drag_n_s_m, params.thrust_coeff_n_s2,
            params.rotor_speed_min_rad_s, params.rotor_speed_max_rad_s, params.motor_time_constant_s,
        ],  # fmt: skip
        dtype=float,
    )


# --- one vehicle: derivative, RK4, renormalisation ------------------------------------------


@_jit
def _derivative_into(x, cmd, wind, p, out):  # noqa: ANN001, ANN202
    """``rigid_body.derivative`` of one vehicle into ``out`` (``cmd`` is clipped here)."""
    lo, hi, tau = p[_WMIN], p[_WMAX], p[_TAU]
    c0 = lo if cmd[0] < lo else hi if cmd[0] > hi else cmd[0]
    c1 = lo if cmd[1] < lo else hi if cmd[1] > hi else cmd[1]
    c2 = lo if cmd[2] < lo else hi if cmd[2] > hi else cmd[2]
    c3 = lo if cmd[3] < lo else hi if cmd[3] > hi else cmd[3]
    if tau == 0.0:
        w0, w1, w2, w3 = c0, c1, c2, c3
    else:
        w0, w1, w2, w3 = x[13], x[14], x[15], x[16]
    k = p[_K]
    an, ae, ad, qwd, qxd, qyd, qzd, pd, qd, rd = _rates(
        x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10], x[11], x[12],
        k * w0 * w0, k * w1 * w1, k * w2 * w2, k * w3 * w3, wind[0], wind[1], wind[2],
        p[_M], p[_G], p[_L], p[_C], p[_IXX], p[_IYY], p[_IZZ], p[_DX], p[_DY], p[_DZ],
    )  # fmt: skip
    out[0], out[1], out[2] = x[3], x[4], x[5]
    out[3], out[4], out[5] = an, ae, ad
    out[6], out[7], out[8], out[9] = qwd, qxd, qyd, qzd
    out[10], out[11], out[12] = pd, qd, rd
    if tau == 0.0:
        out[13] = out[14] = out[15] = out[16] = 0.0
    else:
        rate = 1.0 / tau
        out[13], out[14] = (c0 - w0) * rate, (c1 - w1) * rate
        out[15], out[16] = (c2 - w2) * rate, (c3 - w3) * rate


@_jit
def _rk4_into(x, cmd, wind, p, dt, out, k1, k2, k3, k4, tmp):  # noqa: ANN001, ANN202
    """``integrate.rk4_step`` of the rigid body, then ``rigid_body.normalize``, into ``out``.

    The arithmetic is in the reference's order (``x + 0.5 * dt * k`` is ``x + (0.5 dt) k``).
    """
    n = x.shape[0]
    half = 0.5 * dt
    _derivative_into(x, cmd, wind, p, k1)
    for i in range(n):
        tmp[i] = x[i] + half * k1[i]
    _derivative_into(tmp, cmd, wind, p, k2)
    for i in range(n):
        tmp[i] = x[i] + half * k2[i]
    _derivative_into(tmp, cmd, wind, p, k3)
    for i in range(n):
        tmp[i] = x[i] + dt * k3[i]
    _derivative_into(tmp, cmd, wind, p, k4)
    sixth = dt / 6.0
    for i in range(n):
        out[i] = x[i] + sixth * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    _normalize(out)


@_jit
def _normalize(x):  # noqa: ANN001, ANN202
    inv = 1.0 / math.sqrt(x[6] * x[6] + x[7] * x[7] + x[8] * x[8] + x[9] * x[9])
    x[6] *= inv
    x[7] *= inv
    x[8] *= inv
    x[9] *= inv


# --- many vehicles ------------------------------------------------------------------------------


#: Vehicles per block in the batch kernel: each block's states, transposed to (17, BLOCK), stay in
#: the core's L1 cache while it takes all its steps, and every loop over a block's vehicles is
#: straight-line arithmetic that LLVM turns into SIMD instructions. The kernels take RK4's four
#: stages in a loop over one inlined copy of the derivative (``_stage``), not four copies: the same
#: arithmetic in the same order, compiled in 15 s instead of 23 (``_step_many_kernel``) and 24
#: instead of 43 (``_advance_blocks_kernel``), as fast (make test compiles them all from cold).
BLOCK = 32


@_vjit
def _stage(src, dst, cmd, wind, p, n):  # noqa: ANN001, ANN202
    """``rigid_body.derivative`` of the first ``n`` vehicles of a (17, BLOCK) block."""
    k, lo, hi, tau = p[_K], p[_WMIN], p[_WMAX], p[_TAU]
    moving = tau != 0.0
    rate = 1.0 / tau if moving else 0.0
    for j in range(n):
        c0 = min(max(cmd[0, j], lo), hi)
        c1 = min(max(cmd[1, j], lo), hi)
        c2 = min(max(cmd[2, j], lo), hi)
        c3 = min(max(cmd[3, j], lo), hi)
        w0 = src[13, j] if moving else c0
        w1 = src[14, j] if moving else c1
        w2 = src[15, j] if moving else c2
        w3 = src[16, j] if moving else c3
        an, ae, ad, qwd, qxd, qyd, qzd, pd, qd, rd = _rates_v(
            src[3, j], src[4, j], src[5, j], src[6, j], src[7, j], src[8, j], src[9, j], src[10, j], src[11, j],
            src[12, j], k * w0 * w0, k * w1 * w1, k * w2 * w2, k * w3 * w3, wind[0, j], wind[1, j], wind[2, j],
            p[_M], p[_G], p[_L], p[_C], p[_IXX], p[_IYY], p[_IZZ], p[_DX], p[_DY], p[_DZ],
        )  # fmt: skip
        dst[0, j] = src[3, j]
        dst[1, j] = src[4, j]
        dst[2, j] = src[5, j]
        dst[3, j] = an
        dst[4, j] = ae
        dst[5, j] = ad
        dst[6, j] = qwd
        dst[7, j] = qxd
        dst[8, j] = qyd
        dst[9, j] = qzd
        dst[10, j] = pd
        dst[11, j] = qd
        dst[12, j] = rd
        dst[13, j] = (c0 - w0) * rate
        dst[14, j] = (c1 - w1) * rate
        dst[15, j] = (c2 - w2) * rate
        dst[16, j] = (c3 - w3) * rate


@_pjit
def _derivative_many_kernel(x, cmd, wind, p, out):  # noqa: ANN001, ANN202
    n_all = x.shape[0]
    for block in _prange((n_all + BLOCK - 1) // BLOCK):
        a = block * BLOCK
        n = min(n_all, a + BLOCK) - a
        xb = np.empty((STATE_SIZE, BLOCK))
        cb = np.empty((4, BLOCK))
        wb = np.empty((3, BLOCK))
        db = np.empty((STATE_SIZE, BLOCK))
        xb[:, :n] = x[a : a + n].T
        cb[:, :n] = cmd[a : a + n].T
        wb[:, :n] = wind[a : a + n].T
        _stage(xb, db, cb, wb, p, n)
        out[a : a + n] = db[:, :n].T


@_pjit
def _step_many_kernel(x, cmd, wind, p, dt, n_steps):  # noqa: ANN001, ANN202
    n_all = x.shape[0]
    half = 0.5 * dt
    sixth = dt / 6.0
    for block in _prange((n_all + BLOCK - 1) // BLOCK):
        a = block * BLOCK
        n = min(n_all, a + BLOCK) - a
        xb = np.empty((STATE_SIZE, BLOCK))
        cb = np.empty((4, BLOCK))
        wb = np.empty((3, BLOCK))
        ks = np.empty((4, STATE_SIZE, BLOCK))
        t = np.empty((STATE_SIZE, BLOCK))
        xb[:, :n] = x[a : a + n].T
        cb[:, :n] = cmd[a : a + n].T
        wb[:, :n] = wind[a : a + n].T
        for _ in range(n_steps):  # RK4, then the quaternion renormalised (rigid_body.normalize)
            for i in range(STATE_SIZE):
                for j in range(n):
                    t[i, j] = xb[i, j]
            for s in range(4):
                _stage(t, ks[s], cb, wb, p, n)
                if s < 3:
                    h = dt if s == 2 else half
                    for i in range(STATE_SIZE):
                        for j in range(n):
                            t[i, j] = xb[i, j] + h * ks[s, i, j]
            for i in range(STATE_SIZE):
                for j in range(n):
                    xb[i, j] = xb[i, j] + sixth * (ks[0, i, j] + 2.0 * ks[1, i, j] + 2.0 * ks[2, i, j] + ks[3, i, j])
            for j in range(n):
                inv = 1.0 / math.sqrt(xb[6, j] ** 2 + xb[7, j] ** 2 + xb[8, j] ** 2 + xb[9, j] ** 2)
                xb[6, j] *= inv
                xb[7, j] *= inv
                xb[8, j] *= inv
                xb[9, j] *= inv
        x[a : a + n] = xb[:, :n].T


def _batch_inputs(x: np.ndarray, values: np.ndarray, width: int) -> np.ndarray:
    """``values`` ((width,) or (N, width)) as a fresh writable C-contiguous (N, width) float64
    array: always the same array type, so numba compiles each kernel once (a read-only view, as
    ``ascontiguousarray(broadcast_to(...))`` returns for an input already (N, width), is another
    type and cost a second compilation of up to half a minute)."""
    out = np.empty((x.shape[0], width))
    out[:] = values
    return out


def derivative_many(
    x: np.ndarray, rotor_speed_cmd_rad_s: np.ndarray, wind_ned_m_s: np.ndarray, params: VehicleParams
) -> np.ndarray:
    """``rigid_body.derivative`` of N vehicles at once.

    Parameters
    ----------
    x : ndarray, shape (N, 17)
    rotor_speed_cmd_rad_s : array_like, shape (4,) or (N, 4)
    wind_ned_m_s : array_like, shape (3,) or (N, 3)
    params : VehicleParams
        One vehicle type for the whole batch.

    Returns
    -------
    ndarray, shape (N, 17)
    """
    xs = np.ascontiguousarray(x, dtype=float)
    if not NUMBA:
        return rigid_body.derivative(xs, rotor_speed_cmd_rad_s, wind_ned_m_s, params)
    out = np.empty_like(xs)
    _derivative_many_kernel(xs, _batch_inputs(xs, rotor_speed_cmd_rad_s, 4), _batch_inputs(xs, wind_ned_m_s, 3),
                            param_vector(params), out)  # fmt: skip
    return out


def step_many(
    x: np.ndarray,
    rotor_speed_cmd_rad_s: np.ndarray,
    wind_ned_m_s: np.ndarray,
    params: VehicleParams,
    dt_s: float,
    n_steps: int = 1,
) -> np.ndarray:
    """Advance N vehicles ``n_steps`` RK4 steps in place, inputs held, quaternions renormalised.

    Each step equals ``normalize(rk4_step(lambda x: derivative(x, cmd, wind, params), x, dt))``
    for each vehicle. No ground contact (vehicles in free flight).

    Parameters
    ----------
    x : ndarray, shape (N, 17), float64, C-contiguous
        States; overwritten with the result (and returned).
    rotor_speed_cmd_rad_s : array_like, shape (4,) or (N, 4)
    wind_ned_m_s : array_like, shape (3,) or (N, 3)
    params : VehicleParams
    dt_s : float
        Physics step, s.
    n_steps : int
        Steps to take with the same inputs.
    """
    if x.dtype != np.float64 or not x.flags.c_contiguous or x.ndim != 2 or x.shape[1] != STATE_SIZE:
        raise ValueError("x must be a C-contiguous float64 array of shape (N, 17)")
    if NUMBA:
        _step_many_kernel(x, _batch_inputs(x, rotor_speed_cmd_rad_s, 4), _batch_inputs(x, wind_ned_m_s, 3),
                          param_vector(params), float(dt_s), int(n_steps))  # fmt: skip
        return x
    return step_many_numpy(x, rotor_speed_cmd_rad_s, wind_ned_m_s, params, dt_s, n_steps)


def step_many_numpy(
    x: np.ndarray,
    rotor_speed_cmd_rad_s: np.ndarray,
    wind_ned_m_s: np.ndarray,
    params: VehicleParams,
    dt_s: float,
    n_steps: int = 1,
) -> np.ndarray:
    """``step_many`` vectorised with numpy over the batch (no numba): one array operation per line
    of ``rigid_body._rates``. What ``step_many`` falls back to, and its benchmark's baseline."""
    cmd = _batch_inputs(x, rotor_speed_cmd_rad_s, 4)
    wind = _batch_inputs(x, wind_ned_m_s, 3)
    half = 0.5 * dt_s
    for _ in range(n_steps):
        k1 = rigid_body.derivative(x, cmd, wind, params)
        k2 = rigid_body.derivative(x + half * k1, cmd, wind, params)
        k3 = rigid_body.derivative(x + half * k2, cmd, wind, params)
        k4 = rigid_body.derivative(x + dt_s * k3, cmd, wind, params)
        x += (dt_s / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        q = x[:, QUAT]
        x[:, QUAT] = q * (1.0 / np.sqrt(np.sum(q * q, axis=1)))[:, None]
    return x


# --- one vehicle, one control sample: the inner loops ------------------------------------------


@_jit
def _euler_from_quat(w, x, y, z):  # noqa: ANN001, ANN202
    """``rotations.euler_from_quat``."""
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


@_jit
def _real_torques(e0, e1, e2, d0, d1, d2, t0, t1, t2, i0, i1, i2, index, sign):  # noqa: ANN001, ANN202
    """``euler_lagrange.real_torques`` (eq. 16) on floats: ``C eta_dot + J tau~``.

    ``index`` is the W_eta angle (0: phi, zyx; 2: psi, castillo/printed), ``sign`` its sign.
    """
    a = e0 if index == 0 else e2
    return _real_torques_sc(math.sin(e1), math.cos(e1), math.sin(a), math.cos(a), d0, d1, d2, t0, t1, t2, i0, i1, i2,
                            index, sign)  # fmt: skip


# eq. 16 on floats, the law's own (euler_lagrange.real_torques_terms), compiled
_real_torques_sc_i = _ijit(real_torques_terms)
_real_torques_sc = _jit(real_torques_terms)


@_jit
def _euler_accel_command(x, thrust, tau_tilde, believed, index, sign, p, cmd):  # noqa: ANN001, ANN202
    """EulerAccelActuation + RigidBodyModel.rotor_speed_command at state ``x``, into ``cmd``."""
    qw, qx, qy, qz = x[6], x[7], x[8], x[9]
    n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    roll, pitch, yaw = _euler_from_quat(qw / n, qx / n, qy / n, qz / n)
    # offboard.model.euler_lagrange.zyx_euler_rates_from_body_rates
    sr, cr = math.sin(roll), math.cos(roll)
    cp, tp = math.cos(pitch), math.tan(pitch)
    pr, qr, rr = x[10], x[11], x[12]
    vertical = qr * sr + rr * cr
    t0, t1, t2 = _real_torques(
        roll, pitch, yaw, pr + vertical * tp, qr * cr - rr * sr, vertical / cp,
        tau_tilde[0], tau_tilde[1], tau_tilde[2], believed[0], believed[1], believed[2], index, sign,
    )  # fmt: skip
    # offboard.model.euler_lagrange.zyx_body_torque_from_generalized
    sp = math.sin(pitch)
    vert = (t2 + sp * t0) / cp
    _speeds_for(thrust, t0, cr * t1 + sr * vert, -sr * t1 + cr * vert, p, cmd)


def _tau_speeds(qw, qx, qy, qz, pr, qr, rr, thrust, u0, u1, u2, i0, i1, i2, index, sign, k, w_min, w_max, arm, drag):  # noqa: ANN001, ANN202
    """EulerAccelActuation + RigidBodyModel.rotor_speed_command on floats, as ``_euler_accel_command``
    computes them but with the sines and cosines of the Euler angles taken from the quaternion
    algebraically (the arguments of ``_euler_from_quat``'s atan2 over their norm; the pitch's
    cosine as sqrt(1 - sin^2), |pitch| <= 90 deg): the same numbers to rounding with no
    trigonometric call, so that the batch kernel's loop over vehicles compiles to SIMD
    instructions. Returns the four rotor-speed commands (rad/s)."""
    n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    w, a, b, c = qw / n, qx / n, qy / n, qz / n
    sp = max(-1.0, min(1.0, 2.0 * (w * b - c * a)))
    cp = math.sqrt(1.0 - sp * sp)
    y_r, x_r = 2.0 * (w * a + b * c), 1.0 - 2.0 * (a * a + b * b)
    h_r = math.sqrt(y_r * y_r + x_r * x_r)
    sr, cr = y_r / h_r, x_r / h_r
    y_y, x_y = 2.0 * (w * c + a * b), 1.0 - 2.0 * (b * b + c * c)
    h_y = math.sqrt(y_y * y_y + x_y * x_y)
    sa = sr if index == 0 else y_y / h_y
    ca = cr if index == 0 else x_y / h_y
    # rigid_body.euler_rates_from_body_rates
    vertical = qr * sr + rr * cr
    t0, t1, t2 = _real_torques_sc_i(sp, cp, sa, ca, pr + vertical * (sp / cp), qr * cr - rr * sr, vertical / cp,
                                    u0, u1, u2, i0, i1, i2, index, sign)  # fmt: skip
    # rigid_body.body_torque_from_generalized, rigid_body.rotor_speeds_for
    vert = (t2 + sp * t0) / cp
    f0, f1, f2, f3 = _mix_forces_i(thrust, t0, cr * t1 + sr * vert, -sr * t1 + cr * vert, k, w_min, w_max, arm, drag)
    return math.sqrt(f0 / k), math.sqrt(f1 / k), math.sqrt(f2 / k), math.sqrt(f3 / k)


_tau_speeds_i = _ijit(_tau_speeds)


@_jit
def _euler_accel_command_algebraic(x, thrust, tau_tilde, believed, index, sign, p, cmd):  # noqa: ANN001, ANN202
    """``_euler_accel_command`` by ``_tau_speeds`` (no trigonometric call), into ``cmd``."""
    cmd[0], cmd[1], cmd[2], cmd[3] = _tau_speeds_i(
        x[6], x[7], x[8], x[9], x[10], x[11], x[12], thrust, tau_tilde[0], tau_tilde[1], tau_tilde[2],
        believed[0], believed[1], believed[2], index, sign, p[_K], p[_WMIN], p[_WMAX], p[_L], p[_C],
    )  # fmt: skip


@_jit
def _speeds_for(thrust, tx, ty, tz, p, cmd):  # noqa: ANN001, ANN202
    """``rigid_body.rotor_speeds_for`` into ``cmd``."""
    k = p[_K]
    f0, f1, f2, f3 = _mix_forces(thrust, tx, ty, tz, k, p[_WMIN], p[_WMAX], p[_L], p[_C])
    cmd[0] = math.sqrt(f0 / k)
    cmd[1] = math.sqrt(f1 / k)
    cmd[2] = math.sqrt(f2 / k)
    cmd[3] = math.sqrt(f3 / k)


@_jit
def _ground(x):  # noqa: ANN001, ANN202
    """``RigidBodyModel.ground_contact`` in place (after ``normalize``); True when resting."""
    _normalize(x)
    if x[2] < 0.0 or (x[2] == 0.0 and x[5] < 0.0):
        return False
    yaw = _euler_from_quat(x[6], x[7], x[8], x[9])[2]
    x[2] = 0.0
    x[3] = x[4] = x[5] = 0.0
    # rotations.quat_from_euler(0, 0, yaw)
    cr, sr = math.cos(0.0), math.sin(0.0)
    cp, sp = math.cos(0.0), math.sin(0.0)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    x[6] = cr * cp * cy + sr * sp * sy
    x[7] = sr * cp * cy - cr * sp * sy
    x[8] = cr * sp * cy + sr * cp * sy
    x[9] = cr * cp * sy - sr * sp * cy
    x[10] = x[11] = x[12] = 0.0
    return True


@_jit
def physics_scratch():  # noqa: ANN202
    """The work arrays of one ``physics_step`` loop: RK4's k1..k4, a stage state, the next state."""
    return (np.empty(STATE_SIZE), np.empty(STATE_SIZE), np.empty(STATE_SIZE), np.empty(STATE_SIZE),
            np.empty(STATE_SIZE), np.empty(STATE_SIZE))  # fmt: skip


@_jit
def _advance(x, n_steps, dt, mode, thrust, torque, believed, index, sign, p, winds, ground, xdot, cmd):  # noqa: ANN001, ANN202
    """``n_steps`` of ``VehicleSim.step``: actuation, RK4, normalise, ground. Returns on_ground.

    ``mode`` 0: held thrust and body torque (mixed once); 1: the paper's tau~ (``torque``) with
    eq. 16 at every step; 2: the same, by ``_euler_accel_command_algebraic``. ``winds``
    (n_steps, 3). ``x`` and ``xdot`` are updated in place.
    """
    k1, k2, k3, k4, tmp, nxt = physics_scratch()
    resting = False
    if mode == 0:
        _speeds_for(thrust, torque[0], torque[1], torque[2], p, cmd)
    for step in range(n_steps):
        if mode == 1:
            _euler_accel_command(x, thrust, torque, believed, index, sign, p, cmd)
        elif mode == 2:
            _euler_accel_command_algebraic(x, thrust, torque, believed, index, sign, p, cmd)
        resting = physics_step(x, cmd, winds[step], p, dt, ground, xdot, nxt, k1, k2, k3, k4, tmp)
    return resting


@_jit
def physics_step(x, cmd, wind, p, dt, ground, xdot, nxt, k1, k2, k3, k4, tmp):  # noqa: ANN001, ANN201
    """One ``VehicleSim`` physics step with rotor commands ``cmd``, in place: RK4, renormalise,
    ``xdot`` = mean derivative over the step, ground contact. Returns whether it rests."""
    _rk4_into(x, cmd, wind, p, dt, nxt, k1, k2, k3, k4, tmp)
    for i in range(STATE_SIZE):
        xdot[i] = (nxt[i] - x[i]) / dt
    resting = False
    if ground:
        resting = _ground(nxt)
        if resting:
            for i in range(STATE_SIZE):
                xdot[i] = 0.0
    for i in range(STATE_SIZE):
        x[i] = nxt[i]
    return resting


@_pjit
def _advance_many_kernel(x, active, n_steps, dt, mode, thrust, torque, believed, index, sign, p, winds, ground, xdot, cmd, resting):  # noqa: ANN001, ANN202
    for i in _prange(x.shape[0]):
        if active[i]:
            resting[i] = _advance(x[i], n_steps, dt, mode, thrust[i], torque[i], believed[i], index, sign, p[i], winds[i],
                                  ground, xdot[i], cmd[i])  # fmt: skip


@_ijit
def _stage_each(src, dst, cmd, wind, pb, n):  # noqa: ANN001, ANN202
    """``_stage`` with each vehicle's own parameters (``pb``: (14, BLOCK)), no fast-math."""
    for j in range(n):
        k, lo, hi, tau = pb[_K, j], pb[_WMIN, j], pb[_WMAX, j], pb[_TAU, j]
        moving = tau != 0.0
        rate = 1.0 / tau if moving else 0.0
        c0 = min(max(cmd[0, j], lo), hi)
        c1 = min(max(cmd[1, j], lo), hi)
        c2 = min(max(cmd[2, j], lo), hi)
        c3 = min(max(cmd[3, j], lo), hi)
        w0 = src[13, j] if moving else c0
        w1 = src[14, j] if moving else c1
        w2 = src[15, j] if moving else c2
        w3 = src[16, j] if moving else c3
        an, ae, ad, qwd, qxd, qyd, qzd, pd, qd, rd = _rates_i(
            src[3, j], src[4, j], src[5, j], src[6, j], src[7, j], src[8, j], src[9, j], src[10, j], src[11, j],
            src[12, j], k * w0 * w0, k * w1 * w1, k * w2 * w2, k * w3 * w3, wind[0, j], wind[1, j], wind[2, j],
            pb[_M, j], pb[_G, j], pb[_L, j], pb[_C, j], pb[_IXX, j], pb[_IYY, j], pb[_IZZ, j], pb[_DX, j], pb[_DY, j],
            pb[_DZ, j],
        )  # fmt: skip
        dst[0, j] = src[3, j]
        dst[1, j] = src[4, j]
        dst[2, j] = src[5, j]
        dst[3, j] = an
        dst[4, j] = ae
        dst[5, j] = ad
        dst[6, j] = qwd
        dst[7, j] = qxd
        dst[8, j] = qyd
        dst[9, j] = qzd
        dst[10, j] = pd
        dst[11, j] = qd
        dst[12, j] = rd
        if moving:
            dst[13, j] = (c0 - w0) * rate
            dst[14, j] = (c1 - w1) * rate
            dst[15, j] = (c2 - w2) * rate
            dst[16, j] = (c3 - w3) * rate
        else:
            dst[13, j] = dst[14, j] = dst[15, j] = dst[16, j] = 0.0


@_bjit
def _advance_blocks_kernel(x, active, n_steps, dt, mode, thrust, torque, believed, index, sign, p, winds, ground, xdot, cmd, resting):  # noqa: ANN001, ANN202
    """``_advance_many_kernel`` with mode 2's command (``_tau_speeds``) or mode 0's held one, the
    active vehicles taken in blocks of ``BLOCK`` transposed to (rows, BLOCK), as ``_step_many_kernel``
    does: each step's command, RK4 stages, renormalisation and mean derivative are loops over a
    block's vehicles that compile to SIMD instructions. Ground contact (a vehicle at or below the
    ground) goes by ``_ground`` one vehicle at a time."""
    rows = np.nonzero(active)[0]
    n_all = rows.shape[0]
    half = 0.5 * dt
    sixth = dt / 6.0
    for block in _prange((n_all + BLOCK - 1) // BLOCK):
        a = block * BLOCK
        n = min(n_all, a + BLOCK) - a
        xb = np.zeros((STATE_SIZE, BLOCK))
        nb = np.zeros((STATE_SIZE, BLOCK))
        db = np.zeros((STATE_SIZE, BLOCK))
        ks = np.zeros((4, STATE_SIZE, BLOCK))
        t = np.zeros((STATE_SIZE, BLOCK))
        pb = np.ones((14, BLOCK))
        ub = np.zeros((4, BLOCK))
        bb = np.ones((3, BLOCK))
        cb = np.zeros((4, BLOCK))
        wb = np.zeros((3, BLOCK))
        rb = np.zeros(BLOCK, dtype=np.bool_)
        one = np.empty(STATE_SIZE)
        for j in range(n):
            i = rows[a + j]
            for r in range(STATE_SIZE):
                xb[r, j] = x[i, r]
            for r in range(14):
                pb[r, j] = p[i, r]
            ub[0, j] = thrust[i]
            for r in range(3):
                ub[r + 1, j] = torque[i, r]
                bb[r, j] = believed[i, r]
            for r in range(4):
                cb[r, j] = cmd[i, r]
        if mode == 0:
            for j in range(n):
                f0, f1, f2, f3 = _mix_forces_i(ub[0, j], ub[1, j], ub[2, j], ub[3, j], pb[_K, j], pb[_WMIN, j], pb[_WMAX, j],
                                               pb[_L, j], pb[_C, j])  # fmt: skip
                k = pb[_K, j]
                cb[0, j] = math.sqrt(f0 / k)
                cb[1, j] = math.sqrt(f1 / k)
                cb[2, j] = math.sqrt(f2 / k)
                cb[3, j] = math.sqrt(f3 / k)
        for step in range(n_steps):
            for j in range(n):
                i = rows[a + j]
                wb[0, j] = winds[i, step, 0]
                wb[1, j] = winds[i, step, 1]
                wb[2, j] = winds[i, step, 2]
            if mode != 0:
                for j in range(n):
                    c0, c1, c2, c3 = _tau_speeds_i(
                        xb[6, j], xb[7, j], xb[8, j], xb[9, j], xb[10, j], xb[11, j], xb[12, j], ub[0, j], ub[1, j],
                        ub[2, j], ub[3, j], bb[0, j], bb[1, j], bb[2, j], index, sign, pb[_K, j], pb[_WMIN, j],
                        pb[_WMAX, j], pb[_L, j], pb[_C, j],
                    )  # fmt: skip
                    cb[0, j] = c0
                    cb[1, j] = c1
                    cb[2, j] = c2
                    cb[3, j] = c3
            # RK4 in the reference's order (_rk4_into), then renormalised
            for r in range(STATE_SIZE):
                for j in range(n):
                    t[r, j] = xb[r, j]
            for s in range(4):
                _stage_each(t, ks[s], cb, wb, pb, n)
                if s < 3:
                    h = dt if s == 2 else half
                    for r in range(STATE_SIZE):
                        for j in range(n):
                            t[r, j] = xb[r, j] + h * ks[s, r, j]
            for r in range(STATE_SIZE):
                for j in range(n):
                    nb[r, j] = xb[r, j] + sixth * (ks[0, r, j] + 2.0 * ks[1, r, j] + 2.0 * ks[2, r, j] + ks[3, r, j])
            for j in range(n):
                inv = 1.0 / math.sqrt(nb[6, j] * nb[6, j] + nb[7, j] * nb[7, j] + nb[8, j] * nb[8, j] + nb[9, j] * nb[9, j])
                nb[6, j] *= inv
                nb[7, j] *= inv
                nb[8, j] *= inv
                nb[9, j] *= inv
            # physics_step: the mean derivative, then the ground (whose _normalize runs again)
            for r in range(STATE_SIZE):
                for j in range(n):
                    db[r, j] = (nb[r, j] - xb[r, j]) / dt
            if ground:
                for j in range(n):
                    inv = 1.0 / math.sqrt(nb[6, j] * nb[6, j] + nb[7, j] * nb[7, j] + nb[8, j] * nb[8, j]
                                          + nb[9, j] * nb[9, j])  # fmt: skip
                    nb[6, j] *= inv
                    nb[7, j] *= inv
                    nb[8, j] *= inv
                    nb[9, j] *= inv
                for j in range(n):
                    rb[j] = False
                    if not (nb[2, j] < 0.0 or (nb[2, j] == 0.0 and nb[5, j] < 0.0)):
                        for r in range(STATE_SIZE):
                            one[r] = nb[r, j]
                        rb[j] = _ground(one)
                        for r in range(STATE_SIZE):
                            nb[r, j] = one[r]
                            if rb[j]:
                                db[r, j] = 0.0
            xb, nb = nb, xb
        for j in range(n):
            i = rows[a + j]
            for r in range(STATE_SIZE):
                x[i, r] = xb[r, j]
                xdot[i, r] = db[r, j]
            for r in range(4):
                cmd[i, r] = cb[r, j]
            if ground and n_steps > 0:
                resting[i] = rb[j]


def advance_many(
    x: np.ndarray,
    active: np.ndarray,
    n_steps: int,
    dt_s: float,
    thrust_n: np.ndarray,
    tau_tilde_rad_s2: np.ndarray,
    believed_inertia_kg_m2: np.ndarray,
    euler_rate_form: EulerRateForm,
    params: np.ndarray,
    winds: np.ndarray,
    ground: bool,
    xdot: np.ndarray,
    cmd: np.ndarray,
    resting: np.ndarray,
    mode: int = 1,
) -> None:
    """``FastRigidBodySim.step(n_steps)`` with an ``EulerAccelActuation`` for each of N vehicles
    at once, in place: the paper's tau~ with eq. 16 at every physics step (believed inertia and
    W_eta form), mixer, RK4, renormalisation, ground contact. Each vehicle has its own parameters.

    Parameters
    ----------
    x, xdot : ndarray (N, 17)
        States and their mean derivatives over the last step (updated).
    active : ndarray (N,) of bool
        Only these are stepped.
    thrust_n : ndarray (N,); tau_tilde_rad_s2, believed_inertia_kg_m2 : ndarray (N, 3)
    params : ndarray (N, 14)
        ``param_vector`` of each vehicle.
    winds : ndarray (N, n_steps, 3)
        The wind of each physics step.
    cmd : ndarray (N, 4)
        The rotor-speed commands (updated; what an instant motor reports).
    resting : ndarray (N,) of bool
        Whether each rests on the ground afterwards (updated).
    mode : int
        1: tau~ as above; 0: ``thrust_n`` and ``tau_tilde_rad_s2`` are a held thrust and body
        torque (``HeldActuation``, as ``VehicleSim``'s idle actuation before the first command).
    """
    index, sign = _EULER_FORMS[euler_rate_form]
    if mode in (0, 2) and NUMBA:
        _advance_blocks_kernel(x, active, int(n_steps), float(dt_s), int(mode), thrust_n, tau_tilde_rad_s2,
                               believed_inertia_kg_m2, index, sign, params, winds, bool(ground), xdot, cmd, resting)  # fmt: skip
        return
    _advance_many_kernel(x, active, int(n_steps), float(dt_s), int(mode), thrust_n, tau_tilde_rad_s2, believed_inertia_kg_m2,
                         index, sign, params, winds, bool(ground), xdot, cmd, resting)  # fmt: skip


class CompiledKernel(Protocol):
    """What ``is_cached`` reads of a kernel: a numba dispatcher compiled with ``cache=True`` (numba
    ships no types, so its cache is ``Any``)."""

    py_func: types.FunctionType
    _cache: Any


def is_cached(*kernels: CompiledKernel) -> bool:
    """Whether numba's on-disk cache holds these compiled kernels for the source this process
    imported: then loading them takes a fraction of a second, where compiling takes seconds (first
    run). Numba's own test, its index's stamp of the source (a hash of its content): a file
    touched or checked out again unchanged is still cached, as numba loads it (a test of the
    files' times said no there, and the plant then ran interpreted for good, since numba never
    saved the index again)."""
    if not NUMBA:
        return False
    try:
        return all(kernel._cache._cache_file._load_index() for kernel in kernels)
    except (AttributeError, OSError, EOFError, ValueError, pickle.UnpicklingError):
        return False


def stale_cache_files(cache_dir: str | os.PathLike[str], module_stem: str, depends_on: tuple[str, ...]) -> list[str]:
    """The files of numba's on-disk cache in ``cache_dir`` of the kernels of module
    ``module_stem`` (``<stem>.<function>-<line>.py3xx.nbi`` / ``.nbc``) older than the newest of
    the source files ``depends_on``.

    numba keys a cached kernel to its own module's file only. A kernel that has another module's
    compiled functions built into it (``px4_kernel``'s have the physics of this module; this
    module's have ``rigid_body``'s equations) would after an edit of that other file keep serving
    the old machine code: stale physics, with nothing said (one edit here left ``px4_kernel``
    1e-14 off its own Python loop, which its test caught)."""
    try:
        newest = max(os.path.getmtime(f) for f in depends_on)
        names = os.listdir(cache_dir)
    except (OSError, ValueError):
        return []
    out = []
    for name in names:
        if name.startswith(module_stem + ".") and name.endswith((".nbi", ".nbc")):
            path = os.path.join(cache_dir, name)
            try:
                if os.path.getmtime(path) < newest:
                    out.append(path)
            except OSError:  # another process removed it first
                continue
    return out


def drop_stale_cache(kernel: CompiledKernel, depends_on: tuple[str, ...]) -> None:
    """Remove the cached machine code of ``kernel``'s module that is older than any of
    ``depends_on`` (``stale_cache_files``), so that numba compiles those kernels again at their
    first call. Call it where the module's kernels are defined, before any is called."""
    if not NUMBA:
        return
    try:
        cache_dir = kernel._cache._cache_path
    except AttributeError:
        return
    stem = os.path.splitext(os.path.basename(kernel.py_func.__code__.co_filename))[0]
    for path in stale_cache_files(cache_dir, stem, depends_on):
        try:
            os.remove(path)
        except OSError:  # another process (an xdist worker, a Dask worker) removed it first
            pass


# this module's kernels have rigid_body's equations and euler_lagrange's eq. 16 built in
drop_stale_cache(_advance_many_kernel, (rigid_body.__file__, euler_lagrange.__file__))


def warm_up() -> None:
    """Load (or compile) the one-vehicle kernel now, not at the first physics step (numba loads
    its cached machine code lazily, which takes a good part of a second)."""
    x = np.zeros(STATE_SIZE)
    x[6] = 1.0
    _advance(x, 1, 1e-3, 0, 0.0, np.zeros(3), np.zeros(3), 0, -1.0, param_vector(VehicleParams()), np.zeros((1, 3)),
             True, np.zeros(STATE_SIZE), np.zeros(4))  # fmt: skip


_EULER_FORMS = EULER_FORM_TERMS  # the one table (offboard.model.euler_lagrange)


def compile_many() -> None:
    """Compile (first time: about a minute on one core) or load the many-vehicle kernels by running
    each once on three vehicles: ``derivative_many``, ``step_many`` and ``advance_many`` in its
    per-vehicle and blocked forms (the sweep's). ``python -m sitl_plant.dynamics.batch``; make test
    runs it in the background at the lowest priority (Makefile), make bench before its run.
    The one-vehicle kernels are ``sitl_plant.px4_kernel.compile_all``'s."""
    n = 3
    params = VehicleParams()
    x = np.zeros((n, STATE_SIZE))
    x[:, 6] = 1.0
    x[:, 2] = -1.0
    p = np.tile(param_vector(params), (n, 1))
    for mode in (2, 1):  # the sweep's first: more of the tests use it
        advance_many(x, np.ones(n, dtype=bool), 2, 1e-3, np.full(n, params.mass_kg * params.gravity_m_s2),
                     np.zeros((n, 3)), np.ones((n, 3)), next(iter(_EULER_FORMS)), p, np.zeros((n, 2, 3)), True,
                     np.zeros((n, STATE_SIZE)), np.zeros((n, 4)), np.zeros(n, dtype=bool), mode=mode)  # fmt: skip
    step_many(x, np.full(4, 300.0), np.zeros(3), params, 1e-3)
    derivative_many(x, np.full(4, 300.0), np.zeros(3), params)


class FastRigidBodySim(VehicleSim):
    """``VehicleSim`` with a ``RigidBodyModel``, stepped by the compiled kernels.

    Same constructor, attributes (``model``, ``x``, ``time_s``, ``steps``, ``on_ground``,
    ``actuation``) and methods (``step``, ``truth``, ``truth_position_ned``) as
    ``VehicleSim``, of which it is a subclass, and the same results to rounding
    (``tests/unit/sitl_plant/test_batch.py``).

    ``HeldActuation`` and ``EulerAccelActuation`` run a whole ``step(n)`` in one compiled
    call, and so does an actuation with an ``advance_rigid_body(sim, n_steps, winds) -> bool``
    method when it returns True (the plant's ``Px4Loop`` in its attitude and rate modes, fused
    with the physics in ``sitl_plant.px4_kernel``). An actuation with a
    ``held(model, x, max_steps) -> (thrust, torque, k)`` method (the
    plant's ``Px4Loop``, whose output is held between gyro samples) is called once per ``k``
    steps, which are integrated in one compiled call; any other actuation is called in Python
    once per physics step.
    """

    def __init__(
        self,
        model: RigidBodyModel,
        *,
        physics_dt_s: float = 1e-3,
        wind=None,  # noqa: ANN001 - a dynamics.wind.WindField
        ground: bool = True,
        initial_pos_ned_m: np.ndarray | None = None,
        initial_yaw_rad: float = 0.0,
    ) -> None:
        if not isinstance(model, RigidBodyModel):
            raise TypeError("FastRigidBodySim steps a RigidBodyModel")
        super().__init__(
            model, physics_dt_s=physics_dt_s, wind=wind, ground=ground,
            initial_pos_ned_m=initial_pos_ned_m, initial_yaw_rad=initial_yaw_rad,
        )  # fmt: skip
        self.x = np.ascontiguousarray(self.x, dtype=float)
        self._last_xdot = np.ascontiguousarray(self._last_xdot, dtype=float)
        self._cmd = np.zeros(4)
        self._no_wind: np.ndarray = np.zeros((0, 3))
        self._zeros3 = np.zeros(3)
        self._believed: tuple[np.ndarray | None, np.ndarray] = (None, self._zeros3)  # (inertia, its diagonal)

    _model: RigidBodyModel

    @property
    def model(self) -> Model:
        """The vehicle model stepped (a ``RigidBodyModel``)."""
        return self._model

    @model.setter
    def model(self, model: Model) -> None:
        """A new vehicle (the plant rebuilds it when a SIM_* parameter changes): new kernel parameters."""
        if not isinstance(model, RigidBodyModel):
            raise TypeError("FastRigidBodySim steps a RigidBodyModel")
        self._model = model
        self._p = param_vector(model.params)

    def _winds(self, n_steps: int) -> np.ndarray:
        if self.wind is None:
            if self._no_wind.shape[0] < n_steps:
                self._no_wind = np.zeros((n_steps, 3))
            return self._no_wind
        out = np.empty((n_steps, 3))
        pos = self.x[0:3]
        for i in range(n_steps):
            out[i] = self.wind.velocity_ned((self.steps + i) * self.physics_dt_s, pos)
        self._wind_now = out[n_steps - 1].copy()
        return out

    def _held(self, thrust: float, torque: np.ndarray, n_steps: int, winds: np.ndarray) -> None:
        """``n_steps`` with thrust and body torque held (mixed once), in one compiled call."""
        self.on_ground = bool(
            _advance(self.x, n_steps, self.physics_dt_s, 0, thrust, torque, self._zeros3, 0, -1.0, self._p, winds,
                     self.ground, self._last_xdot, self._cmd)  # fmt: skip
        )

    def step(self, n_steps: int = 1) -> None:
        """Advance ``n_steps`` physics steps with the current actuation."""
        act = self.actuation
        winds = self._winds(n_steps)
        if isinstance(act, HeldActuation):
            self._held(float(act.thrust_n), np.asarray(act.torque_nm, dtype=float), n_steps, winds)
        elif isinstance(act, EulerAccelActuation):
            if self._believed[0] is not act.believed_inertia:  # the same believed matrix every sample
                self._believed = (act.believed_inertia, np.ascontiguousarray(np.diag(act.believed_inertia), dtype=float))
            believed = self._believed[1]
            index, sign = _EULER_FORMS[act.form]
            self.on_ground = bool(  # mode 2: eq. 16 with no trigonometric call, as the batch's (the same to rounding, 15 % faster)
                _advance(self.x, n_steps, self.physics_dt_s, 2, float(act.thrust_n), np.asarray(act.tau_tilde, dtype=float),
                         believed, index, sign, self._p, winds, self.ground, self._last_xdot, self._cmd)  # fmt: skip
            )
        elif (advance := getattr(act, "advance_rigid_body", None)) is not None and advance(self, n_steps, winds):
            pass  # the actuation flew the steps itself, in one compiled call (Px4Loop)
        else:
            held = getattr(act, "held", None)
            done = 0
            while done < n_steps:
                if held is not None:
                    thrust, torque, k = held(self._model, self.x, n_steps - done)
                else:
                    (thrust, torque), k = act(self._model, self.x), 1
                self._held(float(thrust), np.asarray(torque, dtype=float), k, winds[done : done + k])
                done += k
                self.steps += k
                self.time_s = self.steps * self.physics_dt_s
            return
        self.steps += n_steps
        self.time_s = self.steps * self.physics_dt_s

    def truth_position_ned(self) -> np.ndarray:
        """The true position now, NED, m (a copy)."""
        return self.x[0:3].copy()

    def truth(self) -> VehicleState:
        """The true state now; acceleration is the mean over the last physics step."""
        self._model._cmd = self._cmd  # the rotor speeds it reports with an instant motor model
        return super().truth()


if __name__ == "__main__":
    import time

    start = time.monotonic()
    compile_many()
    print(f"many-vehicle kernels ready ({'numba' if NUMBA else 'no numba: interpreted'}) in {time.monotonic() - start:.1f} s")
