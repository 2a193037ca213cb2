"""Smoke test of bench/loop.py with tiny sizes: it runs the real processes, returns finite positive
figures and well-formed markdown, and leaves no process behind. No timed assertion."""

from __future__ import annotations

import math
import os
import subprocess
import time

import pytest

from bench import loop


def _alive(pattern: str) -> list[str]:
    out = subprocess.run(["pgrep", "-af", pattern], capture_output=True, text=True).stdout
    return [line for line in out.splitlines() if "pgrep" not in line]


def test_floor_ping_pong_counts_cycles():
    r = loop.floor(cycles=50, warmup=5)
    assert r["cycles"] == 50 and math.isfinite(r["cycles_per_s"]) and r["cycles_per_s"] > 0
    assert not _alive("--floor-role")


def test_breakdown_attributes_samples_to_the_innermost_part(tmp_path):
    raw = tmp_path / "plant.raw"
    root = "<module> (sitl_plant/cli.py:1);run_lockstep (sitl_plant/server.py:700)"
    raw.write_text(
        f"{root};Link.wait (sitl_plant/link.py:260) 40\n"
        f"{root};Plant.advance (sitl_plant/server.py:264);FastRigidBodySim.step (sitl_plant/dynamics/batch.py:601);"
        "Px4Loop.held (sitl_plant/inner_loops.py:450) 30\n"
        f"{root};Plant.advance (sitl_plant/server.py:264) 10\n"
        "<module> (sitl_plant/cli.py:1);import_stuff (x.py:1) 99\n"  # outside the loop: not counted
    )
    profile = loop.breakdown(raw, loop.PLANT_PARTS, loop.PLANT_SCOPE, cycle_us=200.0)
    rows = {r["part"]: r["us_per_cycle"] for r in profile["rows"]}
    assert profile["samples"] == 80  # the 99 outside the loop are not counted
    assert rows["waiting for the setpoint (select)"] == 100.0  # 40 of 80 samples: half the cycle
    assert rows["PX4 loops in Python (position modes, or no numba)"] == 75.0
    assert rows["autopilot, truth state"] == 25.0
    assert sum(rows.values()) == 200.0  # the shares make up the cycle


def test_breakdown_without_a_sample_in_the_loop_says_so(tmp_path):
    raw = tmp_path / "plant.raw"
    raw.write_text("<module> (sitl_plant/cli.py:1);import_stuff (x.py:1) 99\n")
    with pytest.raises(RuntimeError, match="no py-spy sample inside run_lockstep"):
        loop.breakdown(raw, loop.PLANT_PARTS, loop.PLANT_SCOPE, cycle_us=200.0)


def test_the_second_floor_replays_the_loops_own_messages(tmp_path):
    """Issue 16: a ping-pong of the messages a real lockstep flight carried, cycle by cycle."""
    run = loop.fly(tmp_path / "flight", loop.hover(tmp_path, 3.0), lockstep=True, rss_interval_s=None)
    tlog = tmp_path / "flight" / "plant.tlog"
    cycles = loop.recorded_cycles(tlog)
    assert len(cycles) == loop.RECORDED_CYCLES
    with pytest.raises(RuntimeError, match="not the wall clock"):  # lockstep logs of the vehicle's time
        loop.hand_overs(tlog, tmp_path / "flight" / "flight.tlog")
    stamps = [c["t_ms"] for c in cycles]
    assert stamps == list(range(stamps[0], stamps[0] + 50 * len(stamps), 50))  # consecutive lockstep periods
    mix = loop.mix_floor(tlog, cycles=30, warmup=5)
    assert mix["cycles"] == 30 and math.isfinite(mix["cycles_per_s"]) and mix["cycles_per_s"] > 0
    counts = mix["message_counts"]
    # one telemetry pair and one echo a cycle; the streams the offboard switched off are not there
    assert counts["ATTITUDE"] == counts["LOCAL_POSITION_NED"] == counts["SET_ATTITUDE_TARGET"] == loop.RECORDED_CYCLES
    assert "ATTITUDE_QUATERNION" not in counts and "HIGHRES_IMU" not in counts
    assert not _alive("--floor-role")
    floor = loop.floor(cycles=30, warmup=5)
    # the floors also wait as the loop does: polling, then sleeping (offboard.model.busywait)
    polled = loop.floor(cycles=30, warmup=5, spin_s=loop.LOCKSTEP_SPIN_S)
    polled_mix = loop.mix_floor(tlog, cycles=30, warmup=5, spin_s=loop.LOCKSTEP_SPIN_S)
    assert polled["cycles"] == polled_mix["cycles"] == 30 and polled["cycles_per_s"] > 0 and polled_mix["cycles_per_s"] > 0
    assert not _alive("--floor-role")
    rate = loop._cycles_per_s(run["summary"])
    result = {
        "lockstep": {
            "cycles_per_s": rate, "floor_cycles_per_s": polled["cycles_per_s"], "ratio": rate / polled["cycles_per_s"],
            "mix_floor_cycles_per_s": polled_mix["cycles_per_s"], "mix_floor": polled_mix,
            "mix_ratio": rate / polled_mix["cycles_per_s"], "spin_s": loop.LOCKSTEP_SPIN_S,
            "floor_sleeping_cycles_per_s": floor["cycles_per_s"], "mix_floor_sleeping_cycles_per_s": mix["cycles_per_s"],
            "commands": ["python -m sitl_plant.cli", "python -m offboard.cli fly"],
        },  # fmt: skip
        "profile": {"error": "not profiled in the smoke test"},
        "real_time": [],
        "memory": {"paper_helix_hwm_kb": {}, "long": {}},
    }
    text = loop.markdown(result)
    assert text.count("| floor: pymavlink ping-pong of the loop's own messages |") == 1
    assert "≥ 50 % of the floor of its own messages" in text
    assert text.count("each side sleeping in its wait at once |") == 2 and "polling its socket for up to 500 µs" in text
    # the profile's table: each process's parts make up the profiled cycle, its work is all but the wait
    result["profile"] = {
        "tool": "py-spy", "sample_hz": 250, "sim_s": 1200.0, "cycles_per_s_profiled": 5000.0, "cycles": 24001,
        "plant": {"samples": 80, "rows": [{"part": "waiting for the setpoint (select)", "us_per_cycle": 150.0},
                                          {"part": "autopilot, truth state", "us_per_cycle": 50.0}]},
        "offboard": {"samples": 90, "rows": [{"part": "waiting for telemetry (select)", "us_per_cycle": 120.0},
                                             {"part": "controller law", "us_per_cycle": 80.0}]},
    }  # fmt: skip
    result["hand_overs"] = {"sim_s": 300.0, "cycles_per_s": 4000.0, "cycles": 4800, "cycle_p50_us": 250.0,
                            "parts": [{"part": p, "p50_us": 60.0, "p90_us": 70.0} for p, _, _ in loop.HAND_OVERS]}  # fmt: skip
    text = loop.markdown(result)
    assert "over the middle 4800 cycles" in text and "(median 250 µs)" in text
    assert f"| {loop.HAND_OVERS[3][0]} | 60 | 70 |" in text
    assert "200 µs a cycle" in text and "80 samples inside the plant's loop, 90 inside the offboard's" in text
    assert "| plant | **work (all but waiting)** | **50.0** |" in text
    assert "| offboard | **work (all but waiting)** | **80.0** |" in text
    for pid in run["pids"]:
        assert not os.path.exists(f"/proc/{pid}") or "zombie" in open(f"/proc/{pid}/status").read()


def test_the_hand_overs_come_from_both_processes_wall_clock_logs(tmp_path):
    """Issue 16: where a lockstep cycle's time goes, from the two tlogs stamped with the wall clock
    (``--log-clock wall`` on both sides), with no sampler in either process."""
    before = time.time()
    loop.fly(tmp_path / "flight", loop.hover(tmp_path, 3.0), lockstep=True, rss_interval_s=None,
             fly_args=("--log-clock", "wall"), plant_args=("--log-clock", "wall"))  # fmt: skip
    after = time.time()
    d = tmp_path / "flight"
    for tlog in (d / "plant.tlog", d / "flight.tlog"):
        stamps = list(loop._first_logged(tlog, ("ATTITUDE",))["ATTITUDE"].values())
        assert stamps and before <= min(stamps) and max(stamps) <= after  # the wall clock, as the flight ran
    ho = loop.hand_overs(d / "plant.tlog", d / "flight.tlog")
    assert ho["cycles"] >= 40  # a 3 s hover's 60 samples and more, the middle 80 % of them
    for part in ho["parts"]:
        assert 0.0 < part["p50_us"] <= part["p90_us"] < 1e6
    assert ho["cycle_p50_us"] > max(part["p50_us"] for part in ho["parts"])
