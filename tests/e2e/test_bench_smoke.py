"""``bench/run.py --quick``: the harness runs end to end and writes a complete report.

Tiny sizes, so this checks the harness and the agreements it measures (closed form = pseudo-
inverse, compiled = reference physics), never a speed: speed is only ever printed.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import pytest
from helpers import REPO

from bench import loop


pytestmark = [pytest.mark.slow, pytest.mark.e2e]


def _finite_positive(value: float) -> bool:
    return isinstance(value, (int, float)) and math.isfinite(value) and value > 0


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench") / "RESULTS.md"
    proc = subprocess.run(
        [sys.executable, str(REPO / "bench" / "run.py"), "--quick", "--workers", "1", "--output", str(out)],
        capture_output=True, text=True, timeout=600, cwd=REPO,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out, json.loads((out.parent / "results.json").read_text(), parse_constant=_not_strict)


def _not_strict(word: str) -> float:
    raise ValueError(f"results.json is not strict JSON: {word}")  # NaN or Infinity (docs/json.md)


def test_the_lockstep_cycles_hand_overs_are_measured(quick_run):
    _, results = quick_run
    ho = results["loop"]["hand_overs"]
    assert ho["cycles"] > 0 and [p["part"] for p in ho["parts"]] == [part for part, _, _ in loop.HAND_OVERS]
    assert all(_finite_positive(p["p50_us"]) and p["p50_us"] <= p["p90_us"] for p in ho["parts"])


def test_report_has_every_section(quick_run):
    out, _ = quick_run
    text = out.read_text()
    for heading in ("# Benchmarks", "## Speed", "### Controller step", "### Physics: one vehicle",
                    "### Physics: many vehicles", "### MAVLink lockstep loop", "### Real-time loop",
                    "### Memory", "## Tracking", "#### helix", "## The law through an autopilot's attitude loop", "## Sweep (issue 15)",
                    "### Faults: a lossy link, a killed offboard"):  # fmt: skip
        assert heading in text, heading
    assert "Machine:" in text and "python bench/run.py --quick" in text
    assert "Target ≥ 500× (issue 16): " in text
    assert (out.parent / "img" / "tracking-helix.png").stat().st_size > 1000


def test_speed_figures_and_agreements(quick_run):
    _, results = quick_run
    c, p = results["speed"]["controller"], results["speed"]["physics"]
    for key in ("law_step_us", "law_step_yaw_aware_limits_us", "controller_step_us", "pinv_us"):
        assert _finite_positive(c[key]), key
    assert c["pinv_max_difference"] < 1e-9  # eq. 39-42 solve eq. 35 exactly
    for key in ("fast_x_realtime", "fast_physics_only_x_realtime", "vehicle_sim_x_realtime", "no_numba_x_realtime"):
        assert _finite_positive(p[key]), key
    assert p["max_position_difference_m"] < 1e-9  # the fast simulator flies as the reference
    assert [row["vehicles"] for row in results["speed"]["batch"]] == [1, 10]
    assert all(_finite_positive(row["compiled_per_s"]) for row in results["speed"]["batch"])


def test_sweep_part_flies_its_flights(quick_run):
    _, results = quick_run
    s = results["sweep"]
    assert s["sweep"]["flights"] == 8 and s["sweep"]["tasks"] == 2
    assert _finite_positive(s["sweep"]["flights_per_s"]) and _finite_positive(s["one_at_a_time"]["flights_per_s"])
    rss = s["client_rss_mib"]  # the client's memory part way and at the end, for the flat-memory claim
    assert rss["at_flights"] == [4, 8] and all(_finite_positive(m) for m in rss["mib"])
    assert rss["growth_mib"] == pytest.approx(rss["mib"][1] - rss["mib"][0])
    c = s["ceiling"]  # two plain processes against one: the machine's own bound on the workers' scaling
    assert c["flights"] == 8 * s["sweep"]["flights_per_task"] and len(c["pair_s"]) == 2 and c["repeats"] == 1
    assert all(_finite_positive(x) for x in (c["alone_s"], *c["pair_s"]))
    assert c["speedup"] == pytest.approx(2 * c["alone_s"] / max(c["pair_s"]))


def test_tracking_flies_every_controller_in_every_condition(quick_run):
    _, results = quick_run
    flights = results["tracking"]["flights"]
    combos = {(f["loop"], f["condition"], f["controller"]) for f in flights}
    assert len(combos) == len(flights) == 32  # 4 conditions x 4 controllers x 2 loops
    assert {f["controller"] for f in flights if f["loop"] == "px4-attitude"} == {"paper", "paper-designed", "se3", "px4"}
    for f in flights:
        assert f["diverged_at_s"] is None, f
        assert f["flown_s"] == pytest.approx(0.5)
        assert 0.0 <= f["rms_m"] <= f["max_m"] < 5.0


def test_bad_option_is_one_line():
    proc = subprocess.run([sys.executable, str(REPO / "bench" / "run.py"), "--only", "speed,warp"],
                          capture_output=True, text=True, cwd=REPO)  # fmt: skip
    assert proc.returncode == 2
    assert "unknown part 'warp'" in proc.stderr and "Traceback" not in proc.stderr


def test_faults_part_completes_its_flights(quick_run):
    _, results = quick_run
    lossy, kill = results["faults"]["lossy"], results["faults"]["kill"]
    assert lossy["clean_status"] == "complete" and lossy["trials"] == 1
    assert kill["fired"] == kill["trials"] == 1  # the plant's failsafe fired after the SIGKILL


def test_faults_quick_flies_the_lossy_link_and_fails_safe_in_time(quick_run):
    """What ``bench/faults.py --quick`` says it runs (one lossy seed, one kill), and that both
    went as issue 14 requires: the lossy flight completed, the failsafe fired within its bound."""
    _, results = quick_run
    lossy, kill = results["faults"]["lossy"], results["faults"]["kill"]
    assert [r["seed"] for r in lossy["runs"]] == [1] and lossy["complete"] == 1, lossy["runs"]
    assert kill["trials"] == 1 and kill["within_bound"] == 1, kill
    assert kill["max_s"] <= kill["bound_s"] == pytest.approx(1.05)
    assert results["faults"]["shortfalls"] == []  # the report says all was met (and would flag what was not)


def test_loop_part_gives_finite_figures_and_markdown_and_leaves_no_process(quick_run):
    """The lockstep, real-time and long flights of ``bench/loop.py``: finite figures, well-formed
    tables, and every process the harness started gone."""
    _, results = quick_run
    r = results["loop"]
    long = r["memory"]["long"]
    assert long["status"] == "complete" and long["cycles_per_s"] > 0
    assert long["hwm_kb"]["plant"] > 0 and long["hwm_kb"]["offboard"] > 0
    assert [rt["rate_hz"] for rt in r["real_time"]] == [50.0, 250.0]
    for rt in r["real_time"]:
        assert rt["samples"] > 0 and rt["latency_count"] > 0
        for key in ("jitter_p50_ms", "jitter_max_ms", "latency_p50_ms", "latency_max_ms"):
            assert math.isfinite(rt[key]) and rt[key] >= 0, key
        assert rt["latency_p50_ms"] > 0
    assert _finite_positive(r["lockstep"]["cycles_per_s"]) and _finite_positive(r["lockstep"]["mix_floor_cycles_per_s"])
    text = loop.markdown(r)
    for heading in ("### MAVLink lockstep loop", "### Real-time loop", "### Memory"):
        assert text.count(heading) == 1
    for line in text.splitlines():
        if line.startswith("|"):
            assert line.endswith("|") and "nan" not in line.lower(), line
    memory = text.split("### Memory", 1)[1]
    for name in ("plant", "offboard"):  # a row each, fitted or (too short a hover) saying why not
        assert memory.count(f"| {name} |") == 1, memory
        assert name in long or "No growth fitted" in memory, memory
    for pid in long["pids"] + [pid for rt in r["real_time"] for pid in rt["pids"]]:
        assert not os.path.exists(f"/proc/{pid}") or "zombie" in open(f"/proc/{pid}/status").read()
