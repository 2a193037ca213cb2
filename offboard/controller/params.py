"""The controller's parameters: Table I's gains, what it believes of the vehicle, and options.

They live in a TOML file (``offboard/controller/paper.toml`` is the paper's); every field is
validated on load with a one-line error naming the file and field.
"""

from __future__ import annotations

from typing import Any

import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

from offboard.model.euler_lagrange import EulerRateForm
from offboard.model.tomlfile import Fields, read_toml
from offboard.model.vehicle import EULER_RATE_FORMS

PAPER_CONTROLLER_FILE = Path(__file__).parent / "paper.toml"

GAIN_NAMES = tuple(f"kx{i}" for i in range(1, 13))

#: The setpoints a design can be made for (``offboard tune --setpoint-output``, ``offboard fly --output``).
DESIGNED_OUTPUTS = ("attitude", "rates")


@dataclass(frozen=True)
class ControllerGains:
    """The twelve gains k_x1 ... k_x12 of eq. 31-33 (Table I); each must lie in (0, 1)."""

    kx1: float = 0.78
    kx2: float = 0.8
    kx3: float = 0.77
    kx4: float = 0.8
    kx5: float = 0.9
    kx6: float = 0.95
    kx7: float = 0.7
    kx8: float = 0.67
    kx9: float = 0.7
    kx10: float = 0.67
    kx11: float = 0.8
    kx12: float = 0.85

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not 0.0 < value < 1.0:
                raise ValueError(f"{f.name} must lie in (0, 1) (Appendix A), got {value}")


@dataclass(frozen=True)
class ActionLimits:
    """Optional bounds on the actions (the paper's future work). ``None`` = unbounded.

    Attributes
    ----------
    thrust_min_n, thrust_max_n : float or None
        Bounds on u.
    tilt_max_rad : float or None
        Bound on each of the angle references x7ez (roll) and x9ez (pitch), or with
        ``tilt_cone`` on the tilt of the thrust axis from the vertical (PX4's MPC_TILTMAX_AIR:
        per angle, 35 deg on both gives 48 deg of tilt).
    tilt_cone : bool
        Bound the thrust axis's tilt instead of each angle.
    speed_xy_max_m_s, speed_up_max_m_s, speed_down_max_m_s : float or None
        Bounds on the desired speeds of eq. 32 (horizontal norm; up; down), as PX4's
        MPC_XY_VEL_MAX, MPC_Z_VEL_MAX_UP, MPC_Z_VEL_MAX_DN: a step in the reference is then flown
        at a bounded speed, inside the range the linear design holds for
        (docs/controller-design.md).
    yaw_rate_max_rad_s : float or None
        Bound on the yaw reference's rate (PX4's MPC_YAWRAUTO_MAX): the law's yaw reference
        slews towards x11d at most this fast (``LawMemory.yaw_ref``).
    rate_carry_s : float
        With ``tilt_max_rad``, the body-rate output's tilt bound (``paper.tilt_bounded_rates``):
        how far the vehicle's rate loop carries a body rate once its setpoint drops to zero, as a
        time, plus the latency (``design.rate_carry_s``; 0: the rate stops with the sample).
    """

    thrust_min_n: float | None = None
    thrust_max_n: float | None = None
    tilt_max_rad: float | None = None
    tilt_cone: bool = False
    speed_xy_max_m_s: float | None = None
    speed_up_max_m_s: float | None = None
    speed_down_max_m_s: float | None = None
    yaw_rate_max_rad_s: float | None = None
    rate_carry_s: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate_carry_s) and self.rate_carry_s >= 0.0):
            raise ValueError(f"rate_carry_s must be >= 0, got {self.rate_carry_s}")
        lo, hi = self.thrust_min_n, self.thrust_max_n
        if lo is not None and hi is not None and not lo < hi:
            raise ValueError(f"thrust_min_n ({lo}) must be below thrust_max_n ({hi})")
        if self.tilt_max_rad is not None and not 0.0 < self.tilt_max_rad < math.pi / 2:
            raise ValueError(f"tilt_max_rad must lie in (0, pi/2), got {self.tilt_max_rad}")
        for name in SPEED_LIMITS:
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be > 0, got {value}")

    @property
    def any(self) -> bool:
        """Whether any limit is set."""
        return any(getattr(self, name) is not None for name in ("thrust_min_n", "thrust_max_n", "tilt_max_rad", *SPEED_LIMITS))


#: The optional bounds on the desired speeds of eq. 32 and on the yaw reference's rate (``ActionLimits``).
SPEED_LIMITS = ("speed_xy_max_m_s", "speed_up_max_m_s", "speed_down_max_m_s", "yaw_rate_max_rad_s")


@dataclass(frozen=True)
class ControllerParams:
    """Everything the law needs besides the state and the references.

    Attributes
    ----------
    sample_time_s : float
        To, the sample time (eq. 21), seconds.
    mass_kg, arm_length_m, inertia_kg_m2, gravity_m_s2 : float
        The vehicle as the controller believes it (Table II makes these differ from the truth).
    euler_rate_form : EulerRateForm
        W_eta used for eq. 16 (see ``offboard.model.euler_lagrange``).
    drag_to_thrust_m : float
        Rotor drag coefficient c = k_m/k_f for the rotor forces of eq. 9-11.
    gains : ControllerGains
    yaw_aware : bool
        Write the horizontal part of the law in the heading frame (rotate the horizontal
        increments by -psi before eq. 28-29 and 39). Off reproduces the paper exactly; on is what
        a vehicle whose thrust turns with yaw needs.
    limits : ActionLimits
        Off by default, so the reproduction is exact.
    integral_gain_per_s : float
        ki of the optional integral action on the position errors (``law`` module docstring);
        0 (the default) is the paper's law.
    integral_limit_m_s : float
        Anti-windup: the integral's contribution to each desired speed is clamped to +- this.
    velocity_integral_gain_per_s2 : float
        ki of the optional integral action on the velocity errors of eq. 33 (``law`` module
        docstring), m/s^2 of acceleration per metre of integrated speed error; 0 (the default)
        is the paper's law.
    vertical_velocity_integral_gain_per_s2 : float or None
        The velocity integral's ki on the vertical axis (PX4's MPC_Z_VEL_I_ACC beside
        MPC_XY_VEL_I_ACC): the design chooses it with the vertical loop (``design._search_vertical``).
        None, the default, uses ``velocity_integral_gain_per_s2`` on every axis.
    velocity_integral_limit_m_s2 : float
        The velocity integral's acceleration is clamped to +- this on each axis (default g / 2:
        a steady disturbance beyond it, a 50 % mass error or a 27 deg tilt bias, is not one to
        hold against).
    reference_lead_s2 : (float, float)
        c2 (horizontal, vertical) of the designed closed loop's reference response
        ``T = 1 + c2 s^2``: the law is handed ``r - c2 r''`` (``offboard.frames.tracking_reference``,
        docs/controller-design.md). (0, 0), the default, hands it ``r``: the paper's law.
    tilt_lead : float
        The attitude handed to an autopilot's attitude loop is x7ez, x9ez plus ``tilt_lead``
        times their difference from the measured angles (``LawOutput.roll_setpoint_rad``): a
        lead on the autopilot's attitude P, chosen with the gains by ``offboard tune``
        (docs/controller-design.md). 0, the default, hands x7ez and x9ez themselves.
    linear_drag_n_s_m : float
        A linear aerodynamic drag ``-d v`` (N) the controller believes (PX4 SIH's SIH_KDV):
        the law's eq. 27 then asks the thrust to make it up too. 0, the default, is the paper's
        model (eq. 18 has no drag).
    velocity_integral_hold_s : float
        After a reference step (the 3D position error jumps by more than ``law.STEP_M`` in a
        sample, the flight's start included) the velocity integral holds until the error is
        below ``law.SETTLED_M`` or for at most this long (s): a step's transient is not a
        disturbance to learn. The design sets it to its loop's settling time; 0 (the default)
        holds only on the bounds.
    velocity_from_position_s : float
        T of the complementary filter that makes the velocity the law reads consistent with the
        position it tracks (``offboard.controller.velocity``): below 1/T the derivative of the
        position estimate, above it the vehicle's velocity estimate. 0, the default, reads the
        velocity as measured: the paper's law.
    velocity_from_position_identify : bool
        Choose that T from the estimates' own noise in flight (``ConsistentVelocity(identify=True)``:
        the steady-state Kalman filter of their velocity bias, from 5 s of samples on),
        ``velocity_from_position_s`` until then. False, the default: T as given.
    setpoint_output : str or None
        The setpoint the gains were designed for (``offboard tune --setpoint-output``):
        ``"attitude"`` (the autopilot's attitude loop closed around them) or ``"rates"`` (the
        law's kx7..kx10 close it around the autopilot's rate loop). ``offboard fly`` flies a file
        with that output, and refuses another. None, the default (Table I's file): not said.
    """

    sample_time_s: float = 0.05
    mass_kg: float = 0.5
    arm_length_m: float = 0.24
    inertia_kg_m2: tuple[float, float, float] = (3.8e-3, 3.8e-3, 7.1e-3)
    gravity_m_s2: float = 9.81
    euler_rate_form: EulerRateForm = EulerRateForm.CASTILLO
    drag_to_thrust_m: float = 0.016
    gains: ControllerGains = field(default_factory=ControllerGains)
    yaw_aware: bool = False
    limits: ActionLimits = field(default_factory=ActionLimits)
    integral_gain_per_s: float = 0.0
    integral_limit_m_s: float = 3.0
    velocity_integral_gain_per_s2: float = 0.0
    vertical_velocity_integral_gain_per_s2: float | None = None
    velocity_integral_limit_m_s2: float = 4.9
    reference_lead_s2: tuple[float, float] = (0.0, 0.0)
    tilt_lead: float = 0.0
    linear_drag_n_s_m: float = 0.0
    velocity_integral_hold_s: float = 0.0
    velocity_from_position_s: float = 0.0
    velocity_from_position_identify: bool = False
    setpoint_output: str | None = None

    def __post_init__(self) -> None:
        for key in ("sample_time_s", "mass_kg", "arm_length_m", "gravity_m_s2", "drag_to_thrust_m"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{key} must be > 0, got {value}")
        if len(self.inertia_kg_m2) != 3 or min(self.inertia_kg_m2) <= 0:
            raise ValueError(f"inertia_kg_m2 must be 3 positive numbers, got {self.inertia_kg_m2}")
        if not (math.isfinite(self.integral_gain_per_s) and self.integral_gain_per_s >= 0):
            raise ValueError(f"integral_gain_per_s must be >= 0, got {self.integral_gain_per_s}")
        if not (math.isfinite(self.integral_limit_m_s) and self.integral_limit_m_s > 0):
            raise ValueError(f"integral_limit_m_s must be > 0, got {self.integral_limit_m_s}")
        if not (math.isfinite(self.velocity_integral_gain_per_s2) and self.velocity_integral_gain_per_s2 >= 0):
            raise ValueError(f"velocity_integral_gain_per_s2 must be >= 0, got {self.velocity_integral_gain_per_s2}")
        up = self.vertical_velocity_integral_gain_per_s2
        if up is not None and not (math.isfinite(up) and up >= 0):
            raise ValueError(f"vertical_velocity_integral_gain_per_s2 must be >= 0, got {up}")
        if not (math.isfinite(self.velocity_integral_limit_m_s2) and self.velocity_integral_limit_m_s2 > 0):
            raise ValueError(f"velocity_integral_limit_m_s2 must be > 0, got {self.velocity_integral_limit_m_s2}")
        if not (math.isfinite(self.linear_drag_n_s_m) and self.linear_drag_n_s_m >= 0):
            raise ValueError(f"linear_drag_n_s_m must be >= 0, got {self.linear_drag_n_s_m}")
        if not (math.isfinite(self.velocity_integral_hold_s) and self.velocity_integral_hold_s >= 0):
            raise ValueError(f"velocity_integral_hold_s must be >= 0, got {self.velocity_integral_hold_s}")
        if not (math.isfinite(self.velocity_from_position_s) and self.velocity_from_position_s >= 0):
            raise ValueError(f"velocity_from_position_s must be >= 0, got {self.velocity_from_position_s}")
        if self.velocity_from_position_identify and not self.velocity_from_position_s > 0:
            raise ValueError("velocity_from_position_identify needs velocity_from_position_s > 0 (the T it starts from)")
        if not (math.isfinite(self.tilt_lead) and self.tilt_lead >= 0):
            raise ValueError(f"tilt_lead must be >= 0, got {self.tilt_lead}")
        if len(self.reference_lead_s2) != 2 or not all(math.isfinite(v) for v in self.reference_lead_s2):
            raise ValueError(f"reference_lead_s2 must be 2 finite numbers, got {self.reference_lead_s2}")
        if self.setpoint_output is not None and self.setpoint_output not in DESIGNED_OUTPUTS:
            raise ValueError(f"setpoint_output must be one of {DESIGNED_OUTPUTS} or None, got {self.setpoint_output!r}")
        if self.euler_rate_form not in EULER_RATE_FORMS:
            raise ValueError(f"euler_rate_form must be one of {EULER_RATE_FORMS}, got {self.euler_rate_form!r}")
        object.__setattr__(self, "euler_rate_form", EulerRateForm(self.euler_rate_form))  # a caller's word: its enum

    def with_changes(self, **changes: Any) -> ControllerParams:
        """A copy with the named fields changed (checked as a new one is)."""
        return replace(self, **changes)


def controller_from_table(f: Fields) -> ControllerParams:
    """Build ``ControllerParams`` from a TOML table shaped like ``paper.toml``."""
    law = f.sub("law")
    model = f.sub("model")
    gains_table = f.sub("gains")
    limits_table = f.sub("limits", optional=True)
    gains = ControllerGains(**{name: gains_table.number(name, gt=0.0, lt=1.0) for name in GAIN_NAMES})
    gains_table.reject_unknown()
    tilt_deg = limits_table.raw("tilt_max_deg", None)
    limits = ActionLimits(
        thrust_min_n=None if not limits_table.has("thrust_min_n") else limits_table.number("thrust_min_n"),
        thrust_max_n=None if not limits_table.has("thrust_max_n") else limits_table.number("thrust_max_n", gt=0),
        tilt_max_rad=None if tilt_deg is None else math.radians(limits_table.number("tilt_max_deg", gt=0, lt=90)),
        tilt_cone=limits_table.boolean("tilt_cone", False),
        **{name: limits_table.number(name, gt=0) if limits_table.has(name) else None for name in SPEED_LIMITS},
        rate_carry_s=limits_table.number("rate_carry_s", 0.0, ge=0),
    )
    if limits.thrust_min_n is not None and limits.thrust_max_n is not None and limits.thrust_min_n >= limits.thrust_max_n:
        raise limits_table.error("thrust_min_n", "must be below thrust_max_n")
    limits_table.reject_unknown()
    if law.boolean("velocity_from_position_identify", False) and not law.number("velocity_from_position_s", 0.0, ge=0) > 0:
        raise law.error("velocity_from_position_identify", "needs velocity_from_position_s > 0 (the T it starts from)")
    params = ControllerParams(
        sample_time_s=law.number("sample_time_s", gt=0),
        yaw_aware=law.boolean("yaw_aware", False),
        integral_gain_per_s=law.number("integral_gain_per_s", 0.0, ge=0),
        integral_limit_m_s=law.number("integral_limit_m_s", 3.0, gt=0),
        velocity_integral_gain_per_s2=law.number("velocity_integral_gain_per_s2", 0.0, ge=0),
        vertical_velocity_integral_gain_per_s2=law.number("vertical_velocity_integral_gain_per_s2", ge=0)
        if law.has("vertical_velocity_integral_gain_per_s2") else None,
        velocity_integral_limit_m_s2=law.number("velocity_integral_limit_m_s2", 4.9, gt=0),
        reference_lead_s2=law.vector("reference_lead_s2", 2, default=(0.0, 0.0)),  # type: ignore[arg-type]
        tilt_lead=law.number("tilt_lead", 0.0, ge=0),
        velocity_integral_hold_s=law.number("velocity_integral_hold_s", 0.0, ge=0),
        velocity_from_position_s=law.number("velocity_from_position_s", 0.0, ge=0),
        velocity_from_position_identify=law.boolean("velocity_from_position_identify", False),
        setpoint_output=law.string("setpoint_output", choices=DESIGNED_OUTPUTS) if law.has("setpoint_output") else None,
        mass_kg=model.number("mass_kg", gt=0),
        arm_length_m=model.number("arm_length_m", gt=0),
        inertia_kg_m2=model.vector("inertia_kg_m2", 3, gt=0),  # type: ignore[arg-type]
        gravity_m_s2=model.number("gravity_m_s2", 9.81, gt=0),
        euler_rate_form=EulerRateForm(model.string("euler_rate_form", EulerRateForm.CASTILLO, choices=EULER_RATE_FORMS)),
        drag_to_thrust_m=model.number("drag_to_thrust_m", 0.016, gt=0),
        linear_drag_n_s_m=model.number("linear_drag_n_s_m", 0.0, ge=0),
        gains=gains,
        limits=limits,
    )
    law.reject_unknown()
    model.reject_unknown()
    f.reject_unknown()
    return params


def load_controller(path: str | Path) -> ControllerParams:
    """Read a controller parameter file (see ``paper.toml``)."""
    path = Path(path)
    return controller_from_table(Fields(read_toml(path), path.name))
