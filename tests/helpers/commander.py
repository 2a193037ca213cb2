"""A small pymavlink client for the commander comparison (tests/e2e/test_px4_parity_commander.py).

The same code talks to the real PX4 SITL and to ``sitl-plant``: it listens on a UDP port
(``udpin``), waits for the autopilot's heartbeat, sends commands and collects every COMMAND_ACK
(PX4 sends two for DO_SET_MODE), the heartbeats, STATUSTEXTs and the local position with the
vehicle's own ``time_boot_ms`` (so durations are simulation time, whatever ``--speed``). While it
waits it keeps sending what it was told to: a GCS heartbeat every wall second, position setpoints
(proof of offboard life) and MANUAL_CONTROL (virtual sticks), each at 50 Hz of wall time.
"""

from __future__ import annotations

import fcntl
import math
import os
import socket
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

from pymavlink import mavutil

from offboard.demo import free_udp_ports, stop_process

REPO = Path(__file__).resolve().parents[2]
mavlink = mavutil.mavlink

POSITION_ONLY = 0b0000_1111_1111_1000  # SET_POSITION_TARGET_LOCAL_NED: x, y, z (and yaw) used
AUTO_LOITER, AUTO_TAKEOFF, AUTO_LAND, AUTO_RTL = (4, 3), (4, 2), (4, 6), (4, 5)
POSCTL, ALTCTL, OFFBOARD, MANUAL = (3, 0), (2, 0), (6, 0), (1, 0)


#: PX4's custom modes (main, sub) by the name QGroundControl shows, for the parity findings.
MODE_NAMES = {AUTO_LOITER: "Hold", AUTO_TAKEOFF: "Takeoff", AUTO_LAND: "Land", AUTO_RTL: "Return", (4, 4): "Mission",
              (4, 8): "Follow Target", POSCTL: "Position", ALTCTL: "Altitude", OFFBOARD: "Offboard", MANUAL: "Manual",
              (7, 0): "Stabilized", (10, 0): "Termination", (3, 1): "Orbit"}  # fmt: skip


def mode_name(mode: tuple[int, int]) -> str:
    """``mode`` (main, sub) by name, or as ``main/sub``."""
    return MODE_NAMES.get((mode[0], mode[1]), f"{mode[0]}/{mode[1]}")


def heartbeat_text(hb: tuple[int, tuple[int, int], int] | None) -> str:
    """(base_mode, mode, system_status) as the parity pages write it: ``Position 209 / 5``."""
    return "none" if hb is None else f"{mode_name(hb[1])} {hb[0]} / {hb[2]}"


def results_text(results: list[int]) -> str:
    """COMMAND_ACK results by name: ``ACCEPTED, TEMPORARILY_REJECTED`` (``none`` for no ACK)."""
    names = mavlink.enums["MAV_RESULT"]
    return ", ".join(names[r].name.removeprefix("MAV_RESULT_") if r in names else str(r) for r in results) or "none"


def mode_of(custom_mode: int) -> tuple[int, int]:
    main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
    return (main, sub if main == 4 else 0)


@dataclass
class Ack:
    command: int
    result: int
    wall_s: float


@dataclass
class Sample:
    t_s: float  # vehicle time
    pos_ned_m: tuple[float, float, float]
    vel_ned_m_s: tuple[float, float, float]


@dataclass
class Client:
    port: int
    conn: object = None
    heartbeat: object = None
    boot_s: float = 0.0
    acks: list[Ack] = field(default_factory=list)
    texts: list[tuple[float, str]] = field(default_factory=list)
    samples: list[Sample] = field(default_factory=list)
    gps_alt: list[tuple[float, float]] = field(default_factory=list)  # vehicle time, GPS altitude AMSL (m)
    heartbeats: list[tuple[float, int, int, int]] = field(default_factory=list)  # t, base_mode, custom_mode, status
    setpoint: tuple[float, float, float] | None = None
    sticks: tuple[int, int, int, int] | None = None
    attitude_yaw: float = 0.0
    yaw_samples: list[tuple[float, float]] = field(default_factory=list)
    of_loss_t: float = 1.0  # the vehicle's COM_OF_LOSS_T, for the test's arithmetic
    estimator_flags: list[tuple[float, int]] = field(default_factory=list)  # vehicle time, ESTIMATOR_STATUS flags
    #: the simulator's truth (HIL_STATE_QUATERNION, on request): vehicle time, lat, lon (deg), alt AMSL (m)
    truths: list[tuple[float, float, float, float]] = field(default_factory=list)
    #: stops the vehicle's GPS (``fly_side_by_side``: PX4's shell, the plant's MAV_CMD_INJECT_FAILURE)
    fail_gps: Callable[[], None] | None = None
    _next_hb: float = 0.0
    _next_send: float = 0.0

    def connect(self, timeout_s: float = 60.0) -> None:
        self.conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{self.port}", source_system=245, source_component=190)
        # room for a few seconds of a vehicle at --speed 4 (~1 500 datagrams/s): the two clients of a
        # side-by-side run share one interpreter, and a starved one overflowed the 208 kB default
        # (a make test run lost PX4's "Failsafe activated" so); the kernel caps it at rmem_max
        self.conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        deadline = time.monotonic() + timeout_s
        while self.heartbeat is None:
            assert time.monotonic() < deadline, "no autopilot heartbeat"
            self.pump(0.2)

    # -- the loop --------------------------------------------------------------------------------

    def pump(self, wall_s: float, until: Callable[[], bool] | None = None) -> bool:
        end = time.monotonic() + wall_s
        while True:
            now = time.monotonic()
            if until is not None and until():
                return True
            if now >= end:
                return False
            self._send_due(now)
            msg = self.conn.recv_match(blocking=True, timeout=0.005)
            while msg is not None:
                self._take(msg)
                msg = self.conn.recv_match(blocking=False)

    def _send_due(self, now: float) -> None:
        c = self.conn
        if self.heartbeat is None:
            return
        if now >= self._next_hb:
            c.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            self._next_hb = now + 0.2
        if now >= self._next_send:
            self._next_send = now + 0.02
            if self.setpoint is not None:
                n, e, d = self.setpoint
                c.mav.set_position_target_local_ned_send(int(self.t_s * 1000), c.target_system, c.target_component,
                                                         mavlink.MAV_FRAME_LOCAL_NED, POSITION_ONLY,
                                                         n, e, d, 0, 0, 0, 0, 0, 0, 0, 0)
            if self.sticks is not None:
                x, y, z, r = self.sticks
                c.mav.manual_control_send(c.target_system, x, y, z, r, 0)

    def _take(self, msg) -> None:
        kind = msg.get_type()
        if msg.get_srcComponent() != 1 and kind != "COMMAND_ACK":
            return
        if kind == "HEARTBEAT" and msg.autopilot == mavlink.MAV_AUTOPILOT_PX4:
            self.heartbeat = msg
            self.heartbeats.append((self.t_s, msg.base_mode, msg.custom_mode, msg.system_status))
        elif kind == "COMMAND_ACK":
            self.acks.append(Ack(int(msg.command), int(msg.result), time.monotonic()))
        elif kind == "STATUSTEXT":
            self.texts.append((self.t_s, msg.text))
        elif kind == "LOCAL_POSITION_NED":
            self.boot_s = msg.time_boot_ms / 1000.0
            self.samples.append(Sample(self.boot_s, (msg.x, msg.y, msg.z), (msg.vx, msg.vy, msg.vz)))
        elif kind == "GPS_RAW_INT":
            self.gps_alt.append((self.t_s, msg.alt / 1000.0))
        elif kind == "ESTIMATOR_STATUS":
            self.estimator_flags.append((self.t_s, int(msg.flags)))
        elif kind == "HIL_STATE_QUATERNION":  # no time of its own (PX4 sends 0): the estimate's before it
            self.truths.append((self.t_s, msg.lat / 1e7, msg.lon / 1e7, msg.alt / 1000.0))
        elif kind == "ATTITUDE":
            self.boot_s = max(self.boot_s, msg.time_boot_ms / 1000.0)
            self.attitude_yaw = msg.yaw
            self.yaw_samples.append((msg.time_boot_ms / 1000.0, msg.yaw))

    # -- what it reads ---------------------------------------------------------------------------

    @property
    def t_s(self) -> float:
        return self.boot_s

    @property
    def mode(self) -> tuple[int, int]:
        return mode_of(self.heartbeat.custom_mode)

    @property
    def armed(self) -> bool:
        return bool(self.heartbeat.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)

    @property
    def down_m(self) -> float:
        return self.samples[-1].pos_ned_m[2] if self.samples else 0.0

    def wait(self, cond: Callable[[], bool], sim_s: float, speed: float) -> bool:
        """Until ``cond()``, at most ``sim_s`` of vehicle time (a loaded machine may run the
        vehicle slower than ``speed``: the wall-clock cap is generous)."""
        t0 = self.t_s
        self.pump(sim_s / speed * 4.0 + 10.0, lambda: cond() or self.t_s >= t0 + sim_s)
        return cond()

    def wait_sim(self, sim_s: float) -> None:
        t0 = self.t_s
        self.pump(600.0, lambda: self.t_s >= t0 + sim_s)

    # -- commands --------------------------------------------------------------------------------

    def command(self, command: int, *params: float, settle_s: float = 0.3, attempts: int = 3) -> list[int]:
        """Send a COMMAND_LONG; the results of every ACK for it within ``settle_s`` of wall time
        after the first one. A try waits 2 s for its ACK and is repeated (with the confirmation
        field counting up) when none came, as MAVSDK and QGroundControl do: on a loaded machine a
        PX4 at ``--speed 4`` can answer later than that. A refusal is an answer, never retried."""
        p = list(params) + [0.0] * (7 - len(params))
        first = len(self.acks)
        c = self.conn
        for confirmation in range(attempts):
            c.mav.command_long_send(c.target_system, c.target_component, command, confirmation, *p)
            if self.pump(2.0, lambda: any(a.command == command for a in self.acks[first:])):
                break
        self.pump(settle_s)
        return [a.result for a in self.acks[first:] if a.command == command]

    def set_mode(self, mode: tuple[int, int]) -> list[int]:
        """DO_SET_MODE; every ACK (PX4 sends its second 5-12 ms after the first in real time)."""
        return self.command(mavlink.MAV_CMD_DO_SET_MODE, 1, mode[0], mode[1], settle_s=0.15)

    def arm(self, arm: bool = True) -> list[int]:
        return self.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1 if arm else 0, settle_s=0.1)

    def take_off(self, ground_down_m: float, speed: float, sim_s: float = 30.0) -> None:
        """Arm and NAV_TAKEOFF to the vehicle's take-off height, until Hold holds it 1.5 m or more
        above ``ground_down_m`` (at most ``sim_s`` of the vehicle's time). After boot, a fall or a
        landing the arm's ACK can miss the 2 s a try waits on a loaded machine: retried, as MAVSDK
        does (a refusal still fails). A vehicle still on the ground after ``sim_s`` (a PX4 at
        ``--speed 4`` starved by a loaded machine once sat there, or disarmed itself, as PX4 does
        10 s after an arm without a take-off) is armed and sent the take-off once more, as a
        ground station's user would; a second failure says what the vehicle did."""
        takeoff: list[int] = []
        for _ in range(2):
            results: list[int] = []
            for _ in range(4):
                results = self.arm()
                if results:
                    break
                self.pump(1.0)
            assert results[-1:] == [mavlink.MAV_RESULT_ACCEPTED], f"arming: {results}"
            takeoff = self.command(mavlink.MAV_CMD_NAV_TAKEOFF, math.nan, 0, 0, math.nan, math.nan, math.nan, math.nan, settle_s=0.0)
            if self.wait(lambda: self.mode == AUTO_LOITER and self.down_m < ground_down_m - 1.5, sim_s, speed):
                return
            if ground_down_m - self.down_m > 0.5:  # it flew: not in Hold at its height, which a retry would not mend
                break
        raise AssertionError(f"no takeoff on {self.port}: take-off ACKs {takeoff}, mode {self.mode}, armed {self.armed}, "
                             f"{ground_down_m - self.down_m:.2f} m up, texts {self.texts[-5:]}")

    def set_param(self, name: str, value: float, integer: bool) -> None:
        c = self.conn
        if integer:
            raw = struct.unpack("<f", struct.pack("<i", int(value)))[0]
            kind = mavlink.MAV_PARAM_TYPE_INT32
        else:
            raw, kind = float(value), mavlink.MAV_PARAM_TYPE_REAL32
        c.mav.param_set_send(c.target_system, c.target_component, name.encode(), raw, kind)
        self.pump(0.3)

    def get_param(self, name: str) -> float | None:
        """PARAM_REQUEST_READ by name; the value (INT32 decoded from its bytes) or None."""
        c = self.conn
        got: list = []

        def seen() -> bool:
            msg = c.messages.get("PARAM_VALUE")
            if msg is not None and msg.param_id == name:
                got.append(msg)
            return bool(got)

        for _ in range(3):
            c.mav.param_request_read_send(c.target_system, c.target_component, name.encode(), -1)
            if self.pump(1.0, seen):
                msg = got[0]
                if msg.param_type == mavlink.MAV_PARAM_TYPE_INT32:
                    return float(struct.unpack("<i", struct.pack("<f", msg.param_value))[0])
                return float(msg.param_value)
        return None

    def texts_since(self, t_s: float) -> list[str]:
        return [text for t, text in self.texts if t >= t_s]

    def close(self) -> None:
        self.conn.close()


# --- the plant as a process ------------------------------------------------------------------------


class PlantProcess:
    """``python -m sitl_plant.cli --speed S`` sending its API link to ``port``; stopped by ``stop()``."""

    def __init__(self, port: int, speed: float, *extra: str) -> None:
        cmd = [sys.executable, "-m", "sitl_plant.cli", "--api-bind", "127.0.0.1:0", "--api-remote", f"127.0.0.1:{port}",
               "--gcs-bind", "none", "--speed", f"{speed:g}", "--quiet", *extra]
        self.proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                     env={**os.environ, "PYTHONUNBUFFERED": "1"})

    def stop(self) -> None:
        stop_process(self.proc)


@dataclass
class Observed:
    """What one vehicle answered to a side-by-side script: acks, heartbeats and texts by step, figures by name."""

    acks: dict[str, list[int]] = field(default_factory=dict)
    heartbeat: dict[str, tuple[int, tuple[int, int], int]] = field(default_factory=dict)
    texts: dict[str, list[str]] = field(default_factory=dict)
    figures: dict[str, float] = field(default_factory=dict)


def heartbeat_state(c: Client) -> tuple[int, tuple[int, int], int]:
    """The last HEARTBEAT as (base_mode, (main, sub) mode, system_status)."""
    h = c.heartbeat
    return (int(h.base_mode), mode_of(h.custom_mode), int(h.system_status))


def settle_heartbeat(c: Client) -> None:
    """Pump until the first heartbeat (1 Hz of vehicle time) sent at least 0.3 s of vehicle time
    from now: it tells the status after what was just asked."""
    t0 = c.t_s
    c.pump(6.0, lambda: bool(c.heartbeats) and c.heartbeats[-1][0] >= t0 + 0.3)


def print_figures(result: tuple, width: int = 55) -> None:  # noqa: ANN001
    """Each figure of a side-by-side run's (PX4, plant) observations, PX4's beside the plant's (-s)."""
    for name in result[0].figures:
        print(f"{name:<{width}} PX4 {result[0].figures[name]:7.2f}   plant {result[1].figures.get(name, math.nan):7.2f}")


def free_port() -> int:
    return free_udp_ports(1)[0]


T = TypeVar("T")


def _inject_gps_failure(c: Client) -> None:
    results = c.command(mavlink.MAV_CMD_INJECT_FAILURE, mavlink.FAILURE_UNIT_SENSOR_GPS, mavlink.FAILURE_TYPE_OFF, 0, 0, 0, 0, 0)
    assert results[-1:] == [mavlink.MAV_RESULT_ACCEPTED], f"MAV_CMD_INJECT_FAILURE: {results}"


def fly_side_by_side(folder: Path, speed: float, script: Callable[[Client], T]) -> tuple[T, T]:
    """(PX4's, the plant's): ``script`` run on a real PX4 SITL and on ``sitl-plant``, both at
    ``speed``, at the same time (a thread each). The plant is given PX4's COM_OF_LOSS_T and
    COM_RC_LOSS_T (PX4's start-up script multiplies them by the speed factor), so both run the same
    timeouts. ``script`` gets a connected client and closes nothing: the client is closed after.

    One such comparison at a time across the test workers (a lock file): two PX4s at speed 4 on
    two cores ran late enough to miss their failsafe and termination timings."""
    from bench.px4sitl import running_px4

    with open(Path(tempfile.gettempdir()) / "px4-side-by-side.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        return _fly_side_by_side(folder, speed, script, running_px4)


def _fly_side_by_side(folder: Path, speed: float, script: Callable[[Client], T], running_px4) -> tuple[T, T]:  # noqa: ANN001
    with running_px4(folder, speed=speed) as px4:
        px4_client = Client(px4.api_listen_port)
        px4_client.connect()
        loss_t = px4_client.get_param("COM_OF_LOSS_T")
        rc_loss_t = px4_client.get_param("COM_RC_LOSS_T")
        assert loss_t is not None and rc_loss_t is not None
        port = free_port()
        plant = PlantProcess(port, speed)
        try:
            plant_client = Client(port)
            plant_client.connect()
            plant_client.set_param("COM_OF_LOSS_T", loss_t, integer=False)
            plant_client.set_param("COM_RC_LOSS_T", rc_loss_t, integer=False)
            plant_client.set_param("SYS_FAILURE_EN", 1, integer=True)  # as PX4 SITL publishes it (px4_params.toml)
            got = plant_client.get_param("COM_OF_LOSS_T")
            assert got is not None and abs(got - loss_t) < 1e-6, (got, loss_t)
            for c in (px4_client, plant_client):
                c.of_loss_t = loss_t
            # PX4 v1.16's SIH build never answers MAV_CMD_INJECT_FAILURE: its GPS is stopped from its shell
            def stop_px4_gps() -> None:
                px4.shell("sensor_gps_sim", "stop")

            px4_client.fail_gps = stop_px4_gps
            plant_client.fail_gps = lambda: _inject_gps_failure(plant_client)

            def run(c: Client) -> T:
                try:
                    return script(c)
                finally:
                    c.close()

            with ThreadPoolExecutor(2) as pool:
                px4_run, plant_run = pool.submit(run, px4_client), pool.submit(run, plant_client)
                return px4_run.result(), plant_run.result()
        finally:
            plant.stop()
