"""Every controller by name, built from one belief: what ``--controller`` and the benchmarks pick.

- ``paper``: the paper's law (``offboard.controller.paper.PaperController``) with the gains,
  options and limits of its ``ControllerParams``;
- ``se3``: Lee's geometric controller (``offboard.baselines.SE3Controller``), RotorPy's gains;
- ``px4``: PX4's position cascade (``offboard.baselines.Px4PositionController``), PX4's gains.

All three believe the same mass and inertia and keep the same thrust range, tilt limit and
sample time, all taken from the one ``ControllerParams`` (a controller file, or what ``offboard
fly`` resolved from the vehicle), so that a comparison differs in the law alone.
"""

from __future__ import annotations

import enum
import math

from offboard.baselines import Px4Gains, Px4PositionController, SE3Controller
from offboard.controller.command import Controller
from offboard.model.vehicle import VEHICLE_MODELS, VehicleModel
from offboard.controller.paper import PaperController
from offboard.controller.params import ControllerParams
from offboard.controller.prediction import LatencyPredictor

#: PX4's MPC_TILTMAX_AIR default, for a baseline whose belief has no tilt limit.
DEFAULT_BASELINE_TILT_RAD = math.radians(45.0)


class ControllerKind(enum.StrEnum):
    """The controllers by name (module docstring)."""

    PAPER = "paper"
    SE3 = "se3"
    PX4 = "px4"


CONTROLLER_KINDS = tuple(k.value for k in ControllerKind)


def make_controller(
    kind: ControllerKind | str, params: ControllerParams, *, vehicle_model: VehicleModel | str = VehicleModel.RIGID_BODY,
    predictor: LatencyPredictor | None = None,
) -> Controller:  # fmt: skip
    """The ``kind`` controller believing ``params`` (mass, inertia, gravity, limits, To);
    ``predictor``: the paper's law handed the state predicted over the latency (the baselines
    take none).

    Raises
    ------
    ValueError
        An unknown kind, or a baseline asked to fly the paper's model (they are rigid-body
        controllers: their attitude is a rotation, not eq. 13's generalised coordinates).
    """
    try:
        kind = ControllerKind(kind)
    except ValueError:
        raise ValueError(f"controller must be one of {CONTROLLER_KINDS}, got {kind!r}") from None
    if vehicle_model not in VEHICLE_MODELS:
        raise ValueError(f"vehicle_model must be one of {VEHICLE_MODELS}, got {vehicle_model!r}")
    vehicle_model = VehicleModel(vehicle_model)
    if kind is ControllerKind.PAPER:
        return PaperController(params, vehicle_model=vehicle_model, predictor=predictor)
    if predictor is not None:
        raise ValueError(f"the {kind} controller takes no latency prediction (the paper's law does)")
    if vehicle_model is not VehicleModel.RIGID_BODY:
        raise ValueError(f"the {kind} controller flies a rigid body, not the paper's model")
    limits = params.limits
    thrust_min = limits.thrust_min_n if limits.thrust_min_n is not None else 0.0
    if kind is ControllerKind.SE3:
        return SE3Controller(
            params.mass_kg, params.inertia_kg_m2, gravity_m_s2=params.gravity_m_s2,
            thrust_min_n=thrust_min, thrust_max_n=limits.thrust_max_n, tilt_max_rad=limits.tilt_max_rad,
            sample_time_s=params.sample_time_s,
        )  # fmt: skip
    tilt = limits.tilt_max_rad if limits.tilt_max_rad is not None else DEFAULT_BASELINE_TILT_RAD
    return Px4PositionController(
        params.mass_kg, params.sample_time_s, Px4Gains(tilt_max_rad=tilt), gravity_m_s2=params.gravity_m_s2,
        thrust_min_n=thrust_min, thrust_max_n=limits.thrust_max_n if limits.thrust_max_n is not None else math.inf,
    )  # fmt: skip
