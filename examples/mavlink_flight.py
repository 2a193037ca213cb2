"""A MAVLink flight from Python: sitl-plant in lockstep in a child process, the offboard in this one.

The same ``Flight`` ``offboard fly`` runs: discover the vehicle, read its parameters, design the
gains for its inner loop, stream setpoints, OFFBOARD, arm, fly the mission, land, disarm. The
log goes to ``RUN_DIR/flight.tlog``. Run: ``python examples/mavlink_flight.py [RUN_DIR]``.
"""

import subprocess
import sys
from pathlib import Path

from offboard.controller import PAPER_CONTROLLER_FILE, load_controller
from offboard.demo import free_udp_ports, stop_process
from offboard.flight import ControllerChoice, Flight, FlightConfig, LogClock
from offboard.link import MavLink
from offboard.metrics import format_table, summarize
from offboard.missions import MISSIONS_DIR, load_mission

run_dir = Path(sys.argv[1] if len(sys.argv) > 1 else "runs/example-mavlink")
run_dir.mkdir(parents=True, exist_ok=True)
plant_port, our_port = free_udp_ports(2)  # never assume 14540/14550 are free
plant = subprocess.Popen([sys.executable, "-m", "sitl_plant.cli", "--lockstep", "--quiet", "--gcs-bind", "none",
                          "--api-bind", f"127.0.0.1:{plant_port}", "--api-remote", f"127.0.0.1:{our_port}"])
mission = load_mission(MISSIONS_DIR / "figure-eight.toml")
log_clock = LogClock(lockstep=True)  # in lockstep the log is stamped with the vehicle's time, not the wall's
link = MavLink(f"udpin:127.0.0.1:{our_port}", sysid=245, compid=191, tlog_path=run_dir / "flight.tlog", log_time_us=log_clock)
try:
    choice = ControllerChoice(base=load_controller(PAPER_CONTROLLER_FILE), tuned=True, latency_s=0.0)
    config = FlightConfig(lockstep=True, connect=f"udpin:127.0.0.1:{our_port}")
    flight = Flight(link, mission.trajectory, choice, config, log_clock=log_clock, event=lambda text: print("offboard:", text))
    result = flight.run()
finally:
    link.close()
    stop_process(plant)
print(format_table(summarize(result.record)))
print(f"status {result.status.value}, landed {result.landed}, disarmed {result.disarmed}; log {run_dir / 'flight.tlog'}")
sys.exit(result.status.exit_code)
