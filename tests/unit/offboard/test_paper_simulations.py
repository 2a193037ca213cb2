"""The paper's three simulations (Section 4), run from their scenario files in missions/."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from offboard.cli import main
from offboard.errors import UserError
from offboard.inprocess import run_scenario
from offboard.metrics import summarize
from offboard.record import FlightStatus
from offboard.scenario import load_scenario
from helpers import REPO

MISSIONS = REPO / "missions"


def fly(name: str):
    scenario = load_scenario(MISSIONS / name)
    record = run_scenario(scenario)
    return scenario, record, summarize(record)


def closed_form_z_error_m(params, true_mass_kg: float) -> float:
    """Steady-state z error (reference minus actual, up) from a mass error: docs/reproduction.md."""
    k = params.gains
    to, g = params.sample_time_s, params.gravity_m_s2
    return g * to**2 * (true_mass_kg / params.mass_kg - 1.0) / ((1.0 - k.kx5) * (1.0 - k.kx6))


@pytest.fixture(scope="module")
def sim1():
    return fly("paper-sim1.toml")


@pytest.mark.slow
def test_sim1_converges_in_every_phase(sim1):
    scenario, record, summary = sim1
    assert record.status is FlightStatus.COMPLETE, record.status_detail
    for hold in ("hold-12m", "descent"):
        steady = summary.phase(hold).steady_state_m
        assert steady is not None and abs(steady["3d"]) < 1e-3, (hold, steady)
    t, err = record["t_s"], np.linalg.norm(record.error_ned_m, axis=1)
    late_helix = (t > 8.0) & (t < 12.0)
    assert np.sqrt(np.mean(err[late_helix] ** 2)) < 0.05  # the helix is tracked (Fig. 5)
    assert err[-1] < 1e-3  # and the flight ends on the origin


def test_sim1_reference_switches_ask_for_considerable_actions(sim1):
    """Fig. 6: at the switches the unbounded thrust spikes far beyond hover (and reverses)."""
    _, record, summary = sim1
    hover = 0.5 * 9.81
    assert summary.peak_thrust_n > 20 * hover
    assert summary.min_thrust_n < 0


def test_sim1_as_the_paper_states_it_diverges_at_the_start():
    _, record, _ = fly("paper-sim1-as-stated.toml")
    assert record.status is FlightStatus.DIVERGED
    assert record["t_s"][-1] < 1.0  # the 2.8 m initial step, docs/reproduction.md


def test_sim1_with_held_torques_diverges_at_the_first_large_transient():
    _, record, _ = fly("paper-sim1-held-torque.toml")
    assert record.status is FlightStatus.DIVERGED
    assert record["t_s"][-1] < 1.0


def test_sim2_noise_free_z_error_matches_its_closed_form():
    scenario, record, _ = fly("paper-sim2-noise-free.toml")
    assert record.status is FlightStatus.COMPLETE, record.status_detail
    t = record["t_s"]
    late = (t > 9.0) & (t < 12.0)
    z_error_up = -np.mean(record.error_ned_m[late, 2])  # NED down error -> up error
    expected = closed_form_z_error_m(scenario.controller, scenario.vehicle.mass_kg)
    assert expected == pytest.approx(-0.8175, abs=1e-4)
    assert z_error_up == pytest.approx(expected, rel=0.02)


@pytest.mark.slow
def test_sim2_with_noise_is_reproducible_and_drifts_as_integrated_noise_does():
    """Position and speed integrated from noisy accelerations drift (docs/reproduction.md):
    the flight completes, its true error exceeds the noise-free run's, and a seed repeats it."""
    _, record, _ = fly("paper-sim2.toml")
    _, again, _ = fly("paper-sim2.toml")
    _, clean, _ = fly("paper-sim2-noise-free.toml")
    assert record.status is FlightStatus.COMPLETE, record.status_detail
    np.testing.assert_array_equal(record["pos_ned_m"], again["pos_ned_m"])
    late = (record["t_s"] > 9.0) & (record["t_s"] < 12.0)
    noisy_err = np.linalg.norm(record.error_ned_m[late], axis=1).mean()
    clean_err = np.linalg.norm(clean.error_ned_m[late], axis=1).mean()
    assert noisy_err > clean_err + 0.1


@pytest.mark.slow
def test_sim2_with_the_integral_option_loses_the_z_offset():
    _, record, _ = fly("paper-sim2-integral.toml")
    assert record.status is FlightStatus.COMPLETE, record.status_detail
    late = (record["t_s"] > 9.0) & (record["t_s"] < 12.0)
    assert abs(np.mean(record.error_ned_m[late, 2])) < 0.1  # against 0.82 m without it


@pytest.mark.slow
def test_sim2_over_the_whole_mission_diverges_at_the_yaw_switch():
    _, record, _ = fly("paper-sim2-as-stated.toml")
    assert record.status is FlightStatus.DIVERGED
    assert 12.0 <= record["t_s"][-1] < 13.0


def distance_to_square_m(north: float, east: float, side: float = 5.0) -> float:
    corners = np.array([(0, 0), (side, 0), (side, side), (0, side), (0, 0)], dtype=float)
    point = np.array([north, east])
    best = math.inf
    for a, b in zip(corners[:-1], corners[1:]):
        d = b - a
        u = np.clip(np.dot(point - a, d) / d.dot(d), 0.0, 1.0)
        best = min(best, float(np.linalg.norm(point - (a + u * d))))
    return best


@pytest.mark.slow
def test_sim3_turns_the_square_corners_along_curves():
    """At each corner the velocity reference jumps: the path leaves the square in a curve of a few
    centimetres (this law is far more aggressive than the paper's plots) and rejoins it mid-side."""
    _, record, _ = fly("paper-sim3.toml")
    assert record.status is FlightStatus.COMPLETE, record.status_detail
    pos, t = record["pos_ned_m"], record["t_s"]
    for corner_time in (10.0, 15.0, 20.0):  # (5, 5), (0, 5), back to (0, 0)
        around = (t > corner_time - 0.5) & (t < corner_time + 2.0)
        deviation = max(distance_to_square_m(n, e) for n, e, _ in pos[around])
        assert 0.02 < deviation < 0.5, (corner_time, deviation)
        mid_side = np.argmin(np.abs(t - (corner_time + 2.5)))
        assert distance_to_square_m(*pos[mid_side, :2]) < 0.01
        assert abs(pos[mid_side, 2] + 5.0) < 0.1  # at 5 m height (the corner also dips z)
    assert np.linalg.norm(record.error_ned_m[-1]) < 0.01  # settles at the end


@pytest.mark.slow
def test_rigid_body_needs_the_yaw_aware_law_at_psi_pi_over_2():
    _, aware, aware_summary = fly("paper-sim1-rigid-body.toml")
    _, plain, _ = fly("paper-sim1-rigid-body-plain.toml")
    assert aware.status is FlightStatus.COMPLETE, aware.status_detail
    t = aware["t_s"]
    late = (t > 8.0) & (t < 12.0)
    assert np.sqrt(np.mean(np.sum(aware.error_ned_m[late] ** 2, axis=1))) < 0.3
    # without it the law pushes sideways where it means forward: the vehicle flies off (or tips over)
    late_plain = plain["t_s"] > 8.0
    assert plain.status is FlightStatus.DIVERGED or np.min(np.linalg.norm(plain.error_ned_m[late_plain], axis=1)) > 10.0


@pytest.mark.slow
def test_simulate_command_prints_one_json_object(tmp_path, capsys):
    code = main(["simulate", str(MISSIONS / "paper-sim1.toml"), "--json", "--no-plots", "--run-dir", str(tmp_path)])
    assert code == 0
    payload = json.loads(capsys.readouterr().out)
    phases = {p["name"]: p for p in payload["phases"]}
    assert {"whole flight", "after 5 s", "helix", "hold-12m", "descent"} <= set(phases)
    helix = phases["helix"]
    assert helix["start_s"] == 0.0 and helix["end_s"] == pytest.approx(12.0)
    for axis in ("north", "east", "down", "3d"):
        stats = helix["axes"][axis]
        assert set(stats) == {"rms_m", "max_m", "mean_m"}
        assert stats["max_m"] >= stats["rms_m"] >= 0
    assert (tmp_path / "summary.json").is_file() and (tmp_path / "series.csv").is_file()


def test_simulate_command_exit_code_says_it_diverged(tmp_path, capsys):
    code = main(["simulate", str(MISSIONS / "paper-sim1-as-stated.toml"), "--no-plots", "--run-dir", str(tmp_path)])
    assert code == FlightStatus.DIVERGED.exit_code
    assert "diverged" in capsys.readouterr().out


@pytest.mark.parametrize(
    "edit, message",
    [
        (('model = "paper"', 'model = "blimp"'), "scenario.model: expected one of paper, rigid-body, got 'blimp'"),
        (('mission = "paper-helix.toml"', 'mission = "nowhere.toml"'), "scenario: mission: no mission file 'nowhere.toml'"),
        (("physics_dt_s = 0.001", "physics_dt_s = 0.003"), "integer multiple"),
        (('sensors = "clean"', 'sensors = "sonar"'), "scenario.sensors"),
        (("kx5 = 0.9", "kx5 = 1.5"), "controller.gains.kx5: must lie in (0, 1), got 1.5"),
        (("seed = 1", "seed = 1\nspeed = 3"), "scenario.speed: unknown field"),
        (("sample_time_s = 0.05", 'sample_time_s = 0.05\nsetpoint_output = "up"'), "controller.law.setpoint_output: expected one of"),
        # a controller designed for another loop than the drive flies (offboard fly refuses another output likewise)
        (("sample_time_s = 0.05", 'sample_time_s = 0.05\nsetpoint_output = "rates"'),
         "designed for body-rate setpoints ([law] setpoint_output = \"rates\"), which no in-process drive flies"),
        (("sample_time_s = 0.05", 'sample_time_s = 0.05\nsetpoint_output = "attitude"'),
         'designed for an autopilot\'s attitude loop ([law] setpoint_output = "attitude"): fly them with drive = "px4"'),
    ],
)
def test_bad_scenario_files_give_one_line(tmp_path, capsys, edit, message):
    text = (MISSIONS / "paper-sim1.toml").read_text()
    old, new = edit
    assert old in text
    text = text.replace(old, new, 1).replace('"../sitl_plant/', f'"{MISSIONS.parent}/sitl_plant/')
    path = tmp_path / "bad.toml"
    path.write_text(text.replace('mission = "paper-helix.toml"', f'mission = "{MISSIONS / "paper-helix.toml"}"'))
    with pytest.raises(UserError) as info:
        load_scenario(path)
    assert message in str(info.value) and str(info.value).startswith("bad.toml: ")
    assert main(["simulate", str(path), "--no-plots", "--run-dir", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_a_drive_override_the_controller_was_not_designed_for_is_one_line(tmp_path, capsys):
    """``--drive`` over a scenario whose controller says what it was designed for: the same check
    as the file's own drive, in one line naming the override."""
    text = (MISSIONS / "paper-sim1.toml").read_text().replace("sample_time_s = 0.05", 'sample_time_s = 0.05\nsetpoint_output = "attitude"', 1)
    text = text.replace('drive = "inner-loop"', 'drive = "px4"', 1).replace('model = "paper"', 'model = "rigid-body"', 1)
    text = text.replace('"../sitl_plant/', f'"{MISSIONS.parent}/sitl_plant/').replace('mission = "paper-helix.toml"', f'mission = "{MISSIONS / "paper-helix.toml"}"')
    path = tmp_path / "designed.toml"
    path.write_text(text)
    assert load_scenario(path).drive == "px4"  # the loop it was designed for: loads
    assert main(["simulate", str(path), "--drive", "held-torque", "--no-plots", "--run-dir", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "with --drive held-torque: " in err[0] and 'fly them with drive = "px4"' in err[0], err


def test_a_mission_given_as_a_scenario_says_what_to_do(capsys):
    """The issue: `offboard simulate paper-helix.toml` said only "scenario: missing"."""
    assert main(["simulate", str(MISSIONS / "paper-helix.toml"), "--no-plots"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"offboard simulate: error: paper-helix.toml: a mission file ([mission]), not a scenario ([scenario]): fly it "
                   f"with `offboard fly {MISSIONS / 'paper-helix.toml'}`, or name it in a scenario, as "
                   "missions/paper-sim1.toml names paper-helix.toml"]  # fmt: skip


def test_every_bundled_scenario_loads():
    files = sorted(MISSIONS.glob("paper-sim*.toml"))
    assert len(files) >= 3
    for path in files:
        scenario = load_scenario(path)
        assert scenario.controller.sample_time_s == 0.05
        assert math.isfinite(scenario.flight_duration_s)
