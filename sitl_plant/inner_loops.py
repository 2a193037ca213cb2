"""The vehicle-side loops: setpoints and autopilot tasks turned into an actuation for ``VehicleSim``.

Three ways a setpoint becomes thrust and torque (``InnerLoops.actuation_for``):

- ``px4`` inner loop (default, ``Px4Loop``): PX4's ``mc_att_control`` (quaternion attitude error
  with reduced-attitude/yaw weighting, P gains ``MC_*_P``, rate limits ``MC_*RATE_MAX``; on the
  paper model, whose W_eta is not a rigid body's kinematics away from psi = 0, the same P acts on
  the Euler-angle errors and ``omega_sp = W_eta eta_dot_sp``) and
  ``mc_rate_control`` (PID ``MC_*RATE_P/I/D`` with integrator limits ``MC_*_INT_LIM``), run at
  most at ``IMU_GYRO_RATEMAX`` (every ``ceil(1 / (dt IMU_GYRO_RATEMAX))`` physics steps, the
  torque held in between), as PX4 runs them on each gyro sample. As in PX4 the rate PID's output is the **normalised torque** in [-1, 1];
  the body FRD torque is ``u * SIM_TQ_RP_MAX`` (roll, pitch) and ``u * SIM_TQ_Y_MAX`` (yaw), and
  reaches the model as the generalised torque ``W_eta^T tau_body`` (virtual work:
  ``tau_body . omega = (W_eta^T tau_body) . eta_dot``) through ``model.torque_from_generalized``
  (for the rigid body, whose input is the body torque, this round trip is the identity and is
  skipped).
- ``paper`` inner loop (``paper_actuation``): at each setpoint the body-rate reference becomes
  an Euler-rate reference ``eta_dot_ref = W_eta^-1 omega_ref`` and the paper's
  ``tau_tilde = (eta_dot_ref - eta_dot) / PAP_TO`` (eq. 40-42) is held until the next setpoint,
  with eq. 16 applied at every physics step with the inertia ``PAP_I**`` the loop believes
  (``EulerAccelActuation``).
- Actuator setpoints (``actuator_actuation``): normalised torques and thrust scaled by
  ``SIM_TQ_*_MAX`` and ``SIM_THR_MAX`` and held: the model's torque input directly (generalised
  torques for the paper model, body torques for the rigid body).

Thrust in newtons is always ``clip(thrust_norm, 0, 1) * SIM_THR_MAX``, as PX4 clips it.

The Hold / Land / Takeoff / Return modes use a small position controller in PX4's shape
(``mc_pos_control``: P on position, PID on velocity, thrust vector with hover thrust
``MPC_THR_HOVER`` and tilt limit ``MPC_TILTMAX_AIR``) at 50 Hz, feeding the PX4 attitude loop.
For the paper model, whose translation ignores yaw (eq. 18), the tilt is computed from eq. 18
itself, so these modes work at any heading.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Callable

import numpy as np

from offboard.model.attitude import Quat, Vec3, bodyz_to_attitude
from offboard.model.attitude import dcm_z as _dcm_z
from offboard.model.attitude import qinv as _qinv
from offboard.model.attitude import qmul as _qmul
from offboard.model.attitude import qnormalize as _qnormalize
from offboard.model.attitude import quat_between as _quat_between
from offboard.model.attitude import quat_from_euler as _quat_from_euler
from offboard.model.euler_lagrange import EulerRateForm, euler_rate_matrix
from sitl_plant.autopilot import (
    ActuatorSetpoint,
    AttitudeSetpoint,
    IdleTask,
    OffboardTask,
    PositionSetpoint,
    PositionTask,
    Setpoint,
    Task,
)
from sitl_plant.dynamics.rigid_body import QUAT, RATES, RigidBodyModel
from sitl_plant.params import ParamTable
from sitl_plant.simulation import IDLE, Actuation, EulerAccelActuation, HeldActuation, Model, PaperModel

if TYPE_CHECKING:
    from sitl_plant.dynamics.batch import FastRigidBodySim

POSITION_LOOP_DT_S = 0.02  # PX4 runs mc_pos_control at 50 Hz
_I_FACTOR_RATE = math.radians(400.0)  # PX4 RateControl: integrator fades for errors near 400 deg/s


def model_euler_form(model: Model) -> EulerRateForm:
    """The W_eta form of a model: the vehicle file's for the paper model, ZYX for a rigid body."""
    if isinstance(model, PaperModel):
        return model.params.euler_rate_form
    return EulerRateForm.ZYX


def _is_rigid_body(model: Model) -> bool:
    return isinstance(model, RigidBodyModel)


# --- reading the model's attitude -------------------------------------------------------------


def _state_reader(model: Model) -> Callable[[np.ndarray], tuple[Quat, Vec3, tuple[float, float, float]]]:
    """A function x -> (quaternion wxyz, body rates FRD, Euler angles) for this model (the
    rigid body's Euler angles are not computed: its loops use the quaternion)."""
    if _is_rigid_body(model):

        def read_rigid(x: np.ndarray) -> tuple[Quat, Vec3, tuple[float, float, float]]:
            # the quaternion loop needs no Euler angles: skip them on this hot path
            q = _qnormalize(tuple(x[QUAT].tolist()))
            return q, tuple(x[RATES].tolist()), (0.0, 0.0, 0.0)

        return read_rigid
    form = model_euler_form(model)

    def read_euler(x: np.ndarray) -> tuple[Quat, Vec3, tuple[float, float, float]]:
        eta, eta_dot = model.euler(x)
        phi, theta, psi = (float(v) for v in eta)
        w = euler_rate_matrix(eta, form)
        omega = w @ eta_dot
        return _quat_from_euler(phi, theta, psi), (float(omega[0]), float(omega[1]), float(omega[2])), (phi, theta, psi)

    return read_euler


def _torque_writer(model: Model) -> Callable[[np.ndarray, tuple[float, float, float], Vec3], np.ndarray]:
    """A function (x, euler, tau_body) -> the model's torque input exerting the body torque."""
    if _is_rigid_body(model):
        return lambda x, eta, tau: np.array(tau)
    form = model_euler_form(model)

    def write(x: np.ndarray, eta: tuple[float, float, float], tau: Vec3) -> np.ndarray:
        w = euler_rate_matrix(np.asarray(eta), form)
        return model.torque_from_generalized(x, w.T @ np.asarray(tau))

    return write


# --- PX4's attitude, rate and position loops ---------------------------------------------------


class Px4Loop:
    """PX4's attitude P and rate PID (and, for the auto modes, a position PID): an actuation.

    Called by ``VehicleSim`` at every physics step with the true state ``x``; keeps its own
    integrators, so one object serves a whole flight (``reset()`` when disarmed).

    Parameters
    ----------
    params : ParamTable
        Gains are read from ``MC_*`` and ``MPC_*``; call ``reload()`` after a change.
    model : Model
        The simulated vehicle (to read its attitude and to apply torques).
    physics_dt_s : float
        The integration step; the loops run every ``ceil(1 / (physics_dt_s IMU_GYRO_RATEMAX))`` steps.
    """

    def __init__(self, params: ParamTable, model: Model, physics_dt_s: float) -> None:
        self.params = params
        self.dt = physics_dt_s
        self.landed = True
        self.bind(model)
        self.reload()
        self.reset()
        self._mode = "idle"
        self._q_sp: Quat = (1.0, 0.0, 0.0, 0.0)
        self._rates_sp: Vec3 = (0.0, 0.0, 0.0)
        self._yaw_ff = 0.0
        self._thrust_n = 0.0
        self._pos_task: PositionTask | None = None
        self.last_output: tuple[float, np.ndarray] = (0.0, np.zeros(3))

    def bind(self, model: Model) -> None:
        """Attach to a (possibly rebuilt) model."""
        self.model = model
        self._read = _state_reader(model)
        self._write = _torque_writer(model)
        self._paper_translation = isinstance(model, PaperModel)
        # the paper model's W_eta (castillo form) is not a rigid body's kinematics away from
        # psi = 0: its attitude loop acts on the Euler angles themselves (see rates_for_attitude)
        self._euler_attitude = isinstance(model, PaperModel)
        self._form = model_euler_form(model)

    def reload(self) -> None:
        """Read the gains and limits again from the parameters (MC_*, MPC_*: after a PARAM_SET)."""
        p = self.params
        roll_p, pitch_p, yaw_p = p["MC_ROLL_P"], p["MC_PITCH_P"], p["MC_YAW_P"]
        self._yaw_w = min(max(yaw_p / roll_p, 0.0), 1.0) if roll_p > 0 else 0.0
        # PX4 compensates the yaw weight's scaling of the output
        self._att_p = (roll_p, pitch_p, yaw_p / self._yaw_w if self._yaw_w > 1e-4 else yaw_p)
        self._rate_p = (p["MC_ROLLRATE_P"], p["MC_PITCHRATE_P"], p["MC_YAWRATE_P"])
        self._rate_i = (p["MC_ROLLRATE_I"], p["MC_PITCHRATE_I"], p["MC_YAWRATE_I"])
        self._rate_d = (p["MC_ROLLRATE_D"], p["MC_PITCHRATE_D"], p["MC_YAWRATE_D"])
        self._int_lim = (p["MC_RR_INT_LIM"], p["MC_PR_INT_LIM"], p["MC_YR_INT_LIM"])
        self._rate_max = tuple(math.radians(p[n]) for n in ("MC_ROLLRATE_MAX", "MC_PITCHRATE_MAX", "MC_YAWRATE_MAX"))
        self._tq_max = (p["SIM_TQ_RP_MAX"], p["SIM_TQ_RP_MAX"], p["SIM_TQ_Y_MAX"])
        self._thr_max = p["SIM_THR_MAX"]
        # the loops run every `_every` physics steps: at most IMU_GYRO_RATEMAX, as PX4's run on the gyro
        self._every = max(1, math.ceil(1.0 / (self.dt * p["IMU_GYRO_RATEMAX"]) - 1e-9))
        self._pos_every = max(1, round(POSITION_LOOP_DT_S / (self.dt * self._every)))  # in loop runs
        self._version = p.version

    def reset(self) -> None:
        """Zero the integrators and the derivative memory (on disarm and mode changes)."""
        self._rate_int = [0.0, 0.0, 0.0]
        self._prev_rates: Vec3 | None = None
        self._vel_int = [0.0, 0.0, 0.0]
        self._pos_count = 0
        self._step_count = 0

    # -- targets ---------------------------------------------------------------------------------

    def fly_attitude(self, q_wxyz: Quat, thrust_n: float, yaw_rate_ff: float = 0.0) -> None:
        """Fly this attitude (body FRD to NED) and thrust (N), the yaw rate feed-forward added (rad/s)."""
        self._mode = "attitude"
        self._q_sp = q_wxyz
        self._yaw_ff = yaw_rate_ff
        self._thrust_n = thrust_n

    def fly_rates(self, rates_frd_rad_s: Vec3, thrust_n: float) -> None:
        """Fly these body rates (FRD, rad/s) and thrust (N)."""
        self._mode = "rates"
        self._rates_sp = rates_frd_rad_s
        self._thrust_n = thrust_n

    def fly_position(self, task: PositionTask) -> None:
        """Fly a position task with the position and velocity loops (their integrators start from zero
        when the loop was not already flying one).
        """
        if self._mode != "position":
            self._vel_int = [0.0, 0.0, 0.0]
            self._pos_count = 0
        self._mode = "position"
        self._pos_task = task

    # -- the loops -------------------------------------------------------------------------------

    def attitude_rates(self, q: Quat, q_sp: Quat, yaw_ff: float) -> Vec3:
        """PX4 AttitudeControl::update: body rate setpoint from the attitude error."""
        e_z = _dcm_z(q)
        e_z_d = _dcm_z(q_sp)
        qd_red = _quat_between(e_z, e_z_d)
        if abs(qd_red[1]) > 1 - 1e-5 or abs(qd_red[2]) > 1 - 1e-5:
            qd_red = q_sp
        else:
            qd_red = _qmul(qd_red, q)
        q_mix = _qmul(_qinv(qd_red), q_sp)
        if q_mix[0] < 0:
            q_mix = (-q_mix[0], -q_mix[1], -q_mix[2], -q_mix[3])
        w0 = min(max(q_mix[0], -1.0), 1.0)
        w3 = min(max(q_mix[3], -1.0), 1.0)
        qd = _qmul(qd_red, (math.cos(self._yaw_w * math.acos(w0)), 0.0, 0.0, math.sin(self._yaw_w * math.asin(w3))))
        qe = _qmul(_qinv(q), qd)
        sign = 2.0 if qe[0] >= 0 else -2.0
        kp = self._att_p
        rates = [sign * qe[1] * kp[0], sign * qe[2] * kp[1], sign * qe[3] * kp[2]]
        if yaw_ff:
            zb = _dcm_z(_qinv(q))
            rates = [rates[i] + zb[i] * yaw_ff for i in range(3)]
        rmax = self._rate_max
        return (
            min(max(rates[0], -rmax[0]), rmax[0]),
            min(max(rates[1], -rmax[1]), rmax[1]),
            min(max(rates[2], -rmax[2]), rmax[2]),
        )

    def euler_attitude_rates(self, eta: tuple[float, float, float], q_sp: Quat, yaw_ff: float) -> Vec3:
        """Attitude P on the Euler angles, for models whose angles are generalised coordinates:
        ``eta_dot_sp = K_P (eta_sp - eta)`` (yaw error wrapped), ``omega_sp = W_eta eta_dot_sp``."""
        w, x, y, z = q_sp
        roll_sp = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
        pitch_sp = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
        yaw_sp = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        kp = self.params
        yaw_err = (yaw_sp - eta[2] + math.pi) % (2.0 * math.pi) - math.pi
        eta_dot_sp = np.array(
            [kp["MC_ROLL_P"] * (roll_sp - eta[0]), kp["MC_PITCH_P"] * (pitch_sp - eta[1]), kp["MC_YAW_P"] * yaw_err + yaw_ff]
        )
        omega = euler_rate_matrix(np.asarray(eta), self._form) @ eta_dot_sp
        rmax = self._rate_max
        return (
            min(max(float(omega[0]), -rmax[0]), rmax[0]),
            min(max(float(omega[1]), -rmax[1]), rmax[1]),
            min(max(float(omega[2]), -rmax[2]), rmax[2]),
        )

    def rates_for_attitude(self, q: Quat, eta: tuple[float, float, float], q_sp: Quat, yaw_ff: float) -> Vec3:
        """The body-rate setpoint for an attitude setpoint, the right way for this model."""
        if self._euler_attitude:
            return self.euler_attitude_rates(eta, q_sp, yaw_ff)
        return self.attitude_rates(q, q_sp, yaw_ff)

    def rate_torque(self, rates: Vec3, rates_sp: Vec3) -> Vec3:
        """PX4 RateControl::update: normalised torque in [-1, 1] from the rate error."""
        prev = self._prev_rates if self._prev_rates is not None else rates
        self._prev_rates = rates
        dt = self.dt * self._every
        out = [0.0, 0.0, 0.0]
        for i in range(3):
            err = rates_sp[i] - rates[i]
            accel = (rates[i] - prev[i]) / dt
            u = self._rate_p[i] * err + self._rate_int[i] - self._rate_d[i] * accel
            if not self.landed and not ((u > 1.0 and err > 0) or (u < -1.0 and err < 0)):
                i_factor = err / _I_FACTOR_RATE
                i_factor = max(0.0, 1.0 - i_factor * i_factor)
                lim = self._int_lim[i]
                self._rate_int[i] = min(max(self._rate_int[i] + i_factor * self._rate_i[i] * err * dt, -lim), lim)
            out[i] = min(max(u, -1.0), 1.0)
        return (out[0], out[1], out[2])

    def position_attitude(self, x: np.ndarray) -> tuple[Quat, float]:
        """PX4 PositionControl (P on position, PID on velocity, thrust vector): attitude, thrust N."""
        task = self._pos_task
        assert task is not None
        p = self.params
        st = self.model.vehicle_state(x, 0.0, np.zeros(self.model.state_size))
        pos, vel = st.pos_ned_m, st.vel_ned_m_s
        dt = POSITION_LOOP_DT_S
        gains = (p["MPC_XY_P"], p["MPC_XY_P"], p["MPC_Z_P"])
        vsp = [
            task.vel_ned_m_s[i] + (0.0 if task.pos_ned_m[i] is None else gains[i] * (task.pos_ned_m[i] - pos[i]))
            for i in range(3)
        ]
        vxy_max = p["MPC_XY_VEL_MAX"]
        vxy = math.hypot(vsp[0], vsp[1])
        if vxy > vxy_max:
            vsp[0] *= vxy_max / vxy
            vsp[1] *= vxy_max / vxy
        up_max = p["MPC_Z_VEL_MAX_UP"] if task.max_climb_m_s is None else min(p["MPC_Z_VEL_MAX_UP"], task.max_climb_m_s)
        # the climb limit last: PX4's takeoff ramp starts below zero (a descent asked for: no thrust)
        vsp[2] = max(min(vsp[2], p["MPC_Z_VEL_MAX_DN"]), -up_max)
        if task.descend_m_s is not None:
            vsp[2] = task.descend_m_s
        kp = (p["MPC_XY_VEL_P_ACC"], p["MPC_XY_VEL_P_ACC"], p["MPC_Z_VEL_P_ACC"])
        ki = (p["MPC_XY_VEL_I_ACC"], p["MPC_XY_VEL_I_ACC"], p["MPC_Z_VEL_I_ACC"])
        g = 9.81
        acc = [0.0, 0.0, 0.0]
        for i in range(3):
            if i < 2 and task.acc_ne_m_s2 is not None:  # Altitude mode: the sticks' tilt as acceleration
                acc[i] = task.acc_ne_m_s2[i]
                self._vel_int[i] = 0.0
                continue
            err = vsp[i] - float(vel[i])
            acc[i] = kp[i] * err + self._vel_int[i] + (task.acc_ff_ne_m_s2[i] if i < 2 else 0.0)
            if not self.landed:
                self._vel_int[i] = min(max(self._vel_int[i] + ki[i] * err * dt, -g), g)
        hover = p["MPC_THR_HOVER"]
        tilt_max = math.radians(p["MPC_TILTMAX_AIR"])
        # specific force wanted, NED: f = a - g e_down; thrust pushes along -body_z
        f = (acc[0], acc[1], acc[2] - g)
        if f[2] > -0.1 * g:  # never ask for less than a tenth of g upward (no inverted flight)
            f = (f[0], f[1], -0.1 * g)
        horiz = math.hypot(f[0], f[1])
        if math.atan2(horiz, -f[2]) > tilt_max:
            scale = -f[2] * math.tan(tilt_max) / horiz
            f = (f[0] * scale, f[1] * scale, f[2])
        norm = math.sqrt(f[0] ** 2 + f[1] ** 2 + f[2] ** 2)
        thrust_n = min(norm / g * hover, 1.0) * self._thr_max
        if self._paper_translation:
            # eq. 18 (z up): F sin(theta) = -a_n, F cos(theta) sin(phi) = a_e, F cos(theta) cos(phi) = a_up + g
            v0, v1, v2 = -f[0], f[1], -f[2]
            roll = math.atan2(v1, v2)
            pitch = math.atan2(v0, math.hypot(v1, v2))
            return _quat_from_euler(roll, pitch, task.yaw_rad), thrust_n
        body_z = (-f[0] / norm, -f[1] / norm, -f[2] / norm)
        return bodyz_to_attitude(body_z, task.yaw_rad), thrust_n

    def __call__(self, model: Model, x: np.ndarray) -> tuple[float, np.ndarray]:
        count = self._step_count
        self._step_count = count + 1
        if count % self._every and self._mode != "idle":
            return self.last_output  # held between gyro samples
        q, rates, eta = self._read(x)
        if self._mode == "position":
            if self._pos_count % self._pos_every == 0:
                self._q_sp, self._thrust_n = self.position_attitude(x)
                self._yaw_ff = 0.0
            self._pos_count += 1
            rates_sp = self.rates_for_attitude(q, eta, self._q_sp, 0.0)
        elif self._mode == "attitude":
            rates_sp = self.rates_for_attitude(q, eta, self._q_sp, self._yaw_ff)
        elif self._mode == "rates":
            rates_sp = self._rates_sp
        else:
            self.last_output = (0.0, np.zeros(3))
            return self.last_output
        u = self.rate_torque(rates, rates_sp)
        tq = self._tq_max
        torque = self._write(x, eta, (u[0] * tq[0], u[1] * tq[1], u[2] * tq[2]))
        self.last_output = (self._thrust_n, torque)
        return self.last_output

    def advance_rigid_body(self, sim: FastRigidBodySim, n_steps: int, winds: np.ndarray) -> bool:
        """Fly ``n_steps`` of a ``FastRigidBodySim`` in one compiled call (``px4_kernel``), the
        same operations as calling this loop at every step; False (nothing done) outside the
        attitude and rate modes or on another model, where the caller steps as usual."""
        if self._mode not in ("attitude", "rates") or self._euler_attitude:
            return False
        from sitl_plant import px4_kernel

        if getattr(self, "_kernel_version", None) != self._version:
            self._kernel_gains = np.array([self._att_p, self._rate_p, self._rate_i, self._rate_d, self._int_lim], dtype=float)
            self._kernel_rate_max = np.array(self._rate_max, dtype=float)
            self._kernel_tq_max = np.array(self._tq_max, dtype=float)
            self._kernel_version = self._version
        torque = np.array(self.last_output[1], dtype=float)
        rate_int = np.array(self._rate_int, dtype=float)
        prev = np.zeros(3) if self._prev_rates is None else np.array(self._prev_rates, dtype=float)
        resting, count, has_prev, thrust = px4_kernel.advance_px4(
            sim.x, n_steps, sim.physics_dt_s, winds, sim.ground, sim._last_xdot, sim._cmd, sim._p,
            self._every, self._step_count, self._mode == "attitude", np.array(self._q_sp, dtype=float),
            np.array(self._rates_sp, dtype=float), float(self._yaw_ff), float(self._thrust_n), float(self.last_output[0]),
            self._yaw_w, self._kernel_gains, self._kernel_rate_max, self._kernel_tq_max, bool(self.landed), rate_int, prev,
            self._prev_rates is not None, torque,
        )  # fmt: skip
        sim.on_ground = bool(resting)
        self._step_count = int(count)
        self._rate_int = rate_int.tolist()
        self._prev_rates = tuple(prev.tolist()) if has_prev else None
        self.last_output = (float(thrust), torque)
        return True

    def held(self, model: Model, x: np.ndarray, max_steps: int) -> tuple[float, np.ndarray, int]:
        """This step's output and for how many steps (``1 <= k <= max_steps``) it holds.

        Exactly what ``k`` calls of ``self(model, x)`` would return at the same states, since
        between two gyro samples the loop returns its last output without reading ``x``: a
        stepper may integrate those ``k`` steps with the output held, in one go (the compiled
        ``FastRigidBodySim`` does). The internal step counter advances by ``k``.
        """
        thrust, torque = self(model, x)
        # idle outputs nothing whatever the state
        k = max_steps if self._mode == "idle" else min(max_steps, 1 + (-self._step_count) % self._every)
        self._step_count += k - 1
        return thrust, torque, k


# --- the paper's loop and the actuator path -----------------------------------------------------


def thrust_newtons(thrust_norm: float | None, thrust_max_n: float) -> float:
    """PX4's collective thrust: the normalised value clipped to [0, 1], times SIM_THR_MAX."""
    if thrust_norm is None:
        return 0.0
    return min(max(thrust_norm, 0.0), 1.0) * thrust_max_n


def paper_actuation(
    setpoint: AttitudeSetpoint,
    model: Model,
    x: np.ndarray,
    params: ParamTable,
    rates_from_attitude: Callable[[Quat], Vec3] | None = None,
) -> EulerAccelActuation:
    """The paper's inner loop for one setpoint (eq. 40-42 and eq. 16).

    ``omega_ref`` (body rates of the setpoint; ignored components count as zero) becomes
    ``eta_dot_ref = W_eta^-1 omega_ref`` at the vehicle's current angles, and
    ``tau_tilde = (eta_dot_ref - eta_dot) / PAP_TO`` with its current (true) Euler rates. When
    the setpoint carries an attitude instead of rates, ``rates_from_attitude`` (PX4's attitude P)
    gives ``omega_ref``.

    Raises
    ------
    numpy.linalg.LinAlgError
        At a singular W_eta (pitch at +-90 deg); the caller keeps the previous actuation.
    """
    form = model_euler_form(model)
    eta, eta_dot = model.euler(x)
    if setpoint.flies_attitude and rates_from_attitude is not None:
        omega_ref: np.ndarray = np.array(rates_from_attitude(setpoint.q_wxyz))  # type: ignore[arg-type]
    else:
        omega_ref = np.array([0.0 if r is None else r for r in setpoint.body_rates_frd_rad_s])
    eta_dot_ref = np.linalg.solve(euler_rate_matrix(eta, form), omega_ref)
    tau_tilde = (eta_dot_ref - eta_dot) / params["PAP_TO"]  # eq. 40-42
    inertia = np.diag([params["PAP_IXX"], params["PAP_IYY"], params["PAP_IZZ"]])
    return EulerAccelActuation(thrust_newtons(setpoint.thrust_norm, params["SIM_THR_MAX"]), tau_tilde, inertia, form)


def actuator_actuation(setpoint: ActuatorSetpoint, params: ParamTable) -> HeldActuation:
    """SET_ACTUATOR_CONTROL_TARGET scaled to newtons and newton-metres, held."""
    c = setpoint.controls
    tq_rp, tq_y = params["SIM_TQ_RP_MAX"], params["SIM_TQ_Y_MAX"]
    return HeldActuation(thrust_newtons(c[3], params["SIM_THR_MAX"]), np.array([c[0] * tq_rp, c[1] * tq_rp, c[2] * tq_y]))


class InnerLoops:
    """Chooses and builds the actuation for the autopilot's task.

    Parameters
    ----------
    params : ParamTable
    model : Model
    physics_dt_s : float
    kind : str
        ``"px4"`` or ``"paper"``: how attitude setpoints are flown.
    """

    KINDS = ("px4", "paper")

    def __init__(self, params: ParamTable, model: Model, physics_dt_s: float, kind: str = "px4") -> None:
        if kind not in self.KINDS:
            raise ValueError(f"inner loop must be one of {self.KINDS}, got {kind!r}")
        self.params = params
        self.kind = kind
        self.px4 = Px4Loop(params, model, physics_dt_s)
        self.model = model
        self._current: Actuation = IDLE
        self._setpoint: Setpoint | None = None
        self.failures = 0

    def bind(self, model: Model) -> None:
        """Attach both loops to a (possibly rebuilt) model."""
        self.model = model
        self.px4.bind(model)

    def actuation_for(self, task: Task, x: np.ndarray, landed: bool) -> Actuation:
        """The actuation to fly ``task`` from state ``x``; reuses the current one when unchanged."""
        if self.params.version != self.px4._version:
            self.px4.reload()
        self.px4.landed = landed
        if isinstance(task, IdleTask):
            if self._current is not IDLE:
                self.px4.reset()
                self.px4._mode = "idle"
            self._setpoint = None
            self._current = IDLE
            return IDLE
        if isinstance(task, PositionTask):
            self.px4.fly_position(task)
            self._setpoint = None
            self._current = self.px4
            return self.px4
        assert isinstance(task, OffboardTask)
        sp = task.setpoint
        if sp is self._setpoint:
            return self._current
        self._setpoint = sp
        if isinstance(sp, PositionSetpoint):
            # PX4's position/velocity offboard: the position controller, whatever the inner loop
            if sp.yaw_rad is None:
                q, _, _ = self.px4._read(x)
                w, qx, qy, qz = q
                yaw = math.atan2(2.0 * (w * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
            else:
                yaw = sp.yaw_rad
            vel = tuple(0.0 if v is None else v for v in sp.vel_ned_m_s)
            self.px4.fly_position(PositionTask(sp.pos_ned_m, yaw, vel_ned_m_s=vel))  # type: ignore[arg-type]
            self._current = self.px4
        elif isinstance(sp, ActuatorSetpoint):
            self._current = actuator_actuation(sp, self.params)
        elif self.kind == "paper":
            try:
                self._current = paper_actuation(sp, self.model, x, self.params, self._attitude_rates_now(x))
            except np.linalg.LinAlgError:
                self.failures += 1
        else:
            thrust = thrust_newtons(sp.thrust_norm, self.params["SIM_THR_MAX"])
            if sp.flies_attitude:
                yaw_ff = sp.body_rates_frd_rad_s[2] or 0.0
                self.px4.fly_attitude(sp.q_wxyz, thrust, yaw_ff)  # type: ignore[arg-type]
            else:
                r = sp.body_rates_frd_rad_s
                self.px4.fly_rates((r[0] or 0.0, r[1] or 0.0, r[2] or 0.0), thrust)
            self._current = self.px4
        return self._current

    def _attitude_rates_now(self, x: np.ndarray) -> Callable[[Quat], Vec3]:
        q, _, eta = self.px4._read(x)
        return lambda q_sp: self.px4.rates_for_attitude(q, eta, q_sp, 0.0)

    def last_output(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        """The thrust (N) and model torque input last applied (for the motor-output telemetry)."""
        current = self._current
        if current is self.px4:
            return self.px4.last_output
        return current(self.model, x)
