"""Physical parameters of a quadrotor, and the TOML file they come from.

Rotor layout (the paper's "+" layout, eq. 11, body FRD axes):

====== ============ ===================== ===========================
rotor  position     spins (seen from top) reaction torque on the body
====== ============ ===================== ===========================
f1     right (+y)   clockwise             -c * f1 (yaw left)
f2     front (+x)   counter-clockwise     +c * f2 (yaw right)
f3     left (-y)    clockwise             -c * f3
f4     rear (-x)    counter-clockwise     +c * f4
====== ============ ===================== ===========================

so that ``tau_phi = (f3 - f1) l``, ``tau_theta = (f2 - f4) l`` (eq. 11) and
``tau_psi = sum(tau_Mi) = c (f2 + f4 - f1 - f3)`` with ``c = k_m / k_f`` the rotor drag
coefficient in metres (``drag_to_thrust_m``).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from offboard.model.euler_lagrange import EulerRateForm
from offboard.model.tomlfile import Fields, read_toml


class VehicleModel(enum.StrEnum):
    """What the vehicle is, as the controller's command and its encoding see it: a rigid body
    (PX4, any real vehicle; ``sitl-plant --model rigid-body``) or the paper's model of eq. 13 and
    18 (``sitl-plant --model paper``), whose angles are generalised coordinates and whose torque
    input is the generalised torque."""

    RIGID_BODY = "rigid-body"
    PAPER = "paper"


#: The vehicle models by name, the rigid body (the default everywhere) first.
VEHICLE_MODELS = tuple(m.value for m in VehicleModel)

#: The bundled vehicle files: data of the simulator's package (sitl_plant/vehicles), found by
#: path so that reading one imports nothing of the simulator.
VEHICLES_DIR = Path(__file__).resolve().parents[2] / "sitl_plant" / "vehicles"
PAPER_VEHICLE_FILE = VEHICLES_DIR / "paper-quad.toml"
#: sitl-plant's default: the paper's quad with PX4 SITL's headroom, hovering at 0.5 (the file says why).
DEFAULT_VEHICLE_FILE = VEHICLES_DIR / "sitl-quad.toml"
#: PX4 v1.16 SITL's SIH quadrotor (airframe 10040), to fly the vehicle PX4 SITL flies.
PX4_SIH_VEHICLE_FILE = VEHICLES_DIR / "px4-sih.toml"

EULER_RATE_FORMS = tuple(f.value for f in EulerRateForm)


@dataclass(frozen=True)
class VehicleParams:
    """A quadrotor's physical parameters (SI units).

    Attributes
    ----------
    mass_kg, arm_length_m, gravity_m_s2
        m, l, g of the paper (Section 4).
    inertia_kg_m2 : tuple of 3 floats
        Principal moments (Ixx, Iyy, Izz) about body FRD axes.
    thrust_coeff_n_s2 : float
        k in ``f_i = k omega_i**2`` (eq. 10), newtons per (rad/s)^2.
    drag_to_thrust_m : float
        c = k_m / k_f, the rotor drag torque per newton of thrust (eq. 11, tau_Mi = +-c f_i).
    rotor_speed_min_rad_s, rotor_speed_max_rad_s : float
        Motor speed limits (rigid-body model only).
    motor_time_constant_s : float
        First-order lag of each motor's speed (rigid-body model only; 0 = instant).
    linear_drag_n_s_m : tuple of 3 floats
        Aerodynamic drag force per unit air-relative velocity along body x, y, z (rigid body).
    euler_rate_form : EulerRateForm
        Which W_eta (eq. 4) the paper model uses: ``castillo`` (the cited model, -sin psi in
        entry (3,2), det = cos theta), ``printed`` (eq. 4 as printed, singular at psi = pi/4)
        or ``zyx`` (a rigid body's true Euler-rate map, roll in those entries).
    """

    mass_kg: float = 0.5
    arm_length_m: float = 0.24
    inertia_kg_m2: tuple[float, float, float] = (3.8e-3, 3.8e-3, 7.1e-3)
    gravity_m_s2: float = 9.81
    thrust_coeff_n_s2: float = 1.0e-5
    drag_to_thrust_m: float = 0.016
    rotor_speed_min_rad_s: float = 0.0
    rotor_speed_max_rad_s: float = 700.0
    motor_time_constant_s: float = 0.02
    linear_drag_n_s_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    euler_rate_form: EulerRateForm = EulerRateForm.CASTILLO
    name: str = field(default="quadrotor", compare=False)

    def __post_init__(self) -> None:
        for key in ("mass_kg", "arm_length_m", "gravity_m_s2", "thrust_coeff_n_s2", "drag_to_thrust_m"):
            if not getattr(self, key) > 0:
                raise ValueError(f"{key} must be > 0, got {getattr(self, key)}")
        if len(self.inertia_kg_m2) != 3 or min(self.inertia_kg_m2) <= 0:
            raise ValueError(f"inertia_kg_m2 must be 3 positive numbers, got {self.inertia_kg_m2}")
        if not 0 <= self.rotor_speed_min_rad_s < self.rotor_speed_max_rad_s:
            raise ValueError("need 0 <= rotor_speed_min_rad_s < rotor_speed_max_rad_s")
        if self.motor_time_constant_s < 0:
            raise ValueError("motor_time_constant_s must be >= 0")
        if self.euler_rate_form not in EULER_RATE_FORMS:
            raise ValueError(f"euler_rate_form must be one of {EULER_RATE_FORMS}")
        object.__setattr__(self, "euler_rate_form", EulerRateForm(self.euler_rate_form))  # a caller's word: its enum

    @property
    def inertia_matrix(self) -> np.ndarray:
        """diag(Ixx, Iyy, Izz), kg m^2."""
        return np.diag(self.inertia_kg_m2)

    @property
    def max_rotor_thrust_n(self) -> float:
        """One rotor's thrust at top speed, k w_max^2, N."""
        return self.thrust_coeff_n_s2 * self.rotor_speed_max_rad_s**2

    @property
    def max_thrust_n(self) -> float:
        """Collective thrust at full throttle (all four rotors at top speed)."""
        return 4.0 * self.max_rotor_thrust_n

    @property
    def max_roll_pitch_torque_nm(self) -> float:
        """Torque with one rotor of a pair at top speed and the other stopped."""
        return self.arm_length_m * self.max_rotor_thrust_n

    @property
    def max_yaw_torque_nm(self) -> float:
        """Torque with one diagonal pair at top speed and the other stopped."""
        return 2.0 * self.drag_to_thrust_m * self.max_rotor_thrust_n

    def with_changes(self, **changes: Any) -> VehicleParams:
        """A copy with the named fields changed (checked as a new one is)."""
        return replace(self, **changes)


def vehicle_from_table(fields: Fields) -> VehicleParams:
    """Build ``VehicleParams`` from a TOML table (see ``vehicles/paper-quad.toml``)."""
    defaults = VehicleParams()
    params = VehicleParams(
        name=fields.string("name", defaults.name),
        mass_kg=fields.number("mass_kg", gt=0),
        arm_length_m=fields.number("arm_length_m", gt=0),
        inertia_kg_m2=fields.vector("inertia_kg_m2", 3, gt=0),  # type: ignore[arg-type]
        gravity_m_s2=fields.number("gravity_m_s2", defaults.gravity_m_s2, gt=0),
        thrust_coeff_n_s2=fields.number("thrust_coeff_n_s2", defaults.thrust_coeff_n_s2, gt=0),
        drag_to_thrust_m=fields.number("drag_to_thrust_m", defaults.drag_to_thrust_m, gt=0),
        rotor_speed_min_rad_s=fields.number("rotor_speed_min_rad_s", defaults.rotor_speed_min_rad_s, ge=0),
        rotor_speed_max_rad_s=fields.number("rotor_speed_max_rad_s", defaults.rotor_speed_max_rad_s, gt=0),
        motor_time_constant_s=fields.number("motor_time_constant_s", defaults.motor_time_constant_s, ge=0),
        linear_drag_n_s_m=fields.vector("linear_drag_n_s_m", 3, defaults.linear_drag_n_s_m, ge=0),  # type: ignore[arg-type]
        euler_rate_form=EulerRateForm(fields.string("euler_rate_form", defaults.euler_rate_form, choices=EULER_RATE_FORMS)),
    )
    if params.rotor_speed_min_rad_s >= params.rotor_speed_max_rad_s:
        raise fields.error("rotor_speed_min_rad_s", "must be below rotor_speed_max_rad_s")
    fields.reject_unknown()
    return params


def load_vehicle(path: str | Path) -> VehicleParams:
    """Read a vehicle file whose top level is the vehicle table."""
    path = Path(path)
    return vehicle_from_table(Fields(read_toml(path), path.name))
