"""offboard.record.control_row: the one place a control sample becomes a record row, for the
in-process run, the MAVLink flight and the re-run of a log."""

from __future__ import annotations

import numpy as np
from numpy.testing import assert_allclose

from offboard import codec
from offboard.controller import PAPER_CONTROLLER_FILE, load_controller
from offboard.controller.paper import PaperController
from offboard.inprocess import Scenario, run_scenario
from offboard.record import COLUMNS, RecordBuilder, control_row
from offboard.trajectory import Line
from offboard.trajectory.base import Reference
from pymavlink.dialects.v20 import common as mavlink
from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle


def sample():
    params = load_controller(PAPER_CONTROLLER_FILE)
    att = mavlink.MAVLink_attitude_message(1500, 0.1, -0.05, 0.3, 0.01, 0.02, -0.03)
    lpn = mavlink.MAVLink_local_position_ned_message(1500, 0.5, -0.25, -1.0, 0.1, 0.2, -0.3)
    measured = codec.measured_state(att, lpn)
    ref = Reference(np.array([1.0, 0.0, -2.0]), yaw_rad=0.4)
    command = PaperController(params).step(measured, ref, ref)
    return measured, ref, command


def test_a_row_has_every_column_from_the_state_the_reference_and_the_law():
    measured, ref, command = sample()
    out = command.law
    row = control_row(1.5, measured, ref, command)
    assert set(row) == set(COLUMNS)
    assert row["t_s"] == 1.5 and row["ref_yaw_rad"] == 0.4 and row["thrust_n"] == out.law.thrust_n
    assert_allclose(row["pos_ned_m"], [0.5, -0.25, -1.0]) and assert_allclose(row["ref_pos_ned_m"], [1.0, 0.0, -2.0])
    assert_allclose(row["euler_rad"], measured.euler_rad, rtol=0, atol=0)
    assert row["ref_euler_rad"] == (out.law.roll_ref_rad, out.law.pitch_ref_rad, out.law.yaw_ref_rad)
    assert_allclose(row["torques_nm"], out.torques_nm) and assert_allclose(row["tau_tilde"], out.law.tau_tilde)
    builder = RecordBuilder()
    builder.append(**row)
    assert len(builder.build()) == 1


def test_a_baselines_command_makes_a_row_with_nan_where_it_has_no_value():
    from offboard.baselines import Px4PositionController

    measured, ref, _ = sample()
    command = Px4PositionController(0.5, 0.05).step(measured, ref, ref)
    row = control_row(1.5, measured, ref, command)
    assert set(row) == set(COLUMNS) and row["thrust_n"] == command.thrust_n
    assert np.all(np.isnan(row["tau_tilde"])) and np.all(np.isnan(row["torques_nm"]))  # PX4's cascade gives neither
    assert row["ref_euler_rad"] == command.attitude_ref_euler_rad
    RecordBuilder().append(**row)


def test_the_in_process_run_records_through_it(monkeypatch):
    import offboard.inprocess as inprocess

    rows = []
    real = inprocess.control_row
    monkeypatch.setattr(inprocess, "control_row", lambda *a: rows.append(real(*a)) or rows[-1])
    vehicle = load_vehicle(PAPER_VEHICLE_FILE)
    trajectory = Line((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), 1.0, yaw_rad=0.0)
    record = run_scenario(Scenario("row", trajectory, vehicle, load_controller(PAPER_CONTROLLER_FILE)))
    assert len(rows) == len(record) == 21
    for name in COLUMNS:
        assert_allclose(np.asarray([r[name] for r in rows], dtype=float).reshape(record[name].shape), record[name], rtol=0, atol=0)
