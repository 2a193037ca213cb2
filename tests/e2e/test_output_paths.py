"""Where the programs write: an output file goes into a folder that exists (a missing one is
refused, never created); a run folder is created with its parents; anything in the way is one
line naming the option and the path (exit 2), never a traceback — as real processes."""

from __future__ import annotations

import subprocess
import sys

import pytest

from offboard.missions import MISSIONS_DIR
from offboard.model.paths import OutputPathError, output_file, output_folder

BOX = str(MISSIONS_DIR / "px4-sitl-box.waypoints")
HELIX = str(MISSIONS_DIR / "paper-helix.toml")


def _run(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *argv], capture_output=True, text=True, timeout=120)


@pytest.fixture
def blocker(tmp_path):
    """A plain file standing where a folder would have to be (no user, root included, can pass)."""
    path = tmp_path / "a-file"
    path.write_text("not a folder\n")
    return path


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["-m", "offboard.cli", "mission", "convert", BOX, "{tmp}/missing/x.plan"],
         "offboard mission: error: output {tmp}/missing/x.plan: the folder {tmp}/missing does not exist "
         "(create it first: mkdir -p {tmp}/missing)"),
        (["-m", "offboard.cli", "mission", "convert", BOX, "{blocker}/x.plan"],
         "offboard mission: error: output {blocker}/x.plan: {blocker} is a file, not a folder"),
        (["-m", "offboard.cli", "mission", "convert", BOX, "{tmp}"],
         "offboard mission: error: output {tmp}: is a folder; give a file name"),
        (["-m", "offboard.cli", "mission", "show", HELIX, "--plot", "{tmp}/out.txt"],
         "offboard mission: error: --plot {tmp}/out.txt: cannot tell a picture format from '.txt'; end the name in .png (or "),
        (["-m", "offboard.cli", "mission", "show", HELIX, "--plot", "{tmp}/figs/helix.png"],
         "offboard mission: error: --plot {tmp}/figs/helix.png: the folder {tmp}/figs does not exist"),
        (["-m", "offboard.cli", "simulate", str(MISSIONS_DIR / "paper-sim3.toml"), "--run-dir", "{blocker}"],
         "offboard simulate: error: --run-dir {blocker}: is a file, not a folder"),
        (["-m", "offboard.cli", "fly", HELIX, "--run-dir", "{blocker}"],
         "offboard fly: error: --run-dir {blocker}: is a file, not a folder"),
        (["-m", "offboard.cli", "fly", HELIX, "--run-dir", "{tmp}/run", "--log", "{tmp}/missing/x.tlog",
          "--connect", "udpin:127.0.0.1:0"],
         "offboard fly: error: --log {tmp}/missing/x.tlog: cannot write the log: the folder {tmp}/missing does not exist"),
        (["-m", "sitl_plant.cli", "--api-bind", "127.0.0.1:0", "--api-remote", "none", "--gcs-bind", "none",
          "--log", "{tmp}/missing/x.tlog"],
         "sitl-plant: error: --log {tmp}/missing/x.tlog: cannot write the log: the folder {tmp}/missing does not exist"),
        (["-m", "offboard.cli", "tune", "--vehicle", "sitl_plant/vehicles/paper-quad.toml", "--output", "{tmp}/missing/c.toml"],
         "offboard tune: error: --output {tmp}/missing/c.toml: the folder {tmp}/missing does not exist"),
    ],
)  # fmt: skip
def test_an_unwritable_output_is_one_line(argv, expected, tmp_path, blocker, capsys):
    fill = {"blocker": str(blocker), "tmp": str(tmp_path)}
    argv = [a.format(**fill) for a in argv]
    if argv[1] in ("offboard.cli", "sitl_plant.cli") and argv[2] not in ("fly",) and "--api-bind" not in argv:
        from offboard.cli import main  # in-process (cheaper); fly and sitl-plant below as real processes

        code, stderr = main(argv[2:]), capsys.readouterr().err
    else:
        proc = _run(*argv)
        code, stderr = proc.returncode, proc.stderr
    assert code == 2, stderr
    assert "Traceback" not in stderr
    lines = stderr.splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith(expected.format(**fill))
    assert not (tmp_path / "missing").exists() and not (tmp_path / "figs").exists()  # nothing created


def test_nothing_is_flown_or_written_before_a_bad_output_is_refused(tmp_path, blocker):
    # simulate checks its run folder before it flies (it used to fly the whole scenario first)
    proc = _run("-m", "offboard.cli", "simulate", str(MISSIONS_DIR / "paper-sim1.toml"), "--run-dir", str(blocker))
    assert proc.returncode == 2
    assert blocker.read_text() == "not a folder\n"


def test_an_output_file_in_an_existing_folder_is_written(tmp_path):
    out = tmp_path / "box.plan"
    proc = _run("-m", "offboard.cli", "mission", "convert", BOX, str(out))
    assert proc.returncode == 0, proc.stderr
    assert out.is_file() and '"fileType": "Plan"' in out.read_text()


def test_the_helpers_say_what_is_in_the_way(tmp_path, blocker):
    assert output_folder(tmp_path / "a" / "b", "--run-dir").is_dir()  # run folders: with their parents
    assert output_file(tmp_path / "a" / "f.png", "--plot") == tmp_path / "a" / "f.png"
    with pytest.raises(OutputPathError, match="a file stands where one of its parent folders should be"):
        output_folder(blocker / "x" / "y", "--run-dir")
    with pytest.raises(OSError):  # callers may catch it as the builtin
        output_file(tmp_path, "output")
    with pytest.raises(OutputPathError, match="does not exist"):
        output_file(tmp_path / "new" / "f.png", "--plot")
    assert not (tmp_path / "new").exists()
