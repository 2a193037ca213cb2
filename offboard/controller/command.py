"""The controller interface: what every trajectory-tracking controller takes and gives.

A controller is stepped once per control sample with the measured state and the references at
this sample and the next, all NED/FRD, and returns a ``Command`` in the forms an autopilot
takes (PX4's OFFBOARD setpoints)::

    controller.reset()
    command = controller.step(state, ref_n, ref_n1)

- **attitude + thrust** (``Command.attitude_wxyz``, ``thrust_n``, ``yaw_rate_ff_rad_s``): what
  SET_ATTITUDE_TARGET carries to PX4's attitude controller; every controller gives it;
- **body rates + thrust** (``body_rate_frd_rad_s``): SET_ATTITUDE_TARGET with the attitude
  ignored, flown by PX4's rate controller; given by controllers that close their own attitude
  loop (the paper's law: eq. 33's angle-rate references through eq. 3);
- **torques + thrust** (``torque_nm``): SET_ACTUATOR_CONTROL_TARGET; given by controllers that
  compute a torque (the paper's eq. 16, Lee's eq. 16).

What sends a command (``offboard.codec.command_setpoint``) or flies it in-process
(``offboard.simulate``) picks the form; a form the controller does not give is ``None`` and
asking for it is an error that names the controller. The controllers: ``PaperController``
(``offboard.controller.paper``), ``SE3Controller`` and ``Px4PositionController``
(``offboard.baselines``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from offboard.trajectory.base import Reference

if TYPE_CHECKING:
    from offboard.controller.law import ControlOutput

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]


class StateEstimate(Protocol):
    """What a controller reads of the vehicle: its estimate, NED/FRD.

    ``offboard.codec.MeasuredState`` (from ATTITUDE and LOCAL_POSITION_NED) and the simulator's
    ``VehicleState`` both are one. An estimate may also carry ``position_time_boot_ms``, its
    position's own stamp (MeasuredState does): the paper's velocity filter then uses it; and
    ``age_s``, how long before the sample it arrived: the latency prediction then predicts over
    the latency plus this sample's age less the usual one.
    """

    @property
    def pos_ned_m(self) -> np.ndarray:
        """Position, NED, m."""
        ...

    @property
    def vel_ned_m_s(self) -> np.ndarray:
        """Velocity, NED, m/s."""
        ...

    @property
    def euler_rad(self) -> np.ndarray:
        """Roll, pitch, yaw (ZYX), rad."""
        ...

    @property
    def body_rate_frd_rad_s(self) -> np.ndarray:
        """Body rates p, q, r (FRD), rad/s."""
        ...

    @property
    def quat_wxyz(self) -> np.ndarray:
        """Attitude quaternion (w, x, y, z), body FRD to NED."""
        ...


@dataclass(frozen=True)
class Command:
    """One control sample's command, NED/FRD (module docstring).

    Attributes
    ----------
    thrust_n : float
        Collective thrust along body -z, N (the law's u).
    attitude_wxyz : (w, x, y, z)
        Attitude target, body FRD -> NED.
    yaw_rate_ff_rad_s : float
        Yaw-rate feed-forward that goes with the attitude target (PX4 adds it to its yaw loop).
    attitude_ref_euler_rad : (roll, pitch, yaw)
        The attitude the controller asked for, as ZYX angles, for the record (the paper's law:
        x7ez, x9ez, x11d(n+1); its ``attitude_wxyz`` may be led past them).
    body_rate_frd_rad_s : (p, q, r) or None
        Body-rate target, or ``None`` for a controller that leaves the attitude loop to the
        autopilot.
    torque_nm : (3,) or None
        The torque input of the vehicle model: body FRD torque for a rigid body (every real
        vehicle); generalised torques for the paper's model (eq. 13). ``None``: not given.
    euler_accel_rad_s2 : (3,) or None
        The paper's tau~ (eq. 40-42), the Euler-angle accelerations its inner loop turns into
        torques by eq. 16; ``None`` for other controllers.
    generalized_torque_nm : (3,) or None
        The paper's real torques of eq. 16 (``C eta_dot + J tau~``), for the record.
    law : ControlOutput or None
        The paper's law's whole output for this sample (``None`` for other controllers).
    """

    thrust_n: float
    attitude_wxyz: Quat
    yaw_rate_ff_rad_s: float
    attitude_ref_euler_rad: Vec3
    body_rate_frd_rad_s: Vec3 | None = None
    torque_nm: Vec3 | None = None
    euler_accel_rad_s2: Vec3 | None = None
    generalized_torque_nm: Vec3 | None = None
    law: ControlOutput | None = None

    def is_finite(self) -> bool:
        """Whether every number the command carries is finite (a NaN command is never sent)."""
        values: list[float] = [self.thrust_n, *self.attitude_wxyz, self.yaw_rate_ff_rad_s, *self.attitude_ref_euler_rad]
        for extra in (self.body_rate_frd_rad_s, self.torque_nm, self.euler_accel_rad_s2, self.generalized_torque_nm):
            if extra is not None:
                values.extend(extra)
        # any NaN or infinity makes the sum NaN or infinite, so a finite sum answers at once; the
        # numbers one by one only when it is not (a sum of finite numbers may overflow)
        return math.isfinite(sum(values)) or all(math.isfinite(v) for v in values)


@runtime_checkable
class Controller(Protocol):
    """A trajectory-tracking controller: pure, stepped once per sample, no I/O and no clock.

    Attributes
    ----------
    name : str
        What it is called in commands, records and tables (``paper``, ``se3``, ``px4``).
    sample_time_s : float
        The period it is designed for (the paper's To).
    """

    name: str
    sample_time_s: float

    def reset(self) -> None:
        """Forget every memory: the next step starts from the measured state."""

    def step(self, state: StateEstimate, ref_n: Reference, ref_n1: Reference) -> Command:
        """The command for the measured ``state`` and the references at this sample and the next."""
        ...


class MissingCommand(ValueError):
    """A command form the controller does not give was asked for (e.g. body rates of PX4's cascade)."""


#: The optional forms of a ``Command`` and what they are called in messages.
FORMS = {
    "body_rate_frd_rad_s": "body-rate",
    "torque_nm": "torque",
    "euler_accel_rad_s2": "Euler-acceleration (tau~)",
    "generalized_torque_nm": "eq. 16 torque",
}


def require(command: Command, form: str, controller: str = "") -> tuple[float, float, float]:
    """``command``'s ``form`` (a key of ``FORMS``); ``MissingCommand`` if the controller gives none."""
    value = getattr(command, form)
    if value is None:
        who = f"the {controller} controller" if controller else "the controller"
        raise MissingCommand(f"{who} gives no {FORMS[form]} command")
    return value
