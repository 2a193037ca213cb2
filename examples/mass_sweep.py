"""A small robustness sweep: the true mass varied while the controller believes 0.5 kg.

Simulation 2's question (the paper's Table II) as a loop: Simulation 1's scenario (the helix
phase on the paper's model, Table I's gains, eq. 16 in the vehicle-side inner loop) with the
vehicle's mass changed, each flight by the one simulation loop. The law has no term for a mass
error, so the error it leaves grows with it (the paper's Fig. 8). Run:
``python examples/mass_sweep.py``.
"""

import dataclasses

import numpy as np

from offboard.inprocess import run_scenario
from offboard.missions import MISSIONS_DIR
from offboard.scenario import load_scenario

base = load_scenario(MISSIONS_DIR / "paper-sim1.toml")
print(f"believed mass {base.controller.mass_kg:g} kg")
print("true mass kg   mean error, last 2 s of the helix (m)")
for mass in (0.40, 0.45, 0.50, 0.55, 0.60, 0.70):
    scenario = dataclasses.replace(base, vehicle=base.vehicle.with_changes(mass_kg=mass), duration_s=12.0)
    record = run_scenario(scenario)
    last = record["t_s"] >= record["t_s"][-1] - 2.0
    print(f"{mass:11.2f}   {np.linalg.norm(record.error_ned_m[last], axis=1).mean():.3f}  ({record.status.value})")
