"""The controllers of the comparison, each with the vehicle loop it flies through in-process.

Two comparisons (``bench.tracking.LOOPS``):

- **through PX4's attitude loop** (``flown_controller``): every controller built as ``offboard
  fly`` builds it for the vehicle (``offboard.flight.resolve_controller``: the belief, PX4's
  12 % thrust floor, the 35 deg tilt limit; the law with Table I's gains and with the gains
  designed for the vehicle's inner loop), its attitude target flown by PX4's attitude and rate
  controllers at the physics rate (``Drive.PX4``): what ``offboard fly --controller K`` through
  sitl-plant's px4 inner loop flies, to float32 rounding (tests/unit/offboard/test_controller_contract.py);
- **each controller's own inner loop** (``contender``), an in-process study:

  every controller is built by ``offboard.controllers.make_controller`` from one belief
  (``belief_params``: the same mass, inertia, thrust range, tilt limit and To) and flown by
  ``offboard.inprocess.simulate`` with a drive (``offboard.inprocess.Drive``):

- ``paper``: the paper's law (yaw-aware, limits), tau~ held and eq. 16 applied at the physics
  rate with the believed inertia (``inner-loop``, the plant's ``paper`` inner loop;
  ``offboard simulate --drive inner-loop``); ``paper+i`` with the integral action;
- ``se3``: Lee's SE(3) controller, its attitude law (Lee eq. 16) at the physics rate
  (``attitude-law``);
- ``px4``: PX4's position cascade, its attitude setpoint flown by the plant's PX4 attitude and
  rate controllers (``sitl_plant.inner_loops.Px4Loop``) at the physics rate (``px4``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from offboard.controller import ActionLimits, ControllerParams
from offboard.controller.command import Controller
from offboard.controllers import make_controller
from offboard.inprocess import Drive
from offboard.model.vehicle import VehicleParams

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

#: The drive each controller flies through in the in-process comparison (module docstring).
DRIVES = {"paper": Drive.INNER_LOOP, "paper+i": Drive.INNER_LOOP, "se3": Drive.ATTITUDE_LAW, "px4": Drive.PX4}


def belief_params(belief: Belief, *, integral_gain_per_s: float = 0.0) -> ControllerParams:
    """The one ``ControllerParams`` every contender is built from (Table I's gains for the law)."""
    extra = {"integral_gain_per_s": integral_gain_per_s} if integral_gain_per_s > 0 else {}
    return ControllerParams(
        sample_time_s=SAMPLE_TIME_S,
        mass_kg=belief.mass_kg,
        inertia_kg_m2=belief.inertia_kg_m2,
        euler_rate_form="zyx",  # a rigid body's Euler-rate map (paper-sim1-rigid-body.toml)
        yaw_aware=True,
        limits=ActionLimits(thrust_min_n=0.0, thrust_max_n=THRUST_MAX_N, tilt_max_rad=math.radians(TILT_MAX_DEG)),
        **extra,  # type: ignore[arg-type]
    )


def contender(kind: str, belief: Belief, integral_gain_per_s: float = 0.0) -> tuple[Controller, Drive]:
    """The ``kind`` controller (``paper``, ``paper+i``, ``se3``, ``px4``) and its drive."""
    if kind not in DRIVES:
        raise ValueError(f"unknown controller {kind!r}")
    params = belief_params(belief, integral_gain_per_s=integral_gain_per_s if kind == "paper+i" else 0.0)
    controller = make_controller("paper" if kind.startswith("paper") else kind, params)
    controller.name = kind
    return controller, DRIVES[kind]


def flown_controller(kind: str, belief: Belief, vehicle: VehicleParams) -> Controller:
    """``kind`` (``paper``: Table I's gains; ``paper-designed``: the gains ``offboard fly`` designs
    for the vehicle, lockstep latency 0; ``se3``; ``px4``) as ``offboard fly`` builds it."""
    from offboard.codec import Scaling
    from offboard.controller import PAPER_CONTROLLER_FILE, load_controller
    from offboard.flight import ControllerChoice, resolve_controller
    from sitl_plant.params import plant_params

    table = plant_params(vehicle)
    values = {name: table[name] for name in table}
    base = load_controller(PAPER_CONTROLLER_FILE)
    from_file = belief != NOMINAL  # a controller file with the belief (Table II): the file's mass and inertia
    if from_file:
        base = base.with_changes(mass_kg=belief.mass_kg, inertia_kg_m2=belief.inertia_kg_m2)
    law = "paper" if kind.startswith("paper") else kind
    choice = ControllerChoice(base=base, kind=law, from_file=from_file, tuned=kind == "paper-designed", latency_s=0.0,
                              yaw_aware=True)
    params, _ = resolve_controller(choice, "rigid-body", values, Scaling(values["SIM_THR_MAX"]))
    controller = make_controller(law, params)
    controller.name = kind
    return controller
