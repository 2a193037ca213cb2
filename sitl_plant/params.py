"""The MAVLink parameter table of ``sitl-plant`` (PARAM_VALUE / PARAM_SET), pure.

Names follow PX4 where PX4 has the parameter (``COM_OF_LOSS_T``, ``MC_ROLLRATE_P`` ...) and use
the ``SIM_`` prefix for the simulated vehicle's physical values, which the ``offboard`` process
reads to learn the vehicle it flies. Every name is at most 16 characters (the MAVLink limit).

Values are stored as Python floats; an ``int`` parameter travels as MAV_PARAM_TYPE_INT32, and a
``real`` one as MAV_PARAM_TYPE_REAL32, so it is rounded to float32 on the wire (the table keeps
the rounded value too, so what a client reads back is what the plant uses).

``ParamTable.set`` validates like PX4's parameter handler: non-finite, out-of-range, read-only
or unknown values are refused and the old value stays (the caller answers with it).
"""

from __future__ import annotations

import math
import struct
import tomllib
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Iterator

from offboard.model.vehicle import VehicleParams

REAL = "real"
INT = "int"

#: Physical parameters whose change rebuilds the simulated vehicle (refused while armed).
PHYSICAL = ("SIM_MASS", "SIM_ARM_LEN", "SIM_IXX", "SIM_IYY", "SIM_IZZ", "SIM_KF", "SIM_KM_KF", "SIM_W_MAX", "SIM_MOT_TAU")

#: PX4 v1.16 SITL's parameters that clients read, with PX4's types and values (the file says which).
PX4_PARAMS_FILE = Path(__file__).with_name("px4_params.toml")

#: COM_OBL_RC_ACT values (PX4's offboard_loss_failsafe_mode): 0 Position (PX4's default),
#: 1 Altitude, 2 Stabilized, 3 Return, 4 Land, 5 Hold, 6 Terminate, 7 Disarm.
OBL_ACT_POSITION = 0
OBL_ACT_LAND = 4
OBL_ACT_HOLD = 5


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name, default, kind, admissible range, unit and meaning."""

    name: str
    default: float
    kind: str = REAL
    min: float = -math.inf
    max: float = math.inf
    unit: str = ""
    description: str = ""
    read_only: bool = False
    choices: tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        if len(self.name) > 16:
            raise ValueError(f"parameter name {self.name!r} is longer than 16 characters")
        if self.kind not in (REAL, INT):
            raise ValueError(f"{self.name}: kind must be {REAL!r} or {INT!r}")


@dataclass(frozen=True)
class SetOutcome:
    """What ``ParamTable.set`` did: ``accepted`` and, when refused, why."""

    accepted: bool
    reason: str = ""


def to_float32(value: float) -> float:
    """The value a REAL32 parameter holds once it has crossed the wire."""
    return struct.unpack("<f", struct.pack("<f", value))[0]


class ParamTable:
    """Ordered parameters with validation; ``version`` counts accepted changes."""

    def __init__(self, specs: list[ParamSpec]) -> None:
        self._specs = {s.name: s for s in specs}
        if len(self._specs) != len(specs):
            raise ValueError("duplicate parameter names")
        self._names = [s.name for s in specs]
        self._index = {name: i for i, name in enumerate(self._names)}
        self._values = {s.name: self._stored(s, s.default) for s in specs}
        self.version = 0

    @staticmethod
    def _stored(spec: ParamSpec, value: float) -> float:
        return float(int(value)) if spec.kind == INT else to_float32(float(value))

    def __len__(self) -> int:
        return len(self._names)

    def __contains__(self, name: object) -> bool:
        return name in self._specs

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def spec(self, name: str) -> ParamSpec:
        """The specification of ``name`` (its default, kind, range, unit, meaning)."""
        return self._specs[name]

    def index(self, name: str) -> int:
        """``name``'s position in the list PARAM_VALUE numbers (param_index)."""
        return self._index[name]

    def name_at(self, index: int) -> str | None:
        """The name at ``index`` (PARAM_REQUEST_READ by index), None out of range."""
        return self._names[index] if 0 <= index < len(self._names) else None

    def set(self, name: str, value: float) -> SetOutcome:
        """Validate and store ``value``; the old value stays when refused."""
        spec = self._specs.get(name)
        if spec is None:
            return SetOutcome(False, f"unknown parameter {name}")
        if spec.read_only:
            return SetOutcome(False, f"{name} is read-only")
        if not math.isfinite(value):
            return SetOutcome(False, f"{name}: refused non-finite value {value}")
        if spec.kind == INT and value != int(value):
            return SetOutcome(False, f"{name}: expected an integer, got {value:g}")
        if not spec.min <= value <= spec.max:
            return SetOutcome(False, f"{name}: {value:g} outside [{spec.min:g}, {spec.max:g}]")
        if spec.choices is not None and int(value) not in spec.choices:
            allowed = ", ".join(str(c) for c in spec.choices)
            return SetOutcome(False, f"{name}: {value:g} not one of {allowed}")
        stored = self._stored(spec, value)
        if stored != self._values[name]:
            self._values[name] = stored
            self.version += 1
        return SetOutcome(True)

    def force(self, name: str, value: float) -> None:
        """Store a value the plant computed itself (derived, read-only parameters)."""
        spec = self._specs[name]
        stored = self._stored(spec, value)
        if stored != self._values[name]:
            self._values[name] = stored
            self.version += 1


# --- the table --------------------------------------------------------------------------------


@lru_cache(maxsize=1)
def px4_published() -> dict[str, tuple[str, float]]:
    """name -> (kind, value) of ``PX4_PARAMS_FILE``: what PX4 v1.16 SITL publishes and clients read."""
    with PX4_PARAMS_FILE.open("rb") as fh:
        table = tomllib.load(fh)
    return {name: (entry["type"], float(entry["value"])) for name, entry in table.items()}


def plant_param_specs(vehicle: VehicleParams, *, sysid: int = 1) -> list[ParamSpec]:
    """Every parameter of the plant, sorted by name as PX4 indexes them: the plant's own (defaults
    from ``vehicle``, see docs/plant.md) and PX4 v1.16 SITL's others that clients read, with
    PX4's type and value (``px4_published``: stored and answered, not used by the simulation)."""
    own = _own_param_specs(vehicle, sysid=sysid)
    names = {s.name for s in own}
    published = [
        ParamSpec(name, value, INT if kind == "int" else REAL, description="PX4 v1.16 SITL's value (published for clients)")
        for name, (kind, value) in px4_published().items()
        if name not in names
    ]
    return sorted(own + published, key=lambda spec: spec.name)


def horizontal_drag_n_s_m(vehicle: VehicleParams) -> float:
    """The vehicle's linear drag as one number, as PX4 SIH publishes SIH_KDV: the mean of its body
    x and y values (a tilt axis's drag near hover; the bundled vehicles' drag is isotropic)."""
    return 0.5 * (vehicle.linear_drag_n_s_m[0] + vehicle.linear_drag_n_s_m[1])


#: SIM_DR_ACC_ERR's default, m/s^2: PX4 v1.16 SIH's EKF2, its GPS stopped in an Offboard hold
#: flown on the estimate (``python bench/px4_dead_reckoning.py``), reported a position 2.6-4.2 m
#: from SIH's truth 4 s later and 3.9-5.9 m 5 s later in four flights: 1/2 b t^2 at b = 0.31-0.52
#: (docs/plant.md). In Hold it was 0.7-0.9 m at 4.5 s (tests/e2e/test_px4_parity_gps_loss.py).
DEAD_RECKONING_ACCEL_ERROR_M_S2 = 0.4


def _own_param_specs(vehicle: VehicleParams, *, sysid: int = 1) -> list[ParamSpec]:
    """The parameters the plant implements."""
    ixx, iyy, izz = vehicle.inertia_kg_m2
    thr_max = vehicle.max_thrust_n
    hover = min(0.9, max(0.05, vehicle.mass_kg * vehicle.gravity_m_s2 / thr_max))
    return [
        # identity, as a ground station expects of PX4
        ParamSpec("SYS_AUTOSTART", 10040, INT, read_only=True, description="airframe id (PX4 SITL's SIH quadrotor, sihsim_quadx)"),
        ParamSpec("MAV_SYS_ID", sysid, INT, read_only=True, description="MAVLink system id (set with --sysid)"),
        ParamSpec("MAV_TYPE", 2, INT, read_only=True, description="MAV_TYPE_QUADROTOR"),
        ParamSpec("SYS_FAILURE_EN", 0, INT, 0, 1, description="enable MAV_CMD_INJECT_FAILURE"),
        # the simulated vehicle (--vehicle FILE); changes rebuild the model, refused while armed
        ParamSpec("SIM_MASS", vehicle.mass_kg, min=1e-3, max=1e3, unit="kg", description="vehicle mass m"),
        ParamSpec("SIM_ARM_LEN", vehicle.arm_length_m, min=1e-3, max=100.0, unit="m", description="arm length l"),
        ParamSpec("SIM_IXX", ixx, min=1e-7, max=1e3, unit="kg m^2", description="inertia about body x (FRD)"),
        ParamSpec("SIM_IYY", iyy, min=1e-7, max=1e3, unit="kg m^2", description="inertia about body y (FRD)"),
        ParamSpec("SIM_IZZ", izz, min=1e-7, max=1e3, unit="kg m^2", description="inertia about body z (FRD)"),
        ParamSpec("SIM_KF", vehicle.thrust_coeff_n_s2, min=1e-12, max=1.0, unit="N/(rad/s)^2", description="rotor thrust coefficient k"),
        ParamSpec("SIM_KM_KF", vehicle.drag_to_thrust_m, min=1e-6, max=10.0, unit="m", description="rotor drag-to-thrust c"),
        ParamSpec("SIM_W_MAX", vehicle.rotor_speed_max_rad_s, min=1.0, max=1e5, unit="rad/s", description="top rotor speed"),
        ParamSpec("SIM_MOT_TAU", vehicle.motor_time_constant_s, min=0.0, max=10.0, unit="s", description="motor time constant"),
        ParamSpec("SIM_THR_MAX", thr_max, read_only=True, unit="N", description="collective thrust at normalised thrust 1"),
        ParamSpec("SIM_TQ_RP_MAX", vehicle.max_roll_pitch_torque_nm, read_only=True, unit="N m", description="roll/pitch torque at normalised 1"),
        ParamSpec("SIM_TQ_Y_MAX", vehicle.max_yaw_torque_nm, read_only=True, unit="N m", description="yaw torque at normalised 1"),
        ParamSpec("SIM_KDV", horizontal_drag_n_s_m(vehicle), read_only=True, unit="N s/m",
                  description="linear drag, horizontal (the vehicle file's linear_drag_n_s_m; PX4 SIH's SIH_KDV)"),
        ParamSpec("SIM_DR_ACC_ERR", DEAD_RECKONING_ACCEL_ERROR_M_S2, min=0.0, max=10.0, unit="m/s^2",
                  description="a GPS lost: the horizontal acceleration error the reported position is dead-reckoned with (0: none)"),
        # commander
        ParamSpec("COM_OF_LOSS_T", 1.0, min=0.0, max=60.0, unit="s", description="offboard-loss timeout"),
        ParamSpec("COM_OBL_RC_ACT", OBL_ACT_POSITION, INT, choices=tuple(range(8)),
                  description="offboard-loss action: 0 Position, 1 Altitude, 2 Stabilized, 3 Return, 4 Land, 5 Hold, 6 Terminate, 7 Disarm"),
        ParamSpec("COM_FAIL_ACT_T", 5.0, min=0.0, max=25.0, unit="s", description="hold before a deferred failsafe action (manual control loss)"),
        ParamSpec("COM_RC_LOSS_T", 0.5, min=0.0, max=35.0, unit="s", description="manual control (MANUAL_CONTROL) loss timeout"),
        ParamSpec("NAV_RCL_ACT", 2, INT, choices=(0, 1, 2, 3, 5, 6),
                  description="manual control loss action after COM_FAIL_ACT_T of Hold: 0 none, 1 Hold, 2 Return, 3 Land, 5 Terminate, 6 Disarm"),
        ParamSpec("COM_SPOOLUP_TIME", 1.0, min=0.0, max=5.0, unit="s", description="motor spool-up after arming, before a takeoff"),
        ParamSpec("LNDMC_TRIG_TIME", 1.0, min=0.1, max=10.0, unit="s", description="land detector: ground contact this long is landed"),
        ParamSpec("COM_DISARM_LAND", 2.0, min=-1.0, max=20.0, unit="s", description="auto-disarm after landing (<= 0 off)"),
        ParamSpec("COM_DISARM_PRFLT", 10.0, min=-1.0, max=20.0, unit="s", description="auto-disarm if no takeoff (<= 0 off)"),
        # the paper's inner loop (--inner-loop paper)
        ParamSpec("PAP_TO", 0.05, min=1e-4, max=10.0, unit="s", description="paper's sample time To"),
        ParamSpec("PAP_IXX", ixx, min=1e-7, max=1e3, unit="kg m^2", description="inertia the paper loop believes"),
        ParamSpec("PAP_IYY", iyy, min=1e-7, max=1e3, unit="kg m^2", description="inertia the paper loop believes"),
        ParamSpec("PAP_IZZ", izz, min=1e-7, max=1e3, unit="kg m^2", description="inertia the paper loop believes"),
        # PX4 attitude (P) and rate (PID) loops, PX4 1.14 defaults; output is normalised torque
        ParamSpec("MC_ROLL_P", 6.5, min=0.0, max=12.0, unit="1/s"),
        ParamSpec("MC_PITCH_P", 6.5, min=0.0, max=12.0, unit="1/s"),
        ParamSpec("MC_YAW_P", 2.8, min=0.0, max=5.0, unit="1/s"),
        ParamSpec("MC_ROLLRATE_P", 0.15, min=0.0, max=0.5, unit="1/(rad/s)"),
        ParamSpec("MC_ROLLRATE_I", 0.2, min=0.0, max=10.0, unit="1/rad"),
        ParamSpec("MC_ROLLRATE_D", 0.003, min=0.0, max=0.01, unit="1/(rad/s^2)"),
        ParamSpec("MC_PITCHRATE_P", 0.15, min=0.0, max=0.6, unit="1/(rad/s)"),
        ParamSpec("MC_PITCHRATE_I", 0.2, min=0.0, max=10.0, unit="1/rad"),
        ParamSpec("MC_PITCHRATE_D", 0.003, min=0.0, max=0.01, unit="1/(rad/s^2)"),
        ParamSpec("MC_YAWRATE_P", 0.2, min=0.0, max=0.6, unit="1/(rad/s)"),
        ParamSpec("MC_YAWRATE_I", 0.1, min=0.0, max=10.0, unit="1/rad"),
        ParamSpec("MC_YAWRATE_D", 0.0, min=0.0, max=0.01, unit="1/(rad/s^2)"),
        ParamSpec("MC_RR_INT_LIM", 0.3, min=0.0, max=1.0, description="roll rate integrator limit"),
        ParamSpec("MC_PR_INT_LIM", 0.3, min=0.0, max=1.0, description="pitch rate integrator limit"),
        ParamSpec("MC_YR_INT_LIM", 0.3, min=0.0, max=1.0, description="yaw rate integrator limit"),
        ParamSpec("IMU_GYRO_RATEMAX", 400, INT, 100, 2000, unit="Hz", description="rate of the attitude and rate loops (at most)"),
        ParamSpec("MC_ROLLRATE_MAX", 220.0, min=0.0, max=1800.0, unit="deg/s"),
        ParamSpec("MC_PITCHRATE_MAX", 220.0, min=0.0, max=1800.0, unit="deg/s"),
        ParamSpec("MC_YAWRATE_MAX", 200.0, min=0.0, max=1800.0, unit="deg/s"),
        # the small built-in position controller of the hold / land / takeoff / RTL modes
        ParamSpec("MPC_XY_P", 0.95, min=0.0, max=2.0, unit="1/s"),
        ParamSpec("MPC_Z_P", 1.0, min=0.1, max=1.5, unit="1/s"),
        ParamSpec("MPC_XY_VEL_P_ACC", 1.8, min=1.2, max=5.0, unit="1/s"),
        ParamSpec("MPC_XY_VEL_I_ACC", 0.4, min=0.0, max=60.0, unit="1/s^2"),
        ParamSpec("MPC_Z_VEL_P_ACC", 4.0, min=2.0, max=15.0, unit="1/s"),
        ParamSpec("MPC_Z_VEL_I_ACC", 2.0, min=0.2, max=3.0, unit="1/s^2"),
        ParamSpec("MPC_XY_VEL_MAX", 12.0, min=0.0, max=20.0, unit="m/s"),
        ParamSpec("MPC_Z_VEL_MAX_UP", 3.0, min=0.5, max=8.0, unit="m/s"),
        ParamSpec("MPC_Z_VEL_MAX_DN", 1.5, min=0.5, max=4.0, unit="m/s"),
        ParamSpec("MPC_YAWRAUTO_MAX", 45.0, min=0.0, max=360.0, unit="deg/s",
                  description="yaw rate limit of the auto modes (PX4's default; the offboard's designed yaw-rate bound)"),
        ParamSpec("MPC_TILTMAX_AIR", 45.0, min=20.0, max=89.0, unit="deg"),
        ParamSpec("MPC_THR_HOVER", hover, min=0.05, max=0.9, description="normalised hover thrust"),
        ParamSpec("MPC_MANTHR_MIN", 0.08, min=0.0, max=1.0,
                  description="minimum collective thrust in the manual modes, normalised; the land detector's bound where no climb rate is controlled (Offboard attitude)"),
        ParamSpec("MPC_THR_MIN", 0.12, min=0.05, max=0.5, description="minimum collective thrust in flight, normalised (the offboard's thrust floor)"),
        ParamSpec("MPC_LAND_SPEED", 0.7, min=0.3, max=4.0, unit="m/s", description="landing speed below MPC_LAND_ALT2"),
        ParamSpec("MPC_Z_V_AUTO_DN", 1.5, min=0.5, max=4.0, unit="m/s", description="auto descent speed (Land above MPC_LAND_ALT1)"),
        ParamSpec("MPC_LAND_ALT1", 10.0, min=0.0, max=122.0, unit="m", description="Land slows below this height"),
        ParamSpec("MPC_LAND_ALT2", 5.0, min=0.0, max=122.0, unit="m", description="Land at MPC_LAND_SPEED below this height"),
        ParamSpec("MPC_LAND_ALT3", 1.0, min=0.0, max=122.0, unit="m", description="Land at MPC_LAND_CRWL below this height"),
        ParamSpec("MPC_LAND_CRWL", 0.3, min=0.1, max=10.0, unit="m/s", description="landing crawl speed near the ground"),
        ParamSpec("MPC_TKO_SPEED", 1.5, min=1.0, max=5.0, unit="m/s"),
        ParamSpec("MPC_TKO_RAMP_T", 3.0, min=0.0, max=5.0, unit="s", description="takeoff ramp of the upward velocity limit"),
        ParamSpec("MPC_VEL_MANUAL", 10.0, min=1.0, max=20.0, unit="m/s", description="Position mode: speed at full stick"),
        ParamSpec("MPC_ACC_HOR", 3.0, min=2.0, max=15.0, unit="m/s^2", description="Position mode: horizontal acceleration"),
        ParamSpec("MPC_MAN_Y_MAX", 150.0, min=0.0, max=400.0, unit="deg/s", description="manual modes: yaw rate at full stick"),
        ParamSpec("MPC_MAN_TILT_MAX", 35.0, min=1.0, max=85.0, unit="deg", description="Altitude mode: tilt at full stick"),
        ParamSpec("MPC_HOLD_DZ", 0.1, min=0.0, max=1.0, description="manual modes: stick dead zone"),
        ParamSpec("MPC_XY_MAN_EXPO", 0.6, min=0.0, max=1.0, description="manual modes: roll/pitch stick expo"),
        ParamSpec("MPC_Z_MAN_EXPO", 0.6, min=0.0, max=1.0, description="manual modes: throttle stick expo"),
        ParamSpec("MPC_YAW_EXPO", 0.6, min=0.0, max=1.0, description="manual modes: yaw stick expo"),
        ParamSpec("MIS_TAKEOFF_ALT", 2.5, min=0.0, max=80.0, unit="m", description="default takeoff height"),
        ParamSpec("NAV_ACC_RAD", 2.0, min=0.05, max=200.0, unit="m", description="acceptance radius (mission waypoints without their own, Return at home)"),
        # the navigator (Mission, Return, Reposition, Orbit; sitl_plant/navigator.py): PX4 v1.16's defaults
        ParamSpec("NAV_MC_ALT_RAD", 0.8, min=0.05, max=200.0, unit="m", description="vertical acceptance radius: of mission items, and a takeoff is complete this close to its height"),
        ParamSpec("MIS_YAW_ERR", 12.0, min=0.0, max=90.0, unit="deg", description="heading error accepted at a waypoint with a yaw"),
        ParamSpec("MPC_XY_CRUISE", 5.0, min=3.0, max=20.0, unit="m/s", description="horizontal speed of the auto modes (DO_CHANGE_SPEED changes it for a mission)"),
        ParamSpec("MPC_JERK_AUTO", 4.0, min=1.0, max=80.0, unit="m/s^3", description="jerk limit of the auto modes' legs"),
        ParamSpec("MPC_Z_V_AUTO_UP", 3.0, min=0.5, max=8.0, unit="m/s", description="climb speed of the auto modes"),
        ParamSpec("RTL_TYPE", 0, kind=INT, choices=(0,), description="Return: 0 straight home (the only one simulated)"),
        ParamSpec("RTL_RETURN_ALT", 30.0, min=0.0, max=150.0, unit="m", description="Return: height above home to come back at (at least the current one)"),
        ParamSpec("RTL_DESCEND_ALT", 10.0, min=0.0, max=150.0, unit="m", description="Return: height over home to descend to before landing"),
        ParamSpec("RTL_LAND_DELAY", 0.0, min=-1.0, max=300.0, unit="s", description="Return: wait at RTL_DESCEND_ALT before landing (< 0: for ever)"),
        ParamSpec("RTL_MIN_DIST", 10.0, min=0.5, max=100.0, unit="m", description="Return: within this distance of home the cone (RTL_CONE_ANG) lowers the return height"),
        ParamSpec("RTL_CONE_ANG", 45, kind=INT, min=0, max=90, unit="deg", description="Return: half angle of the cone over home that sets the return height near home (0: always RTL_RETURN_ALT)"),
        # Follow Target (sitl_plant/follow.py): PX4 v1.16's names, defaults and ranges (follow_target_params.yaml)
        ParamSpec("FLW_TGT_HT", 8.0, min=8.0, unit="m", description="Follow Target: height above home (FLW_TGT_ALT_M 0, 1) or above the target (2)"),
        ParamSpec("FLW_TGT_DST", 8.0, min=1.0, unit="m", description="Follow Target: horizontal distance from the target"),
        ParamSpec("FLW_TGT_FA", 180.0, min=-180.0, max=180.0, unit="deg", description="Follow Target: angle from the target's course, clockwise (180: behind)"),
        ParamSpec("FLW_TGT_ALT_M", 0, INT, choices=(0, 1, 2), description="Follow Target: height above 0 home, 1 the ground (flat: home), 2 the target"),
        ParamSpec("FLW_TGT_MAX_VEL", 5.0, min=0.0, max=20.0, unit="m/s", description="Follow Target: top tangential speed when the orbit angle changes"),
        ParamSpec("FLW_TGT_RS", 0.1, min=0.0, max=1.0, description="Follow Target: responsiveness of the target estimator (lower follows changes faster, filters less noise)"),
    ]


def plant_params(vehicle: VehicleParams, *, sysid: int = 1) -> ParamTable:
    """The plant's parameter table for ``vehicle``."""
    return ParamTable(plant_param_specs(vehicle, sysid=sysid))


def vehicle_from_params(table: ParamTable, base: VehicleParams) -> VehicleParams:
    """``base`` with the physical ``SIM_*`` values of ``table``."""
    return base.with_changes(
        mass_kg=table["SIM_MASS"],
        arm_length_m=table["SIM_ARM_LEN"],
        inertia_kg_m2=(table["SIM_IXX"], table["SIM_IYY"], table["SIM_IZZ"]),
        thrust_coeff_n_s2=table["SIM_KF"],
        drag_to_thrust_m=table["SIM_KM_KF"],
        rotor_speed_max_rad_s=max(table["SIM_W_MAX"], base.rotor_speed_min_rad_s + 1.0),
        motor_time_constant_s=table["SIM_MOT_TAU"],
    )


def refresh_derived(table: ParamTable, vehicle: VehicleParams) -> None:
    """Recompute the read-only maxima after a physical parameter changed."""
    table.force("SIM_THR_MAX", vehicle.max_thrust_n)
    table.force("SIM_TQ_RP_MAX", vehicle.max_roll_pitch_torque_nm)
    table.force("SIM_TQ_Y_MAX", vehicle.max_yaw_torque_nm)
    table.force("SIM_KDV", horizontal_drag_n_s_m(vehicle))
