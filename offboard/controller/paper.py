"""The paper's law behind the controller interface: NED/FRD state in, a ``Command`` out.

``PaperController`` is ``RosalesController`` (the law of eq. 28-42 and the real torques of eq.
16, in the paper's z-up frame) with the conversions at its edges:

- in: the velocity made consistent with the position (``[law] velocity_from_position_s``,
  ``offboard.controller.velocity``) when it is set; the measured Euler rates from the body rates by eq. 3 (``W_eta`` of the controller's form),
  the 12-state of eq. 22 and the references in the paper's frame (``offboard.frames``), led by
  ``[law] reference_lead_s2`` when it is set;
- out (``paper_command``): the attitude target (the law's thrust axis at the heading x11d(n+1)
  on a rigid body, ``frames.setpoint_attitude``), the yaw-rate feed-forward, the body-rate
  target ``W_eta(eta(n)) (x8ref, x10ref, x12ref)`` (eq. 3; on a rigid body with a tilt limit, its
  roll and pitch rates bounded by it: ``tilt_bounded_rates``), the torque input of the vehicle
  model (the eq. 16 torques as body torques ``solve(W_eta^T, tau)`` on a rigid body, as they are
  on the paper's model) and tau~ itself for the paper's inner loop.

Which vehicle it talks to (``vehicle_model``: ``rigid-body``, any real vehicle, or the paper's
model of eq. 13) sets the attitude and torque forms; the law is the same.
"""

from __future__ import annotations

import numpy as np

from offboard.controller.command import Command, StateEstimate
from offboard.model.vehicle import VEHICLE_MODELS, VehicleModel
from offboard.controller.law import ControlOutput, RosalesController
from offboard.controller.params import ControllerParams
from offboard.controller.prediction import LatencyPredictor
from offboard.controller.velocity import ConsistentVelocity
from offboard.frames import floats3, paper_state, setpoint_attitude, tracking_reference
from offboard.model.euler_lagrange import EulerRateForm, body_rates_from_euler_rates, body_torque_from_generalized, euler_rates_from_body_rates
from offboard.trajectory.base import Reference

def paper_state_of(
    state: StateEstimate, euler_rate_form: EulerRateForm, vel_ned_m_s: np.ndarray | None = None
) -> tuple[float, ...]:
    """The 12-state of eq. 22 (paper frame) of a NED/FRD estimate: Euler rates from the body rates
    by eq. 3 with ``euler_rate_form``'s W_eta (``vel_ned_m_s``: a velocity in place of the
    estimate's own)."""
    rates = euler_rates_from_body_rates(state.euler_rad, state.body_rate_frd_rad_s, euler_rate_form)
    vel = state.vel_ned_m_s if vel_ned_m_s is None else vel_ned_m_s
    return paper_state(state.pos_ned_m, vel, state.euler_rad, rates)


def tilt_bounded_rates(euler_rad: np.ndarray, euler_rate_rad_s: np.ndarray | tuple[float, float, float],
                       euler_rate_ref_rad_s: tuple[float, float, float], tilt_max_rad: float, sample_time_s: float,
                       rate_carry_s: float = 0.0) -> tuple[float, float, float]:  # fmt: skip
    """The roll and pitch rate references bounded so that, held for a sample, neither carries its
    angle past the tilt bound b; the yaw rate as it is.

    The angle phi turning at phi_dot (measured) goes on by phi_dot C once the setpoint drops (C:
    ``rate_carry_s``, what the vehicle's rate loop and the latency carry, ``design.rate_carry_s``),
    and the setpoint held for To turns it by To x8ref more, so x8ref is held within
    ((-b - phi - C phi_dot) / To, (b - phi - C phi_dot) / To), likewise x10ref with theta: beyond the
    bound, or carried past it, that asks to turn back within the sample.

    The body-rate output's bound (the attitude output bounds the attitude it hands on, x7ez and
    x9ez, which the autopilot's attitude P follows): eq. 32-33 on the angles carry the memory of the
    last sample's angle error, and after a reference that swings (the helix's 2 m jump: x7ez +34,
    -32, +26 deg in three samples) they ask for rates that turn the vehicle far past x7ez, which the
    rate loop flies at once (63 deg on sitl-plant's quad against its 35 deg bound).
    """
    b, to = tilt_max_rad, sample_time_s
    out = []
    for angle, rate, ref in ((euler_rad[0], euler_rate_rad_s[0], euler_rate_ref_rad_s[0]),
                             (euler_rad[1], euler_rate_rad_s[1], euler_rate_ref_rad_s[1])):  # fmt: skip
        reach = float(angle) + rate_carry_s * float(rate)
        out.append(min(max(ref, (-b - reach) / to), (b - reach) / to))
    return out[0], out[1], euler_rate_ref_rad_s[2]


def paper_command(out: ControlOutput, euler_rad: np.ndarray, params: ControllerParams, vehicle_model: VehicleModel,
                  euler_rate_rad_s: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Command:  # fmt: skip
    """The ``Command`` of one sample of the law (module docstring).

    Parameters
    ----------
    out : ControlOutput
        The law's output for sample n.
    euler_rad : ndarray (3,)
        The measured attitude of sample n, where eq. 3 maps the Euler-rate references.
    params : ControllerParams
        The controller that produced ``out`` (its W_eta form, whether it is yaw-aware).
    vehicle_model : VehicleModel
        ``rigid-body`` or ``paper``.
    euler_rate_rad_s : array (3,)
        The measured Euler rates of sample n, which the body-rate output's tilt bound carries on
        (``tilt_bounded_rates``).
    """
    if vehicle_model not in VEHICLE_MODELS:
        raise ValueError(f"vehicle_model must be one of {VEHICLE_MODELS}, got {vehicle_model!r}")
    law = out.law
    form = params.euler_rate_form
    heading = float(euler_rad[2]) if params.yaw_aware else 0.0
    q = setpoint_attitude(law.roll_setpoint_rad, law.pitch_setpoint_rad, law.yaw_ref_rad, heading, vehicle_model)
    euler_rate_ref = law.euler_rate_ref_rad_s
    # a rigid body's autopilot flies these rates with its rate loop (--output rates): bounded by the tilt; the
    # paper's model flies them with eq. 16 (its plant's paper inner loop), as the law gave them
    if vehicle_model == VehicleModel.RIGID_BODY and params.limits.tilt_max_rad is not None:
        euler_rate_ref = tilt_bounded_rates(euler_rad, euler_rate_rad_s, euler_rate_ref, params.limits.tilt_max_rad,
                                            params.sample_time_s, params.limits.rate_carry_s)  # fmt: skip
    rates = body_rates_from_euler_rates(euler_rad, euler_rate_ref, form)  # eq. 3
    torque: np.ndarray | tuple[float, ...] = out.torques_nm
    if vehicle_model == VehicleModel.RIGID_BODY:
        try:
            torque = body_torque_from_generalized(out.torques_nm, euler_rad, form)
        except np.linalg.LinAlgError:  # W_eta singular (pitch 90 deg): no torque to give
            torque = (float("nan"),) * 3
    return Command(
        thrust_n=law.thrust_n,
        attitude_wxyz=(float(q[0]), float(q[1]), float(q[2]), float(q[3])),
        yaw_rate_ff_rad_s=float(law.yaw_rate_ff_rad_s),
        attitude_ref_euler_rad=(law.roll_ref_rad, law.pitch_ref_rad, law.yaw_ref_rad),
        body_rate_frd_rad_s=floats3(rates),
        torque_nm=floats3(torque),
        euler_accel_rad_s2=law.tau_tilde,
        generalized_torque_nm=floats3(out.torques_nm),
        law=out,
    )


class PaperController:
    """The paper's controller (eq. 28-42, 16) as a ``Controller``: ``step(state, ref_n, ref_n1)``.

    Parameters
    ----------
    params : ControllerParams
        Gains, belief, limits and the switchable extensions (``offboard/controller/paper.toml``
        is the paper's law exactly).
    vehicle_model : VehicleModel
        ``rigid-body`` (default) or ``paper`` (module docstring).
    name : str
        How records and tables call it.
    predictor : LatencyPredictor or None
        Hand the law the state carried over the link's latency instead of the measured one
        (``offboard.controller.prediction``; the gains must then be designed for it,
        ``InnerLoopModel.predict``). None: the measured state, as the paper.
    """

    def __init__(
        self, params: ControllerParams, *, vehicle_model: VehicleModel = VehicleModel.RIGID_BODY, name: str = "paper",
        predictor: LatencyPredictor | None = None,
    ) -> None:  # fmt: skip
        if vehicle_model not in VEHICLE_MODELS:
            raise ValueError(f"vehicle_model must be one of {VEHICLE_MODELS}, got {vehicle_model!r}")
        self.name = name
        self.params = params
        self.vehicle_model = VehicleModel(vehicle_model)  # a caller's word: its enum
        self.sample_time_s = params.sample_time_s
        self.law = RosalesController(params)
        self.velocity = (ConsistentVelocity(params.velocity_from_position_s, params.sample_time_s,
                                            identify=params.velocity_from_position_identify)
                         if params.velocity_from_position_s > 0 else None)  # fmt: skip
        self.predictor = predictor

    def reset(self) -> None:
        """Forget every past sample: the law's memory, the velocity filter and the prediction's history."""
        self.law.reset()
        if self.velocity is not None:
            self.velocity.reset()
        if self.predictor is not None:
            self.predictor.reset()

    def step(self, state: StateEstimate, ref_n: Reference, ref_n1: Reference) -> Command:
        """One sample: the velocity read (``velocity_from_position_s``), the state carried over the latency
        (``predictor``), the law (eq. 28-42) on the paper-frame state and the led references, then eq. 16
        and the setpoint attitude (``paper_command``).
        """
        p = self.params
        vel = None
        if self.velocity is not None:
            stamp = getattr(state, "position_time_boot_ms", None)  # a MAVLink estimate's own stamp
            vel = self.velocity.update(state.pos_ned_m, state.vel_ned_m_s, None if stamp is None else stamp / 1000.0)
        if self.predictor is not None:  # the law is handed the state the setpoint will meet
            state, vel = self.predictor.predict(state, vel), None
        x = paper_state_of(state, p.euler_rate_form, vel)
        lead = p.reference_lead_s2
        out = self.law.step(x, tracking_reference(ref_n, lead), tracking_reference(ref_n1, lead))
        if self.predictor is not None:
            self.predictor.record(out.law.thrust_n, out.law.roll_setpoint_rad, out.law.pitch_setpoint_rad)
        return paper_command(out, state.euler_rad, p, self.vehicle_model, (x[7], x[9], x[11]))
