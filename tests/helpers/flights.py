"""Flights for the end-to-end tests: real processes on free loopback ports.

``fly()`` starts ``offboard fly`` first (listening, so it hears the plant's very first packets),
then ``sitl-plant`` aimed at it, lets the test act while they fly (``during``), and always stops
both. ``UdpProxy`` sits between them when a test needs to cut the link. The few tests at the
end check the helpers themselves.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from pymavlink import mavutil

from bench.linkdelay import DelayedLink
from offboard.demo import free_udp_ports, stop_process
from offboard.model.vehicle import PAPER_VEHICLE_FILE

PY = sys.executable
ENV = {**os.environ, "MPLBACKEND": "Agg", "PYTHONUNBUFFERED": "1"}


def write_mission(path: Path, segments: str, name: str = "test-mission") -> Path:
    """A parametric mission file (paper frame, z up) from its ``[[mission.segment]]`` tables."""
    path.write_text(
        f'[mission]\nname = "{name}"\nframe = "paper-zup"\nangle_unit = "rad"\nstart = [0, 0, 0]\nstart_yaw = 0\n\n'
        + segments
    )
    return path


def arc_mission(path: Path) -> Path:
    """Three seconds of a climbing arc of radius 1 m about (0, 0, 1): a short flight that turns."""
    return write_mission(path, ARC_SEGMENTS)


#: The arc of ``arc_mission``.
ARC_SEGMENTS = """
[[mission.segment]]
type = "helix"
name = "arc"
center = [0, 0, 1]
radius_m = 1.0
phase = 0
angular_rate = 1.0
climb_rate_m_s = 0.2
yaw = 0
until_s = 3
"""


def arc_hold_mission(path: Path) -> Path:
    """``arc_mission``, then a hold of 10 s where the arc ends: in lockstep the arc alone is over in
    about 60 ms of wall time, too soon for frames a test sends at the offboard once it is armed."""
    return write_mission(path, ARC_SEGMENTS + ARC_HOLD_SEGMENT)


#: The hold after the arc of ``arc_hold_mission``.
ARC_HOLD_SEGMENT = """
[[mission.segment]]
type = "hold"
name = "hold"
position = [-0.99, 0.14, 1.6]  # where the arc ends
yaw = 0
until_s = 13
"""


def hover_mission(path: Path, height_m: float = 2.0, duration_s: float = 3.0) -> Path:
    return write_mission(path, f'[[mission.segment]]\ntype = "hold"\nname = "hover"\nposition = [0, 0, {height_m}]\n'
                               f"yaw = 0\nuntil_s = {duration_s}\n")


@dataclass
class Context:
    """What a test can reach while the two processes fly."""

    fly: subprocess.Popen
    plant: subprocess.Popen
    plant_port: int
    offboard_port: int
    gcs_port: int | None
    stderr_path: Path
    proxy: UdpProxy | None = None

    def stderr(self) -> str:
        return self.stderr_path.read_text(errors="replace")

    def wait_for(self, text: str, timeout_s: float = 60.0) -> None:
        """Block until ``offboard fly`` has printed ``text`` on stderr (or fail)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if text in self.stderr():
                return
            if self.fly.poll() is not None:
                pytest.fail(f"offboard fly exited ({self.fly.returncode}) before printing {text!r}:\n{self.stderr()}")
            time.sleep(0.02)
        pytest.fail(f"offboard fly did not print {text!r} within {timeout_s} s:\n{self.stderr()}")


@dataclass
class Flown:
    returncode: int
    stdout: str
    stderr: str
    run_dir: Path
    tlog: Path
    plant_tlog: Path
    plant_returncode: int | None
    summary: dict = field(default_factory=dict)
    #: what the plant wrote on stderr (its exit summary, with ``quiet_plant=False``)
    plant_stderr: str = ""

    @property
    def status(self) -> str:
        return str(self.summary.get("status", ""))


class UdpProxy(DelayedLink):
    """Forwards datagrams between the plant and ``offboard fly`` at once; ``drop`` cuts both ways.

    The plant sends to ``port`` (its ``--api-remote``), which forwards to the offboard's port;
    whatever the offboard answers goes back to the plant, so each process sees one peer, as
    without the proxy (``bench/linkdelay.py`` with no delay).
    """

    def __init__(self, plant_port: int, offboard_port: int) -> None:
        super().__init__(plant_port, offboard_port, delay_s=0.0)


def fly(
    tmp_path: Path,
    mission: Path | str,
    *,
    fly_args: tuple[str, ...] = (),
    plant_args: tuple[str, ...] = (),
    lockstep: bool = True,
    gcs: bool = False,
    proxy: bool = False,
    during: Callable[[Context], None] | None = None,
    before_plant: Callable[[Context], None] | None = None,
    fly_env: dict[str, str] | None = None,
    timeout_s: float = 240.0,
    name: str = "run",
    quiet_plant: bool = True,
    plots: bool = False,
) -> Flown:
    """Fly ``mission`` with ``offboard fly`` against ``sitl-plant``, both real processes
    (``quiet_plant=False``: the plant's banner, status line and exit summary kept in
    ``Flown.plant_stderr``; ``plots=True``: the figures drawn too)."""
    run_dir = tmp_path / name
    run_dir.mkdir(parents=True, exist_ok=True)
    plant_port, offboard_port, gcs_port = free_udp_ports(3)
    stderr_path, plant_stderr_path = run_dir / "offboard.stderr", run_dir / "plant.stderr"
    tlog, plant_tlog = run_dir / "flight.tlog", run_dir / "plant.tlog"
    fly_cmd = [PY, "-m", "offboard.cli", "fly", str(mission), "--connect", f"udpin:127.0.0.1:{offboard_port}",
               "--run-dir", str(run_dir), "--log", str(tlog), *([] if plots else ["--no-plots"]), "--json", *fly_args]
    if lockstep:
        fly_cmd.append("--lockstep")
    # the flights here are the paper's (its quad, Table I or designed gains, figures from its runs):
    # the paper's vehicle unless the test names one (the plant's default hovers at 0.5 as PX4 SITL)
    vehicle = [] if "--vehicle" in plant_args else ["--vehicle", str(PAPER_VEHICLE_FILE)]
    plant_cmd = [PY, "-m", "sitl_plant.cli", "--api-bind", f"127.0.0.1:{plant_port}", *(["--quiet"] if quiet_plant else []),
                 "--log", str(plant_tlog), *vehicle,
                 *(["--gcs-bind", f"127.0.0.1:{gcs_port}", "--gcs-remote", "none"] if gcs else ["--gcs-bind", "none"]),
                 *plant_args]
    if lockstep:
        plant_cmd.append("--lockstep")
    proxy_obj = UdpProxy(plant_port, offboard_port) if proxy else None
    plant_cmd += ["--api-remote", f"127.0.0.1:{proxy_obj.port if proxy_obj else offboard_port}"]
    fly_proc = plant_proc = None
    stdout = ""
    try:
        if proxy_obj is not None:
            proxy_obj.__enter__()
        with stderr_path.open("w") as err:
            fly_proc = subprocess.Popen(fly_cmd, stdout=subprocess.PIPE, stderr=err, text=True, env={**ENV, **(fly_env or {})})
        ctx = Context(fly_proc, None, plant_port, offboard_port, gcs_port if gcs else None, stderr_path, proxy_obj)  # type: ignore[arg-type]
        ctx.wait_for("listening on", 30)
        if before_plant is not None:  # the offboard is up and waiting for a vehicle
            before_plant(ctx)
        with plant_stderr_path.open("w") as plant_err:
            plant_proc = subprocess.Popen(plant_cmd, stdout=subprocess.DEVNULL, stderr=plant_err, env=ENV)
        ctx.plant = plant_proc
        if during is not None:
            during(ctx)
        try:
            stdout, _ = fly_proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            fly_proc.kill()
            stdout, _ = fly_proc.communicate()
            pytest.fail(f"offboard fly did not finish within {timeout_s} s:\n{stderr_path.read_text()}")
    finally:
        if fly_proc is not None and fly_proc.poll() is None:
            stop_process(fly_proc)
        plant_code = stop_process(plant_proc) if plant_proc is not None else None
        if proxy_obj is not None:
            proxy_obj.__exit__(None, None, None)
    summary_path = run_dir / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.is_file() else {}
    return Flown(fly_proc.returncode, stdout, stderr_path.read_text(errors="replace"), run_dir, tlog, plant_tlog, plant_code, summary,
                 plant_stderr_path.read_text(errors="replace") if plant_stderr_path.is_file() else "")


def read_tlog(path: Path) -> list:
    """Every message of a tlog, as pymavlink reads it (the whole file must parse)."""
    log = mavutil.mavlink_connection(str(path), dialect="common", robust_parsing=False)
    out = []
    while True:
        msg = log.recv_match()
        if msg is None:
            break
        out.append(msg)
    return out


def error_3d(s: dict):  # noqa: ANN201 - numpy, imported where used
    """The 3D distance from the reference of each sample of ``series(flown)``."""
    import numpy as np

    pos = np.stack([s[f"pos_ned_m_{i}"] for i in range(3)], axis=1)
    ref = np.stack([s[f"ref_pos_ned_m_{i}"] for i in range(3)], axis=1)
    return np.linalg.norm(ref - pos, axis=1)


def rms(values) -> float:  # noqa: ANN001
    import numpy as np

    return float(np.sqrt(np.mean(np.asarray(values) ** 2)))


def series(flown: Flown) -> dict:
    """The record of a flight (series.csv) as arrays."""
    import numpy as np

    with (flown.run_dir / "series.csv").open() as fh:
        header = fh.readline().strip().split(",")
        data = np.loadtxt(fh, delimiter=",", ndmin=2)
    return {name: data[:, i] for i, name in enumerate(header)}
