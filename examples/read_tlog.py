"""Reading a flight log: any MAVLink tlog into a FlightRecord, its report and the tracking table.

Run: ``python examples/read_tlog.py LOG.tlog [MISSION]`` (the mission, when given, supplies the
references; else the vehicle's POSITION_TARGET_LOCAL_NED do).
"""

import sys

from offboard.errors import UserError
from offboard.metrics import format_table, summarize
from offboard.missions import load_mission
from offboard.replay import TlogReader, build_record, format_log_report, log_report, scan_log

if len(sys.argv) < 2:
    sys.exit("usage: python examples/read_tlog.py LOG.tlog [MISSION]")
try:
    reader = TlogReader(sys.argv[1])
    scan = scan_log(reader)  # one pass over the file; damage is reported, never raised
    trajectory = load_mission(sys.argv[2]).trajectory if len(sys.argv) > 2 else None
except UserError as exc:  # not a log, no such file, a bad mission: one line naming it
    sys.exit(f"read_tlog: {exc}")
record = build_record(scan, trajectory=trajectory, source=sys.argv[1])
print(format_log_report(log_report(reader, scan, 0.0)))
print(f"{len(record)} control samples, {record['t_s'][-1]:.2f} s; columns: {', '.join(record.columns)}")
print(format_table(summarize(record)))
