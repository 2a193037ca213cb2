"""``Supervisor`` after a telemetry outage in OFFBOARD: the vehicle's offboard-loss failsafe may
have taken over, and PX4 v1.16 gives control back within 1 s of the setpoints' return (measured,
docs/parity/commander.md): the flight goes on when it does, and ends LINK_LOST when it does not."""

from __future__ import annotations

import pytest
from pymavlink import mavutil

from offboard.model import px4_modes
from offboard.codec import VehicleStatus
from offboard.flight.config import FlightConfig, FlightEnd
from offboard.flight.supervisor import RETURN_BEATS, Supervisor
from offboard.record import FlightStatus

mavlink = mavutil.mavlink
OFFBOARD = VehicleStatus(True, px4_modes.MAIN_OFFBOARD, 0, mavlink.MAV_STATE_ACTIVE, True)
FAILSAFE_POSITION = VehicleStatus(True, px4_modes.MAIN_POSCTL, 0, mavlink.MAV_STATE_CRITICAL, True)


def after_an_outage() -> tuple[Supervisor, list[str]]:
    said: list[str] = []
    sup = Supervisor(FlightConfig(telemetry_timeout_s=0.3, reconnect_timeout_s=10.0), said.append)
    sup.watching = sup.expect_offboard = sup.expect_armed = True
    sup.heard(0.0)
    sup.on_heartbeat(OFFBOARD, [])
    sup.service(1.0)  # 1 s without telemetry: an outage
    assert sup.in_outage
    sup.telemetry_back(2.5)
    return sup, said


def test_the_vehicle_back_in_offboard_by_the_second_heartbeat_goes_on_flying() -> None:
    sup, said = after_an_outage()
    sup.on_heartbeat(FAILSAFE_POSITION, ["Failsafe activated"])  # sent before the setpoints were back
    sup.on_heartbeat(OFFBOARD, ["Failsafe deactivated: offboard signal back"])
    sup.on_heartbeat(OFFBOARD, [])
    assert sup.outages == [pytest.approx(2.5)] and any("setpoints resumed" in s for s in said)


def test_the_vehicle_left_in_its_failsafe_mode_ends_link_lost_naming_it() -> None:
    sup, _ = after_an_outage()
    for _ in range(RETURN_BEATS - 1):
        sup.on_heartbeat(FAILSAFE_POSITION, ["Failsafe activated"])
    with pytest.raises(FlightEnd) as end:
        sup.on_heartbeat(FAILSAFE_POSITION, ["Failsafe activated"])
    assert end.value.status is FlightStatus.LINK_LOST
    assert "telemetry came back with the vehicle in Position: its failsafe took over" in str(end.value)


def test_after_its_return_a_later_failsafe_still_ends_the_flight() -> None:
    sup, _ = after_an_outage()
    sup.on_heartbeat(OFFBOARD, [])
    with pytest.raises(FlightEnd) as end:
        sup.on_heartbeat(FAILSAFE_POSITION, ["Failsafe activated"])
    assert end.value.status is FlightStatus.FAILSAFE


def test_a_vehicle_disarmed_during_the_outage_ends_the_flight_at_once() -> None:
    """The two heartbeats of grace are for the mode only: a disarm (COM_OBL_RC_ACT 7) still ends it."""
    sup, _ = after_an_outage()
    disarmed = VehicleStatus(False, px4_modes.MAIN_POSCTL, 0, mavlink.MAV_STATE_STANDBY, True)
    with pytest.raises(FlightEnd) as end:
        sup.on_heartbeat(disarmed, ["Disarmed by failsafe"])
    assert end.value.status is FlightStatus.MODE_CHANGED and "disarmed" in str(end.value)
