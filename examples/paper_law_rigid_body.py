"""The paper's law on the rigid body, in-process: Simulation 1's helix with Table I's gains.

The controller and the vehicle of ``missions/paper-sim1-rigid-body.toml`` (the law bounded to
what the rotors can do, eq. 16 at the physics rate with the believed inertia), flown by the one
simulation loop. Run: ``python examples/paper_law_rigid_body.py``.
"""

from offboard.controller.paper import PaperController
from offboard.inprocess import simulate
from offboard.metrics import format_table, summarize
from offboard.missions import MISSIONS_DIR
from offboard.scenario import load_scenario

scenario = load_scenario(MISSIONS_DIR / "paper-sim1-rigid-body.toml")
controller = PaperController(scenario.controller)  # NED in, a Command out (offboard.controller.command)
result = simulate(scenario.vehicle, controller, scenario.trajectory, drive="inner-loop", duration_s=12.0)
print(format_table(summarize(result.record)))
print(f"status {result.status.value}; median controller step {1e6 * float(sorted(result.step_cost_s)[len(result.step_cost_s) // 2]):.0f} us")
