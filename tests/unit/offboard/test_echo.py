"""offboard.echo: the setpoints paired with the vehicle's ATTITUDE_TARGET echo (the flights
against sitl-plant and PX4 are in tests/e2e: test_fly_latency.py, test_px4_flight.py)."""

from __future__ import annotations

import numpy as np

from offboard.echo import MAX_LATENCY_MS, PENDING, SetpointEcho, echo_words, latency_figures


def q(roll: float) -> tuple[float, float, float, float]:
    return (float(np.cos(roll / 2)), float(np.sin(roll / 2)), 0.0, 0.0)


def as_sent(quat: tuple[float, ...]) -> tuple[float, ...]:
    """The quaternion as the wire carries it (float32) and the vehicle echoes it."""
    return tuple(float(np.float32(v)) for v in quat)


THRUST = 0.25


def test_each_echo_pairs_its_setpoint_by_the_quaternion_and_thrust_the_wire_carried():
    echo = SetpointEcho()
    for k in range(5):
        echo.sent(1000 + 50 * k, q(0.01 * k), THRUST)
    # PX4 echoes every other one (its stream at 10 Hz), 4 and 12 ms after the stamps answered
    assert echo.echoed(1004, as_sent(q(0.0)), THRUST) == 4.0
    assert echo.echoed(1112, as_sent(q(0.02)), THRUST) == 12.0
    assert echo.echoed(1112, as_sent(q(0.02)), THRUST) is None  # the same echo again (a stream repeat): paired once
    assert echo.echoed(1300, as_sent(q(0.5)), THRUST) is None  # another module's setpoint: ours to pair, none
    assert echo.echoed(1212, as_sent(q(0.04)), 0.3) is None  # the attitude, not the thrust: not ours
    assert echo.latencies_ms == [4.0, 12.0]
    assert echo.figures() == {"paired": 2, "p50_ms": 8.0, "p90_ms": 11.2, "max_ms": 12.0}


def test_a_repeated_setpoint_is_not_paired_and_an_echo_before_its_stamp_is_counted_not_paired():
    echo = SetpointEcho()
    echo.sent(1000, q(0.1), THRUST)
    echo.sent(1050, q(0.1), THRUST)  # the same setpoint: whose echo it would be cannot be told
    assert echo.echoed(1060, as_sent(q(0.1)), THRUST) is None
    echo.sent(1100, q(0.1), 0.26)  # the same attitude at another thrust (a still hover): told apart
    assert echo.echoed(1104, as_sent(q(0.1)), float(np.float32(0.26))) == 4.0
    echo.sent(1150, q(0.2), THRUST)
    assert echo.echoed(1140, as_sent(q(0.2)), THRUST) is None and echo.inconsistent == 1  # stamped before the telemetry it answers
    echo.sent(1200, q(0.3), THRUST)
    assert echo.echoed(1200 + MAX_LATENCY_MS + 1, as_sent(q(0.3)), THRUST) is None and echo.inconsistent == 2
    assert echo.figures() == {"paired": 1, "p50_ms": 4.0, "p90_ms": 4.0, "max_ms": 4.0}
    assert SetpointEcho().figures() == {"paired": 0, "p50_ms": None, "p90_ms": None, "max_ms": None}
    assert echo_words(SetpointEcho().figures()).startswith("setpoint echo: none paired")


def test_only_the_latest_setpoints_wait_for_their_echo():
    echo = SetpointEcho()
    for k in range(PENDING + 10):
        echo.sent(50 * k, q(0.001 * (k + 1)), THRUST)
    assert echo.echoed(4, as_sent(q(0.001)), THRUST) is None  # long superseded: forgotten
    last = PENDING + 9
    assert echo.echoed(50 * last + 4, as_sent(q(0.001 * (last + 1))), THRUST) == 4.0


def test_the_summary_line_says_the_figures_against_the_design():
    figures = latency_figures([4.0, 4.0, 8.0, 12.0, float("nan")])
    assert figures == {"paired": 4, "p50_ms": 6.0, "p90_ms": 10.8, "max_ms": 12.0}
    assert echo_words(figures, 0.0101) == (
        "setpoint echo: the vehicle took the setpoints 6 ms (median), 10.8 ms (90 %), at most 12 ms after the "
        "telemetry they answer, in its clock (4 ATTITUDE_TARGET echoes); the law was designed for 10 ms")


def test_the_echo_is_asked_for_in_real_time_with_the_attitude_output_from_px4_only():
    """PX4 (and sitl-plant, which says PX4) stamps ATTITUDE_TARGET with when it took the setpoint;
    ArduPilot with when it sends it, whose echo would not be the latency."""
    from pymavlink.dialects.v20 import common as mavlink

    from offboard.codec import SetpointOutput
    from offboard.flight import FlightConfig

    px4, ardupilot = mavlink.MAV_AUTOPILOT_PX4, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert FlightConfig().echoes_setpoints(px4)
    assert not FlightConfig().echoes_setpoints(ardupilot) and not FlightConfig().echoes_setpoints(None)
    assert not FlightConfig(lockstep=True).echoes_setpoints(px4)  # 0 by construction
    assert not FlightConfig(output=SetpointOutput.RATES).echoes_setpoints(px4)  # PX4 echoes no attitude of it
    assert not FlightConfig(setpoint_echo=False).echoes_setpoints(px4)
