"""A mission flown over MAVLink (``offboard fly``): the flight sequence and the control loop, with no sockets.

One idea a module, each importing only those above it:

- ``config``: ``FlightConfig`` (how to fly), ``SampleClock``, the ``Link`` a flight talks over and
  ``FlightEnd``, the exception that ends one;
- ``choice``: the controller flown, from the user's ``ControllerChoice`` and the vehicle's
  parameters (``params_to_read``, ``resolve_controller``; pure, also used without a flight);
- ``protocol``: ``VehicleClient``, the vehicle's MAVLink protocol besides the setpoints: finding
  it, heartbeats, commands with retries and ACKs, parameters, TIMESYNC, HOME_POSITION;
- ``supervisor``: ``Supervisor``, telemetry outages and the vehicle's mode and arming;
- ``guards``: ``TrackGuard`` and ``EstimatorGuard``, when the vehicle is lost (off its reference
  and not closing, or its estimator no longer vouching for the estimate): pure rules;
- ``heading_hold``: ``TakeoffHeadingHold``, the yaw reference held at the take-off heading until
  PX4's EKF2 has aligned its heading in flight: a pure rule;
- ``sampler``: ``Sampler``, when a sample is due (lockstep, our clock, the vehicle's clock), what
  it is made of, and the ``LoopStats``;
- ``mission``: ``Flight``, which owns one of each and runs the sequence (connect, prepare, stream
  and arm, fly the mission, land and disarm) and records the rows: ``FlightResult``.

``offboard/commands/fly.py`` is the argv edge. The names below are the public API
(``from offboard.flight import Flight``).
"""

from offboard.flight.choice import VEHICLE_PARAMS, ControllerChoice, params_to_read, resolve_controller
from offboard.flight.config import AUTO_TELEMETRY_RATE, OUTPUTS, FlightConfig, HeadingHoldMode, Link, SampleClock
from offboard.flight.mission import FLIGHT_COLUMNS, Flight, FlightResult, LogClock, Progress
from offboard.flight.sampler import LoopStats

__all__ = [
    "AUTO_TELEMETRY_RATE",
    "FLIGHT_COLUMNS",
    "OUTPUTS",
    "VEHICLE_PARAMS",
    "ControllerChoice",
    "Flight",
    "FlightConfig",
    "FlightResult",
    "HeadingHoldMode",
    "Link",
    "LogClock",
    "LoopStats",
    "Progress",
    "SampleClock",
    "params_to_read",
    "resolve_controller",
]
