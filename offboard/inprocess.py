"""One simulation loop: any controller, a simulated vehicle, in one process.

``simulate`` samples the vehicle every To through its sensor model, steps the controller
(``offboard.controller.command.Controller``) on the measured state and the references at n and
n+1, and hands its ``Command`` to a **vehicle loop** (``Drive``), the vehicle side that turns a
command into the thrust and torque the physics applies until the next sample:

- ``inner-loop``: the paper's tau~ held for the sample, eq. 16 applied at the physics rate with
  the model the autopilot believes (``EulerAccelActuation``): what the ``paper`` inner loop of
  ``sitl-plant`` does with the rate setpoint, so a MAVLink flight reproduces this run
  (docs/reproduction.md);
- ``held-torque``: the real torques of eq. 16 computed once per sample and held for the whole
  sample (``HeldActuation``), a literal reading of the paper;
- ``px4``: the attitude target flown by PX4's attitude and rate controllers at the physics rate
  (``sitl_plant.inner_loops.Px4Loop``): what a SET_ATTITUDE_TARGET gets from sitl-plant's
  ``px4`` inner loop, or from PX4; every controller gives an attitude target;
- ``attitude-law``: the controller's own attitude law at the physics rate (SE(3)'s Lee eq. 16,
  ``SE3Controller.actuation``), as an in-process study flies it.

``run_scenario`` runs a scenario file's flight (``offboard simulate``) through it; the benchmarks
(``bench/flight.py``) fly every controller through it. The conversions from the vehicle's NED/FRD
report are those the MAVLink process uses (``offboard.controller.paper``).
"""

from __future__ import annotations

import enum
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from offboard.controller import ControllerParams
from offboard.controller.command import Command, Controller, require
from offboard.controller.paper import PaperController
from offboard.metrics import lost_reason
from offboard.model.euler_lagrange import EulerRateForm
from offboard.model.vehicle import VEHICLE_MODELS, VehicleModel, VehicleParams
from offboard.record import FlightRecord, FlightStatus, RecordBuilder, control_row
from offboard.trajectory.base import ReferencePairs, Trajectory
from sitl_plant.dynamics.integrate import steps_per_period
from sitl_plant.dynamics.rigid_body import ROTORS, hover_rotor_speed
from sitl_plant.dynamics.sensors import CleanSensors, SensorModel, sensors_from_spec
from sitl_plant.dynamics.wind import wind_from_spec
from sitl_plant.inner_loops import Px4Loop
from sitl_plant.params import plant_params
from sitl_plant.simulation import Actuation, EulerAccelActuation, HeldActuation, VehicleSim, WindField, make_model


class Drive(enum.StrEnum):
    """How the vehicle side flies a command in-process (module docstring)."""

    INNER_LOOP = "inner-loop"
    HELD_TORQUE = "held-torque"
    PX4 = "px4"
    ATTITUDE_LAW = "attitude-law"


DRIVES = tuple(d.value for d in Drive)
#: The drives of a scenario file (the paper's controller): all but a baseline's own attitude law.
SCENARIO_DRIVES = (Drive.INNER_LOOP.value, Drive.HELD_TORQUE.value, Drive.PX4.value)


class VehicleLoop(Protocol):
    """The vehicle side of an in-process flight: a command in, the actuation for the sample out."""

    def bind(self, sim: VehicleSim) -> None:
        """Called once with the simulation before the flight."""

    def actuation(self, command: Command, sim: VehicleSim) -> Actuation:
        """What the physics applies at every step until the next sample."""
        ...


@dataclass
class PaperInnerLoop:
    """``inner-loop``: tau~ held, eq. 16 at the physics rate with the believed inertia and W_eta."""

    believed_inertia_kg_m2: tuple[float, float, float]
    euler_rate_form: EulerRateForm
    controller: str = "paper"

    def __post_init__(self) -> None:
        self._inertia = np.diag(self.believed_inertia_kg_m2)

    def bind(self, sim: VehicleSim) -> None:
        """Nothing to bind: eq. 16 needs only the command and the believed inertia."""

    def actuation(self, command: Command, sim: VehicleSim) -> Actuation:
        """u and tau~ held, eq. 16 applied at every physics step (``EulerAccelActuation``)."""
        tau_tilde = require(command, "euler_accel_rad_s2", self.controller)
        return EulerAccelActuation(command.thrust_n, np.array(tau_tilde), self._inertia, self.euler_rate_form)


@dataclass
class HeldTorque:
    """``held-torque``: the eq. 16 torques of the sample held as the model's torque input."""

    controller: str = "paper"

    def bind(self, sim: VehicleSim) -> None:
        """Nothing to bind: the torque is the sample's."""

    def actuation(self, command: Command, sim: VehicleSim) -> Actuation:
        """u and the eq. 16 torque of the sample, as the model's torque input, held until the next sample."""
        tau = np.array(require(command, "generalized_torque_nm", self.controller))
        return HeldActuation(command.thrust_n, sim.model.torque_from_generalized(sim.x, tau))


@dataclass
class Px4AttitudeLoop:
    """``px4``: PX4's attitude and rate controllers fly the attitude target (``Px4Loop``)."""

    vehicle: VehicleParams
    loop: Px4Loop | None = None

    def bind(self, sim: VehicleSim) -> None:
        """A fresh PX4 loop on this simulation's model and physics step, flying (not landed)."""
        self.loop = Px4Loop(plant_params(self.vehicle), sim.model, sim.physics_dt_s)
        self.loop.landed = False

    def actuation(self, command: Command, sim: VehicleSim) -> Actuation:
        """The PX4 loop, handed the command's attitude, thrust and yaw-rate feed-forward."""
        assert self.loop is not None, "bind() first"
        self.loop.fly_attitude(command.attitude_wxyz, command.thrust_n, command.yaw_rate_ff_rad_s)
        return self.loop


class HasAttitudeLaw(Protocol):
    name: str

    def actuation(self) -> Actuation:
        """The controller's own attitude law, run at every physics step."""
        ...


@dataclass
class ControllerAttitudeLaw:
    """``attitude-law``: the controller's own attitude law at the physics rate (``actuation()``)."""

    controller: HasAttitudeLaw

    def bind(self, sim: VehicleSim) -> None:
        """Nothing to bind: the controller's law reads the state it is handed."""

    def actuation(self, command: Command, sim: VehicleSim) -> Actuation:
        """The controller's own attitude law (``controller.actuation()``)."""
        return self.controller.actuation()


def vehicle_loop(drive: Drive | str, controller: Controller, vehicle: VehicleParams) -> VehicleLoop:
    """The vehicle loop of ``drive`` for ``controller`` (the paper's inner loop believes what the
    controller believes, as the plant's ``PAP_*`` parameters do)."""
    drive = Drive(drive)
    if drive is Drive.INNER_LOOP:
        params: ControllerParams | None = getattr(controller, "params", None)
        if not isinstance(params, ControllerParams):
            raise ValueError(f"the {controller.name} controller gives no tau~: drive {drive} is the paper's law's")
        return PaperInnerLoop(params.inertia_kg_m2, params.euler_rate_form, controller.name)
    if drive is Drive.HELD_TORQUE:
        return HeldTorque(controller.name)
    if drive is Drive.PX4:
        return Px4AttitudeLoop(vehicle)
    if not callable(getattr(controller, "actuation", None)):
        raise ValueError(f"the {controller.name} controller has no attitude law of its own (drive {drive})")
    return ControllerAttitudeLaw(controller)  # type: ignore[arg-type]


def _diverged(sim: VehicleSim, euler_rad: np.ndarray, pos_ned_m: np.ndarray) -> str:
    """Why the true state means the flight is lost ('' if it is not; ``metrics.lost_reason``)."""
    x = sim.x.tolist()  # a NaN or infinity makes the sum NaN or infinite: one check, per sample
    finite = math.isfinite(sum(x)) or all(math.isfinite(v) for v in x)
    return lost_reason(finite, float(euler_rad[0]), float(euler_rad[1]), pos_ned_m, "simulated")


@dataclass
class FlightResult:
    """What ``simulate`` returns: the record and what the flight cost.

    Attributes
    ----------
    record : FlightRecord
        One row per control sample, the true state (as the paper plots it).
    step_cost_s : ndarray
        Wall time of each controller step.
    physics_wall_s : float
        Wall time spent stepping the physics.
    ended_at_s : float
        Mission time of the last sample taken (where a lost flight was found lost).
    """

    record: FlightRecord
    step_cost_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    physics_wall_s: float = 0.0
    ended_at_s: float = 0.0

    @property
    def status(self) -> FlightStatus:
        """How the flight ended (the record's status)."""
        return self.record.status


def simulate(
    vehicle: VehicleParams,
    controller: Controller,
    trajectory: Trajectory,
    *,
    drive: Drive | str | VehicleLoop = Drive.PX4,
    model: VehicleModel | str = VehicleModel.RIGID_BODY,
    physics_dt_s: float = 1e-3,
    duration_s: float | None = None,
    sensors: SensorModel | None = None,
    wind: WindField | None = None,
    ground: bool = True,
    initial_pos_ned_m: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0),
    initial_yaw_rad: float = 0.0,
    hovering: bool = False,
    fast: bool = False,
    progress: Callable[[float], None] | None = None,
    meta: dict[str, object] | None = None,
    latency_s: float = 0.0,
) -> FlightResult:
    """Fly ``trajectory`` with ``controller`` on a simulated ``vehicle`` (module docstring).

    Parameters
    ----------
    vehicle : VehicleParams
        The true vehicle.
    controller : Controller
        Stepped every ``controller.sample_time_s`` on the sensors' measurement.
    trajectory : Trajectory
        The references (NED).
    drive : Drive, str or VehicleLoop
        How the vehicle flies each command (``vehicle_loop``).
    model : VehicleModel or str
        ``rigid-body`` or ``paper``.
    physics_dt_s : float
        RK4 step; To must be a whole number of them.
    duration_s : float, optional
        The trajectory's duration by default.
    sensors : SensorModel, optional
        Clean (the truth) by default.
    wind : WindField, optional
    ground : bool
        A ground plane at down = 0.
    initial_pos_ned_m, initial_yaw_rad :
        Where the vehicle starts, at rest.
    hovering : bool
        Rotors at hover speed at the start (rigid body), so a vehicle started in the air does
        not fall first.
    fast : bool
        Step a rigid body by the compiled kernels (``FastRigidBodySim``; the same results to
        rounding) instead of ``VehicleSim``.
    progress : callable, optional
        Called with the fraction flown after each sample.
    meta : dict, optional
        The record's metadata.
    latency_s : float
        Link latency: each command reaches the vehicle this long after its sample (rounded to
        physics steps, below To); until then the vehicle flies the previous command (none before
        the first), as a MAVLink setpoint arrives late. 0: at once.
    """
    to = controller.sample_time_s
    n_physics = steps_per_period(to, physics_dt_s)
    n_late = int(round(latency_s / physics_dt_s))
    if not 0 <= n_late < n_physics:
        raise ValueError(f"latency_s must lie in [0, To = {to:g} s), got {latency_s:g}")
    sim_model = make_model(str(VehicleModel(model)), vehicle)
    cls: type[VehicleSim] = VehicleSim
    if fast:
        from sitl_plant.dynamics.batch import FastRigidBodySim  # numba (a third of a second): only when asked

        cls = FastRigidBodySim
    sim = cls(
        sim_model,
        physics_dt_s=physics_dt_s,
        wind=wind,
        ground=ground,
        initial_pos_ned_m=np.array(initial_pos_ned_m, dtype=float),
        initial_yaw_rad=initial_yaw_rad,
    )
    if hovering and VehicleModel(model) is VehicleModel.RIGID_BODY and float(sim.x[2]) < 0.0:

        sim.x[ROTORS] = hover_rotor_speed(vehicle)
    loop = drive if not isinstance(drive, str) else vehicle_loop(drive, controller, vehicle)
    loop.bind(sim)
    meter = sensors if sensors is not None else CleanSensors()
    controller.reset()
    duration = trajectory.duration_s if duration_s is None else duration_s
    samples = int(round(duration / to))
    rows = RecordBuilder()
    costs = np.zeros(samples + 1)
    physics_wall_s = 0.0
    status, detail = FlightStatus.COMPLETE, ""
    t = 0.0
    references = ReferencePairs(trajectory, to)
    for n in range(samples + 1):
        t = n * to
        ref_n, ref_n1 = references.pair(t)
        truth = sim.truth()
        measured = meter.measure(truth)
        start = time.perf_counter()
        command = controller.step(measured, ref_n, ref_n1)
        costs[n] = time.perf_counter() - start
        why = _diverged(sim, truth.euler_rad, truth.pos_ned_m)
        if why:
            status, detail = FlightStatus.DIVERGED, f"at t = {t:.2f} s: {why}"
            break
        rows.append(**control_row(t, truth, ref_n, command))  # the truth, as the paper plots it
        if not command.is_finite():
            status, detail = FlightStatus.NAN_COMMAND, f"at t = {t:.2f} s the controller's output is not finite"
            break
        if n == samples:
            break
        broke = ""
        for part in ("late", "now") if n_late else ("now",):
            if part == "now":  # the command reaches the vehicle (after the previous one's n_late steps)
                sim.actuation = loop.actuation(command, sim)
            try:
                with np.errstate(divide="raise", over="raise", invalid="raise"):
                    start = time.perf_counter()
                    sim.step(n_late if part == "late" else n_physics - n_late)
                    physics_wall_s += time.perf_counter() - start
            except (ArithmeticError, np.linalg.LinAlgError, FloatingPointError) as exc:
                broke = type(exc).__name__
                break
        if broke:
            status, detail = FlightStatus.DIVERGED, f"at t = {t:.2f} s the dynamics broke down ({broke})"
            break
        if progress is not None:
            progress(t / duration)

    record = rows.build(phases=trajectory.phases(), status=status, status_detail=detail,
                        meta={"controller": controller.name, "model": str(model), **(meta or {})})  # fmt: skip
    return FlightResult(record, costs[: len(record)], physics_wall_s, t)


@dataclass(frozen=True)
class Scenario:
    """Everything one reproducible in-process flight needs (``offboard simulate``'s file).

    Attributes
    ----------
    trajectory : Trajectory
        The mission's references (NED).
    vehicle : VehicleParams
        The true vehicle.
    controller : ControllerParams
        What the paper's controller (and the vehicle-side inner loop) believes, and its gains.
    model : str
        ``paper`` (eq. 13, 18) or ``rigid-body``.
    drive : str
        ``inner-loop``, ``held-torque`` or ``px4`` (module docstring).
    sensors, wind : str
        Specs for ``sitl_plant.dynamics.sensors.sensors_from_spec`` / ``wind.wind_from_spec``.
    """

    name: str
    trajectory: Trajectory
    vehicle: VehicleParams
    controller: ControllerParams
    model: VehicleModel = VehicleModel.PAPER
    drive: Drive = Drive.INNER_LOOP
    physics_dt_s: float = 1e-3
    duration_s: float | None = None
    sensors: str = "clean"
    wind: str = "none"
    seed: int = 0
    initial_pos_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    initial_yaw_rad: float = 0.0
    ground: bool = True
    source: str = ""

    def __post_init__(self) -> None:
        if self.model not in VEHICLE_MODELS:
            raise ValueError(f"model must be one of {VEHICLE_MODELS}, got {self.model!r}")
        if self.drive not in SCENARIO_DRIVES:
            raise ValueError(f"drive must be one of {SCENARIO_DRIVES}, got {self.drive!r}")
        object.__setattr__(self, "model", VehicleModel(self.model))  # a word from a file: its enum
        object.__setattr__(self, "drive", Drive(self.drive))
        steps_per_period(self.controller.sample_time_s, self.physics_dt_s)
        # a designed controller flies the loop its design modelled (offboard fly refuses another output likewise)
        designed = self.controller.setpoint_output
        if designed == "rates":
            raise ValueError('the controller\'s gains were designed for body-rate setpoints ([law] setpoint_output = "rates"), '
                             "which no in-process drive flies: fly them over MAVLink, offboard fly --output rates")
        if designed == "attitude" and self.drive != Drive.PX4:
            raise ValueError('the controller\'s gains were designed for an autopilot\'s attitude loop ([law] setpoint_output = '
                             f'"attitude"): fly them with drive = "px4", the loop their design models, not "{self.drive}"')

    @property
    def flight_duration_s(self) -> float:
        """How long the flight lasts: ``duration_s``, or the trajectory's."""
        return self.trajectory.duration_s if self.duration_s is None else self.duration_s


def run_scenario(scenario: Scenario, progress: Callable[[float], None] | None = None) -> FlightRecord:
    """Fly ``scenario`` in-process with the paper's controller; one record row per control sample.

    The record's positions and angles are the true ones (as the paper plots them); the
    controller sees only the sensor model's measurement.
    """
    controller = PaperController(scenario.controller, vehicle_model=scenario.model)
    result = simulate(
        scenario.vehicle,
        controller,
        scenario.trajectory,
        drive=scenario.drive,
        model=scenario.model,
        physics_dt_s=scenario.physics_dt_s,
        duration_s=scenario.flight_duration_s,
        sensors=sensors_from_spec(scenario.sensors, scenario.seed),
        wind=None if scenario.wind == "none" else wind_from_spec(scenario.wind, scenario.seed),
        ground=scenario.ground,
        initial_pos_ned_m=scenario.initial_pos_ned_m,
        initial_yaw_rad=scenario.initial_yaw_rad,
        progress=progress,
        meta={"scenario": scenario.name, "drive": scenario.drive, "source": scenario.source},
    )
    return result.record
