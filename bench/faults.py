"""Faults, measured (issue 14): the paper helix over a lossy, delayed link, and the vehicle's
failsafe when the offboard is killed.

- **A bad link**: ``sitl-plant --link loss=20,delay=50,jitter=20 --seed N`` (sitl_plant/impairment.py,
  both directions) under ``offboard fly`` of the paper helix in real time, for several seeds,
  beside the same flight over a clean link: how many complete, and the helix phase's 3D RMS
  against the clean run's.
- **A killed offboard**: ``offboard fly`` killed with SIGKILL at a seeded random moment of a hover;
  from the plant's log, the time from the last setpoint it received to its failsafe
  (STATUSTEXT), against ``COM_OF_LOSS_T`` plus one control period.

    python bench/faults.py [--quick]

Real time, so trials run a few at a time (they wait more than they compute).
"""

from __future__ import annotations

import argparse
import random
import signal
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.loop import PY, fly, hover  # noqa: E402
from offboard.demo import free_udp_ports  # noqa: E402
from offboard import jsonout  # noqa: E402
from offboard.missions import MISSIONS_DIR  # noqa: E402
from offboard.replay import TlogReader  # noqa: E402

HELIX = MISSIONS_DIR / "paper-helix.toml"
LINK = "loss=20,delay=50,jitter=20"
COM_OF_LOSS_T_S = 1.0  # the plant's default (PX4's)
CONTROL_PERIOD_S = 0.05
PARALLEL = 4
ISSUE_TRIALS = 20  # lossy seeds and offboard kills issue 14 asks for (the full run's)
#: what ``--quick`` runs (the smoke test): seeds of the lossy flight (a 1 s hover), offboard kills
QUICK_LOSSY_SEEDS = [1]
QUICK_KILLS = 1
NUMBERS = {1: "one", 2: "two", 3: "three"}


def _helix_rms(summary: dict) -> float | None:
    """The helix phase's 3D RMS (the whole flight's for a mission without one)."""
    phases = summary.get("phases", [])
    for phase in phases:
        if phase["name"].startswith("helix"):
            return float(phase["axes"]["3d"]["rms_m"])
    return float(phases[0]["axes"]["3d"]["rms_m"]) if phases else None


def lossy_helix(folder: Path, seeds: list[int], mission: Path = HELIX) -> dict:
    """The mission over a clean link and over ``LINK`` for each seed, a few at a time (real time:
    the flights wait on the clock, not on the processor)."""

    def one(seed: int) -> dict:
        try:
            run = fly(folder / f"lossy-{seed}", mission, lockstep=False, rss_interval_s=None,
                      plant_args=("--link", LINK, "--seed", str(seed)))  # fmt: skip
        except RuntimeError as exc:  # no summary: the flight never started (counted, not complete)
            return {"seed": seed, "status": "no summary", "detail": str(exc).splitlines()[-1], "helix_rms_m": None,
                    "lost": None, "received": None}  # fmt: skip
        s = run["summary"]
        return {"seed": seed, "status": s["status"], "helix_rms_m": _helix_rms(s), "lost": s["messages"]["lost"],
                "received": s["messages"]["received"]}  # fmt: skip

    with ThreadPoolExecutor(PARALLEL) as pool:
        clean_run = pool.submit(fly, folder / "clean", mission, lockstep=False, rss_interval_s=None)
        runs = list(pool.map(one, seeds))
        clean = clean_run.result()
    clean_rms = _helix_rms(clean["summary"])
    ratios = sorted(r["helix_rms_m"] / clean_rms for r in runs if r["helix_rms_m"] is not None and clean_rms)
    return {
        "link": LINK, "mission": mission.name, "clean_status": clean["summary"]["status"], "clean_helix_rms_m": clean_rms,
        "runs": runs, "complete": sum(r["status"] == "complete" for r in runs), "trials": len(runs),
        "rms_ratio_median": ratios[len(ratios) // 2] if ratios else None, "rms_ratio_max": ratios[-1] if ratios else None,
        "command": f"python -m sitl_plant.cli --link {LINK} --seed N  |  python -m offboard.cli fly {mission.name}",
    }  # fmt: skip


def _kill_trial(folder: Path, seed: int) -> dict:
    """Hover; SIGKILL the offboard 0.5-3 s after arming (seeded); the plant's failsafe delay."""
    rng = random.Random(seed)
    folder.mkdir(parents=True, exist_ok=True)
    plant_port, fly_port = free_udp_ports(2)
    mission = hover(folder, 30.0)
    out = folder / "offboard.out"
    fly_proc = subprocess.Popen(
        [PY, "-m", "offboard.cli", "fly", str(mission), "--connect", f"udpin:127.0.0.1:{fly_port}", "--run-dir",
         str(folder), "--no-plots"], stdout=subprocess.DEVNULL, stderr=out.open("w"))  # fmt: skip
    plant_proc = subprocess.Popen(
        [PY, "-m", "sitl_plant.cli", "--api-bind", f"127.0.0.1:{plant_port}", "--api-remote", f"127.0.0.1:{fly_port}",
         "--gcs-bind", "none", "--quiet", "--log", str(folder / "plant.tlog")], stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while "armed: flying" not in out.read_text() and time.monotonic() < deadline and fly_proc.poll() is None:
            time.sleep(0.02)
        time.sleep(rng.uniform(0.5, 3.0))
        fly_proc.send_signal(signal.SIGKILL)
        fly_proc.wait()
        time.sleep(COM_OF_LOSS_T_S + 1.0)
    finally:
        for proc in (fly_proc, plant_proc):
            if proc.poll() is None:
                proc.terminate()
                proc.wait(timeout=20)
    log = list(TlogReader(folder / "plant.tlog"))
    setpoints = [r.time_s for r in log if r.msg.get_type() == "SET_ATTITUDE_TARGET"]
    last = setpoints[-1] if setpoints else None
    fired = [r.time_s for r in log if last is not None and r.time_s > last and r.msg.get_type() == "STATUSTEXT"
             and "failsafe" in r.msg.text.lower()]  # fmt: skip
    return {"seed": seed, "failsafe_after_s": (fired[0] - last) if fired else None}


def kill_trials(folder: Path, n: int, seed: int = 14) -> dict:
    with ThreadPoolExecutor(PARALLEL) as pool:
        trials = list(pool.map(lambda i: _kill_trial(folder / f"kill-{i}", seed * 1000 + i), range(n)))
    delays = [t["failsafe_after_s"] for t in trials if t["failsafe_after_s"] is not None]
    bound = COM_OF_LOSS_T_S + CONTROL_PERIOD_S
    return {"trials": n, "fired": len(delays), "within_bound": sum(d <= bound for d in delays), "bound_s": bound,
            "max_s": max(delays) if delays else None, "min_s": min(delays) if delays else None}  # fmt: skip


def shortfalls(result: dict) -> list[str]:
    """What fell short of issue 14's figures (every lossy flight complete, every failsafe within
    its bound), one sentence each; [] when all was met."""
    lossy, kill = result["lossy"], result["kill"]
    out = []
    if lossy["complete"] < lossy["trials"]:
        out.append(f"the lossy flight completed in {lossy['complete']} of {lossy['trials']} seeds, not all")
    if kill["fired"] < kill["trials"]:
        out.append(f"the failsafe fired in {kill['fired']} of {kill['trials']} kill trials, not all")
    if kill["within_bound"] < kill["trials"]:
        out.append(f"the failsafe came within {kill['bound_s']:.2f} s of the last setpoint in {kill['within_bound']} of "
                   f"{kill['trials']} kill trials, not all")  # fmt: skip
    return out


def measure(quick: bool = False, folder: Path | None = None) -> dict:
    folder = folder or Path(tempfile.mkdtemp(prefix="bench-faults-"))
    mission = hover(folder, 1.0) if quick else HELIX
    seeds = QUICK_LOSSY_SEEDS if quick else list(range(1, ISSUE_TRIALS + 1))
    if quick:  # the harness, not the figures: the one lossy flight and the one kill at once
        with ThreadPoolExecutor(2) as pool:
            kill = pool.submit(kill_trials, folder / "kill", QUICK_KILLS)
            result = {"lossy": lossy_helix(folder / "lossy", seeds, mission), "kill": kill.result()}
    else:  # one after the other: the kill trials time the failsafe to 50 ms, not on a loaded machine
        result = {"lossy": lossy_helix(folder / "lossy", seeds, mission), "kill": kill_trials(folder / "kill", ISSUE_TRIALS)}
    result["shortfalls"] = shortfalls(result)
    return result


def markdown(result: dict) -> str:
    lossy, kill = result["lossy"], result["kill"]
    rms = lossy["clean_helix_rms_m"]
    lines = [
        "### Faults: a lossy link, a killed offboard",
        "",
        f"`{lossy['command']}` (real time, both directions of the link impaired):",
        "",
        "| flight | complete | helix 3D RMS | RMS / clean run (median, max) |",
        "|---|---|---|---|",
        f"| clean link | {lossy['clean_status']} | {rms:.3f} m |  |" if rms is not None else "| clean link | n/a | n/a | |",
        f"| {lossy['link']} | {lossy['complete']} of {lossy['trials']} seeds | "
        + (f"{lossy['rms_ratio_median'] * rms:.3f} m (median) | {lossy['rms_ratio_median']:.2f}, {lossy['rms_ratio_max']:.2f} |"
           if lossy["rms_ratio_median"] is not None and rms is not None else "n/a | n/a |"),
        "",
        f"Offboard killed (SIGKILL) at a seeded moment 0.5-3 s into a hover, {kill['trials']} trials: the plant's "
        f"failsafe fired in {kill['fired']}, within COM_OF_LOSS_T + one control period ({kill['bound_s']:.2f} s) of the "
        f"last setpoint in {kill['within_bound']}"
        + (f" (from {kill['min_s']:.3f} to {kill['max_s']:.3f} s)." if kill["max_s"] is not None else "."),
    ]  # fmt: skip
    short = shortfalls(result)
    few = f"; issue 14 asks for {ISSUE_TRIALS}" if min(kill["trials"], lossy["trials"]) < ISSUE_TRIALS else ""
    met = f"Met (issue 14): every lossy flight complete, every failsafe within its bound ({kill['trials']} kill trials{few})."
    lines += ["", *(f"**NOT MET (issue 14): {text}.**" for text in short)] if short else ["", met]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    seeds, kills = len(QUICK_LOSSY_SEEDS), QUICK_KILLS
    parser.add_argument("--quick", action="store_true",
                        help=f"{NUMBERS.get(seeds, seeds)} lossy seed{'s' * (seeds != 1)} of a 1 s hover and "
                             f"{NUMBERS.get(kills, kills)} kill{'s' * (kills != 1)} (the smoke test)")  # fmt: skip
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    result = measure(args.quick)
    print(jsonout.dumps(result, indent=1) if args.json else markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
