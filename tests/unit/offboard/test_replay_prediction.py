"""How well a flight's latency prediction predicted (offboard.replay.prediction)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from offboard.controller.design import inner_loop_from_params
from offboard.controller.prediction import LatencyPredictor
from offboard.frames import setpoint_attitude
from offboard.model.vehicle import PAPER_VEHICLE_FILE, VehicleModel, load_vehicle
from offboard.replay.prediction import check_prediction, setpoint_tilt_about, thrust_axis
from offboard.trajectory.base import Phase
from sitl_plant.params import plant_params

TO = 0.05


@dataclass(frozen=True)
class _State:
    time_boot_ms: int
    pos_ned_m: np.ndarray
    vel_ned_m_s: np.ndarray
    euler_rad: np.ndarray
    body_rate_frd_rad_s: np.ndarray
    position_time_boot_ms: int | None = None


def _model(latency_s: float):  # noqa: ANN202
    table = plant_params(load_vehicle(PAPER_VEHICLE_FILE))
    return inner_loop_from_params({name: table[name] for name in table}, latency_s)


@pytest.mark.parametrize("heading", [0.0, 1.1, -2.8])
def test_a_setpoints_tilt_is_read_back_about_the_heading_the_law_wrote_it_about(heading):
    """``frames.setpoint_attitude`` keeps the thrust axis of (x7ez, x9ez) about the law's heading
    whatever yaw the setpoint asks for; reading the logged quaternion back about that heading
    gives the law's angles."""
    rng = np.random.default_rng(5)
    for _ in range(20):
        roll, pitch, yaw_ref = rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(-math.pi, math.pi)
        q = setpoint_attitude(roll, pitch, yaw_ref, heading, VehicleModel.RIGID_BODY)
        assert setpoint_tilt_about(q, heading) == pytest.approx((roll, pitch), abs=1e-9)


def test_the_thrust_axis_is_body_z_in_ned():
    assert np.allclose(thrust_axis(np.array(0.0), np.array(0.0), np.array(0.7)), [0.0, 0.0, 1.0])
    # pitched nose down (negative pitch) facing east: body z leans towards the west
    axis = thrust_axis(np.array(0.0), np.array(-0.2), np.array(math.pi / 2))
    assert axis[1] < 0.0 and abs(axis[0]) < 1e-12 and axis[2] == pytest.approx(math.cos(0.2))


def test_a_vehicle_coasting_level_is_predicted_exactly_and_the_measured_state_is_a_latency_behind():
    """Level, hover's thrust held, 1.2 m/s north and 0.5 east: the prediction lands on what the
    log holds a latency later; the measured state is |v| L behind it."""
    latency = 0.12
    model = _model(latency)
    v = np.array([1.2, 0.5, 0.0])
    stamps = np.arange(0, 20_000, 10)  # telemetry every 10 ms for 20 s
    attitude = np.column_stack([stamps, np.zeros((len(stamps), 3))])
    position = np.column_stack([stamps, np.outer(stamps / 1000.0, v) + [0.0, 0.0, -5.0], np.tile(v, (len(stamps), 1))])
    samples = [_State(int(t), position[i, 1:4], v, np.zeros(3), np.zeros(3), int(t)) for i, t in enumerate(stamps) if t % 50 == 0]
    hover_q = np.tile(np.asarray(setpoint_attitude(0.0, 0.0, 0.0, 0.0, VehicleModel.RIGID_BODY), dtype=float), (len(samples), 1))
    thrust = np.full(len(samples), 0.5 * 9.81)
    check = check_prediction(LatencyPredictor(model, TO, 0.5, 9.81), samples, hover_q, thrust, np.zeros(len(samples)), attitude, position)
    assert check is not None and check.samples == len(samples) - 2  # the last two horizons lie past the log (19 990 ms)
    assert check.position_rms_m < 1e-9 and check.velocity_rms_m_s < 1e-9 and check.tilt_rms_deg < 1e-6
    assert check.position_rms_measured_m == pytest.approx(np.linalg.norm(v) * latency, rel=1e-9)
    assert check.velocity_rms_measured_m_s < 1e-12
    assert "prediction over 120 ms" in check.describe() and check.to_dict()["samples"] == check.samples
    assert check.phases == ()  # no phases asked for


def test_each_phase_of_the_mission_gets_its_own_figures():
    """A vehicle level at 1 m/s until 10 s, then level at 3 m/s (a step of the telemetry's speed,
    which no setpoint explains): the prediction is exact within each phase and off across the
    step; the phases' figures say where."""
    latency = 0.1
    model = _model(latency)
    stamps = np.arange(0, 20_000, 10)
    speed = np.where(stamps < 10_000, 1.0, 3.0)
    north = np.cumsum(speed * 0.01) - speed[0] * 0.01
    attitude = np.column_stack([stamps, np.zeros((len(stamps), 3))])
    position = np.column_stack([stamps, north, np.zeros(len(stamps)), np.full(len(stamps), -5.0), speed, np.zeros((len(stamps), 2))])
    keep = stamps % 50 == 0
    samples = [_State(int(t), position[i, 1:4], position[i, 4:7], np.zeros(3), np.zeros(3), int(t)) for i, t in enumerate(stamps) if keep[i]]
    n = len(samples)
    hover_q = np.tile(np.asarray(setpoint_attitude(0.0, 0.0, 0.0, 0.0, VehicleModel.RIGID_BODY), dtype=float), (n, 1))
    phases = (Phase("slow", 0.0, 9.8), Phase("step", 9.8, 10.2), Phase("fast", 10.2, 30.0), Phase("never", 40.0, 50.0))
    check = check_prediction(LatencyPredictor(model, TO, 0.5, 9.81), samples, hover_q, np.full(n, 0.5 * 9.81), np.zeros(n),
                             attitude, position, t_s=stamps[keep] / 1000.0, phases=phases)  # fmt: skip
    assert check is not None
    found = dict(check.phases)
    assert list(found) == ["slow", "step", "fast"]  # a phase with no sample is left out
    assert sum(c.samples for c in found.values()) == check.samples
    assert found["slow"].velocity_rms_m_s < 1e-9 and found["fast"].velocity_rms_m_s < 1e-9
    # the 2 m/s the telemetry jumped by, which the prediction of the two samples whose horizon crosses 10 s could not know
    assert found["step"].velocity_rms_m_s == pytest.approx(2.0 * math.sqrt(2 / 8))
    assert set(check.to_dict()["phases"]) == {"slow", "step", "fast"}
    assert [line.split(":")[0].strip() for line in check.describe().splitlines()[1:]] == ["slow", "step", "fast"]


def test_no_sample_within_the_log_is_no_check():
    model = _model(0.1)
    state = _State(0, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    table = np.array([[0.0, 0, 0, 0, 0, 0, 0], [50.0, 0, 0, 0, 0, 0, 0]])
    q = np.array([[1.0, 0.0, 0.0, 0.0]])
    assert check_prediction(LatencyPredictor(model, TO, 0.5), [state], q, np.array([4.9]), np.zeros(1), table, table) is None
