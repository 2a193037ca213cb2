"""Stepping a quadrotor model at the physics rate: ``VehicleSim``.

No sockets, files or clocks here: the MAVLink autopilot and the in-process ``offboard simulate``
both drive a ``VehicleSim`` the same way, which is what makes them comparable sample for sample.

- A **model** (``PaperModel`` here, ``sitl_plant.dynamics.rigid_body.RigidBodyModel``) is a pure ``derivative(x, thrust, torque, wind)``
  plus the conversions of its state to a ``VehicleState`` in NED/FRD.
- An **actuation** is what the autopilot's inner loop asks of the model at each physics step:
  ``HeldActuation`` (thrust and torques held for the sample: the paper's eq. 16 torques computed
  once per sample, or an actuator setpoint) or ``EulerAccelActuation`` (the paper's tau_tilde held
  for the sample, turned into torques by eq. 16 at every physics step with the autopilot's own,
  possibly wrong, model parameters).
- Ground contact, wind and RK4 are applied here, inputs held over each physics step.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from offboard.model.euler_lagrange import EulerRateForm, euler_rate_matrix, real_torques
from offboard.model.rotations import quat_from_euler
from offboard.model.state import VehicleState
from offboard.model.vehicle import VEHICLE_MODELS, VehicleParams
from sitl_plant.dynamics import paper_model
from sitl_plant.dynamics.integrate import rk4_step
from sitl_plant.dynamics.rigid_body import RigidBodyModel
from sitl_plant.dynamics.wind import WindField

__all__ = ["VehicleState", "VehicleSim", "PaperModel", "HeldActuation", "EulerAccelActuation", "Model"]


class Model(Protocol):
    """What ``VehicleSim`` needs of a dynamics model."""

    params: VehicleParams
    state_size: int

    def initial_state(self, pos_ned_m: np.ndarray, yaw_rad: float) -> np.ndarray:
        """The state at rest at ``pos_ned_m`` (NED, m), heading ``yaw_rad``, level."""
        ...

    def derivative(self, x: np.ndarray, thrust_n: float, torque_nm: np.ndarray, wind_ned_m_s: np.ndarray) -> np.ndarray:
        """dx/dt at ``x`` with the thrust (N), this model's torque input (N m) and the air's velocity (NED, m/s)."""
        ...

    def vehicle_state(self, x: np.ndarray, time_s: float, xdot: np.ndarray) -> VehicleState:
        """The ``VehicleState`` (NED/FRD) of ``x`` at ``time_s``; the acceleration from ``xdot``."""
        ...

    def euler(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(eta, eta_dot): the Euler angles and their rates, for eq. 16."""
        ...

    def torque_from_generalized(self, x: np.ndarray, tau_generalized: np.ndarray) -> np.ndarray:
        """This model's torque input that exerts the generalised torque of eq. 13."""
        ...

    def ground_contact(self, x: np.ndarray) -> tuple[np.ndarray, bool]:
        """State after contact with the ground plane, and whether it rests on it."""
        ...

    def normalize(self, x: np.ndarray) -> np.ndarray:
        """The state after an integration step, projected back onto its manifold (unit quaternion)."""
        ...


class PaperModel:
    """The paper's model (eq. 13, 18) in its own z-up frame; see ``dynamics.paper_model``."""

    state_size = paper_model.STATE_SIZE

    def __init__(self, params: VehicleParams) -> None:
        self.params = params
        self._inertia = params.inertia_matrix
        self._form = params.euler_rate_form

    def initial_state(self, pos_ned_m: np.ndarray, yaw_rad: float) -> np.ndarray:
        """At rest at ``pos_ned_m`` (NED, m; the paper's frame is z up), yaw ``yaw_rad``, level."""
        x = np.zeros(self.state_size)
        x[paper_model.POSITION] = [pos_ned_m[0], pos_ned_m[1], -pos_ned_m[2]]
        x[10] = yaw_rad
        return x

    def derivative(self, x: np.ndarray, thrust_n: float, torque_nm: np.ndarray, wind_ned_m_s: np.ndarray) -> np.ndarray:
        """Eq. 13 and 18 (``paper_model.derivative``) with u = ``thrust_n`` and the generalised torque ``torque_nm``; the paper's
        model has no drag, so the wind does not enter.
        """
        # The paper's model has no aerodynamic drag, so the air's velocity does not enter.
        p = self.params
        return paper_model.derivative(x, thrust_n, torque_nm, p.mass_kg, self._inertia, p.gravity_m_s2, self._form)

    def euler(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(eta, eta_dot), the state's own angles and angle rates."""
        return x[paper_model.ANGLES], x[paper_model.ANGLE_RATES]

    def torque_from_generalized(self, x: np.ndarray, tau_generalized: np.ndarray) -> np.ndarray:
        """The generalised torque itself: eq. 13 takes it as its input."""
        return tau_generalized

    def normalize(self, x: np.ndarray) -> np.ndarray:
        """``x`` unchanged: Euler angles need no projection."""
        return x  # Euler angles need no projection

    def ground_contact(self, x: np.ndarray) -> tuple[np.ndarray, bool]:
        """At or below the ground moving down: on the ground, the vertical and horizontal speeds zero (no
        bounce, no sliding).
        """
        if x[4] > 0.0 or (x[4] == 0.0 and x[5] > 0.0):
            return x, False
        x = x.copy()
        x[4] = 0.0
        x[[1, 3, 5]] = 0.0  # no bounce, no sliding
        return x, True

    def vehicle_state(self, x: np.ndarray, time_s: float, xdot: np.ndarray) -> VehicleState:
        """The state in NED/FRD: the paper's z-up position and speeds turned, body rates by W_eta, the ZYX quaternion."""
        eta, eta_dot = self.euler(x)
        return VehicleState(
            time_s=time_s,
            pos_ned_m=np.array([x[0], x[2], -x[4]]),
            vel_ned_m_s=np.array([x[1], x[3], -x[5]]),
            acc_ned_m_s2=np.array([xdot[1], xdot[3], -xdot[5]]),
            euler_rad=eta.copy(),
            euler_rate_rad_s=eta_dot.copy(),
            body_rate_frd_rad_s=euler_rate_matrix(eta, self._form) @ eta_dot,
            quat_wxyz=quat_from_euler(*eta),
        )


#: The simulated vehicles: the rigid body with rotors (the default) and the paper's model.


def make_model(kind: str, vehicle: VehicleParams) -> Model:
    """The simulated vehicle: ``rigid-body`` (default) or the ``paper`` model (eq. 13, 18)."""
    if kind == "paper":
        return PaperModel(vehicle)
    if kind == "rigid-body":
        return RigidBodyModel(vehicle)
    raise ValueError(f"model must be one of {VEHICLE_MODELS}, got {kind!r}")


# --- actuation: what the inner loop asks of the model at each physics step ---------------


@dataclass(frozen=True)
class HeldActuation:
    """Thrust (N) and the model's torque input (N m), held for the whole sample."""

    thrust_n: float
    torque_nm: np.ndarray

    def __call__(self, model: Model, x: np.ndarray) -> tuple[float, np.ndarray]:
        return self.thrust_n, self.torque_nm


@dataclass(frozen=True)
class EulerAccelActuation:
    """The paper's tau_tilde held for the sample, eq. 16 applied at every physics step.

    ``believed_inertia`` and ``form`` are the autopilot's model of the vehicle, which may differ
    from the true one (Table II).
    """

    thrust_n: float
    tau_tilde: np.ndarray
    believed_inertia: np.ndarray
    form: EulerRateForm = EulerRateForm.CASTILLO

    def __call__(self, model: Model, x: np.ndarray) -> tuple[float, np.ndarray]:
        eta, eta_dot = model.euler(x)
        tau = real_torques(eta, eta_dot, self.tau_tilde, self.believed_inertia, self.form)  # eq. 16
        return self.thrust_n, model.torque_from_generalized(x, tau)


class Actuation(Protocol):
    def __call__(self, model: Model, x: np.ndarray) -> tuple[float, np.ndarray]: ...


IDLE = HeldActuation(0.0, np.zeros(3))


class VehicleSim:
    """A model stepped by RK4 at ``physics_dt_s`` with actuation held between updates.

    Parameters
    ----------
    model : Model
        The true vehicle.
    physics_dt_s : float
        RK4 step (default 1 ms).
    wind : WindField, optional
        Air velocity in NED, sampled once per physics step.
    ground : bool
        Whether the ground plane (down = 0) is solid.
    """

    def __init__(
        self,
        model: Model,
        *,
        physics_dt_s: float = 1e-3,
        wind: WindField | None = None,
        ground: bool = True,
        initial_pos_ned_m: np.ndarray | None = None,
        initial_yaw_rad: float = 0.0,
    ) -> None:
        if physics_dt_s <= 0:
            raise ValueError(f"physics_dt_s must be > 0, got {physics_dt_s}")
        self.model = model
        self.physics_dt_s = physics_dt_s
        self.wind = wind
        self.ground = ground
        self.time_s = 0.0
        self.steps = 0
        pos = np.zeros(3) if initial_pos_ned_m is None else np.asarray(initial_pos_ned_m, dtype=float)
        self.x = model.initial_state(pos, initial_yaw_rad)
        self.on_ground = ground and bool(pos[2] >= 0.0)
        self.actuation: Actuation = IDLE
        self._wind_now = np.zeros(3)
        self._last_xdot = model.derivative(self.x, 0.0, np.zeros(3), self._wind_now)
        if self.on_ground:
            self._last_xdot = np.zeros_like(self._last_xdot)

    @property
    def model(self) -> Model:
        """The true vehicle (the plant replaces it when a SIM_* parameter changes)."""
        return self._model

    @model.setter
    def model(self, model: Model) -> None:
        self._model = model

    def step(self, n_steps: int = 1) -> None:
        """Advance ``n_steps`` physics steps with the current actuation."""
        model, dt = self.model, self.physics_dt_s
        for _ in range(n_steps):
            if self.wind is not None:
                self._wind_now = self.wind.velocity_ned(self.time_s, self.truth_position_ned())
            thrust, torque = self.actuation(model, self.x)
            wind = self._wind_now

            def f(x: np.ndarray) -> np.ndarray:
                return model.derivative(x, thrust, torque, wind)

            x_new = model.normalize(rk4_step(f, self.x, dt))
            self._last_xdot = (x_new - self.x) / dt
            if self.ground:
                x_new, self.on_ground = model.ground_contact(x_new)
                if self.on_ground:
                    self._last_xdot = np.zeros_like(self._last_xdot)
            self.x = x_new
            self.steps += 1
            self.time_s = self.steps * dt

    def truth_position_ned(self) -> np.ndarray:
        """The true position now, NED, m."""
        return self.model.vehicle_state(self.x, self.time_s, self._last_xdot).pos_ned_m

    def truth(self) -> VehicleState:
        """The true state now; acceleration is the mean over the last physics step."""
        state = self.model.vehicle_state(self.x, self.time_s, self._last_xdot)
        if self.on_ground != state.on_ground:

            state = replace(state, on_ground=self.on_ground)
        return state
