"""``offboard tune``: a controller file designed for a vehicle, from a file or a live vehicle."""

from __future__ import annotations

import json
import math
import re
import subprocess
import time

import pytest

from offboard.cli import main
from offboard.controller import PAPER_CONTROLLER_FILE, load_controller
from offboard.controller.design import AxisGains, MarginSpec, analyse_axis, axis_plants
from offboard.controller.tuning import design_for_vehicle, vehicle_values
from offboard.demo import free_udp_ports, stop_process
from offboard.missions import MISSIONS_DIR
from sitl_plant.params import plant_params
from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle
from helpers.flights import ENV, PY
from helpers import PX4_PARAMS_JSON


def plant_values() -> dict[str, float]:
    table = plant_params(load_vehicle(PAPER_VEHICLE_FILE))
    return {name: table[name] for name in table}


def tune(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["tune", *args])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.slow
def test_tune_a_vehicle_file_writes_the_designed_controller(tmp_path, capsys):
    out = tmp_path / "tuned.toml"
    code, _, err = tune(capsys, "--vehicle", str(PAPER_VEHICLE_FILE), "--output", str(out))
    assert code == 0, err
    params = load_controller(out)  # a controller file offboard fly --controller reads
    design = design_for_vehicle(vehicle_values(plant_values()), sample_time_s=0.05)
    h, v = design.horizontal, design.vertical
    g = params.gains
    assert (g.kx1, g.kx2, g.kx3, g.kx4, g.kx5, g.kx6) == (h.k_pos, h.k_vel, h.k_pos, h.k_vel, v.k_pos, v.k_vel)
    assert (g.kx7, g.kx8) == (0.7, 0.67)  # Table I's: the autopilot closes the attitude loop
    assert params.tilt_lead == float(h.lead) and params.reference_lead_s2 == pytest.approx(design.reference_lead_s2, abs=1e-6)
    assert params.limits.tilt_cone and params.limits.speed_down_max_m_s == 1.5
    assert params.setpoint_output == "attitude"  # what it was designed for: offboard fly flies it so
    # ... and offboard fly --controller FILE flies it with those bounds (it once dropped all but the tilt and thrust)
    from offboard.codec import Scaling
    from offboard.flight import ControllerChoice, resolve_controller

    values = plant_values()
    flown, _ = resolve_controller(ControllerChoice(base=params, from_file=True), "rigid-body", values, Scaling(values["SIM_THR_MAX"]))
    assert flown.limits == params.limits
    assert params.mass_kg == 0.5 and params.euler_rate_form == "zyx" and params.yaw_aware
    # what it achieved is printed, one line per axis, and kept in the file's comments
    lines = err.strip().splitlines()
    assert [line.split()[0] for line in lines[:3]] == ["north", "east", "up"] and all("gain margin" in x for x in lines[:3])
    assert lines[3].startswith("Table I (kx1 0.78, kx2 0.8) on this loop: |pole| max 0.98")  # barely stable
    assert "phase margin" in out.read_text()


@pytest.mark.slow
def test_tune_from_a_parameter_file_equals_tune_from_the_vehicle_file(tmp_path, capsys):
    values = plant_values()
    as_json = tmp_path / "params.json"
    as_json.write_text(json.dumps({k: {"value": v} for k, v in values.items()}))  # PX4 params.json layout
    as_qgc = tmp_path / "vehicle.params"
    as_qgc.write_text("# Onboard parameters\n" + "".join(f"1\t1\t{k}\t{v!r}\t9\n" for k, v in values.items()))
    files = []
    for name, args in (("a", ("--vehicle", str(PAPER_VEHICLE_FILE))), ("b", ("--params", str(as_json))),
                       ("c", ("--params", str(as_qgc)))):  # fmt: skip
        path = tmp_path / f"{name}.toml"
        code, _, err = tune(capsys, *args, "--output", str(path))
        assert code == 0, err
        files.append(load_controller(path))
    assert files[0] == files[1] == files[2]


def test_tune_to_stdout_and_a_margin_figure(tmp_path, capsys):
    png = tmp_path / "margins.png"
    code, out, err = tune(capsys, "--vehicle", str(PAPER_VEHICLE_FILE), "--latency", "0.02", "--plot", str(png))
    assert code == 0, err
    assert out.startswith("# The law's gains") and "[gains]" in out and "latency 20 ms" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("args, message", [
    (("--params", "/nonexistent/p.json"), "--params /nonexistent/p.json: No such file"),
    (("--vehicle", str(PAPER_VEHICLE_FILE), "--sample-time", "0"), "--sample-time must be > 0"),
    (("--vehicle", str(PAPER_VEHICLE_FILE), "--plot", "x.txt"), "--plot x.txt: expected a .png"),
    (("--vehicle", str(PAPER_VEHICLE_FILE), "--gain-margin", "40"), "no gains with closed-loop rates"),
    (("--vehicle", str(PAPER_VEHICLE_FILE), "--sensitivity-peak", "1"), "--sensitivity-peak must be > 1, got 1.0"),
    (("--vehicle", str(PAPER_VEHICLE_FILE), "--sensitivity-peak", "nan"), "--sensitivity-peak must be > 1, got nan"),
    (("--vehicle", str(PAPER_VEHICLE_FILE), "--sensitivity-peak", "1.05"), "sensitivity peak 1.05"),
    (("--vehicle", str(PAPER_VEHICLE_FILE), "--output", "/nonexistent/dir/x.toml"), "--output /nonexistent/dir/x.toml"),
    (("--vehicle", str(PAPER_VEHICLE_FILE), "--setpoint-output", "rates", "--search", "s.toml"), "searches --setpoint-output attitude only"),
])  # fmt: skip
def test_bad_input_is_one_line(args, message, capsys):
    code, _, err = tune(capsys, *args)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize("content, message", [
    ('{"SIM_MASS": "heavy"}', "SIM_MASS: expected a finite number"),
    ("[1, 2]", "expected an object of name -> value"),
    ("{1: 2}", "not JSON"),
    ('{"SIM_THR_MAX": 19.6, "SIM_MASS": 0.5}', "SIM_TQ_RP_MAX nor SIH_T_MAX"),
    ('{"SIM_MASS": 0.5}', "no SIM_THR_MAX or SIH_T_MAX"),
    ("1\t1\tSIM_MASS\tlots\t9\n", ":1: SIM_MASS: not a number"),
])  # fmt: skip
def test_bad_parameter_files_are_one_line(tmp_path, content, message, capsys):
    path = tmp_path / "p.json"
    path.write_text(content)
    code, _, err = tune(capsys, "--params", str(path))
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err


def test_sih_parameters_become_the_vehicles_values():
    values = vehicle_values({"SIH_MASS": 1.0, "SIH_T_MAX": 5.0, "SIH_IXX": 0.025, "SIH_L_ROLL": 0.2, "SIH_T_TAU": 0.05,
                             "SIH_KDV": 1.0, "CA_ROTOR_COUNT": 4})  # fmt: skip
    assert values["SIM_THR_MAX"] == 20.0 and values["SIM_MASS"] == 1.0 and values["SIM_IXX"] == 0.025
    assert values["SIM_ARM_LEN"] == 0.2 and values["SIM_MOT_TAU"] == 0.05 and values["SIM_KDV"] == 1.0


@pytest.mark.e2e
def test_tune_reads_a_live_vehicle(tmp_path, capsys):
    """--connect: the parameters come over MAVLink from a running sitl-plant."""
    plant_port, our_port = free_udp_ports(2)
    plant = subprocess.Popen([PY, "-m", "sitl_plant.cli", "--api-bind", f"127.0.0.1:{plant_port}", "--api-remote",
                              f"127.0.0.1:{our_port}", "--gcs-bind", "none", "--quiet", "--vehicle", str(PAPER_VEHICLE_FILE)],
                             env=ENV)  # fmt: skip  (the vehicle the file below names: the same design both ways)
    try:
        time.sleep(0.5)
        live = tmp_path / "live.toml"
        code, _, err = tune(capsys, "--connect", f"udpin:127.0.0.1:{our_port}", "--output", str(live))
        assert code == 0, err
    finally:
        stop_process(plant)
    from_file = tmp_path / "file.toml"
    assert tune(capsys, "--vehicle", str(PAPER_VEHICLE_FILE), "--output", str(from_file))[0] == 0
    # float32 on the wire: the same design, the same gains to the file's 4 decimals
    a, b = load_controller(live), load_controller(from_file)
    assert a.gains == b.gains and a.tilt_lead == b.tilt_lead
    assert math.isclose(a.mass_kg, b.mass_kg, rel_tol=1e-6)


def test_margin_spec_defaults_are_the_documented_ones():
    assert MarginSpec() == MarginSpec(gain_margin=2.0, phase_margin_deg=45.0, delay_margin_s=0.05)


DOC = PAPER_VEHICLE_FILE.parents[2] / "docs" / "controller-design.md"


def doc_blocks() -> list[str]:
    parts = DOC.read_text().split("```")
    return [parts[i].strip() for i in range(1, len(parts), 2)]


def test_the_design_doc_quotes_what_offboard_tune_prints_for_the_plant(capsys):
    code, _, err = tune(capsys, "--vehicle", str(PAPER_VEHICLE_FILE))
    assert code == 0 and err.strip() == doc_blocks()[0]


@pytest.mark.skipif(not PX4_PARAMS_JSON.is_file(), reason="no ../shared/px4-sitl/params.json (PX4 SITL's parameters)")
def test_the_design_doc_quotes_what_offboard_tune_prints_for_px4(capsys):
    code, _, err = tune(capsys, "--params", str(PX4_PARAMS_JSON), "--latency", "0.01")
    assert code == 0 and err.strip() == doc_blocks()[1]


def test_the_design_doc_quotes_what_offboard_tune_prints_for_body_rates(capsys):
    code, _, err = tune(capsys, "--vehicle", str(PAPER_VEHICLE_FILE), "--setpoint-output", "rates")
    quoted = [block for block in doc_blocks() if block.startswith("angles (rates)")]
    assert code == 0 and quoted == [err.strip()]


def test_the_design_doc_quotes_the_proportional_loops_settling_without_the_integral():
    """docs/controller-design.md, the body-rate output: "without it the loops settle as the attitude
    output's do: 2 % in A s horizontally (attitude output B s) and C s vertically", each the 2 %
    settling time of the designed loop with its velocity integral off (what ``step_hold_s`` reads)."""
    quoted = re.search(r"2 % in ([0-9.]+) s horizontally \(attitude output ([0-9.]+) s\) and ([0-9.]+) s vertically",
                       " ".join(DOC.read_text().split()))  # fmt: skip
    assert quoted, "the sentence is gone from docs/controller-design.md"
    values = vehicle_values(plant_values())

    def settling(body_rates: bool, vertical: bool) -> float:
        design = design_for_vehicle(values, sample_time_s=0.05, body_rates=body_rates)
        north, _, up = axis_plants(design.model, design.sample_time_s)
        plant, axis = (up, design.up) if vertical else (north, design.north)
        g = axis.gains
        return analyse_axis(plant, AxisGains(g.k_pos, g.k_vel, g.lead), design.sample_time_s).settling_time_s

    computed = (settling(True, False), settling(False, False), settling(True, True))
    assert [float(x) for x in quoted.groups()] == [round(t, 1) for t in computed]


def test_the_velocity_integral_is_designed_unless_switched_off(capsys, tmp_path):
    on, off = tmp_path / "on.toml", tmp_path / "off.toml"
    assert tune(capsys, "--vehicle", str(PAPER_VEHICLE_FILE), "--output", str(on))[0] == 0
    assert tune(capsys, "--vehicle", str(PAPER_VEHICLE_FILE), "--no-integral", "--output", str(off))[0] == 0
    assert load_controller(on).velocity_integral_gain_per_s2 > 0.0
    assert load_controller(off).velocity_integral_gain_per_s2 == 0.0
    # the same position and velocity gains: the integral is searched on top of them
    assert load_controller(on).gains.kx1 == load_controller(off).gains.kx1


@pytest.mark.slow
def test_tune_for_a_body_rate_output_designs_the_angle_gains_too(tmp_path, capsys):
    """--setpoint-output rates: the law closes the attitude loop (kx7..kx10 designed, on the rate
    loop; no tilt lead), said first in what it prints and in the file's comments."""
    out = tmp_path / "rates.toml"
    code, _, err = tune(capsys, "--vehicle", str(PAPER_VEHICLE_FILE), "--setpoint-output", "rates", "--output", str(out))
    assert code == 0, err
    params = load_controller(out)
    design = design_for_vehicle(vehicle_values(plant_values()), sample_time_s=0.05, body_rates=True)
    angle, h = design.model.angle_gains, design.horizontal
    assert angle is not None
    g = params.gains
    assert (g.kx7, g.kx8, g.kx9, g.kx10) == (angle.k_pos, angle.k_vel, angle.k_pos, angle.k_vel) != (0.7, 0.67, 0.7, 0.67)
    assert (g.kx1, g.kx2) == (h.k_pos, h.k_vel) and params.tilt_lead == 0.0
    assert (g.kx11, g.kx12) == (load_controller(PAPER_CONTROLLER_FILE).gains.kx11, load_controller(PAPER_CONTROLLER_FILE).gains.kx12)
    lines = err.strip().splitlines()
    assert lines[0].startswith("angles (rates) kx7 = kx9") and "phase margin" in lines[0]
    assert "kx1..kx10 designed" in out.read_text() and "fly it with --output rates" in out.read_text()
    assert params.setpoint_output == "rates"  # offboard fly flies it with --output rates, and refuses another


def test_a_files_designed_setpoint_is_what_fly_flies_and_another_is_refused_in_one_line(tmp_path, capsys):
    """A controller file says what its gains were designed for (``[law] setpoint_output``):
    ``offboard fly`` flies that output when --output is not given, and refuses another before it
    connects (a rates design flown through the attitude loop, or an attitude design's Table I angle
    gains closing the rates loop, is a loop no design saw)."""
    from offboard.commands.fly import FlyArgumentError, flown_output

    assert flown_output(None, "rates", tmp_path / "r.toml") == "rates"
    assert flown_output(None, None, None) == "attitude"  # Table I's file says nothing: the attitude
    assert flown_output("actuator", None, None) == "actuator"
    assert flown_output("rates", "rates", tmp_path / "r.toml") == "rates"
    with pytest.raises(FlyArgumentError, match=r"--output attitude: the gains of .*r\.toml were designed for --output rates"):
        flown_output("attitude", "rates", tmp_path / "r.toml")
    rates = PAPER_CONTROLLER_FILE.read_text().replace("[law]", '[law]\nsetpoint_output = "rates"', 1)
    (tmp_path / "r.toml").write_text(rates)
    assert load_controller(tmp_path / "r.toml").setpoint_output == "rates"
    (port,) = free_udp_ports(1)
    code = main(["fly", str(MISSIONS_DIR / "paper-helix.toml"), "--controller", str(tmp_path / "r.toml"), "--output", "attitude",
                 "--connect", f"udpin:127.0.0.1:{port}", "--run-dir", str(tmp_path / "run")])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "were designed for --output rates" in err and "offboard tune --setpoint-output attitude" in err
    assert not (tmp_path / "run").exists()  # refused before anything was flown or written
    (tmp_path / "bad.toml").write_text(rates.replace('"rates"', '"thrust"'))
    with pytest.raises(ValueError, match=r"bad\.toml.*setpoint_output.*attitude, rates"):
        load_controller(tmp_path / "bad.toml")
