"""The paper's law against SE(3) and PX4's cascade on one mission, through PX4's attitude loop.

Every controller is built as ``offboard fly --controller K`` builds it for the vehicle (the same
belief, thrust range, tilt limit and To; the law with the gains designed for the vehicle's inner
loop), and hands its attitude target to PX4's attitude and rate controllers every 50 ms: the
in-process twin of the MAVLink flight through sitl-plant. Run:
``python examples/law_vs_se3.py [MISSION]`` (default: the paper's square).
"""

import sys

import numpy as np

from offboard.codec import Scaling
from offboard.controller import PAPER_CONTROLLER_FILE, load_controller
from offboard.controllers import make_controller
from offboard.flight import ControllerChoice, resolve_controller
from offboard.inprocess import Drive, simulate
from offboard.missions import MISSIONS_DIR, load_mission
from sitl_plant.params import plant_params
from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle

mission = load_mission(sys.argv[1] if len(sys.argv) > 1 else MISSIONS_DIR / "paper-square.toml")
vehicle = load_vehicle(PAPER_VEHICLE_FILE)
table = plant_params(vehicle)  # the parameters the plant publishes, as offboard fly reads them
published = {name: table[name] for name in table}
start = mission.trajectory.reference(0.0)
for kind in ("paper", "se3", "px4"):
    choice = ControllerChoice(base=load_controller(PAPER_CONTROLLER_FILE), kind=kind, tuned=kind == "paper", latency_s=0.0)
    params, _ = resolve_controller(choice, "rigid-body", published, Scaling(published["SIM_THR_MAX"]))
    result = simulate(vehicle, make_controller(kind, params), mission.trajectory, drive=Drive.PX4,
                      initial_pos_ned_m=start.pos_ned_m, initial_yaw_rad=start.yaw_rad, hovering=True)
    error = np.linalg.norm(result.record.error_ned_m, axis=1)
    print(f"{kind:6s} {result.status.value}: RMS {np.sqrt(np.mean(error ** 2)):.3f} m, max {error.max():.3f} m")
