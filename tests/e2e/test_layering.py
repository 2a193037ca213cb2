"""The controller process imports nothing of the simulator (issue 12): a real ``offboard fly``
against the plant, with Python reporting every import it makes (PYTHONPROFILEIMPORTTIME), lazy
ones included. Before the move to ``offboard/model`` it loaded 19 ``sitl_plant`` modules."""

from __future__ import annotations

import re

from helpers.flights import fly, hover_mission


def test_offboard_fly_never_imports_the_simulator(tmp_path):
    flown = fly(tmp_path, hover_mission(tmp_path / "hover.toml", 1.0, 1.0), fly_env={"PYTHONPROFILEIMPORTTIME": "1"})
    assert flown.returncode == 0, flown.stderr[-3000:]
    imported = re.findall(r"^import time:\s+\d+ \|\s+\d+ \|\s+(\S.*)$", flown.stderr, re.M)
    modules = {m.strip() for m in imported}
    assert "offboard.flight" in modules and "offboard.model.rotations" in modules  # the report is there
    assert not sorted(m for m in modules if m.split(".")[0] == "sitl_plant")
