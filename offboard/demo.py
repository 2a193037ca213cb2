"""``make demo``: the paper's helix flown over MAVLink by two real processes.

Starts ``sitl-plant`` (default rigid-body model, PX4-like inner loop) and ``offboard fly``
(attitude output, yaw-aware law) on free UDP ports, flies ``missions/paper-helix.toml``, and
leaves in the run folder the offboard's ``flight.tlog``, the plant's ``plant.tlog``, the paper's
figures (PNG), ``series.csv``, ``summary.txt`` and ``summary.json``; then stops the plant.

Both children run in their own sessions, so Ctrl-C reaches only this process, which forwards
one SIGINT to ``offboard fly`` (it lands and disarms) and then stops the plant; a second Ctrl-C
stops the offboard at once. No child outlives the demo, whatever happens.

    python -m offboard.demo --run-dir runs/demo [--lockstep] [--mission FILE]
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from offboard.errors import UserError
from offboard.missions import MISSIONS_DIR
from offboard.model.clihelp import HelpFormatter
from offboard.model.paths import output_folder
from offboard.model.vehicle import PAPER_VEHICLE_FILE

PAPER_HELIX = MISSIONS_DIR / "paper-helix.toml"
STOP_TIMEOUT_S = 5.0


#: PX4 SITL's and QGroundControl's ports: a real PX4 or ground station may be on them.
PX4_PORTS = frozenset({14540, 14550, 14580, 18570})


def free_udp_ports(count: int) -> list[int]:
    """Ports the OS has just handed out for UDP on 127.0.0.1 (all distinct, none of PX4_PORTS)."""
    while True:
        socks = []
        try:
            for _ in range(count):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                s.bind(("127.0.0.1", 0))
                socks.append(s)
            ports = [s.getsockname()[1] for s in socks]
        finally:
            for s in socks:
                s.close()
        if not PX4_PORTS & set(ports):
            return ports


def stop_process(proc: subprocess.Popen, sig: int = signal.SIGINT, timeout_s: float = STOP_TIMEOUT_S) -> int:
    """Ask a child to stop, then insist: SIGINT, wait, SIGKILL. Returns its exit code."""
    if proc.poll() is None:
        try:
            proc.send_signal(sig)
            return proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
    return proc.wait()


def build_parser() -> argparse.ArgumentParser:
    """``python -m offboard.demo``'s options."""
    parser = argparse.ArgumentParser(
        prog="python -m offboard.demo",
        description="Fly the paper's helix over MAVLink: sitl-plant and offboard fly as two processes.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--run-dir", type=Path, default=None, help="run folder (default: runs/demo-<time>)")
    parser.add_argument("--mission", type=Path, default=PAPER_HELIX, help="mission file")
    parser.add_argument("--model", choices=("rigid-body", "paper"), default="rigid-body", help="sitl-plant --model")
    parser.add_argument("--lockstep", action="store_true", help="deterministic and as fast as the CPU allows, instead of real time")
    parser.add_argument("--quiet", action="store_true", help="no progress from offboard fly")
    return parser


def main(argv: list[str] | None = None) -> int:
    """``make demo``: the plant and ``offboard fly`` on the paper helix, as two processes; the run folder's
    path and verdict; the flight's exit code.
    """
    args = build_parser().parse_args(argv)
    run_dir: Path = args.run_dir or Path("runs") / f"demo-{time.strftime('%Y%m%d-%H%M%S')}"
    try:
        output_folder(run_dir, "--run-dir")
    except UserError as exc:
        print(f"demo: error: {exc}", file=sys.stderr)
        return 2
    plant_port, offboard_port = free_udp_ports(2)
    python = sys.executable
    plant_cmd = [
        python, "-m", "sitl_plant.cli", "--model", args.model, "--vehicle", str(PAPER_VEHICLE_FILE),  # the paper's quad
        "--api-bind", f"127.0.0.1:{plant_port}", "--api-remote", f"127.0.0.1:{offboard_port}",
        "--gcs-bind", "none", "--log", str(run_dir / "plant.tlog"),
    ]  # fmt: skip  (not --quiet: plant.log keeps its banner, a status line every 10 s and its summary)
    fly_cmd = [
        python, "-m", "offboard.cli", "fly", str(args.mission), "--model", args.model,
        "--connect", f"udpin:127.0.0.1:{offboard_port}", "--run-dir", str(run_dir),
        "--log", str(run_dir / "flight.tlog"),
    ]  # fmt: skip
    if args.lockstep:
        plant_cmd.append("--lockstep")
        fly_cmd.append("--lockstep")
    if args.quiet:
        fly_cmd.append("--quiet")
    (run_dir / "commands.txt").write_text(" ".join(plant_cmd) + "\n" + " ".join(fly_cmd) + "\n")

    interrupts = {"count": 0}

    def on_signal(signum: int, frame: object) -> None:
        interrupts["count"] += 1
        raise KeyboardInterrupt

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    plant: subprocess.Popen | None = None
    fly: subprocess.Popen | None = None
    code = 1
    try:
        # the offboard first, so that it hears the plant's very first packets
        fly = subprocess.Popen(fly_cmd, start_new_session=True)
        plant_log = (run_dir / "plant.log").open("w")
        with plant_log:
            plant = subprocess.Popen(plant_cmd, stdout=plant_log, stderr=subprocess.STDOUT, start_new_session=True)
        print(f"demo: sitl-plant (pid {plant.pid}) on UDP {plant_port}, offboard fly (pid {fly.pid}) on UDP "
              f"{offboard_port}; {'lockstep' if args.lockstep else 'real time'}", file=sys.stderr, flush=True)
        while True:
            try:
                code = fly.wait()
                break
            except KeyboardInterrupt:
                if interrupts["count"] == 1:
                    print("\ndemo: interrupted: offboard fly lands and disarms (Ctrl-C again to stop at once)",
                          file=sys.stderr, flush=True)
                    fly.send_signal(signal.SIGINT)
                else:
                    fly.kill()
    except KeyboardInterrupt:
        code = 130
    finally:
        for proc in (fly, plant):
            if proc is not None:
                try:
                    stop_process(proc)
                except KeyboardInterrupt:
                    proc.kill()
                    proc.wait()
        for s, handler in previous.items():
            signal.signal(s, handler)
    files = sorted(p.name for p in run_dir.iterdir() if p.is_file())
    print(f"demo: run folder {run_dir.resolve()}: {', '.join(files)}", file=sys.stderr)
    verdict = _verdict(run_dir / "summary.json")
    if verdict:
        print(f"demo: {verdict}", file=sys.stderr)
    if (run_dir / "summary.txt").is_file():
        print(f"demo: summary in {run_dir / 'summary.txt'}, figures {run_dir}/*.png, logs flight.tlog (offboard) "
              f"and plant.tlog (plant)", file=sys.stderr)
    return code if code >= 0 else 128 - code


def _verdict(summary_json: Path) -> str:
    """The flight's one-line verdict from its summary.json ('' without one)."""
    import json

    try:
        data = json.loads(summary_json.read_text())
    except (OSError, ValueError):
        return ""
    verdict = data.get("verdict") if isinstance(data, dict) else None
    limit = ((data.get("controller") or {}).get("tilt_max_deg")) if isinstance(data, dict) else None
    if not isinstance(verdict, str):
        return ""
    return verdict + (f" (limit {limit:g} deg)" if isinstance(limit, (int, float)) else "") + f", status {data.get('status')}"


if __name__ == "__main__":
    os.environ.setdefault("MPLBACKEND", "Agg")
    sys.exit(main())
