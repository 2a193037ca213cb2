"""``make demo`` (``python -m offboard.demo``): two processes, a run folder, nothing left behind."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import time

import pytest

from helpers.flights import ENV, PY, hover_mission, read_tlog
from helpers import REPO

pytestmark = pytest.mark.e2e

FIGURES = ("path3d.png", "position.png", "attitude.png", "errors.png", "actions.png")


def child_pids(stderr: str) -> list[int]:
    return [int(p) for p in re.findall(r"\(pid (\d+)\)", stderr)]


def assert_gone(pids: list[int]) -> None:
    assert len(pids) == 2
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


@pytest.mark.slow
def test_demo_flies_the_paper_helix_and_leaves_the_run_folder(tmp_path):
    run_dir = tmp_path / "demo"
    proc = subprocess.run([PY, "-m", "offboard.demo", "--run-dir", str(run_dir), "--lockstep", "--quiet"],
                          capture_output=True, text=True, env=ENV, timeout=300)
    assert proc.returncode == 0, proc.stderr
    for name in ("flight.tlog", "plant.tlog", "summary.txt", "summary.json", "series.csv", *FIGURES):
        assert (run_dir / name).is_file() and (run_dir / name).stat().st_size > 0, name
    for name in FIGURES:
        assert (run_dir / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["mission"] == "paper-helix" and summary["status"] == "complete"
    assert summary["output"] == "attitude" and summary["model"] == "rigid-body" and summary["controller"]["yaw_aware"]
    assert "whole flight" in (run_dir / "summary.txt").read_text()
    assert str(run_dir.resolve()) in proc.stderr  # it says where things are
    assert_gone(child_pids(proc.stderr))
    msgs = read_tlog(run_dir / "flight.tlog")
    assert sum(m.get_type() == "SET_ATTITUDE_TARGET" for m in msgs) > 800
    # the tracking table's 12 m maxima are the paper's steps: the verdict says how it tracked after them
    verdict = next(line for line in proc.stderr.splitlines() if line.startswith("demo: tracked within "))
    assert re.search(r"after the steps \(3D RMS [0-9.]+ m\); peak tilt [0-9.]+ deg \(limit 35 deg\), status complete$", verdict)
    assert summary["peak_tilt_deg"] <= summary["controller"]["tilt_max_deg"] + 0.5  # the issue saw 51.3 deg against 35
    assert [round(s["size_m"]) for s in summary["reference_steps"]] == [3, 2, 12]
    # docs/offboard.md quotes this lockstep flight's verdict (deterministic: lockstep logs are identical)
    page = " ".join((REPO / "docs" / "offboard.md").read_text().split())
    quoted = re.search(r"`python -m offboard\.demo --lockstep`'s flight ends `verdict: ([^`]+)`", page).group(1)
    assert summary["verdict"] == quoted
    assert summary["settled"]["max_m"] < 0.2
    plant_log = (run_dir / "plant.log").read_text()  # the issue: it was empty
    assert plant_log.startswith("sitl-plant: rigid-body model") and "sitl-plant: stopped at t=" in plant_log


def test_ctrl_c_on_the_demo_lands_and_leaves_no_process(tmp_path):
    run_dir = tmp_path / "demo"
    # 600 s: lockstep flies ~80x real time, and the interrupt must come before the hover ends
    # (with 60 s it once came after: the flight was over and offboard fly was drawing its figures)
    mission = hover_mission(tmp_path / "hover.toml", 2.0, 600.0)
    err_path = tmp_path / "demo.stderr"
    with err_path.open("w") as err:
        proc = subprocess.Popen([PY, "-m", "offboard.demo", "--run-dir", str(run_dir), "--lockstep", "--mission", str(mission)],
                                stdout=subprocess.DEVNULL, stderr=err, env=ENV)
    try:
        deadline = time.monotonic() + 60
        while "mission started" not in err_path.read_text() and time.monotonic() < deadline:
            assert proc.poll() is None, err_path.read_text()
            time.sleep(0.05)
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    stderr = err_path.read_text()
    assert code == 130, stderr
    assert_gone(child_pids(stderr))
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["landed"] and summary["disarmed"]
    assert read_tlog(run_dir / "flight.tlog")
