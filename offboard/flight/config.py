"""How a MAVLink flight is configured, and what its parts share: the link they talk over, the
sample clock's choices, and the exception that ends a flight.

The bottom of ``offboard.flight``: every other module of the package imports this one, and it
imports none of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import Protocol

from offboard.codec import OUTPUTS, SetpointOutput
from offboard.metrics import LOST_TRACK_M
from offboard.model.vehicle import VEHICLE_MODELS, VehicleModel
from offboard.record import FlightStatus
from pymavlink.dialects.v20 import common as mavlink


#: ``FlightConfig.telemetry_rate_hz`` that follows the sample rate (``telemetry_rate_for``).
AUTO_TELEMETRY_RATE = "auto"
#: In real time the telemetry comes at a whole multiple of the sample rate at or above this:
#: sampled on our own clock, the freshest ATTITUDE is then at most ~10 ms old.
REAL_TIME_TELEMETRY_MIN_HZ = 100.0


class SampleClock(StrEnum):
    """What paces the real-time samples: our clock, the vehicle's, or the one that runs at its rate."""

    WALL = "wall"
    VEHICLE = "vehicle"
    AUTO = "auto"


class HeadingHoldMode(StrEnum):
    """``offboard fly --takeoff-heading-hold``: hold the yaw reference at the take-off heading until
    the vehicle's estimator has aligned its heading in flight (``heading_hold``)."""

    AUTO = "auto"  #: where the vehicle publishes an EKF2 fusing a magnetometer (``heading_hold.aligns_in_flight``)
    ON = "on"
    OFF = "off"


class Link(Protocol):
    """What a flight needs of a MAVLink link (``offboard.link.MavLink`` or a test double)."""

    def send(self, msg: mavlink.MAVLink_message) -> None:
        """Send one message to the vehicle (and log it)."""
        ...

    def recv(self, timeout_s: float) -> mavlink.MAVLink_message | None:
        """The next message from the link within ``timeout_s`` (None: none came)."""
        ...

    def pending(self) -> bool:
        """Whether a message already waits (without blocking)."""
        ...


@dataclass(frozen=True)
class FlightConfig:
    """How to fly (the command line's choices; defaults are ``offboard fly``'s).

    Attributes
    ----------
    output : str
        ``attitude`` (SET_ATTITUDE_TARGET) or ``actuator`` (SET_ACTUATOR_CONTROL_TARGET).
    model : str
        ``rigid-body`` or ``paper``: what the vehicle's ATTITUDE angles are (``codec``).
    lockstep : bool
        Sample on telemetry arrival instead of on our own clock.
    clock : SampleClock
        Real time: sample on our clock (``wall``), on the vehicle's ``time_boot_ms``
        (``vehicle``), or on whichever runs at the vehicle's rate, measured before OFFBOARD
        (``auto``; module docstring).
    telemetry_timeout_s : float
        Telemetry older than this (wall clock) stops the setpoints: LINK_LOST.
    reconnect_timeout_s : float
        How long to wait for telemetry to come back before giving up.
    heartbeat_timeout_s : float
        How long to wait for the vehicle's first HEARTBEAT.
    command_timeout_s, command_attempts : float, int
        COMMAND_ACK wait per attempt, and attempts (MAVLink's command protocol; MAVSDK waits
        0.5 s). Six tries get a command through a link losing 20 % each way but 0.2 % of the
        time (0.36^6), where three 1 s tries failed one flight in four; and before giving up the
        vehicle's heartbeat is asked whether the command took effect (its ACKs lost).
    param_timeout_s, param_attempts : float, int
        PARAM_VALUE wait per attempt, and attempts (the same reasoning).
    prestream_samples : int
        Setpoints streamed before asking for OFFBOARD.
    land_timeout_s : float
        Wall-clock limit for the landing (then we report and stop waiting).
    telemetry_rate_hz : float, "auto" or None
        Rate asked for LOCAL_POSITION_NED and ATTITUDE (None: leave the vehicle's defaults;
        ``"auto"``: the sample rate 1/To in lockstep, where the vehicle sends one of each a period
        whatever the rate, and in real time the smallest whole multiple of it at or above
        ``REAL_TIME_TELEMETRY_MIN_HZ``, so that a sample's telemetry is at most ~10 ms old). At
        equal rates the vehicle stamps them alike, and a real-time sample uses the ATTITUDE of the
        latest LOCAL_POSITION_NED's instant: PX4's defaults (30 and 100 Hz) leave the law
        differencing positions and velocities up to 33 ms old against fresher angles, which
        shows as jagged angle references and a lasting oscillation on the paper helix.
    unread_streams_off : bool
        Switch off (MAV_CMD_SET_MESSAGE_INTERVAL -1) PX4's default streams we never read
        (``codec.UNREAD_STREAMS``), as PX4's clients do: the vehicle then neither builds nor sends
        them, and we neither parse nor log them.
    setpoint_echo : bool
        Ask for the vehicle's ATTITUDE_TARGET (``echo.ECHO_RATE_HZ``, PX4's default on its API
        link) and pair it with the attitude setpoints sent: the loop's latency in the vehicle's
        clock (``offboard.echo``). Attitude output, not in lockstep (where it is 0 by
        construction), and only from a vehicle whose HEARTBEAT says PX4 (whose ATTITUDE_TARGET
        carries when it took the setpoint; sitl-plant's too); off, ATTITUDE_TARGET is switched off
        with the streams we never read.
    lost_track_m : float
        In flight: LOST_TRACK when the 3D error stays above this through
        ``metrics.LOST_TRACK_WINDOW_S`` and does not shrink (``guards.TrackGuard``; inf: never).
    watch_estimator : bool
        ESTIMATE_LOST when the vehicle's ESTIMATOR_STATUS stops vouching for what the law reads
        (``guards.EstimatorGuard``).
    takeoff_heading_hold : HeadingHoldMode
        Hold the yaw reference at the take-off heading until the vehicle's estimator has aligned
        its heading in flight (``heading_hold.TakeoffHeadingHold``): ``auto`` where the vehicle
        publishes an EKF2 that fuses a magnetometer (PX4), ``on``, ``off``.
    target_system : int or None
        Fly this system id (None: the first autopilot heard).
    connect : str
        The address listened on / connected to (for messages only).
    """

    output: SetpointOutput = SetpointOutput.ATTITUDE
    model: VehicleModel = VehicleModel.RIGID_BODY
    lockstep: bool = False
    clock: SampleClock = SampleClock.WALL
    telemetry_timeout_s: float = 0.5
    reconnect_timeout_s: float = 5.0
    heartbeat_timeout_s: float = 10.0
    command_timeout_s: float = 0.5
    command_attempts: int = 6
    param_timeout_s: float = 0.3
    param_attempts: int = 6
    prestream_samples: int = 10
    land_timeout_s: float = 60.0
    telemetry_rate_hz: float | str | None = AUTO_TELEMETRY_RATE
    unread_streams_off: bool = True
    setpoint_echo: bool = True
    lost_track_m: float = LOST_TRACK_M
    watch_estimator: bool = True
    takeoff_heading_hold: HeadingHoldMode = HeadingHoldMode.AUTO
    target_system: int | None = None
    connect: str = ""

    def __post_init__(self) -> None:
        if self.output not in OUTPUTS:
            raise ValueError(f"output must be one of {OUTPUTS}, got {self.output!r}")
        if self.model not in VEHICLE_MODELS:
            raise ValueError(f"model must be one of {VEHICLE_MODELS}, got {self.model!r}")
        object.__setattr__(self, "output", SetpointOutput(self.output))  # a word from the command line: its enum
        object.__setattr__(self, "model", VehicleModel(self.model))
        object.__setattr__(self, "takeoff_heading_hold", HeadingHoldMode(self.takeoff_heading_hold))
        for name in ("telemetry_timeout_s", "reconnect_timeout_s", "heartbeat_timeout_s", "command_timeout_s",
                     "param_timeout_s", "land_timeout_s"):  # fmt: skip
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be > 0, got {value}")
        if not self.lost_track_m > 0:  # inf is allowed: never
            raise ValueError(f"lost_track_m must be > 0, got {self.lost_track_m}")
        if self.command_attempts < 1 or self.param_attempts < 1 or self.prestream_samples < 1:
            raise ValueError("attempts and prestream_samples must be >= 1")
        rate = self.telemetry_rate_hz
        if rate is not None and rate != AUTO_TELEMETRY_RATE and not (isinstance(rate, (int, float)) and math.isfinite(rate) and rate > 0):
            raise ValueError(f"telemetry_rate_hz must be > 0, {AUTO_TELEMETRY_RATE!r} or None, got {rate!r}")

    def echoes_setpoints(self, autopilot: int | None) -> bool:
        """Whether the flight pairs its setpoints with the ATTITUDE_TARGET of a vehicle whose
        HEARTBEAT names ``autopilot`` (MAV_AUTOPILOT): ``setpoint_echo``, the attitude output, not
        in lockstep, and PX4, whose ATTITUDE_TARGET carries when it took the setpoint (ArduPilot
        stamps it when it sends it: its echo would not be the latency)."""
        return (self.setpoint_echo and not self.lockstep and self.output == SetpointOutput.ATTITUDE
                and autopilot == mavlink.MAV_AUTOPILOT_PX4)  # fmt: skip

    def telemetry_rate_for(self, sample_time_s: float) -> float | None:
        """The ATTITUDE and LOCAL_POSITION_NED rate to ask for at sample time To (None: the vehicle's)."""
        rate = self.telemetry_rate_hz
        if rate != AUTO_TELEMETRY_RATE:
            return None if rate is None else float(rate)
        sample_hz = 1.0 / sample_time_s
        if self.lockstep:
            return sample_hz
        return sample_hz * max(1, math.ceil(REAL_TIME_TELEMETRY_MIN_HZ / sample_hz - 1e-9))



class FlightEnd(Exception):
    """The flight ends with this status (raised while handling a message or a sample, caught in
    ``Flight.run``); ``stop_setpoints``: not one more setpoint (the vehicle is not ours to command)."""

    def __init__(self, status: FlightStatus, detail: str, *, stop_setpoints: bool = False) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.stop_setpoints = stop_setpoints
