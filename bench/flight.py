"""One closed-loop flight in process, any controller, on the rigid body: the tracking benchmark's unit.

``offboard.inprocess.simulate`` flies it (the one simulation loop), with the compiled rigid body
(``sitl_plant.dynamics.batch.FastRigidBodySim``; ``fast=False``: ``VehicleSim`` itself); this
module only starts the vehicle where the benchmark wants it and reads the arrays it tabulates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from offboard.controller.command import Controller
from offboard.inprocess import Drive, simulate
from offboard.record import FlightStatus
from offboard.trajectory.base import Trajectory
from sitl_plant.dynamics.sensors import sensors_from_spec
from sitl_plant.dynamics.wind import wind_from_spec
from offboard.model.vehicle import VehicleParams

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
    controller: Controller,
    drive: Drive,
    trajectory: Trajectory,
    vehicle: VehicleParams,
    *,
    duration_s: float | None = None,
    sensors: str = "clean",
    wind: str = "none",
    seed: int = 1,
    start_at_reference: bool = True,
    fast: bool = True,
) -> FlightResult:
    """Fly ``trajectory`` with ``controller`` through ``drive``; see the module docstring.

    ``start_at_reference``: the vehicle starts at rest at the reference's position and heading
    at t = 0, rotors at hover speed (on the ground if that position is on the ground).
    """
    ref0 = trajectory.reference(0.0)
    start = np.array(ref0.pos_ned_m, dtype=float) if start_at_reference else np.zeros(3)
    start[2] = min(start[2], 0.0)
    result = simulate(
        vehicle, controller, trajectory, drive=drive, physics_dt_s=PHYSICS_DT_S, duration_s=duration_s,
        sensors=sensors_from_spec(sensors, seed), wind=None if wind == "none" else wind_from_spec(wind, seed),
        initial_pos_ned_m=start, initial_yaw_rad=ref0.yaw_rad if start_at_reference else 0.0,
        hovering=start_at_reference, fast=fast,
    )  # fmt: skip
    record = result.record
    euler = record["euler_rad"]
    n = len(record)
    t = record["t_s"]
    diverged = None if record.status is FlightStatus.COMPLETE else result.ended_at_s
    return FlightResult(
        t_s=np.asarray(t, dtype=float), pos_ned_m=record["pos_ned_m"].reshape(-1, 3),
        ref_ned_m=record["ref_pos_ned_m"].reshape(-1, 3),
        tilt_rad=np.arccos(np.clip(np.cos(euler[:, 0]) * np.cos(euler[:, 1]), -1.0, 1.0)) if n else np.zeros(0),
        thrust_n=np.asarray(record["thrust_n"], dtype=float), cost_s=result.step_cost_s, diverged_at_s=diverged,
        physics_wall_s=result.physics_wall_s,
    )  # fmt: skip
