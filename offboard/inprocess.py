"""The controller and a simulated vehicle in one process: the paper's reproduction.

``run_scenario`` samples the vehicle every To through its sensor model, runs the controller on
the measured state and the references at n and n+1, and drives the vehicle in one of two ways
(NOTES.md, "What a careful reproduction runs into"):

- ``inner-loop``: tau~ is held for the sample and a vehicle-side inner loop applies eq. 16 at the
  physics rate with the model the autopilot believes (``EulerAccelActuation``). This is what the
  ``paper`` inner loop of ``sitl-plant`` does with a SET_ATTITUDE_TARGET, so a MAVLink flight
  reproduces this run.
- ``held-torque``: the real torques of eq. 16 are computed once per sample by the controller and
  held for the whole sample (``HeldActuation``), as a literal reading of the paper.

The conversions from the vehicle's NED/FRD report are those the MAVLink process uses
(``offboard.frames``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from offboard.controller import ControllerParams, RosalesController
from offboard.frames import euler_rates_from_body_rates, paper_state, tracking_reference
from offboard.record import FlightRecord, FlightStatus, RecordBuilder, control_row
from offboard.trajectory.base import Trajectory
from sitl_plant.dynamics.integrate import steps_per_period
from sitl_plant.simulation import EulerAccelActuation, HeldActuation, Model, PaperModel, VehicleSim
from sitl_plant.vehicle import VehicleParams

DRIVES = ("inner-loop", "held-torque")
MODELS = ("paper", "rigid-body")


@dataclass(frozen=True)
class Scenario:
    """Everything one reproducible in-process flight needs.

    Attributes
    ----------
    trajectory : Trajectory
        The mission's references (NED).
    vehicle : VehicleParams
        The true vehicle.
    controller : ControllerParams
        What the controller (and the vehicle-side inner loop) believes, and its gains.
    model : str
        ``paper`` (eq. 13, 18) or ``rigid-body``.
    drive : str
        ``inner-loop`` or ``held-torque`` (module docstring).
    sensors, wind : str
        Specs for ``sitl_plant.dynamics.sensors.sensors_from_spec`` / ``wind.wind_from_spec``.
    """

    name: str
    trajectory: Trajectory
    vehicle: VehicleParams
    controller: ControllerParams
    model: str = "paper"
    drive: str = "inner-loop"
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
        if self.model not in MODELS:
            raise ValueError(f"model must be one of {MODELS}, got {self.model!r}")
        if self.drive not in DRIVES:
            raise ValueError(f"drive must be one of {DRIVES}, got {self.drive!r}")
        steps_per_period(self.controller.sample_time_s, self.physics_dt_s)

    @property
    def flight_duration_s(self) -> float:
        return self.trajectory.duration_s if self.duration_s is None else self.duration_s


def make_model(name: str, vehicle: VehicleParams) -> Model:
    if name == "paper":
        return PaperModel(vehicle)
    from sitl_plant.dynamics.rigid_body import RigidBodyModel

    return RigidBodyModel(vehicle)


def _diverged(x_state: tuple[float, ...], sim_state: np.ndarray) -> str:
    if not np.all(np.isfinite(sim_state)):
        return "the simulated state is no longer finite"
    phi, theta = x_state[6], x_state[8]
    if math.cos(phi) * math.cos(theta) <= 0.0:
        return f"tilt past 90 degrees (roll {math.degrees(phi):.0f}, pitch {math.degrees(theta):.0f} deg)"
    if max(abs(x_state[0]), abs(x_state[2]), abs(x_state[4])) > 1e4:
        return "position beyond 10 km"
    return ""


def run_scenario(scenario: Scenario, progress: Callable[[float], None] | None = None) -> FlightRecord:
    """Fly ``scenario`` in-process; returns one record row per control sample.

    The record's positions and angles are the true ones (as the paper plots them); the
    controller sees only the sensor model's measurement.
    """
    from sitl_plant.dynamics.sensors import sensors_from_spec
    from sitl_plant.dynamics.wind import wind_from_spec

    params: ControllerParams = scenario.controller
    to = params.sample_time_s
    n_physics = steps_per_period(to, scenario.physics_dt_s)
    model = make_model(scenario.model, scenario.vehicle)
    sim = VehicleSim(
        model,
        physics_dt_s=scenario.physics_dt_s,
        wind=None if scenario.wind == "none" else wind_from_spec(scenario.wind, scenario.seed),
        ground=scenario.ground,
        initial_pos_ned_m=np.array(scenario.initial_pos_ned_m),
        initial_yaw_rad=scenario.initial_yaw_rad,
    )
    sensors = sensors_from_spec(scenario.sensors, scenario.seed)
    controller = RosalesController(params)
    believed_inertia = np.diag(params.inertia_kg_m2)
    trajectory = scenario.trajectory
    samples = int(round(scenario.flight_duration_s / to))
    rows = RecordBuilder()
    status, detail = FlightStatus.COMPLETE, ""

    for n in range(samples + 1):
        t = n * to
        truth = sim.truth()
        measured = sensors.measure(truth)
        euler_rates = euler_rates_from_body_rates(measured.euler_rad, measured.body_rate_frd_rad_s, params.euler_rate_form)
        x = paper_state(measured.pos_ned_m, measured.vel_ned_m_s, measured.euler_rad, euler_rates)
        ref_n, ref_n1 = trajectory.reference(t), trajectory.reference(t + to)
        out = controller.step(x, tracking_reference(ref_n, controller.params.reference_lead_s2), tracking_reference(ref_n1, controller.params.reference_lead_s2))
        law = out.law
        true_x = paper_state(truth.pos_ned_m, truth.vel_ned_m_s, truth.euler_rad, truth.euler_rate_rad_s)
        why = _diverged(true_x, sim.x)
        if why:
            status, detail = FlightStatus.DIVERGED, f"at t = {t:.2f} s: {why}"
            break
        rows.append(**control_row(t, truth, ref_n, out))  # the truth, as the paper plots it
        if not out.is_finite():
            status, detail = FlightStatus.NAN_COMMAND, f"at t = {t:.2f} s the controller's output is not finite"
            break
        if n == samples:
            break
        if scenario.drive == "inner-loop":
            sim.actuation = EulerAccelActuation(law.thrust_n, np.array(law.tau_tilde), believed_inertia, params.euler_rate_form)
        else:
            sim.actuation = HeldActuation(law.thrust_n, model.torque_from_generalized(sim.x, out.torques_nm))
        try:
            with np.errstate(divide="raise", over="raise", invalid="raise"):
                sim.step(n_physics)
        except (ArithmeticError, np.linalg.LinAlgError, FloatingPointError) as exc:
            status, detail = FlightStatus.DIVERGED, f"at t = {t:.2f} s the dynamics broke down ({type(exc).__name__})"
            break
        if progress is not None:
            progress(t / scenario.flight_duration_s)

    return rows.build(
        phases=trajectory.phases(),
        status=status,
        status_detail=detail,
        meta={"scenario": scenario.name, "model": scenario.model, "drive": scenario.drive, "source": scenario.source},
    )
