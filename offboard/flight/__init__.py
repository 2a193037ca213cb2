"""A mission flown over MAVLink (``offboard fly``): the flight sequence and the control loop, with no sockets.

``offboard/commands/fly.py`` is the argv edge. The names below are the public API
(``from offboard.flight import Flight``).
"""

from offboard.flight.choice import VEHICLE_PARAMS, ControllerChoice, params_to_read, resolve_controller
from offboard.flight.config import AUTO_TELEMETRY_RATE, OUTPUTS, FlightConfig, Link, SampleClock
from offboard.flight.mission import FLIGHT_COLUMNS, Flight, FlightResult, LogClock, LoopStats, Progress

__all__ = [
    "AUTO_TELEMETRY_RATE",
    "FLIGHT_COLUMNS",
    "OUTPUTS",
    "VEHICLE_PARAMS",
    "ControllerChoice",
    "Flight",
    "FlightConfig",
    "FlightResult",
    "Link",
    "LogClock",
    "LoopStats",
    "Progress",
    "SampleClock",
    "params_to_read",
    "resolve_controller",
]
