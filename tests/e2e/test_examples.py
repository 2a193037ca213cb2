"""Every script in examples/ runs, as a researcher would run it, and says what it should.

Each is a real process (``python examples/X.py``), plots headless; the MAVLink example starts a
real sitl-plant on free ports and the tlog example reads the log it leaves.
"""

from __future__ import annotations

import re
import subprocess
import sys


from offboard.missions import MISSIONS_DIR, load_mission
from helpers.flights import ENV
from helpers import REPO

EXAMPLES = REPO / "examples"
COVERED = {"paper_law_rigid_body", "law_vs_se3", "mass_sweep", "mavlink_flight", "read_tlog"}


def run(name: str, *args: str, timeout: float = 300.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(EXAMPLES / f"{name}.py"), *args], capture_output=True, text=True,
                          env=ENV, timeout=timeout, cwd=EXAMPLES.parent)  # fmt: skip


def test_every_example_is_run_here():
    assert {p.stem for p in EXAMPLES.glob("*.py")} == COVERED


def test_the_paper_law_on_the_rigid_body():
    proc = run("paper_law_rigid_body")
    assert proc.returncode == 0, proc.stderr
    assert "status complete" in proc.stdout and "helix" in proc.stdout


def test_the_law_against_the_baselines_through_px4s_attitude_loop():
    proc = run("law_vs_se3")
    assert proc.returncode == 0, proc.stderr
    rms = {m.group(1): float(m.group(2)) for m in re.finditer(r"^(\w+)\s+complete: RMS ([\d.]+) m", proc.stdout, re.M)}
    assert set(rms) == {"paper", "se3", "px4"}
    assert max(rms.values()) < 0.5  # the 5 m square at 1 m/s, every controller tracks it


def test_the_mass_sweep_is_best_at_the_believed_mass():
    proc = run("mass_sweep")
    assert proc.returncode == 0, proc.stderr
    rows = {float(m.group(1)): float(m.group(2)) for m in re.finditer(r"^\s+([\d.]+)\s+([\d.]+)\s+\(complete\)", proc.stdout, re.M)}
    assert len(rows) == 6
    assert min(rows, key=rows.get) == 0.5  # the law has no term for a mass error (the paper's Fig. 8)


def test_a_mavlink_flight_from_python_then_its_log_read_back(tmp_path):
    proc = run("mavlink_flight", str(tmp_path / "run"))
    assert proc.returncode == 0, proc.stderr + proc.stdout
    assert "status complete, landed True, disarmed True" in proc.stdout
    log = tmp_path / "run" / "flight.tlog"
    assert log.stat().st_size > 10_000
    mission = MISSIONS_DIR / "figure-eight.toml"
    read = run("read_tlog", str(log), str(mission))
    assert read.returncode == 0, read.stderr
    duration = load_mission(mission).trajectory.duration_s
    assert f"duration {duration:.2f} s, status complete" in read.stdout
    assert re.search(r"^\d+ control samples", read.stdout, re.M)


def test_reading_a_log_that_is_not_there_is_one_line(tmp_path):
    proc = run("read_tlog", str(tmp_path / "missing.tlog"))
    assert proc.returncode != 0
    assert "missing.tlog" in proc.stderr and "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


def test_docs_api_names_only_objects_that_exist():
    """Every object docs/api.md lists is importable from the module it names."""
    import importlib

    text = (EXAMPLES.parent / "docs" / "api.md").read_text()
    checked = 0
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 3 or not cells[1].startswith("`"):
            continue
        modules = re.findall(r"`([\w.]+)`", cells[1])
        names = re.findall(r"`([A-Za-z_]\w*)(?=[(`])", cells[0])  # `name` or `name(...)`
        loaded = [importlib.import_module(m) for m in modules]
        for name in names:
            assert any(hasattr(m, name) for m in loaded), f"docs/api.md: {name} is in none of {modules}"
            checked += 1
    assert checked > 40
