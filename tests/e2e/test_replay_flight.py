"""Replay of real flights: `sitl-plant --lockstep` and `offboard fly --lockstep` as two processes.

One short mission is flown per output (attitude, actuator); every test reads the logs the two
processes left: the re-run reproduces the logged setpoints exactly, changed gains change them,
the report's numbers are the flight's own, pymavlink's mavlogdump.py reads both logs.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import socket
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from offboard.cli import main
from offboard.controller import PAPER_CONTROLLER_FILE
from offboard.replay import TlogReader, build_record, scan_log

pytestmark = pytest.mark.e2e

BIN = Path(sys.executable).parent
MISSION = """
[mission]
name = "replay-test"
frame = "ned"
angle_unit = "rad"
start = [0, 0, 0]
start_yaw = 0

[[mission.segment]]
type = "hold"
name = "climb"
position = [0, 0, -1]
yaw = 0
until_s = 2.5

[[mission.segment]]
type = "line"
name = "line"
to = [0.8, 0.6, -1.2]
speed_m_s = 0.5

[[mission.segment]]
type = "hold"
name = "hold"
position = [0.8, 0.6, -1.2]
yaw = 0.4
until_s = 6
"""


@dataclass
class Flown:
    run_dir: Path
    mission: Path
    flight_log: Path  # offboard fly's
    plant_log: Path  # sitl-plant's
    summary: dict
    output: str


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def fly(folder: Path, output: str, model: str = "rigid-body", extra: tuple[str, ...] = (), *,
        mission_file: str = "replay-test.toml", mission_text: str = MISSION, plant_extra: tuple[str, ...] = (),
        lockstep: bool = True) -> Flown:  # fmt: skip
    folder.mkdir(parents=True, exist_ok=True)
    mission = folder / mission_file
    mission.write_text(mission_text)
    run_dir = folder / "run"
    port = free_udp_port()
    plant = subprocess.Popen(
        [str(BIN / "sitl-plant"), *(["--lockstep"] if lockstep else []), "--model", model, "--inner-loop", "paper" if model == "paper" else "px4",
         "--api-bind", "127.0.0.1:0",
         "--api-remote", f"127.0.0.1:{port}", "--gcs-bind", "none", "--log", str(folder / "plant.tlog"),
         "--quiet", "--duration", "120", *plant_extra],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )  # fmt: skip
    try:
        done = subprocess.run(
            [str(BIN / "offboard"), "fly", str(mission), "--connect", f"udpin:127.0.0.1:{port}", *(["--lockstep"] if lockstep else []),
             "--output", output, "--model", model, "--run-dir", str(run_dir), "--quiet", "--no-plots", *extra],
            capture_output=True, text=True, timeout=120, cwd=folder,
        )  # fmt: skip
    finally:
        plant.send_signal(signal.SIGINT)
        try:
            plant.wait(timeout=10)
        except subprocess.TimeoutExpired:
            plant.kill()
            plant.wait()
    assert done.returncode == 0, done.stdout + done.stderr
    summary = json.loads((run_dir / "summary.json").read_text())
    return Flown(run_dir, mission, run_dir / "flight.tlog", folder / "plant.tlog", summary, output)


@pytest.fixture(scope="module", params=["attitude", "rates", "actuator"])
def flown(request, tmp_path_factory) -> Flown:
    return fly(tmp_path_factory.mktemp(f"flight-{request.param}"), request.param)


@pytest.fixture(scope="module")
def flown_real_time(tmp_path_factory) -> Flown:
    """make demo's setting: real time, attitude output, the gains designed for the vehicle and the
    law handed the state predicted over the measured latency (and each sample's telemetry age)."""
    return fly(tmp_path_factory.mktemp("flight-real-time"), "attitude", lockstep=False)


@pytest.fixture(scope="module")
def flown_paper_model(tmp_path_factory) -> Flown:
    """The paper's model with the plant's paper inner loop (the law's rates flown as eq. 16)."""
    return fly(tmp_path_factory.mktemp("flight-paper"), "attitude", model="paper")


def integral_controller(folder: Path) -> Path:
    """Table I's gains with integral action (a field summary.json did not always record)."""
    text = PAPER_CONTROLLER_FILE.read_text()
    assert "integral_gain_per_s = 0.0" in text and "yaw_aware = false" in text
    path = folder / "integral.toml"
    path.write_text(text.replace("integral_gain_per_s = 0.0", "integral_gain_per_s = 0.4").replace("yaw_aware = false", "yaw_aware = true"))
    return path


@pytest.fixture(scope="module")
def flown_with_controller_file(tmp_path_factory) -> Flown:
    folder = tmp_path_factory.mktemp("flight-controller-file")
    folder.mkdir(exist_ok=True)
    return fly(folder, "attitude", extra=("--controller", str(integral_controller(folder))))


#: A geo-referenced mission (QGC WPL): take-off to 2 m, 3 m north, land; home at the plant's default.
GEO_MISSION = "\n".join("\t".join(item) for item in (
    ("QGC WPL 110",),
    ("0", "1", "0", "16", "0", "0", "0", "0", "47.397742", "8.545594", "488.0", "1"),
    ("1", "0", "3", "22", "0", "0", "0", "nan", "47.397742", "8.545594", "2.0", "1"),
    ("2", "0", "3", "16", "0", "0", "0", "nan", "47.397769", "8.545594", "2.0", "1"),
    ("3", "0", "3", "21", "0", "0", "0", "nan", "0", "0", "0.0", "1"),
)) + "\n"  # fmt: skip
#: The vehicle's home 1.5 m north of the mission's: the mission is flown 1.5 m south of the vehicle's origin.
GEO_VEHICLE_HOME = f"{47.397742 + 1.5 / 111_195.0:.8f},8.545594,488.0"


@pytest.fixture(scope="module")
def flown_geo(tmp_path_factory) -> Flown:
    return fly(tmp_path_factory.mktemp("flight-geo"), "attitude", mission_file="geo.waypoints", mission_text=GEO_MISSION,
               plant_extra=("--home", GEO_VEHICLE_HOME))  # fmt: skip


def replay_json(capsys, *argv: str) -> tuple[int, dict]:
    code = main(["replay", *argv, "--json", "--no-plots"])
    captured = capsys.readouterr()
    assert captured.out, captured.err
    return code, json.loads(captured.out)


def changed_gains(folder: Path) -> Path:
    text = PAPER_CONTROLLER_FILE.read_text()
    assert "kx1 = 0.78" in text
    path = folder / "changed.toml"
    path.write_text(text.replace("kx1 = 0.78", "kx1 = 0.6").replace("kx3 = 0.77", "kx3 = 0.6"))
    return path


def test_rerun_with_the_flights_controller_reproduces_the_log_exactly(flown, tmp_path, capsys):
    code, payload = replay_json(capsys, str(flown.flight_log), "--rerun", "--mission", str(flown.mission), "--run-dir", str(tmp_path / "r"))
    rerun = payload["rerun"]
    assert code == 0
    assert rerun["output"] == flown.output and rerun["controller"].startswith("the flight's")
    assert rerun["samples"] == payload["samples"] == len(_series(flown)) > 100
    assert rerun["exact"] and rerun["mismatched_samples"] == 0 and rerun["missing_samples"] == 0
    assert set(rerun["max_difference"].values()) == {0.0}


def test_rerun_encodes_with_the_flights_own_setpoint_function(flown, tmp_path, capsys, monkeypatch):
    """codec.command_setpoint is the one encoding: the re-run's every sample goes through it, exactly."""
    from offboard import codec

    calls = []
    original = codec.command_setpoint

    def spy(*args, **kwargs):
        calls.append(kwargs["output"])
        return original(*args, **kwargs)

    monkeypatch.setattr(codec, "command_setpoint", spy)
    code, payload = replay_json(capsys, str(flown.flight_log), "--rerun", "--mission", str(flown.mission), "--run-dir", str(tmp_path / "r"))
    assert code == 0 and payload["rerun"]["exact"]
    assert calls == [flown.output] * payload["rerun"]["samples"]


def test_summary_names_the_mission_and_controller_files_by_full_path(flown, flown_with_controller_file):
    assert flown.summary["mission_file"] == str(flown.mission.resolve())
    assert flown.summary["controller_file"] is None  # the default: the paper's gains, the vehicle's SIM_*
    other = flown_with_controller_file
    assert other.summary["controller_file"] == str((other.mission.parent / "integral.toml").resolve())
    assert other.summary["controller"]["integral_gain_per_s"] == 0.4


def test_rerun_finds_the_mission_from_summary_json_wherever_it_is_run(flown, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # neither beside the log nor here nor among the bundled missions
    code, payload = replay_json(capsys, str(flown.flight_log), "--rerun", "--run-dir", str(tmp_path / "r"))
    assert code == 0 and payload["rerun"]["exact"]
    assert payload["mission"].startswith(str(flown.mission.resolve())) and payload["references"] == "mission"


def _copy_flight(flown: Flown, folder: Path, edit) -> Path:
    """The flight's log and an edited summary.json in ``folder`` (the fixture's stay untouched)."""
    folder.mkdir()
    log = folder / flown.flight_log.name
    log.write_bytes(flown.flight_log.read_bytes())
    summary = json.loads((flown.run_dir / "summary.json").read_text())
    edit(summary)
    (folder / "summary.json").write_text(json.dumps(summary))
    return log


def test_rerun_uses_the_controller_file_named_in_summary_json(flown_with_controller_file, tmp_path, capsys, monkeypatch):
    flown = flown_with_controller_file
    monkeypatch.chdir(tmp_path)
    code, payload = replay_json(capsys, str(flown.flight_log), "--rerun", "--run-dir", str(tmp_path / "r"))
    assert code == 0 and payload["rerun"]["exact"] and payload["rerun"]["samples"] > 100
    assert payload["rerun"]["controller"].startswith("the flight's") and "integral.toml" in payload["rerun"]["controller"]
    # a summary that records no resolved controller: the file it names alone decides (its integral action)
    log = _copy_flight(flown, tmp_path / "bare", lambda s: s.pop("controller"))
    code, payload = replay_json(capsys, str(log), "--rerun", "--run-dir", str(tmp_path / "r2"))
    assert code == 0 and payload["rerun"]["exact"], payload["rerun"]
    assert "integral.toml" in payload["rerun"]["controller"]


def test_rerun_reads_a_summary_from_before_the_file_fields(flown, tmp_path, capsys, monkeypatch):
    def older(summary: dict) -> None:
        del summary["mission_file"], summary["controller_file"]

    log = _copy_flight(flown, tmp_path / "old", older)
    (tmp_path / "old" / flown.mission.name).write_text(flown.mission.read_text())  # found by name, beside the log
    monkeypatch.chdir(tmp_path)
    code, payload = replay_json(capsys, str(log), "--rerun", "--run-dir", str(tmp_path / "r"))
    assert code == 0 and payload["rerun"]["exact"] and payload["rerun"]["controller"].startswith("the flight's")
    assert "named in summary.json" in payload["mission"]


def test_rerun_of_the_plants_log_also_reproduces_it(flown, tmp_path, capsys):
    code, payload = replay_json(capsys, str(flown.plant_log), "--rerun", "--mission", str(flown.mission),
                                "--model", "rigid-body", "--run-dir", str(tmp_path / "r"))  # fmt: skip
    assert code == 0 and payload["rerun"]["exact"], payload["rerun"]
    assert payload["samples"] == len(_series(flown))


def test_rerun_with_changed_gains_shows_the_difference(flown, tmp_path, capsys):
    new = changed_gains(tmp_path)
    run_dir = tmp_path / "r"
    code = main(["replay", str(flown.flight_log), "--rerun", "--controller", str(new), "--mission", str(flown.mission), "--run-dir", str(run_dir), "--quiet"])
    text = capsys.readouterr().out
    assert code == 0
    payload = json.loads((run_dir / "summary.json").read_text())["rerun"]
    assert not payload["exact"] and payload["mismatched_samples"] > 10
    assert max(payload["max_difference"].values()) > 1e-3
    assert payload["first_mismatch"]["t_s"] > 0.0  # the first samples (a hold at the start point) agree
    assert "samples differ" in text and "changed.toml" in text
    assert (run_dir / "rerun.png").stat().st_size > 20_000
    rows = list(csv.DictReader((run_dir / "rerun.csv").open()))
    assert len(rows) == payload["samples"]


def _series(flown: Flown) -> list[dict]:
    return list(csv.DictReader((flown.run_dir / "series.csv").open()))


def test_replayed_record_is_the_flights_record(flown):
    """Sample for sample: the same time_boot_ms, state, references as offboard fly recorded."""
    from offboard.missions import load_mission

    series = _series(flown)
    scan = scan_log(TlogReader(flown.flight_log))
    record = build_record(scan, trajectory=load_mission(flown.mission).trajectory)
    assert_allclose(record.meta["time_boot_ms"], [float(r["time_boot_ms"]) for r in series])
    assert_allclose(record["t_s"], [float(r["t_s"]) for r in series], rtol=0, atol=0)
    for name in ("pos_ned_m", "vel_ned_m_s", "euler_rad", "ref_pos_ned_m"):
        expected = np.array([[float(r[f"{name}_{i}"]) for i in range(3)] for r in series])
        assert_allclose(record[name], expected, rtol=0, atol=0)


def test_report_matches_the_flights_own_summary(flown, tmp_path, capsys):
    code, payload = replay_json(capsys, str(flown.flight_log), "--rerun", "--mission", str(flown.mission), "--run-dir", str(tmp_path / "r"))
    assert code == 0
    ours, theirs = payload, flown.summary
    assert [p["name"] for p in ours["phases"]] == [p["name"] for p in theirs["phases"]]
    for a, b in zip(ours["phases"], theirs["phases"]):
        assert a["samples"] == b["samples"]
        for axis in ("north", "east", "down", "3d"):
            for stat in ("rms_m", "max_m", "mean_m"):
                assert a["axes"][axis][stat] == pytest.approx(b["axes"][axis][stat], rel=1e-12, abs=1e-15)
    for key in ("peak_thrust_n", "min_thrust_n", "peak_tilt_deg", "duration_s"):
        assert ours[key] == pytest.approx(theirs[key], rel=1e-12), key
    assert_allclose(ours["peak_torques_nm"], theirs["peak_torques_nm"], rtol=1e-12)


def test_report_without_rerun_takes_commands_from_the_messages(flown, tmp_path, capsys):
    code, payload = replay_json(capsys, str(flown.flight_log), "--mission", str(flown.mission), "--run-dir", str(tmp_path / "r"))
    assert code == 0 and payload["commands"] == ("attitude" if flown.output == "rates" else flown.output)  # the message kind
    # the thrust sent is u / SIM_THR_MAX in float32: the flight's peak u to float32 precision
    assert payload["peak_thrust_n"] == pytest.approx(flown.summary["peak_thrust_n"], rel=1e-6)
    events = payload["log_report"]["events"]
    modes = [e["text"] for e in events if e["kind"] == "mode"]
    assert "Offboard" in modes and modes[-1] == "Land"
    sources = {(s["system"], s["component"]): s for s in payload["log_report"]["sources"]}
    assert sources[(1, 1)]["role"] == "vehicle" and sources[(245, 191)]["role"] == "onboard controller"
    assert sources[(1, 1)]["lost"] == 0  # loopback, lockstep: nothing lost
    sent = {r["message"]: r["count"] for r in payload["log_report"]["rates"] if r["system"] == 245}
    assert sent == {k: v for k, v in flown.summary["messages"]["sent_by_type"].items()}


def test_mavlogdump_reads_both_logs(flown):
    for log in (flown.flight_log, flown.plant_log):
        done = subprocess.run(
            [sys.executable, str(BIN / "mavlogdump.py"), "--types", "ATTITUDE,LOCAL_POSITION_NED,SET_ATTITUDE_TARGET,"
             "SET_ACTUATOR_CONTROL_TARGET", str(log)],
            capture_output=True, text=True, timeout=120, env={**os.environ, "MAVLINK20": "1"},
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        lines = done.stdout.splitlines()
        scan = scan_log(TlogReader(log))
        setpoint = "SET_ATTITUDE_TARGET" if flown.output in ("attitude", "rates") else "SET_ACTUATOR_CONTROL_TARGET"
        for kind, rows in (("ATTITUDE", scan.attitude[1]), ("LOCAL_POSITION_NED", scan.local_position[1])):
            assert sum(f" {kind} {{" in line for line in lines) == len(rows) > 100
        target = scan.set_attitude if flown.output in ("attitude", "rates") else scan.set_actuator
        assert sum(f" {setpoint} {{" in line for line in lines) == len(target[1]) > 100


def test_figures_of_a_replayed_flight(flown, tmp_path, capsys):
    run_dir = tmp_path / "figs"
    code = main(["replay", str(flown.flight_log), "--run-dir", str(run_dir), "--quiet"])
    capsys.readouterr()
    assert code == 0
    for name in ("path3d", "position", "attitude", "errors", "actions"):
        data = (run_dir / f"{name}.png").read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000


def test_a_truncated_flight_log_reruns_exactly_up_to_the_damage(flown, tmp_path, capsys):
    data = flown.flight_log.read_bytes()
    offsets = [m.offset for m in TlogReader(flown.flight_log)]
    partial = offsets[len(offsets) // 2]
    cut_at = partial + 13  # inside a record, mid-flight
    log = tmp_path / "flight.tlog"
    log.write_bytes(data[:cut_at])
    code = main(["replay", str(log), "--rerun", "--mission", str(flown.mission), "--run-dir", str(tmp_path / "r"),
                 "--json", "--no-plots"])  # fmt: skip
    captured = capsys.readouterr()
    assert code == 0, captured.err
    warning = captured.err.strip().splitlines()
    assert len(warning) == 1 and "mid-packet" in warning[0]
    assert f"byte {partial}" in warning[0]
    payload = json.loads(captured.out)
    assert 10 < payload["samples"] < len(_series(flown))
    assert payload["rerun"]["exact"]


def test_a_corrupted_setpoint_is_reported_missing_and_the_rest_is_read(flown, tmp_path, capsys):
    records = list(TlogReader(flown.flight_log))
    kind = "SET_ATTITUDE_TARGET" if flown.output in ("attitude", "rates") else "SET_ACTUATOR_CONTROL_TARGET"
    setpoints = [r for r in records if r.msg.get_type() == kind]
    victim = setpoints[len(setpoints) // 2]
    victim_ms = int(victim.msg.time_boot_ms if flown.output in ("attitude", "rates") else victim.msg.time_usec // 1000)
    data = bytearray(flown.flight_log.read_bytes())
    data[victim.offset + 8 + 12] ^= 0xFF  # a payload byte: the checksum fails
    log = tmp_path / "flight.tlog"
    log.write_bytes(bytes(data))
    code = main(["replay", str(log), "--rerun", "--mission", str(flown.mission), "--run-dir", str(tmp_path / "r"),
                 "--json", "--no-plots"])  # fmt: skip
    captured = capsys.readouterr()
    warning = captured.err.strip().splitlines()[0]
    assert f"damaged at byte {victim.offset}" in warning and "checksum" in warning
    payload = json.loads(captured.out)
    assert code == 1  # the flight's own controller no longer reproduces every sample ...
    assert payload["samples"] == len(_series(flown)) - 1 and payload["rerun"]["missing_samples"] == 1
    lost_t = next(float(r["t_s"]) for r in _series(flown) if int(float(r["time_boot_ms"])) == victim_ms)
    first = payload["rerun"]["first_mismatch"]
    assert first is not None and first["t_s"] > lost_t  # every sample before the lost one is exact


def test_paper_model_flight_reruns_exactly_and_reports_the_flights_numbers(flown_paper_model, tmp_path, capsys):
    flown = flown_paper_model
    code, payload = replay_json(capsys, str(flown.flight_log), "--rerun", "--mission", str(flown.mission), "--run-dir", str(tmp_path / "r"))
    assert code == 0
    assert payload["rerun"]["exact"] and payload["rerun"]["model"] == "paper"
    assert payload["samples"] == len(_series(flown))
    for a, b in zip(payload["phases"], flown.summary["phases"]):
        assert a["axes"]["3d"]["rms_m"] == pytest.approx(b["axes"]["3d"]["rms_m"], rel=1e-12)
    assert payload["peak_thrust_n"] == pytest.approx(flown.summary["peak_thrust_n"], rel=1e-12)


# --- a geo-referenced mission, flown away from the vehicle's origin -------------------------------


def _series_refs(flown: Flown) -> np.ndarray:
    return np.array([[float(r[f"ref_pos_ned_m_{i}"]) for i in range(3)] for r in _series(flown)])


def test_replay_compares_a_geo_mission_with_the_reference_where_it_was_flown(flown_geo, tmp_path, capsys, monkeypatch):
    from offboard.missions import load_mission

    flown = flown_geo
    offset = flown.summary["mission_offset_ned_m"]
    assert offset[0] == pytest.approx(-1.5, abs=0.01) and abs(offset[1]) < 1e-6  # the flight moved it 1.5 m south
    monkeypatch.chdir(tmp_path)
    run_dir = tmp_path / "r"
    code, payload = replay_json(capsys, str(flown.flight_log), "--rerun", "--run-dir", str(run_dir))
    assert code == 0 and payload["rerun"]["exact"], payload["rerun"]  # the law saw the moved references too
    assert payload["mission_offset_ned_m"] == offset and "mission_offset_ned_m" in payload["mission"]
    replayed = np.array([[float(r[f"ref_pos_ned_m_{i}"]) for i in range(3)] for r in csv.DictReader((run_dir / "series.csv").open())])
    assert_allclose(replayed, _series_refs(flown), rtol=0, atol=0)  # the references the flight flew, exactly
    as_written = load_mission(flown.mission).trajectory.reference(0.0).pos_ned_m
    assert replayed[0][0] == pytest.approx(as_written[0] - 1.5, abs=0.01)
    # and the errors are the flight's own, phase by phase
    for a, b in zip(payload["phases"], flown.summary["phases"]):
        assert a["axes"]["3d"]["rms_m"] == pytest.approx(b["axes"]["3d"]["rms_m"], rel=1e-12)


def test_without_summary_the_logged_home_position_places_a_geo_mission(flown_geo, tmp_path, capsys):
    flown = flown_geo
    log = tmp_path / "alone.tlog"  # no summary.json describes it
    log.write_bytes(flown.flight_log.read_bytes())
    run_dir = tmp_path / "r"
    code, payload = replay_json(capsys, str(log), "--mission", str(flown.mission), "--run-dir", str(run_dir))
    assert code == 0 and "HOME_POSITION" in payload["mission"]
    assert_allclose(payload["mission_offset_ned_m"], flown.summary["mission_offset_ned_m"], rtol=0, atol=0)
    replayed = np.array([[float(r[f"ref_pos_ned_m_{i}"]) for i in range(3)] for r in csv.DictReader((run_dir / "series.csv").open())])
    assert_allclose(replayed, _series_refs(flown), rtol=0, atol=0)


# --- logs that are not the flight.tlog their summary.json describes (the issue's item 2) ---------


@pytest.mark.parametrize("flown", ["attitude"], indirect=True)
def test_the_plants_log_beside_the_flights_summary_takes_its_mission(flown, tmp_path, capsys):
    """The demo's run folder: flight.tlog, plant.tlog and flight.tlog's summary.json side by side."""
    folder = tmp_path / "demo"
    folder.mkdir()
    for name in ("flight.tlog", "summary.json"):
        (folder / name).write_bytes((flown.run_dir / name).read_bytes())
    (folder / "plant.tlog").write_bytes(flown.plant_log.read_bytes())
    code, payload = replay_json(capsys, str(folder / "plant.tlog"), "--run-dir", str(tmp_path / "r"))
    assert code == 0
    assert payload["references"] == "mission" and "summary.json of flight.tlog, the same run" in payload["mission"]
    whole = payload["phases"][0]["axes"]["3d"]
    assert whole["rms_m"] == pytest.approx(flown.summary["phases"][0]["axes"]["3d"]["rms_m"], rel=0.05)


@pytest.mark.parametrize("flown", ["attitude"], indirect=True)
def test_a_copied_log_without_references_says_how_to_get_them(flown, tmp_path, capsys):
    log = tmp_path / "copy-of-flight.tlog"
    log.write_bytes(flown.flight_log.read_bytes())
    run_dir = tmp_path / "r"
    assert main(["replay", str(log), "--run-dir", str(run_dir), "--no-plots"]) == 0
    captured = capsys.readouterr()
    warnings = captured.err.strip().splitlines()
    assert len(warnings) == 1 and "no references" in warnings[0] and warnings[0].endswith("pass --mission FILE")
    assert "references none (pass --mission FILE for the tracking errors)" in captured.out
    assert "no tracking errors: no references" in captured.out and " nan " not in captured.out
    payload = json.loads((run_dir / "summary.json").read_text())
    assert payload["phases"][0]["axes"]["3d"]["rms_m"] is None
    # --mission FILE fixes it
    code, payload = replay_json(capsys, str(log), "--mission", str(flown.mission), "--run-dir", str(tmp_path / "r2"))
    assert code == 0 and payload["references"] == "mission" and payload["phases"][0]["axes"]["3d"]["rms_m"] > 0


@pytest.mark.parametrize("flown", ["attitude"], indirect=True)
def test_a_log_cut_in_half_is_not_a_complete_flight(flown, tmp_path, capsys):
    data = flown.flight_log.read_bytes()
    log = tmp_path / "half.tlog"
    log.write_bytes(data[: len(data) // 2])
    code, payload = replay_json(capsys, str(log), "--mission", str(flown.mission), "--run-dir", str(tmp_path / "r"))
    assert code == 0
    assert payload["status"] == "incomplete", payload["status_detail"]
    assert payload["status_detail"].endswith("before the mission's end at 6.00 s")
    assert payload["duration_s"] < 6.0
    # the whole log: complete
    code, payload = replay_json(capsys, str(flown.flight_log), "--mission", str(flown.mission), "--run-dir", str(tmp_path / "r2"))
    assert payload["status"] == "complete"


#: Climbs past EKF2's 1.5 m while its heading asks for 1 rad: a take-off heading hold has something to hold.
HOLD_MISSION = MISSION.replace("position = [0, 0, -1]\nyaw = 0", "position = [0, 0, -2.5]\nyaw = 1.0")


@pytest.fixture(scope="module")
def flown_heading_hold(tmp_path_factory) -> Flown:
    return fly(tmp_path_factory.mktemp("flight-heading-hold"), "attitude", extra=("--takeoff-heading-hold", "on"),
               mission_text=HOLD_MISSION)  # fmt: skip


def test_a_flight_that_held_its_heading_reruns_exactly_and_only_with_the_hold(flown_heading_hold, tmp_path, capsys):
    hold = flown_heading_hold.summary["takeoff_heading_hold"]
    assert hold["mode"] == "on" and hold["held"] and 1.0 < hold["released_s"] < 2.5
    yaw = {float(row["t_s"]): float(row["ref_yaw_rad"]) for row in _series(flown_heading_hold)}
    assert all(abs(v - np.radians(hold["heading_deg"])) < 1e-9 for t, v in yaw.items() if t < hold["released_s"] - 1e-9)
    assert yaw[2.0] == pytest.approx(1.0)  # the mission's heading once let go
    code, payload = replay_json(capsys, str(flown_heading_hold.flight_log), "--rerun", "--mission", str(flown_heading_hold.mission),
                                "--run-dir", str(tmp_path / "r"))  # fmt: skip
    assert code == 0 and payload["rerun"]["exact"], payload["rerun"]
    # the same log re-run without the hold (a summary from before it): the yaw setpoints differ while it held
    summary = flown_heading_hold.run_dir / "summary.json"
    kept = summary.read_text()
    try:
        summary.write_text(json.dumps({k: v for k, v in json.loads(kept).items() if k != "takeoff_heading_hold"}))
        code, payload = replay_json(capsys, str(flown_heading_hold.flight_log), "--rerun", "--mission", str(flown_heading_hold.mission),
                                    "--run-dir", str(tmp_path / "r2"))  # fmt: skip
    finally:
        summary.write_text(kept)
    first = payload["rerun"]["first_mismatch"]
    assert code == 1 and not payload["rerun"]["exact"] and first is not None and first["t_s"] < hold["released_s"]


def test_a_real_time_flight_with_its_latency_predicted_re_runs_exactly(flown_real_time, tmp_path, capsys):
    """The re-run predicts the state over the latency the flight did (summary.json's
    predicted_latency_s), with each sample's telemetry age (series.csv's telemetry_age_s) and the
    references that far ahead: before, it handed the law the measured state and every sample of
    make demo's flight differed (q up to 0.03)."""
    flown = flown_real_time
    latency = flown.summary["predicted_latency_s"]
    assert latency is not None and 0.0 < latency < 0.1
    ages = np.array([float(r["telemetry_age_s"]) for r in _series(flown)])
    assert np.all(np.isfinite(ages)) and np.all(ages >= 0.0) and ages.max() > 0.0
    code, payload = replay_json(capsys, str(flown.flight_log), "--rerun", "--run-dir", str(tmp_path / "r"))
    rerun = payload["rerun"]
    assert code == 0 and rerun["exact"] and rerun["mismatched_samples"] == 0, rerun["first_mismatch"]
    assert "state predicted over" in rerun["controller"] and "ages from series.csv" in rerun["controller"]
    # and how well that prediction predicted: the state handed the law against what the vehicle
    # reported a latency later, beside the measured state's (flown: 0.1 mm against 16 mm)
    check = rerun["prediction"]
    assert check is not None and check["samples"] > 0.9 * rerun["samples"] and check["latency_s"] == pytest.approx(latency, abs=1e-6)
    assert check["position_rms_m"] < 0.25 * check["position_rms_measured_m"]
    # the log and summary.json alone (no series.csv): predicted over the latency, and it says so
    alone = tmp_path / "alone"
    alone.mkdir()
    for name in ("flight.tlog", "summary.json"):
        (alone / name).write_bytes((flown.run_dir / name).read_bytes())
    code, payload = replay_json(capsys, str(alone / "flight.tlog"), "--rerun", "--run-dir", str(tmp_path / "r2"))
    assert "no readable series.csv with the telemetry's ages" in payload["rerun"]["controller"]
    assert payload["rerun"]["samples"] == rerun["samples"]


def test_a_lockstep_flight_predicts_nothing_and_records_no_age(flown):
    assert flown.summary["predicted_latency_s"] is None
    assert all(r["telemetry_age_s"] == "nan" for r in _series(flown))


def test_a_real_time_flight_whose_samples_outpace_its_telemetry_re_runs_exactly(tmp_path, capsys):
    """Telemetry at 15 Hz, samples at 20 Hz (a radio link's rates): a quarter of the samples
    find no newer telemetry and answer the stamp the sample before answered, with commands of
    their own. The re-run steps the law at every one of them, as the flight did (it skipped them:
    91 of 121 samples re-run, 88 differing)."""
    flown = fly(tmp_path / "slow-telemetry", "attitude", lockstep=False, extra=("--telemetry-rate", "15"))
    stamps = [int(float(r["time_boot_ms"])) for r in _series(flown)]
    repeated = sum(1 for a, b in zip(stamps, stamps[1:]) if a == b)
    assert repeated > 0.1 * len(stamps), f"{repeated} of {len(stamps)} samples read the telemetry the sample before read"
    code, payload = replay_json(capsys, str(flown.flight_log), "--rerun", "--run-dir", str(tmp_path / "r"))
    rerun = payload["rerun"]
    assert code == 0 and rerun["samples"] == len(stamps)
    assert rerun["exact"] and rerun["mismatched_samples"] == 0, rerun["first_mismatch"]
