"""Sensor models: clean, the paper's integrated 5 % acceleration noise, ordinary IMU/EKF noise."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from numpy.testing import assert_allclose

from sitl_plant.dynamics import rigid_body as rb
from offboard.model.euler_lagrange import euler_rate_matrix
from offboard.model.rotations import quat_from_euler
from sitl_plant.dynamics.sensors import (
    IMU_DEFAULTS,
    CleanSensors,
    ImuNoise,
    PaperAccelNoise,
    SensorSpecError,
    sensors_from_spec,
    sensors_from_table,
)
from offboard.model.errors import ParameterFileError, UserError
from sitl_plant.simulation import HeldActuation, VehicleSim
from offboard.model.state import VehicleState
from offboard.model.tomlfile import Fields
from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle

PAPER = load_vehicle(PAPER_VEHICLE_FILE)
DT = 0.05  # the paper's To


def constant_acceleration(acc, n: int, dt: float = DT, euler=(0.1, -0.2, 4.0)) -> list[VehicleState]:
    """Truth samples of a body moving with a constant acceleration (NED)."""
    acc = np.asarray(acc, dtype=float)
    states = []
    for k in range(n):
        t = k * dt
        states.append(
            VehicleState(
                time_s=t,
                pos_ned_m=np.array([1.0, 2.0, -3.0]) + 0.5 * acc * t * t,
                vel_ned_m_s=acc * t,
                acc_ned_m_s2=acc.copy(),
                euler_rad=np.array(euler),
                euler_rate_rad_s=np.array([0.3, -0.1, 0.2]),
                body_rate_frd_rad_s=euler_rate_matrix(np.array(euler), "zyx") @ [0.3, -0.1, 0.2],
                quat_wxyz=quat_from_euler(*euler),
            )
        )
    return states


def flight(n_samples: int = 60) -> list[VehicleState]:
    """Truth samples of a real rigid-body flight with changing accelerations."""
    sim = VehicleSim(rb.RigidBodyModel(PAPER), ground=False, initial_pos_ned_m=np.array([0.0, 0.0, -5.0]))
    sim.x[rb.ROTORS] = rb.hover_rotor_speed(PAPER)
    weight = PAPER.mass_kg * PAPER.gravity_m_s2
    states = []
    for k in range(n_samples):
        sim.actuation = HeldActuation(weight * (1.0 + 0.2 * math.sin(k / 5)), np.array([0.01, -0.02, 0.003]) * math.cos(k / 7))
        sim.step(50)
        states.append(sim.truth())
    return states


def errors(sensors, truths) -> dict[str, np.ndarray]:
    measured = [sensors.measure(t) for t in truths]
    return {
        name: np.array([getattr(m, name) - getattr(t, name) for m, t in zip(measured, truths)])
        for name in ("pos_ned_m", "vel_ned_m_s", "acc_ned_m_s2", "euler_rad", "euler_rate_rad_s", "body_rate_frd_rad_s")
    }


def test_clean_is_the_truth() -> None:
    for truth in flight(10):
        assert CleanSensors().measure(truth) is truth


def test_paper_noise_with_zero_fraction_is_the_truth_exactly() -> None:
    sensors = PaperAccelNoise(0.0, seed=1)
    for truth in flight():
        measured = sensors.measure(truth)
        for name in ("pos_ned_m", "vel_ned_m_s", "acc_ned_m_s2", "euler_rad", "quat_wxyz"):
            assert_allclose(getattr(measured, name), getattr(truth, name), rtol=0, atol=1e-12)


def test_paper_velocity_error_grows_as_integrated_five_percent_acceleration_noise() -> None:
    acc = np.array([2.0, -0.5, 0.0])
    n = 4001
    err = errors(PaperAccelNoise(0.05, seed=2), constant_acceleration(acc, n))
    steps = np.diff(err["vel_ned_m_s"], axis=0)
    # each step adds eta dt with eta ~ N(0, (0.05 |a|)^2): std 0.05 |a| dt per axis
    assert_allclose(steps[:, :2].std(axis=0), 0.05 * np.abs(acc[:2]) * DT, rtol=0.05)
    assert_allclose(steps[:, :2].mean(axis=0), 0.0, atol=4 * 0.05 * 2.0 * DT / math.sqrt(n))
    assert_allclose(err["vel_ned_m_s"][:, 2], 0.0, atol=0)  # no acceleration, no noise
    # acceleration readings: truth + eta
    assert_allclose(err["acc_ned_m_s2"][:, :2].std(axis=0), 0.05 * np.abs(acc[:2]), rtol=0.05)
    # a random walk: the error spreads as sqrt(n)
    assert np.abs(err["vel_ned_m_s"][-1, 0]) > 0.0
    # position integrates the velocity error (trapezoid)
    e_v = err["vel_ned_m_s"]
    assert_allclose(np.diff(err["pos_ned_m"], axis=0), 0.5 * DT * (e_v[1:] + e_v[:-1]), atol=1e-12)
    # attitude and rates untouched
    for name in ("euler_rad", "euler_rate_rad_s", "body_rate_frd_rad_s"):
        assert_allclose(err[name], 0.0, atol=0)


def test_paper_noise_scales_with_the_acceleration() -> None:
    small = errors(PaperAccelNoise(0.05, seed=3), constant_acceleration([1.0, 0, 0], 2000))
    large = errors(PaperAccelNoise(0.05, seed=3), constant_acceleration([4.0, 0, 0], 2000))
    ratio = np.diff(large["vel_ned_m_s"][:, 0]) / np.diff(small["vel_ned_m_s"][:, 0])
    assert_allclose(ratio, 4.0, rtol=1e-9)  # same seed, same draws, four times the size


def test_paper_noise_restarts_when_time_goes_back() -> None:
    sensors = PaperAccelNoise(0.05, seed=4)
    truths = constant_acceleration([3.0, 1.0, -1.0], 50)
    for truth in truths:
        sensors.measure(truth)
    again = sensors.measure(truths[0])
    assert_allclose(again.vel_ned_m_s, truths[0].vel_ned_m_s, atol=0)
    assert_allclose(again.pos_ned_m, truths[0].pos_ned_m, atol=0)


@pytest.mark.parametrize("make", [lambda seed: PaperAccelNoise(0.05, seed), lambda seed: ImuNoise(seed=seed)])
def test_noise_is_reproducible_from_its_seed(make) -> None:
    truths = flight(30)
    first = errors(make(5), truths)
    again = errors(make(5), truths)
    other = errors(make(6), truths)
    for name in first:
        assert_allclose(first[name], again[name], atol=0)
    assert not np.allclose(first["vel_ned_m_s"], other["vel_ned_m_s"])
    sensors = make(5)
    errors(sensors, truths)
    sensors.reset()
    assert_allclose(errors(sensors, truths)["vel_ned_m_s"], first["vel_ned_m_s"], atol=0)


def test_imu_noise_has_the_stated_deviations() -> None:
    truths = constant_acceleration([0.5, 0.0, -0.2], 6000)
    err = errors(ImuNoise(0.1, 0.2, 0.01, 0.05, 0.3, seed=7), truths)
    assert_allclose(err["pos_ned_m"].std(axis=0), 0.1, rtol=0.05)
    assert_allclose(err["vel_ned_m_s"].std(axis=0), 0.2, rtol=0.05)
    assert_allclose(err["acc_ned_m_s2"].std(axis=0), 0.3, rtol=0.05)
    assert_allclose(err["body_rate_frd_rad_s"].std(axis=0), 0.05, rtol=0.05)
    # a small rotation of std 0.01 per body axis moves each Euler angle by about that much
    assert_allclose(err["euler_rad"].std(axis=0), 0.01, rtol=0.25)
    assert_allclose(err["euler_rad"].mean(axis=0), 0.0, atol=0.001)  # the unwrapped yaw of 4 rad kept


def test_imu_noise_of_zero_is_the_truth() -> None:
    sensors = ImuNoise(0.0, 0.0, 0.0, 0.0, 0.0, seed=1)
    for truth in flight(10):
        measured = sensors.measure(truth)
        for name in ("pos_ned_m", "vel_ned_m_s", "euler_rad", "euler_rate_rad_s", "quat_wxyz"):
            assert_allclose(getattr(measured, name), getattr(truth, name), atol=0)


def test_imu_attitude_noise_is_a_consistent_rotation() -> None:
    truth = constant_acceleration([0, 0, 0], 1, euler=(0.2, 0.3, -1.0))[0]
    measured = ImuNoise(att_std_rad=0.05, seed=8).measure(truth)
    assert np.linalg.norm(measured.quat_wxyz) == pytest.approx(1.0)
    assert_allclose(quat_from_euler(*measured.euler_rad), measured.quat_wxyz, atol=1e-12)
    assert not np.allclose(measured.euler_rad, truth.euler_rad)


# --- specs and tables ----------------------------------------------------------------------------


def test_specs_build_each_model() -> None:
    assert isinstance(sensors_from_spec("clean", 0), CleanSensors)
    paper = sensors_from_spec("paper", 3)
    assert isinstance(paper, PaperAccelNoise) and paper.fraction == 0.05 and paper.seed == 3
    assert sensors_from_spec(" paper:0.1 ", 0).fraction == 0.1
    imu = sensors_from_spec("imu", 0)
    assert isinstance(imu, ImuNoise) and imu.pos_std_m == IMU_DEFAULTS["pos"] and imu.acc_std_m_s2 == IMU_DEFAULTS["acc"]
    imu = sensors_from_spec("imu:pos=0.5,rate=0.02", 0)
    assert (imu.pos_std_m, imu.rate_std_rad_s, imu.vel_std_m_s) == (0.5, 0.02, IMU_DEFAULTS["vel"])


@pytest.mark.parametrize(
    ("spec", "names"),
    [
        ("noisy", "'noisy'"),
        ("", "unknown model"),
        ("paper:lots", "fraction"),
        ("paper:-0.1", "fraction"),
        ("clean:1", "no arguments"),
        ("imu:pos=1,gps=2", "'gps=2'"),
        ("imu:pos", "'pos'"),
        ("imu:pos=x", "pos must be a number"),
        ("imu:pos=1,pos=2", "twice"),
        ("imu:vel=inf", "vel"),
    ],
)
def test_bad_specs_give_one_line_naming_the_part(spec: str, names: str) -> None:
    with pytest.raises(SensorSpecError) as info:
        sensors_from_spec(spec, 0)
    assert names in str(info.value) and "\n" not in str(info.value)
    assert isinstance(info.value, ValueError) and isinstance(info.value, UserError)


def test_tables_build_each_model() -> None:
    assert isinstance(sensors_from_table(Fields({"model": "clean"}, "s.toml", "sensors."), 0), CleanSensors)
    paper = sensors_from_table(Fields({"model": "paper", "accel_noise_fraction": 0.02}, "s.toml", "sensors."), 9)
    assert isinstance(paper, PaperAccelNoise) and paper.fraction == 0.02 and paper.seed == 9
    imu = sensors_from_table(Fields({"model": "imu", "vel_std_m_s": 0.3}, "s.toml", "sensors."), 0)
    assert isinstance(imu, ImuNoise) and imu.vel_std_m_s == 0.3 and imu.pos_std_m == IMU_DEFAULTS["pos"]


@pytest.mark.parametrize(
    ("table", "where"),
    [
        ({}, "s.toml: sensors.model"),
        ({"model": "gps"}, "s.toml: sensors.model"),
        ({"model": "paper", "accel_noise_fraction": -1}, "s.toml: sensors.accel_noise_fraction"),
        ({"model": "paper", "pos_std_m": 0.1}, "s.toml: sensors.pos_std_m"),  # an imu key
        ({"model": "imu", "att_std_rad": "big"}, "s.toml: sensors.att_std_rad"),
    ],
)
def test_bad_tables_name_the_file_and_field(table: dict, where: str) -> None:
    with pytest.raises(ParameterFileError, match=f"^{re.escape(where)}: "):
        sensors_from_table(Fields(table, "s.toml", "sensors."), 0)
