"""`offboard mission show|check|convert`, in process and once as a real process."""

from __future__ import annotations

import subprocess
import sys

import pytest

from offboard.cli import main
from offboard.missions import MISSIONS_DIR

HELIX = MISSIONS_DIR / "paper-helix.toml"
BAD_TOML = '[mission]\nframe = "ned"\nangle_unit = "deg"\n[[mission.segment]]\ntype = "circle"\ncenter = [0, 0, -5]\nradius_m = -2\nangular_rate = 30\nduration_s = 5\n'


def test_check_valid_exits_0(capsys):
    assert main(["mission", "check", str(HELIX)]) == 0
    out = capsys.readouterr().out
    assert out.strip() == f"{HELIX}: OK: paper-helix, 3 segments, 40.00 s"


def test_check_invalid_exits_2_with_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text(BAD_TOML)
    assert main(["mission", "check", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err == "offboard mission: error: bad.toml: mission.segment #1 (circle): radius_m: must be > 0, got -2\n"


def test_check_as_a_real_process(tmp_path):
    bad = tmp_path / "bad.waypoints"
    bad.write_text("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t47.4\t8.5\t488\t1\n1\t0\t3\t183\t0\t0\t0\t0\t0\t0\t0\t1\n")
    cmd = [sys.executable, "-m", "offboard.cli", "mission", "check"]
    bad_run = subprocess.run([*cmd, str(bad)], capture_output=True, text=True, timeout=120)
    assert bad_run.returncode == 2
    assert bad_run.stdout == ""
    assert bad_run.stderr.splitlines() == [
        "offboard mission: error: bad.waypoints: line 3 (item 1): command: MAV_CMD_DO_SET_SERVO (183) is not supported; "
        "expected one of NAV_WAYPOINT (16), NAV_LOITER_TIME (19), NAV_LAND (21), NAV_TAKEOFF (22), DO_CHANGE_SPEED (178)"
    ]
    good_run = subprocess.run([*cmd, str(MISSIONS_DIR / "px4-sitl-survey.plan")], capture_output=True, text=True, timeout=120)
    assert good_run.returncode == 0, good_run.stderr
    assert "OK: px4-sitl-survey" in good_run.stdout


def test_show_prints_the_summary(capsys):
    assert main(["mission", "show", str(HELIX)]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert lines[0] == "mission   paper-helix  (paper-helix.toml)"
    table = {line.split()[1]: line.split() for line in lines if line[:1].isdigit()}
    assert set(table) == {"helix", "hold-12m", "descent"}
    helix = table["helix"]
    assert helix[2:8] == ["Helix", "track", "0.00", "12.00", "25.85", "2.15"]  # 12 s x sqrt(2^2 + 0.8^2) m/s
    assert table["hold-12m"][2:6] == ["Hold", "hold", "12.00", "13.00"]
    assert "total     40.00 s, 25.85 m of path (3 segments)" in out
    assert "bounds    north [-2.00, 2.00]  east [-2.00, 2.00]  down [-12.00, 0.00] m (NED)" in out
    assert "t = 12.00 s  helix -> hold-12m" in out and "t = 25.00 s  hold-12m -> descent: 12.00 m, yaw +90.0 deg" in out
    assert "reference starts 2.83 m from it" in out  # the helix starts at (2, 0, 2), the vehicle at the origin
    assert "plot:" not in out


def test_show_writes_a_plot(tmp_path, capsys):
    from matplotlib.image import imread

    png = tmp_path / "figs" / "box.png"
    png.parent.mkdir()  # output files go into existing folders (offboard/model/paths.py: the one rule, as --log's)
    assert main(["mission", "show", str(MISSIONS_DIR / "px4-sitl-box.waypoints"), "--plot", str(png)]) == 0
    assert f"plot: {png}" in capsys.readouterr().out
    image = imread(png)
    assert image.shape[0] > 300 and image.shape[1] > 600
    assert image[..., :3].std() > 0.05  # something is drawn


def test_convert_round_trip(tmp_path, capsys):
    src = MISSIONS_DIR / "px4-sitl-box.waypoints"
    assert main(["mission", "convert", str(src), str(tmp_path / "box.plan")]) == 0
    assert main(["mission", "convert", str(tmp_path / "box.plan"), str(tmp_path / "box.waypoints")]) == 0
    assert (tmp_path / "box.waypoints").read_text() == src.read_text()
    assert main(["mission", "convert", str(HELIX), str(tmp_path / "x.plan")]) == 2
    assert "a parametric mission has no MAVLink items" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["mission"], ["mission", "show"], ["mission", "show", str(HELIX), "--dt", "0"]])
def test_bad_arguments_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    assert "usage:" in capsys.readouterr().err


def test_show_names_the_velocity_steps_of_the_square(capsys):
    """The issue: "max a 0.00" for a square whose velocity steps at every corner."""
    assert main(["mission", "show", str(MISSIONS_DIR / "paper-square.toml")]) == 0
    out = capsys.readouterr().out
    square = next(line.split() for line in out.splitlines() if line.startswith("1  square"))
    assert square[8] == "steps"  # the max a column
    assert ("speed the velocity reference steps (unbounded acceleration, not smoothed): t = 5.00 s 1.41 m/s (square), "
            "t = 10.00 s 1.41 m/s (square), t = 15.00 s 1.41 m/s (square), t = 20.00 s 1.00 m/s (square -> hold)") in " ".join(out.split())
    assert max(len(line) for line in out.splitlines()) <= 100
    assert "acceleration 0.00 m/s^2 between the velocity steps" in out


def test_show_lists_no_velocity_step_where_the_reference_is_smooth(capsys):
    assert main(["mission", "show", str(MISSIONS_DIR / "px4-sitl-box.waypoints")]) == 0
    out = capsys.readouterr().out
    assert "velocity reference steps" not in out and "steps" not in out
