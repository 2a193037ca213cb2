"""offboard: the Rosales et al. trajectory-tracking controller and the process that flies it over MAVLink.

- ``offboard.controller``: the law of eq. 28-42 and eq. 16 as a pure object (paper's z-up frame inside).
- ``offboard.trajectory``: references ``reference(t)`` in NED (helix, hold, line, waypoints, ...).
- ``offboard.frames``: NED/FRD <-> the paper's frame, the only place they are converted.
"""
