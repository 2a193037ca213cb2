"""offboard.flight.heading_hold: the yaw reference held at the take-off heading until PX4's EKF2 has
aligned its heading in flight (1.5 m above the take-off point, then 1 s). The rule alone, then a
flight against the real plant in-process (``test_fly_flight.PlantLink``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from offboard.flight import ControllerChoice, Flight, FlightConfig, HeadingHoldMode, params_to_read
from offboard.flight.guards import HeadingResetWatch
from offboard.flight.heading_hold import (
    EKF2_ALIGN_HEIGHT_M,
    EKF2_ALIGN_SETTLE_S,
    EKF2_DELAY_MAX_S,
    HEADING_ALIGN_PARAMS,
    TakeoffHeadingHold,
    alignment_delay_s,
    aligns_in_flight,
    highest_down_m,
)
from offboard.record import FlightStatus
from offboard.trajectory.analytic import Hold, Line
from offboard.trajectory.base import Reference
from helpers import FakeClock
from test_fly_flight import PAPER, PlantLink, make_plant

DT = 0.05


def ref(yaw: float = 1.2, rate: float = 0.3) -> Reference:
    return Reference(np.array([1.0, 2.0, -3.0]), np.array([0.1, 0.2, 0.3]), np.array([0.0, 0.0, 0.1]), yaw, rate)


def test_the_heading_is_held_until_ekf2_has_aligned_and_a_second_more():
    hold = TakeoffHeadingHold(heading_rad=0.4, takeoff_down_m=0.2, delay_s=0.3)
    downs = [0.2, 0.0, -0.8, -1.2]  # passes 1.5 m above 0.2 at -1.31 (t = 0.2 s)
    holding = [hold.update(k * 0.05, d) for k, d in enumerate(downs)]
    assert holding == [True] * 4 and hold.passed_s is None
    assert hold.update(0.2, -1.31) and hold.passed_s == pytest.approx(0.2)
    # EKF2 aligns 0.3 s later (its EKF2_DELAY_MAX), then a second, whatever the height does meanwhile
    assert hold.update(0.2 + 0.3 + EKF2_ALIGN_SETTLE_S - 0.05, -1.0)
    assert not hold.update(0.2 + 0.3 + EKF2_ALIGN_SETTLE_S, -1.0) and hold.released_s == pytest.approx(1.5)
    assert not hold.update(5.0, 0.2) and hold.released_s == pytest.approx(1.5)  # released for good


def test_the_alignment_delay_is_the_vehicles_ekf2_delay_max():
    assert alignment_delay_s({"EKF2_DELAY_MAX": 200.0}) == pytest.approx(0.2)  # PX4's default, ms
    assert alignment_delay_s({"EKF2_DELAY_MAX": 350.0}) == pytest.approx(0.35)
    assert alignment_delay_s({}) == EKF2_DELAY_MAX_S
    assert alignment_delay_s({"EKF2_DELAY_MAX": math.nan}) == EKF2_DELAY_MAX_S


def test_while_held_the_yaw_is_the_take_off_heading_and_nothing_else_changes():
    hold = TakeoffHeadingHold(heading_rad=-0.7, takeoff_down_m=0.0)
    r = ref()
    held = hold.apply(r)
    assert held.yaw_rad == -0.7 and held.yaw_rate_rad_s == 0.0
    for name in ("pos_ned_m", "vel_ned_m_s", "acc_ned_m_s2"):
        np.testing.assert_array_equal(getattr(held, name), getattr(r, name))
    hold.update(0.0, -2.0)
    hold.update(EKF2_DELAY_MAX_S + EKF2_ALIGN_SETTLE_S, -2.0)
    assert not hold.holding and hold.apply(r) is r


def test_a_hold_needs_finite_values_and_a_positive_height():
    with pytest.raises(ValueError, match="finite"):
        TakeoffHeadingHold(math.nan, 0.0)
    with pytest.raises(ValueError, match="align_height_m"):
        TakeoffHeadingHold(0.0, 0.0, align_height_m=0.0)


def test_only_an_ekf2_fusing_a_magnetometer_aligns_in_flight():
    assert aligns_in_flight({"EKF2_MAG_TYPE": 0.0, "SYS_HAS_MAG": 1.0})  # PX4 SIH's (automatic)
    assert aligns_in_flight({"EKF2_MAG_TYPE": 1.0})  # heading fusion
    assert not aligns_in_flight({"EKF2_MAG_TYPE": 5.0})  # None
    assert not aligns_in_flight({"EKF2_MAG_TYPE": 0.0, "SYS_HAS_MAG": 0.0})  # no magnetometer
    assert not aligns_in_flight({"SIM_THR_MAX": 20.0})  # sitl-plant: no EKF2


def test_the_vehicle_is_asked_about_its_ekf2_unless_it_is_sitl_plant():
    choice = ControllerChoice(base=PAPER, tuned=True)
    for family in ("SIH", "none"):
        _, optional = params_to_read(choice, FlightConfig(), False, family)
        assert set(HEADING_ALIGN_PARAMS) <= set(optional)
        _, optional = params_to_read(choice, FlightConfig(takeoff_heading_hold="off"), False, family)
        assert not set(HEADING_ALIGN_PARAMS) & set(optional)
    _, optional = params_to_read(choice, FlightConfig(), False, "SIM")
    assert not set(HEADING_ALIGN_PARAMS) & set(optional)


def test_the_missions_highest_point_is_read_from_its_samples():
    low = Line((0.0, 0.0, -1.0), (5.0, 0.0, -1.4), 1.0, yaw_rad=1.0)
    assert highest_down_m(low, DT) == pytest.approx(-1.4, abs=0.01)  # its last sample, 0.016 s short of the end
    assert highest_down_m(Line((0.0, 0.0, -1.0), (0.0, 0.0, -3.0), 1.0), DT) == pytest.approx(-3.0)


# --- flown against the plant ------------------------------------------------------------------------


def fly(trajectory, mode: str, link: PlantLink | None = None):
    link = link if link is not None else PlantLink(make_plant(), FakeClock())
    events: list[str] = []
    flight = Flight(link, trajectory, ControllerChoice(base=PAPER, tuned=True),
                    FlightConfig(lockstep=True, connect="test", takeoff_heading_hold=mode), clock=link.clock,
                    event=events.append)  # fmt: skip
    return flight.run(), link


def test_the_hold_keeps_the_take_off_heading_through_the_climb_then_turns_to_the_missions():
    climb = Line((0.0, 0.0, -3.0), (3.0, 0.0, -3.0), 0.5, yaw_rad=math.pi / 2)  # starts 3 m up, heading east
    result, link = fly(climb, "on")
    assert result.status is FlightStatus.COMPLETE, result.detail
    hh = result.heading_hold
    assert hh is not None and hh["mode"] == "on" and hh["held"] and hh["heading_deg"] == pytest.approx(0.0, abs=1.0)
    t, ref_yaw = result.record["t_s"], result.record["ref_yaw_rad"]
    down = result.record["pos_ned_m"][:, 2]
    passed = t[np.argmax(down < down[0] - EKF2_ALIGN_HEIGHT_M)]
    released = hh["released_s"]
    assert released == pytest.approx(passed + EKF2_DELAY_MAX_S + EKF2_ALIGN_SETTLE_S, abs=DT / 2)  # sitl-plant: no EKF2_DELAY_MAX
    held = t < released
    assert np.all(np.abs(ref_yaw[held] - math.radians(hh["heading_deg"])) < 1e-12)
    assert np.all(ref_yaw[~held] == pytest.approx(math.pi / 2))  # the mission's own from then on
    # the vehicle's heading stayed near the take-off one while held, and turned east after
    yaw = result.record["euler_rad"][:, 2]
    assert np.max(np.abs(yaw[held])) < math.radians(10.0) and abs(yaw[-1] - math.pi / 2) < math.radians(5.0)
    assert any("heading released at t =" in n for n in result.notes)


def test_auto_holds_nothing_on_sitl_plant_and_does_not_ask_it_about_ekf2():
    climb = Line((0.0, 0.0, -3.0), (3.0, 0.0, -3.0), 0.5, yaw_rad=math.pi / 2)
    result, link = fly(climb, "auto")
    assert result.status is FlightStatus.COMPLETE, result.detail
    assert result.heading_hold == {"mode": "auto", "held": False, "heading_deg": None, "released_s": None}
    asked = {m.param_id for m in link.sent if m.get_type() == "PARAM_REQUEST_READ"}
    assert not asked & set(HEADING_ALIGN_PARAMS)
    assert result.record["ref_yaw_rad"][0] == pytest.approx(math.pi / 2)


def test_no_hold_when_the_mission_stays_low():
    low = Line((0.0, 0.0, -1.0), (2.0, 0.0, -1.0), 0.5, yaw_rad=1.0)
    result, _ = fly(low, "on")
    assert result.status is FlightStatus.COMPLETE, result.detail
    assert result.heading_hold["held"] is False
    assert any("never climbs 1.5 m above the take-off point" in n for n in result.notes)


def test_the_mode_is_one_of_three_words():
    assert [m.value for m in HeadingHoldMode] == ["auto", "on", "off"]
    with pytest.raises(ValueError):
        FlightConfig(takeoff_heading_hold="sometimes")


def test_a_re_run_holds_as_summary_json_says_and_refuses_a_hold_it_cannot_read():
    from offboard.commands.replay import ReplayArgumentError, _heading_hold_as_flown

    hold = _heading_hold_as_flown({"takeoff_heading_hold": {"mode": "auto", "held": True, "heading_deg": 90.0, "released_s": 2.2}})
    assert hold is not None and hold.heading_rad == pytest.approx(math.pi / 2)
    assert hold.update(2.15, 0.0) and not hold.update(2.2, 0.0)  # let go at the recorded time, whatever the height
    never = _heading_hold_as_flown({"takeoff_heading_hold": {"held": True, "heading_deg": 0.0, "released_s": None}})
    assert never is not None and never.update(100.0, -50.0)
    for summary in (None, {}, {"takeoff_heading_hold": None}, {"takeoff_heading_hold": {"mode": "off", "held": False}}):
        assert _heading_hold_as_flown(summary) is None
    for bad in ({"heading_deg": float("inf"), "released_s": 2.0}, {"heading_deg": "east", "released_s": 2.0},
                {"heading_deg": 1.0, "released_s": float("nan")}):  # fmt: skip
        with pytest.raises(ReplayArgumentError, match="takeoff_heading_hold held, but"):
            _heading_hold_as_flown({"takeoff_heading_hold": {"held": True, **bad}})


# --- the estimator's heading resets, noted in flight ---------------------------------------------------


def test_a_yaw_jump_the_body_rates_do_not_explain_is_a_reset_and_a_turn_is_not():
    watch = HeadingResetWatch()
    assert watch.observe((1000, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)) is None  # the first row: nothing to compare
    assert watch.observe((1050, 0.0, 0.0, 0.05, 0.0, 0.0, 1.0)) is None  # turning at 1 rad/s: 0.05 rad in 50 ms
    jump = watch.observe((1100, 0.0, 0.0, 0.05 + 0.05 - math.radians(30.0), 0.0, 0.0, 1.0))
    assert jump == pytest.approx(-30.0, abs=0.1)
    assert watch.observe((1100, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0)) is None  # a repeat of the same stamp: ignored
    assert watch.observe((1150, 0.0, 0.0, 0.1 - math.radians(30.0), 0.0, 0.0, 0.0)) is None
    assert watch.resets == [(1100, pytest.approx(-30.0, abs=0.1))]


class ResettingLink(PlantLink):
    """The plant's ATTITUDE with its yaw turned by ``jump_rad`` from the vehicle's ``at_ms`` on: an
    estimator that re-aligned its heading there (the vehicle itself does not turn)."""

    def __init__(self, at_ms: int, jump_rad: float) -> None:
        super().__init__(make_plant(), FakeClock())
        self.at_ms, self.jump_rad = at_ms, jump_rad

    def recv(self, timeout_s: float):
        msg = super().recv(timeout_s)
        if msg is not None and msg.get_type() == "ATTITUDE" and msg.time_boot_ms >= self.at_ms:
            msg.yaw = (msg.yaw + self.jump_rad + math.pi) % (2 * math.pi) - math.pi
        return msg


def test_a_heading_reset_in_flight_is_noted_with_its_mission_time():
    hover = Hold((0.0, 0.0, -3.0), 0.0, 4.0)
    probe, _ = fly(hover, "off")
    assert probe.status is FlightStatus.COMPLETE, probe.detail
    assert probe.heading_resets == [] and not any("reset its heading" in n for n in probe.notes)
    start_ms = int(probe.record["time_boot_ms"][0])
    result, _ = fly(hover, "off", ResettingLink(start_ms + 2000, math.radians(-25.0)))
    assert result.status is FlightStatus.COMPLETE, result.detail
    [reset] = result.heading_resets
    assert reset["deg"] == pytest.approx(-25.0, abs=0.5) and reset["t_s"] == pytest.approx(2.0, abs=0.06)
    assert any(f"reset its heading by {reset['deg']:+.1f} deg at t = {reset['t_s']:.2f} s" in n for n in result.notes)
    # the yaw the flight recorded is the estimator's, reset from then on
    t, yaw = result.record["t_s"], result.record["euler_rad"][:, 2]
    assert abs(yaw[t < 1.9]).max() < math.radians(1.0) and yaw[t > 2.1] == pytest.approx(math.radians(-25.0), abs=math.radians(1.0))
