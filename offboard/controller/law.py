"""The tracking law of Rosales et al., eq. 28-42, and the real torques of eq. 16.

Everything here is in the paper's frame (x north, y east, z **up**; phi, theta, psi) with the
12-state of eq. 22::

    x = (x, x_dot, y, y_dot, z, z_dot, phi, phi_dot, theta, theta_dot, psi, psi_dot)
         x1  x2    x3  x4    x5  x6    x7   x8       x9     x10        x11  x12

One sample of the law (steps 1-6; docs/reproduction.md for the choices where the paper is silent), given the measured state x(n), the references
(x1d, x3d, x5d, x11d) at n and n+1, and the controller's memory of the previous sample:

1. desired speeds, eq. 32: ``x2d(n+1) = (x1d(n+1) - kx1 (x1d(n) - x1(n)) - x1(n)) / To`` ...
2. reference speeds, eq. 33: ``x2ref(n+1) = x2d(n+1) - kx2 (x2d(n) - x2(n))`` ...
3. increments, eq. 34: ``dx2 = x2ref - x2(n)`` ...
4. the angles that make eq. 27 exactly solvable, eq. 28 and the non-singular form of eq. 29:
   ``tan x7ez = dx4 / (dx6 + g To)``, ``tan x9ez = -dx2 cos x7ez / (dx6 + g To)``;
5. angular loops, eq. 31-33 for x7..x12, then eq. 40-42: ``tau~ = (x_ref - x(n)) / To``;
6. thrust, eq. 39, with the angles just computed (as Appendix A, eq. A.8, uses them).

``law_step`` is a pure function of floats written against a small math namespace (``ops``), so
the same lines run on Python floats (fast, one vehicle) or on numpy arrays (a batch of vehicles).

Choices where the paper is silent or garbled (each pinned by a test):

- **atan2 branch.** When ``dx6 + g To < 0`` (a strong downward step), eq. 28-29 are taken at
  their principal value in (-pi/2, pi/2) and u of eq. 39 changes sign, rather than the
  upside-down solution a plain ``atan2(num, den)`` would give. With a positive thrust floor
  (``limits.thrust_min_n > 0``: rotors that cannot push down, PX4's MPC_THR_MIN) u cannot change
  sign, so the angles are taken for the thrust actually flown: ``dx6 + g To`` floored at
  ``thrust_min_n To / m``. The negative-u branch would point the horizontal force the wrong way
  and feed back (the demo's 12 m descent rang at 35 deg; docs/offboard.md).
- **Start-up memory.** At n = 0 the previous desired values are initialised from the measured
  state: x2d(0) = x2(0), ..., x7ez(0) = x7(0), x9ez(0) = x9(0).
- **Integral action** (``integral_gain_per_s`` > 0, off by default): the paper names the mass
  error as the law's weakness (Simulation 2's steady z error, docs/reproduction.md). An integral
  of each position error, ``i(n+1) = i(n) + ki To (x_d(n) - x(n))`` clamped to
  ``integral_limit_m_s``, is added to the desired speed of eq. 32; at steady state the error
  that feeds it must vanish. It learns only from samples where no bound acted (a desired speed,
  the tilt or the thrust): conditional integration, the anti-windup. Off reproduces the paper
  exactly.
- **Yaw differences** ``x11d - x11`` are wrapped to [-pi, pi), so a yaw reference and a measured
  yaw that differ by whole turns do not spin the vehicle; the paper's steps (pi and pi/2) are
  flown in the same direction as unwrapped differences would.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from types import SimpleNamespace
from typing import NamedTuple

import numpy as np

from offboard.controller.params import ControllerParams
from offboard.model.euler_lagrange import EULER_FORM_TERMS, real_torques_terms
from offboard.model.mixer import rotor_forces

#: Math namespace for scalar (Python float) evaluation of ``law_step``.
MATH_OPS = SimpleNamespace(
    sin=math.sin, cos=math.cos, atan2=math.atan2, copysign=math.copysign, minimum=min, maximum=max,
    hypot=math.hypot, asin=math.asin,
    wrap=lambda a: (a + math.pi) % (2.0 * math.pi) - math.pi,
)
#: Math namespace for batched (numpy array) evaluation of ``law_step``.
NUMPY_OPS = SimpleNamespace(
    sin=np.sin, cos=np.cos, atan2=np.arctan2, copysign=np.copysign, minimum=np.minimum, maximum=np.maximum,
    hypot=np.hypot, asin=np.arcsin,
    wrap=lambda a: np.mod(a + np.pi, 2.0 * np.pi) - np.pi,
)


#: A reference step: the 3D position error grows by more than this in one sample (m). 1 m a sample
#: is 20 m/s at To = 50 ms, faster than any mission flies (PX4's MPC_XY_VEL_MAX is 12 m/s); the
#: paper's steps are 2 m and 12 m. A flight starting farther than this from its reference starts
#: with one. (The flight metrics use the same definition: ``offboard.metrics``.)
STEP_M = 1.0
#: After a step the loop has settled once the 3D error is below this (m): ten times the designed
#: demo helix's error, far below any deliberate step.
SETTLED_M = 0.1


class TrackingReference(NamedTuple):
    """The references the law tracks at one sample, paper frame: (x1d, x3d, x5d, x11d).

    ``yaw_rate_rad_s`` is the reference's own yaw rate (the trajectory's derivative of x11d, 0
    at a step): the law does not use it; the attitude output hands it on as the yaw-rate
    feed-forward (``LawOutput.yaw_rate_ff_rad_s``).
    """

    x_m: float
    y_m: float
    z_up_m: float
    yaw_rad: float
    yaw_rate_rad_s: float = 0.0


class LawMemory(NamedTuple):
    """The controller's memory of sample n: desired speeds and angle references (eq. 31-33).

    ``i1, i3, i5`` hold the optional integral action's contribution to the desired speeds
    (m/s), ``a1, a3, a5`` the optional velocity integral's acceleration (m/s^2); they stay zero
    with the paper's law. ``yaw_ref`` is the slewed yaw reference of the
    optional yaw-rate bound (``ActionLimits.yaw_rate_max_rad_s``); unused without it.
    ``error_m`` is sample n's 3D position error and ``settling`` the seconds left of the velocity
    integral's hold after a reference step (``law_step``); both unused without the hold.
    """

    x2d: float
    x4d: float
    x6d: float
    x8d: float
    x10d: float
    x12d: float
    x7ez: float
    x9ez: float
    i1: float = 0.0
    i3: float = 0.0
    i5: float = 0.0
    yaw_ref: float = 0.0
    a1: float = 0.0
    a3: float = 0.0
    a5: float = 0.0
    error_m: float = 0.0
    settling: float = 0.0

    @classmethod
    def from_state(cls, x: tuple[float, ...] | np.ndarray) -> LawMemory:
        """Start-up memory: every previous desired value equals its measured value (the slewed
        yaw reference starts at the measured yaw)."""
        return cls(x[1], x[3], x[5], x[7], x[9], x[11], x[6], x[8], yaw_ref=x[10])


class LawOutput(NamedTuple):
    """One sample's actions and the intermediate values worth logging.

    Attributes
    ----------
    thrust_n : u of eq. 39 (after the optional limits).
    tau_tilde : (tau~phi, tau~theta, tau~psi) of eq. 40-42, rad/s^2.
    roll_ref_rad, pitch_ref_rad : x7ez and x9ez (eq. 28-29), the angle references at n+1.
    yaw_ref_rad : x11d(n+1).
    euler_rate_ref_rad_s : (x8ref, x10ref, x12ref) of eq. 33, the angle-rate references at n+1.
    yaw_rate_ff_rad_s : the reference's yaw rate at n+1 (not x12ref, which carries the yaw
        error's feedback: tens of rad/s at a yaw step), for an autopilot's yaw feed-forward.
    roll_setpoint_rad, pitch_setpoint_rad : the attitude handed to an autopilot's attitude loop:
        x7ez and x9ez, led by ``tilt_lead`` (``ControllerParams``) past the measured angles.
    """

    thrust_n: float
    tau_tilde: tuple[float, float, float]
    roll_ref_rad: float
    pitch_ref_rad: float
    yaw_ref_rad: float
    euler_rate_ref_rad_s: tuple[float, float, float]
    yaw_rate_ff_rad_s: float = 0.0
    roll_setpoint_rad: float = 0.0
    pitch_setpoint_rad: float = 0.0


def _bound_tilt(limits, x7: float, x9: float, ops: SimpleNamespace) -> tuple[float, float]:  # noqa: ANN001
    """The tilt bound of ``limits`` on (roll, pitch): a cone on the thrust axis or each angle."""
    if limits.tilt_max_rad is None:
        return x7, x9
    if limits.tilt_cone:
        # bound the thrust axis's tilt from the vertical, keeping its horizontal direction (PX4's
        # MPC_TILTMAX_AIR): the axis of eq. 18 is (-sin x9, cos x9 sin x7, cos x9 cos x7)
        bx, by = -ops.sin(x9), ops.cos(x9) * ops.sin(x7)
        bz = ops.cos(x9) * ops.cos(x7)
        scale = ops.minimum(1.0, math.sin(limits.tilt_max_rad) / ops.maximum(ops.hypot(bx, by), 1e-12))
        bx, by = bx * scale, by * scale
        bz = ops.maximum(bz, math.cos(limits.tilt_max_rad))
        return ops.atan2(by, bz), ops.asin(-bx)
    lim = limits.tilt_max_rad
    return ops.minimum(ops.maximum(x7, -lim), lim), ops.minimum(ops.maximum(x9, -lim), lim)


def law_step(
    params: ControllerParams,
    memory: LawMemory,
    x: tuple[float, ...] | np.ndarray,
    ref_n: TrackingReference,
    ref_n1: TrackingReference,
    ops: SimpleNamespace = MATH_OPS,
) -> tuple[LawOutput, LawMemory]:
    """One sample of the law, eq. 28-42. Pure: returns the output and the next memory.

    Parameters
    ----------
    params : ControllerParams
    memory : LawMemory
        Desired values of sample n (``LawMemory.from_state(x)`` at start-up).
    x : sequence of 12 floats (or 12 arrays of one batch shape)
        Measured state x(n), paper frame (eq. 22).
    ref_n, ref_n1 : TrackingReference
        References at n and n+1.
    ops : namespace
        ``MATH_OPS`` for floats, ``NUMPY_OPS`` for arrays.
    """
    g = params.gains
    to = params.sample_time_s
    x1, x2, x3, x4, x5, x6, x7, x8, x9, x10, x11, x12 = x

    # eq. 32: desired speeds that make the position errors decay with kx1, kx3, kx5, kx11
    x2d = (ref_n1.x_m - g.kx1 * (ref_n.x_m - x1) - x1) / to
    x4d = (ref_n1.y_m - g.kx3 * (ref_n.y_m - x3) - x3) / to
    x6d = (ref_n1.z_up_m - g.kx5 * (ref_n.z_up_m - x5) - x5) / to
    i1, i3, i5 = memory.i1, memory.i3, memory.i5
    ki = params.integral_gain_per_s
    if ki > 0.0:  # optional integral action on the position errors (not in the paper)
        cap = params.integral_limit_m_s
        i1 = ops.minimum(ops.maximum(i1 + ki * to * (ref_n.x_m - x1), -cap), cap)
        i3 = ops.minimum(ops.maximum(i3 + ki * to * (ref_n.y_m - x3), -cap), cap)
        i5 = ops.minimum(ops.maximum(i5 + ki * to * (ref_n.z_up_m - x5), -cap), cap)
        x2d, x4d, x6d = x2d + i1, x4d + i3, x6d + i5
    limits = params.limits
    # which outputs a bound changes this sample (1.0) or leaves as the linear law gives them (0.0):
    # the integral learns only from linear samples (conditional integration, below)
    bound_xy = bound_z = bound_tilt = bound_thrust = 0.0
    if limits.speed_xy_max_m_s is not None:  # bounded desired speeds (PX4's MPC_XY_VEL_MAX)
        scale = ops.minimum(1.0, limits.speed_xy_max_m_s / ops.maximum(ops.hypot(x2d, x4d), 1e-12))
        x2d, x4d = x2d * scale, x4d * scale
        bound_xy = bound_xy + (scale < 1.0)
    if limits.speed_up_max_m_s is not None:  # ... MPC_Z_VEL_MAX_UP
        bound_z = bound_z + (x6d > limits.speed_up_max_m_s)
        x6d = ops.minimum(x6d, limits.speed_up_max_m_s)
    if limits.speed_down_max_m_s is not None:  # ... MPC_Z_VEL_MAX_DN
        bound_z = bound_z + (x6d < -limits.speed_down_max_m_s)
        x6d = ops.maximum(x6d, -limits.speed_down_max_m_s)
    yaw_n, yaw_n1, yaw_rate_ff = ref_n.yaw_rad, ref_n1.yaw_rad, ref_n1.yaw_rate_rad_s
    if limits.yaw_rate_max_rad_s is not None:
        # bounded yaw rate (PX4's MPC_YAWRAUTO_MAX in its own modes): the yaw reference slews
        # towards x11d at most yaw_rate_max To a sample; a pi step then turns in pi / rate seconds
        # instead of asking for 63 rad/s while the vehicle is tilted (not in the paper)
        bound = limits.yaw_rate_max_rad_s * to
        yaw_n = memory.yaw_ref
        yaw_n1 = yaw_n + ops.minimum(ops.maximum(ops.wrap(ref_n1.yaw_rad - yaw_n), -bound), bound)
        yaw_rate_ff = (yaw_n1 - yaw_n) / to
    x12d = (ops.wrap(yaw_n1 - x11) - g.kx11 * ops.wrap(yaw_n - x11)) / to

    # eq. 33-34: reference speeds and the increments of eq. 34
    dx2 = x2d - g.kx2 * (memory.x2d - x2) - x2
    dx4 = x4d - g.kx4 * (memory.x4d - x4) - x4
    dx6 = x6d - g.kx6 * (memory.x6d - x6) - x6
    a1, a3, a5 = memory.a1, memory.a3, memory.a5
    kiv_xy = params.velocity_integral_gain_per_s2
    kiv_z = kiv_xy if params.vertical_velocity_integral_gain_per_s2 is None else params.vertical_velocity_integral_gain_per_s2
    kiv = kiv_xy + kiv_z  # > 0: some velocity integral
    if kiv > 0.0:
        # optional integral of the velocity errors of eq. 33 (not in the paper): an acceleration
        # that makes up a steady disturbance (a mass error, wind, an estimator's tilt bias), so
        # that eq. 33's speed, and with it eq. 32's position, settles without an offset; the
        # vertical axis may have its own gain (``vertical_velocity_integral_gain_per_s2``)
        cap = params.velocity_integral_limit_m_s2
        a1 = ops.minimum(ops.maximum(a1 + kiv_xy * to * (memory.x2d - x2), -cap), cap)
        a3 = ops.minimum(ops.maximum(a3 + kiv_xy * to * (memory.x4d - x4), -cap), cap)
        a5 = ops.minimum(ops.maximum(a5 + kiv_z * to * (memory.x6d - x6), -cap), cap)
        dx2, dx4, dx6 = dx2 + to * a1, dx4 + to * a3, dx6 + to * a5
    if params.linear_drag_n_s_m > 0.0:
        # a believed linear drag -d v (N): eq. 23's x2(n+1) = x2(n) + To (-u/m sin x9 - d/m x2(n)),
        # so the thrust must also make up To d/m x2(n) of speed (likewise x4, x6); not in the paper
        kd = to * params.linear_drag_n_s_m / params.mass_kg
        dx2, dx4, dx6 = dx2 + kd * x2, dx4 + kd * x4, dx6 + kd * x6
    vertical = dx6 + params.gravity_m_s2 * to  # dx6 + g To

    if params.yaw_aware:  # horizontal increments in the heading frame (forward, right)
        cpsi, spsi = ops.cos(x11), ops.sin(x11)
        dx_fwd = cpsi * dx2 + spsi * dx4
        dx_right = -spsi * dx2 + cpsi * dx4
    else:
        dx_fwd, dx_right = dx2, dx4

    # eq. 28 and the non-singular form of eq. 29, principal branch (see module docstring)
    if limits.thrust_min_n is not None and limits.thrust_min_n > 0.0:
        # The rotors cannot push down: where the law asks for u < 0, the floor flies u > 0, and
        # angles from the negative-u branch would turn the horizontal force the wrong way
        # (positive feedback: a 1 cm error grew to 35 deg in the demo's 12 m descent). Take
        # the angles for the thrust actually flown: the vertical demand floored at the minimum.
        angle_vertical = ops.maximum(vertical, limits.thrust_min_n * to / params.mass_kg)
        x7ez = ops.atan2(dx_right, angle_vertical)
        x9ez = ops.atan2(-dx_fwd * ops.cos(x7ez), angle_vertical)
    else:
        sign = ops.copysign(1.0, vertical)
        x7ez = ops.atan2(dx_right * sign, vertical * sign)
        x9ez = ops.atan2(-dx_fwd * ops.cos(x7ez) * sign, vertical * sign)
    if (ki > 0.0 or kiv > 0.0) and limits.tilt_max_rad is not None:
        free7, free9 = x7ez, x9ez
        x7ez, x9ez = _bound_tilt(limits, x7ez, x9ez, ops)
        bound_tilt = bound_tilt + (ops.hypot(free7 - x7ez, free9 - x9ez) > 1e-9)
    else:
        x7ez, x9ez = _bound_tilt(limits, x7ez, x9ez, ops)

    s9, c9 = ops.sin(x9ez), ops.cos(x9ez)
    if limits.tilt_max_rad is None:
        # eq. 39 with the angles just computed
        thrust = params.mass_kg / to * (-s9 * dx_fwd + c9 * ops.sin(x7ez) * dx_right + c9 * ops.cos(x7ez) * vertical)
    else:
        # Bounded tilt: eq. 27 is no longer exactly solvable and eq. 39's least-squares u would
        # trade height for the horizontal demand it cannot meet (climbing metres at a switch).
        # Solve the vertical row instead (altitude first, as PX4 does); with unclamped angles it
        # equals eq. 39 (Appendix A, eq. A.8).
        thrust = params.mass_kg / to * vertical / (c9 * ops.cos(x7ez))
    if limits.thrust_min_n is not None:
        bound_thrust = bound_thrust + (thrust < limits.thrust_min_n)
        thrust = ops.maximum(thrust, limits.thrust_min_n)
    if limits.thrust_max_n is not None:
        bound_thrust = bound_thrust + (thrust > limits.thrust_max_n)
        thrust = ops.minimum(thrust, limits.thrust_max_n)
    # Conditional integration (anti-windup): where a bound acted this sample, the loop is not the
    # linear one the integral gain was designed for (docs/controller-design.md), and an integral
    # keeps its value instead of growing on an error the bound, not a steady disturbance, leaves
    # (a 12 m step or descent at the speed limit would wind it up). The position integral holds
    # on any bound; the velocity integral only where the velocity loop's own output is bounded
    # (tilt, thrust): at a bounded desired speed it still tracks that speed. A thrust bound also
    # changes the tilt flown.
    if ki > 0.0:
        hold_xy = ops.minimum(bound_xy + bound_z + bound_tilt + bound_thrust, 1.0)
        hold_z = ops.minimum(bound_z + bound_thrust, 1.0)
        i1 = i1 + hold_xy * (memory.i1 - i1)
        i3 = i3 + hold_xy * (memory.i3 - i3)
        i5 = i5 + hold_z * (memory.i5 - i5)
    error_m, settling = memory.error_m, memory.settling
    if kiv > 0.0:
        # ... and while the loop settles after a reference step (a jump of the 3D position error
        # by more than STEP_M in a sample, the flight's start included): a step is not a
        # disturbance, and the velocity error of its transient, integrated, overshot the demo's
        # 2.8 m start by 0.39 m. ``settling`` counts down the seconds left of the hold: it ends
        # once the error is below SETTLED_M, or after velocity_integral_hold_s (the designed
        # loop's settling time: a steady disturbance then keeps the error up, and the integral
        # is what removes it).
        hold_s = params.velocity_integral_hold_s
        if hold_s > 0.0:
            error_m = ops.hypot(ops.hypot(ref_n.x_m - x1, ref_n.y_m - x3), ref_n.z_up_m - x5)
            jump = (error_m - memory.error_m) > STEP_M
            left = ops.maximum(jump * hold_s, memory.settling - to)
            settling = left * (error_m >= SETTLED_M) * (left > 0.5 * to)  # half a sample: the rounding of the countdown
        on_hold = settling > 0.0
        hold_xy = ops.minimum(bound_tilt + bound_thrust + on_hold, 1.0)
        hold_z = ops.minimum(bound_thrust + on_hold, 1.0)
        a1 = a1 + hold_xy * (memory.a1 - a1)
        a3 = a3 + hold_xy * (memory.a3 - a3)
        a5 = a5 + hold_z * (memory.a5 - a5)

    # eq. 32-33 for the angles, then eq. 40-42
    x8d = (x7ez - g.kx7 * (memory.x7ez - x7) - x7) / to
    x10d = (x9ez - g.kx9 * (memory.x9ez - x9) - x9) / to
    x8ref = x8d - g.kx8 * (memory.x8d - x8)
    x10ref = x10d - g.kx10 * (memory.x10d - x10)
    x12ref = x12d - g.kx12 * (memory.x12d - x12)
    tau_tilde = ((x8ref - x8) / to, (x10ref - x10) / to, (x12ref - x12) / to)

    # the attitude an autopilot's attitude loop is handed: led past the measured angles so that
    # its P loop (a lag eq. 23 does not have) turns faster towards x7ez, x9ez (docs/controller-design.md)
    lead = params.tilt_lead
    roll_sp, pitch_sp = x7ez, x9ez
    if lead > 0.0:
        roll_sp, pitch_sp = _bound_tilt(limits, x7ez + lead * (x7ez - x7), x9ez + lead * (x9ez - x9), ops)

    output = LawOutput(
        thrust_n=thrust,
        tau_tilde=tau_tilde,
        roll_ref_rad=x7ez,
        pitch_ref_rad=x9ez,
        yaw_ref_rad=yaw_n1,
        euler_rate_ref_rad_s=(x8ref, x10ref, x12ref),
        yaw_rate_ff_rad_s=yaw_rate_ff,
        roll_setpoint_rad=roll_sp,
        pitch_setpoint_rad=pitch_sp,
    )
    return output, LawMemory(x2d, x4d, x6d, x8d, x10d, x12d, x7ez, x9ez, i1, i3, i5, yaw_n1, a1, a3, a5, error_m, settling)


@dataclass(frozen=True)
class ControlOutput:
    """What the controller hands on each sample.

    Attributes
    ----------
    law : LawOutput
        u, tau~, the angle and angle-rate references (eq. 28-42).
    torques_nm : ndarray, shape (3,)
        The real (generalised) torques of eq. 16, ``C(eta, eta_dot) eta_dot + J(eta) tau~``,
        with the controller's belief of the inertia, at the measured state.
    arm_length_m, drag_to_thrust_m : float
        The believed rotor layout (l, c) the rotor forces are mixed with.
    """

    law: LawOutput
    torques_nm: np.ndarray
    arm_length_m: float
    drag_to_thrust_m: float

    @cached_property
    def rotor_forces_n(self) -> np.ndarray:
        """f1..f4 that give u and the eq. 16 torques through eq. 9-11 (rotor layout in
        ``offboard.model.vehicle``); unbounded, so they may be negative. Mixed when asked for:
        no drive of the flight loops reads them."""
        return rotor_forces(self.law.thrust_n, self.torques_nm, self.arm_length_m, self.drag_to_thrust_m)

    @property
    def thrust_n(self) -> float:
        """u, the collective thrust, N (eq. 39, or its vertical row with the tilt bounded)."""
        return self.law.thrust_n

    @property
    def tau_tilde(self) -> tuple[float, float, float]:
        """tau~, the Euler-angle accelerations of eq. 40-42, rad/s^2."""
        return self.law.tau_tilde

    def is_finite(self) -> bool:
        """Whether every output (u, tau~, the angle and rate references, the torques) is a finite number."""
        values = (self.law.thrust_n, *self.law.tau_tilde, self.law.roll_ref_rad, self.law.pitch_ref_rad,
                  *self.law.euler_rate_ref_rad_s, *self.torques_nm)
        return all(math.isfinite(v) for v in values)


class RosalesController:
    """The paper's controller as a stateful object: ``step()`` once per sample, ``reset()``.

    It keeps only the memory the law needs (the previous sample's desired values); it does no
    I/O and reads no clock.
    """

    def __init__(self, params: ControllerParams) -> None:
        self.params = params
        i0, i1, i2 = (float(i) for i in params.inertia_kg_m2)
        self._inertia = (i0, i1, i2)  # the believed principal moments
        self._form_terms = EULER_FORM_TERMS[params.euler_rate_form]  # W_eta's angle (index) and sign
        self.memory: LawMemory | None = None

    def reset(self) -> None:
        """Forget the previous sample: the next step starts from the measured state."""
        self.memory = None

    def step(self, x: np.ndarray | tuple[float, ...], ref_n: TrackingReference, ref_n1: TrackingReference) -> ControlOutput:
        """Compute u, tau~ and the real torques for the measured paper-frame state ``x``."""
        state = tuple(map(float, x))
        if len(state) != 12:
            raise ValueError(f"the state must have 12 components (eq. 22), got {len(state)}")
        if self.memory is None:
            self.memory = LawMemory.from_state(state)
        law, self.memory = law_step(self.params, self.memory, state, ref_n, ref_n1)
        # eq. 16 on the measured angles and rates (floats: ``real_torques`` without its conversions)
        index, sign = self._form_terms
        theta, angle = state[8], state[6 + 2 * index]  # W_eta's angle: phi (index 0) or psi (2)
        t0, t1, t2 = law.tau_tilde
        i0, i1, i2 = self._inertia
        torques: np.ndarray = np.array(real_torques_terms(
            math.sin(theta), math.cos(theta), math.sin(angle), math.cos(angle), state[7], state[9], state[11],
            t0, t1, t2, i0, i1, i2, index, sign,
        ))  # fmt: skip
        return ControlOutput(law, torques, self.params.arm_length_m, self.params.drag_to_thrust_m)
