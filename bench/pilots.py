"""The controllers of the comparison, each wrapped as a *pilot*: measured state in, actuation out.

A pilot runs its controller's outer step once per control sample (``command``) and returns the
actuation ``VehicleSim``/``FastRigidBodySim`` applies at every physics step until the next
sample: that is the controller's own inner loop.

- ``paper``: the paper's law (``RosalesController``, yaw-aware, limits), tau~ held and eq. 16
  applied at the physics rate with the believed inertia (``EulerAccelActuation``, the plant's
  ``paper`` inner loop; ``offboard simulate --drive inner-loop``).
- ``se3``: ``offboard.baselines.SE3Controller``; its attitude law (Lee eq. 16) at the physics rate.
- ``px4``: ``offboard.baselines.Px4PositionController``; its attitude setpoint flown by the
  plant's PX4 attitude and rate controllers (``sitl_plant.inner_loops.Px4Loop``) at the physics rate.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from offboard.baselines import Px4Gains, Px4PositionController, SE3Controller
from offboard.controller import ActionLimits, ControllerParams, RosalesController
from offboard.frames import euler_rates_from_body_rates, paper_state, tracking_reference
from offboard.trajectory.base import Reference
from sitl_plant.simulation import EulerAccelActuation
from sitl_plant.state import VehicleState
from sitl_plant.vehicle import VehicleParams

SAMPLE_TIME_S = 0.05  # the paper's To, for every controller
THRUST_MAX_N = 19.6  # the airframe: thrust-to-weight 4 (4 x k w_max^2 = 19.6 N)
TILT_MAX_DEG = 35.0


@dataclass(frozen=True)
class Belief:
    """What every controller believes of the vehicle (Table II makes it wrong)."""

    mass_kg: float = 0.5
    inertia_kg_m2: tuple[float, float, float] = (3.8e-3, 3.8e-3, 7.1e-3)


NOMINAL = Belief()
TABLE_II = Belief(mass_kg=0.6, inertia_kg_m2=(2.7e-3, 4.8e-3, 8.9e-3))


class Pilot:
    """Base: ``command(measured, ref_n, ref_n1) -> actuation``; ``thrust_n`` and ``cost_s`` of the last.

    ``ref_n``, ``ref_n1``: the references at this sample and the next (the paper's law uses both).
    """

    name = ""
    thrust_n = 0.0
    cost_s = 0.0

    def bind(self, model: object) -> None:
        """Called once with the simulated model before the flight."""


class PaperPilot(Pilot):
    def __init__(self, belief: Belief, *, integral_gain_per_s: float = 0.0, name: str = "paper") -> None:
        extra = {"integral_gain_per_s": integral_gain_per_s} if integral_gain_per_s > 0 else {}
        self.params = ControllerParams(
            sample_time_s=SAMPLE_TIME_S,
            mass_kg=belief.mass_kg,
            inertia_kg_m2=belief.inertia_kg_m2,
            euler_rate_form="zyx",  # a rigid body's Euler-rate map (paper-sim1-rigid-body.toml)
            yaw_aware=True,
            limits=ActionLimits(thrust_min_n=0.0, thrust_max_n=THRUST_MAX_N, tilt_max_rad=math.radians(TILT_MAX_DEG)),
            **extra,  # type: ignore[arg-type]
        )
        self.name = name
        self.controller = RosalesController(self.params)
        self._inertia = np.diag(self.params.inertia_kg_m2)

    def command(self, measured: VehicleState, ref_n: Reference, ref_n1: Reference) -> EulerAccelActuation:
        p = self.params
        rates = euler_rates_from_body_rates(measured.euler_rad, measured.body_rate_frd_rad_s, p.euler_rate_form)
        x = paper_state(measured.pos_ned_m, measured.vel_ned_m_s, measured.euler_rad, rates)
        ref_n, ref_n1 = tracking_reference(ref_n), tracking_reference(ref_n1)
        start = time.perf_counter()
        out = self.controller.step(x, ref_n, ref_n1)
        self.cost_s = time.perf_counter() - start
        self.thrust_n = out.law.thrust_n
        return EulerAccelActuation(out.law.thrust_n, np.array(out.law.tau_tilde), self._inertia, p.euler_rate_form)


class Se3Pilot(Pilot):
    name = "se3"

    def __init__(self, belief: Belief) -> None:
        self.controller = SE3Controller(
            belief.mass_kg, belief.inertia_kg_m2, thrust_min_n=0.0, thrust_max_n=THRUST_MAX_N,
            tilt_max_rad=math.radians(TILT_MAX_DEG),
        )  # fmt: skip

    def command(self, measured: VehicleState, reference: Reference, ref_n1: Reference):  # noqa: ANN201
        start = time.perf_counter()
        target = self.controller.step(measured, reference)
        self.cost_s = time.perf_counter() - start
        self.thrust_n = target.thrust_n
        return self.controller.actuation(target)


class Px4Pilot(Pilot):
    name = "px4"

    def __init__(self, belief: Belief) -> None:
        self.controller = Px4PositionController(
            belief.mass_kg, SAMPLE_TIME_S, Px4Gains(tilt_max_rad=math.radians(TILT_MAX_DEG)),
            thrust_min_n=0.0, thrust_max_n=THRUST_MAX_N,
        )  # fmt: skip
        self.loop = None

    def bind(self, model: object) -> None:
        from sitl_plant.inner_loops import Px4Loop
        from sitl_plant.params import plant_params

        vehicle: VehicleParams = model.params  # type: ignore[attr-defined]
        self.loop = Px4Loop(plant_params(vehicle), model, 1e-3)  # type: ignore[arg-type]
        self.loop.landed = False

    def command(self, measured: VehicleState, reference: Reference, ref_n1: Reference):  # noqa: ANN201
        start = time.perf_counter()
        target = self.controller.step(measured, reference)
        self.cost_s = time.perf_counter() - start
        self.thrust_n = target.thrust_n
        assert self.loop is not None
        self.loop.fly_attitude(target.quat_wxyz, target.thrust_n, target.yaw_rate_ff_rad_s)
        return self.loop


def make_pilot(kind: str, belief: Belief, integral_gain_per_s: float = 0.0) -> Pilot:
    if kind == "paper":
        return PaperPilot(belief)
    if kind == "paper+i":
        return PaperPilot(belief, integral_gain_per_s=integral_gain_per_s, name="paper+i")
    if kind == "se3":
        return Se3Pilot(belief)
    if kind == "px4":
        return Px4Pilot(belief)
    raise ValueError(f"unknown controller {kind!r}")
