"""One closed-loop flight in process, any pilot, on the rigid body: the tracking benchmark's unit.

The loop is ``offboard.inprocess.run_scenario``'s (sample the truth through the sensor model
every To, run the controller, hold its actuation for the sample), with the pilot choosing the
actuation and ``sitl_plant.dynamics.batch.FastRigidBodySim`` (the compiled twin of
``VehicleSim``) stepping the physics; ``fast=False`` uses ``VehicleSim`` itself.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from offboard.trajectory.base import Trajectory
from sitl_plant.dynamics.batch import FastRigidBodySim
from sitl_plant.dynamics.integrate import steps_per_period
from sitl_plant.dynamics.rigid_body import ROTORS, RigidBodyModel, hover_rotor_speed
from sitl_plant.dynamics.sensors import sensors_from_spec
from sitl_plant.dynamics.wind import wind_from_spec
from sitl_plant.simulation import VehicleSim
from sitl_plant.vehicle import VehicleParams

PHYSICS_DT_S = 1e-3


@dataclass
class FlightResult:
    """Per-sample arrays of one flight (true state), and how it ended."""

    t_s: np.ndarray
    pos_ned_m: np.ndarray
    ref_ned_m: np.ndarray
    tilt_rad: np.ndarray
    thrust_n: np.ndarray
    cost_s: np.ndarray
    diverged_at_s: float | None
    physics_wall_s: float = 0.0  # wall time spent in the physics stepping alone

    @property
    def error_m(self) -> np.ndarray:
        return np.linalg.norm(self.pos_ned_m - self.ref_ned_m, axis=1)


def fly(
    pilot,  # noqa: ANN001 - bench.pilots.Pilot
    trajectory: Trajectory,
    vehicle: VehicleParams,
    *,
    duration_s: float | None = None,
    sensors: str = "clean",
    wind: str = "none",
    seed: int = 1,
    start_at_reference: bool = True,
    fast: bool = True,
    sample_time_s: float = 0.05,
) -> FlightResult:
    """Fly ``trajectory`` with ``pilot``; see the module docstring.

    ``start_at_reference``: the vehicle starts at rest at the reference's position and heading
    at t = 0, rotors at hover speed (on the ground if that position is on the ground).
    """
    model = RigidBodyModel(vehicle)
    ref0 = trajectory.reference(0.0)
    start = np.array(ref0.pos_ned_m, dtype=float) if start_at_reference else np.zeros(3)
    start[2] = min(start[2], 0.0)
    cls = FastRigidBodySim if fast else VehicleSim
    sim = cls(
        model, physics_dt_s=PHYSICS_DT_S, wind=None if wind == "none" else wind_from_spec(wind, seed),
        initial_pos_ned_m=start, initial_yaw_rad=ref0.yaw_rad if start_at_reference else 0.0,
    )  # fmt: skip
    if start_at_reference and start[2] < 0.0:
        sim.x[ROTORS] = hover_rotor_speed(vehicle)  # hovering at the start, not falling
    pilot.bind(model)
    meter = sensors_from_spec(sensors, seed)
    n_physics = steps_per_period(sample_time_s, PHYSICS_DT_S)
    duration = trajectory.duration_s if duration_s is None else duration_s
    samples = int(round(duration / sample_time_s))
    t_out, pos, ref, tilt, thrust, cost = [], [], [], [], [], []
    diverged = None
    physics_wall_s = 0.0
    ref_next = trajectory.reference(0.0)
    for n in range(samples + 1):
        t = n * sample_time_s
        ref_now, ref_next = ref_next, trajectory.reference((n + 1) * sample_time_s)
        truth = sim.truth()
        phi, theta = float(truth.euler_rad[0]), float(truth.euler_rad[1])
        if (not all(map(math.isfinite, sim.x.tolist())) or math.cos(phi) * math.cos(theta) <= 0.0
                or max(map(abs, truth.pos_ned_m.tolist())) > 1e4):  # fmt: skip
            diverged = t
            break
        actuation = pilot.command(meter.measure(truth), ref_now, ref_next)
        t_out.append(t)
        pos.append(truth.pos_ned_m)
        ref.append(ref_now.pos_ned_m)
        tilt.append(math.acos(max(-1.0, min(1.0, math.cos(phi) * math.cos(theta)))))
        thrust.append(pilot.thrust_n)
        cost.append(pilot.cost_s)
        if n == samples:
            break
        sim.actuation = actuation
        try:
            with np.errstate(divide="raise", over="raise", invalid="raise"):
                start_physics = time.perf_counter()
                sim.step(n_physics)
                physics_wall_s += time.perf_counter() - start_physics
        except (ArithmeticError, FloatingPointError, np.linalg.LinAlgError):
            diverged = t
            break
    return FlightResult(
        t_s=np.array(t_out), pos_ned_m=np.array(pos).reshape(-1, 3), ref_ned_m=np.array(ref).reshape(-1, 3),
        tilt_rad=np.array(tilt), thrust_n=np.array(thrust), cost_s=np.array(cost), diverged_at_s=diverged,
        physics_wall_s=physics_wall_s,
    )  # fmt: skip
