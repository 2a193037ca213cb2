"""``sitl-plant`` as a real process, flown by pymavlink over real UDP on 127.0.0.1.

Every test starts its own plant on OS-chosen ports (the client binds port 0 and passes its
address with ``--api-remote``; the plant binds port 0 and is found from its first packet) and
kills it in the fixture's finaliser. Flights use lockstep, so they are fast and independent of
the machine's load.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from offboard.model.rotations import quat_from_euler
from offboard.model.vehicle import DEFAULT_VEHICLE_FILE, load_vehicle
from helpers import REPO
from helpers.flights import free_udp_ports

pytestmark = pytest.mark.e2e

NAN = math.nan
_DEFAULT = load_vehicle(DEFAULT_VEHICLE_FILE)
HOVER = _DEFAULT.mass_kg * _DEFAULT.gravity_m_s2 / _DEFAULT.max_thrust_n  # the default vehicle: m g / SIM_THR_MAX, ~0.5
IGNORE_ALL = 0b11000111  # SET_ATTITUDE_TARGET with nothing to fly: a lockstep tick, no proof of life


class Client:
    """A pymavlink client on a fresh UDP port, recording everything it receives."""

    def __init__(self) -> None:
        self.conn = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255, source_component=190, dialect="common")
        self.port = self.conn.port.getsockname()[1]
        self.mav = self.conn.mav
        self.acks: list = []
        self.texts: list[str] = []
        self.last: dict[str, object] = {}
        self.counts: Counter[str] = Counter()
        self.stamps: dict[str, set[int]] = {}
        #: the plant's address (``PlantProcess``): anything else is dropped. A lockstep plant of
        #: an earlier test whose client closed keeps sending to that port, which the kernel may
        #: give this client (once a test flew such a plant while its own was still starting)
        self.peer: tuple[str, int] | None = None
        self.foreign = 0
        self.conn.recv = self._recv  # type: ignore[method-assign]

    def _recv(self, n: int | None = None) -> bytes:
        """pymavlink's udpin ``recv``, but a datagram from anyone but ``peer`` is dropped (counted)."""
        try:
            data, sender = self.conn.port.recvfrom(65535)
        except (BlockingIOError, ConnectionRefusedError):
            return b""
        if self.peer is not None and sender != self.peer:
            self.foreign += 1
            return b""
        self.conn.clients = {sender}  # answered alone (pymavlink's udpin sends to every sender)
        return data

    def poll(self, timeout: float = 1.0):
        msg = self.conn.recv_match(blocking=True, timeout=timeout)
        if msg is None:
            return None
        kind = msg.get_type()
        self.counts[kind] += 1
        self.last[kind] = msg
        stamp = getattr(msg, "time_boot_ms", None)
        if stamp is not None:
            self.stamps.setdefault(kind, set()).add(stamp)
        if kind == "COMMAND_ACK":
            self.acks.append(msg)
        elif kind == "STATUSTEXT":
            self.texts.append(msg.text)
        return msg

    def wait_for(self, predicate: Callable[[object], bool], timeout: float = 10.0, what: str = "message"):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            msg = self.poll(min(1.0, max(0.01, deadline - time.monotonic())))
            if msg is not None and predicate(msg):
                return msg
        raise AssertionError(f"no {what} within {timeout} s (received {dict(self.counts)})")

    def wait_type(self, kind: str, timeout: float = 10.0, where: Callable[[object], bool] = lambda m: True):
        return self.wait_for(lambda m: m.get_type() == kind and where(m), timeout, kind)

    def command(self, number: int, *params: float, target=(1, 1)) -> int:
        p = list(params) + [NAN] * (7 - len(params))
        self.mav.command_long_send(target[0], target[1], number, 0, *p)
        return self.wait_type("COMMAND_ACK", where=lambda m: m.command == number).result

    def set_mode(self, main: int, sub: int = 0) -> int:
        """DO_SET_MODE; as PX4 the plant answers twice (ACCEPTED, then the commander's result): the last is the commander's."""
        self.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub)
        return self.wait_type("COMMAND_ACK", where=lambda m: m.command == mavlink.MAV_CMD_DO_SET_MODE).result

    def attitude(self, t_ms: int, roll=0.0, pitch=0.0, yaw=0.0, thrust=HOVER, mask=0b00000111) -> None:
        self.mav.set_attitude_target_send(t_ms, 1, 1, mask, quat_from_euler(roll, pitch, yaw), 0.0, 0.0, 0.0, thrust)

    def param(self, name: str) -> float:
        self.mav.param_request_read_send(1, 1, name.encode(), -1)
        return self.wait_type("PARAM_VALUE", where=lambda m: m.param_id == name).param_value

    def set_param(self, name: str, value: float) -> float:
        self.mav.param_set_send(1, 1, name.encode(), value, mavlink.MAV_PARAM_TYPE_REAL32)
        return self.wait_type("PARAM_VALUE", where=lambda m: m.param_id == name).param_value

    def fly(self, until_ms: int, answer: Callable[[int], None], on_new: Callable[[int], None] | None = None) -> object:
        """Lockstep: answer every LOCAL_POSITION_NED (repeats too) with ``answer(T)`` until T."""
        seen: set[int] = set()
        while True:
            msg = self.wait_type("LOCAL_POSITION_NED")
            t = msg.time_boot_ms
            if t not in seen:
                seen.add(t)
                if on_new is not None:
                    on_new(t)
            if t >= until_ms:
                return msg
            answer(t)

    def close(self) -> None:
        self.conn.close()


class PlantProcess:
    """``python -m sitl_plant.cli`` talking to a ``Client``."""

    def __init__(self, client: Client, args: list[str], quiet: bool = True) -> None:
        self.client = client
        port = free_udp_ports(1)[0]
        client.peer = ("127.0.0.1", port)
        cmd = [sys.executable, "-m", "sitl_plant.cli", "--api-bind", f"127.0.0.1:{port}", "--api-remote", f"127.0.0.1:{client.port}", "--gcs-bind", "none"]
        cmd += (["--quiet"] if quiet else []) + args
        self.proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 10.0) -> tuple[int, str]:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            _, err = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate()
        return self.proc.returncode, err

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.communicate()


@pytest.fixture
def start(request):
    """``start(*args, quiet=True)`` -> (client, plant), both cleaned up after the test."""
    made: list[tuple[Client, PlantProcess]] = []

    def _start(*args: str, quiet: bool = True) -> tuple[Client, PlantProcess]:
        client = Client()
        plant = PlantProcess(client, list(args), quiet)
        made.append((client, plant))
        client.wait_type("HEARTBEAT", timeout=20)
        return client, plant

    yield _start
    for client, plant in made:
        plant.kill()
        client.close()


# --- discovery, commands, parameters ---------------------------------------------------------------


def test_discovery(start):
    client, _ = start("--speed", "1")
    hb = client.wait_type("HEARTBEAT")
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (1, mavlink.MAV_COMP_ID_AUTOPILOT1)
    assert hb.type == mavlink.MAV_TYPE_QUADROTOR and hb.autopilot == mavlink.MAV_AUTOPILOT_PX4
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED and not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.custom_mode == (4 << 16) | (3 << 24)  # Hold
    assert hb.system_status == mavlink.MAV_STATE_STANDBY
    assert mavutil.mode_string_v10(hb) == "LOITER"
    for kind in ("ATTITUDE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "SYS_STATUS", "EXTENDED_SYS_STATE", "HIGHRES_IMU"):
        client.wait_type(kind)
    g = client.wait_type("GLOBAL_POSITION_INT")
    assert (g.lat, g.lon, g.alt) == (473977420, 85455940, 488000)
    assert client.wait_type("EXTENDED_SYS_STATE").landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND
    # requested messages, unknown commands, time sync
    assert client.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == mavlink.MAV_RESULT_ACCEPTED
    version = client.wait_type("AUTOPILOT_VERSION")
    assert version.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    assert client.command(mavlink.MAV_CMD_REQUEST_MESSAGE, 9999) == mavlink.MAV_RESULT_DENIED
    assert client.command(mavlink.MAV_CMD_DO_SET_SERVO, 1, 1500) == mavlink.MAV_RESULT_UNSUPPORTED
    client.mav.timesync_send(0, 123456789)
    sync = client.wait_type("TIMESYNC")
    assert sync.ts1 == 123456789 and sync.tc1 > 0


def test_parameters(start):
    client, _ = start("--speed", "1")
    client.mav.param_request_list_send(1, 1)
    first = client.wait_type("PARAM_VALUE")
    names = {first.param_id: first}
    while len(names) < first.param_count:
        pv = client.wait_type("PARAM_VALUE")
        names[pv.param_id] = pv
    for name in ("SIM_MASS", "SIM_THR_MAX", "SIM_TQ_RP_MAX", "SIM_TQ_Y_MAX", "COM_OF_LOSS_T", "PAP_TO", "MC_ROLLRATE_P"):
        assert name in names
    assert names["SIM_MASS"].param_value == pytest.approx(0.5)
    # the default vehicle (sitl-quad.toml): the paper's quad at 495 rad/s, hovering at 0.5 as PX4 SITL
    assert names["SIM_THR_MAX"].param_value == pytest.approx(_DEFAULT.max_thrust_n) == pytest.approx(4 * 1e-5 * 495.0**2)
    assert names["MPC_THR_HOVER"].param_value == pytest.approx(0.5, abs=0.001)
    assert names["COM_OBL_RC_ACT"].param_type == mavlink.MAV_PARAM_TYPE_INT32
    assert sorted(pv.param_index for pv in names.values()) == list(range(first.param_count))
    # read by index
    index = names["PAP_TO"].param_index
    client.mav.param_request_read_send(1, 1, b"", index)
    assert client.wait_type("PARAM_VALUE", where=lambda m: m.param_index == index).param_id == "PAP_TO"
    # set, refuse NaN and out-of-range with the old value
    assert client.set_param("COM_OF_LOSS_T", 2.5) == pytest.approx(2.5)
    assert client.set_param("COM_OF_LOSS_T", NAN) == pytest.approx(2.5)
    assert client.set_param("COM_OF_LOSS_T", -3.0) == pytest.approx(2.5)
    assert client.param("COM_OF_LOSS_T") == pytest.approx(2.5)
    client.mav.param_set_send(1, 1, b"NO_SUCH_PARAM", 1.0, mavlink.MAV_PARAM_TYPE_REAL32)
    client.wait_type("STATUSTEXT", where=lambda m: "NO_SUCH_PARAM" in m.text)


def test_arm_disarm_and_prearm_refusal(start):
    client, _ = start("--speed", "1", "--unhealthy", "gps")
    status = client.wait_type("SYS_STATUS")
    gps = mavlink.MAV_SYS_STATUS_SENSOR_GPS
    assert status.onboard_control_sensors_present & gps and not status.onboard_control_sensors_health & gps
    assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    client.wait_type("STATUSTEXT", where=lambda m: "Arming denied" in m.text)
    assert not client.wait_type("HEARTBEAT").base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    # forced arming skips the checks, as PX4's 21196
    assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196) == mavlink.MAV_RESULT_ACCEPTED
    hb = client.wait_type("HEARTBEAT")
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED and hb.system_status == mavlink.MAV_STATE_ACTIVE
    assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0) == mavlink.MAV_RESULT_ACCEPTED
    client.wait_type("HEARTBEAT", where=lambda m: not m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)


def test_commands_for_another_system_are_ignored(start):
    client, _ = start("--speed", "1")
    client.mav.command_long_send(7, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    client.mav.command_long_send(1, 77, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    # handled in order: once this answer is here, an answer to the foreign commands would be too
    assert client.param("PAP_TO") == pytest.approx(0.05)
    assert client.acks == []
    assert not client.wait_type("HEARTBEAT").base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED


# --- flying -----------------------------------------------------------------------------------------


def test_offboard_entry_rule(start):
    """PX4 v1.16: disarmed, Offboard is accepted without setpoints (and arming then refused);
    armed, it needs them."""
    client, _ = start("--lockstep")
    assert client.set_mode(6) == mavlink.MAV_RESULT_ACCEPTED
    hb = client.wait_type("HEARTBEAT", where=lambda m: m.custom_mode == 6 << 16)
    assert (hb.base_mode, hb.system_status) == (mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mavlink.MAV_STATE_UNINIT)
    assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    client.wait_type("STATUSTEXT", where=lambda m: "Arming denied" in m.text)
    assert client.set_mode(4, 3) == mavlink.MAV_RESULT_ACCEPTED
    assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
    assert client.set_mode(6) == mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    client.wait_type("STATUSTEXT", where=lambda m: "Offboard" in m.text)
    client.fly(200, lambda t: client.attitude(t, thrust=0.0))
    assert client.set_mode(6) == mavlink.MAV_RESULT_ACCEPTED
    hb = client.wait_type("HEARTBEAT", where=lambda m: m.custom_mode == 6 << 16)
    assert mavutil.mode_string_v10(hb) == "OFFBOARD"


def _take_off_then_offboard(client: Client, height_m: float = 2.0) -> None:
    assert client.set_param("MPC_TKO_SPEED", 3.0) == pytest.approx(3.0)
    assert client.command(mavlink.MAV_CMD_NAV_TAKEOFF, NAN, NAN, NAN, NAN, NAN, NAN, 488.0 + height_m) == mavlink.MAV_RESULT_ACCEPTED
    assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
    pos = client.fly(9000, lambda t: client.attitude(t))  # setpoints as proof of life, not flown yet (PX4's spool-up, ramp, climb)
    assert pos.z == pytest.approx(-height_m, abs=0.2)
    assert client.set_mode(6) == mavlink.MAV_RESULT_ACCEPTED


@pytest.mark.parametrize("model", ["rigid-body", "paper"])
def test_attitude_setpoints_hover_and_pitch(start, model):
    client, _ = start("--lockstep", "--model", model)
    _take_off_then_offboard(client)
    start_pos = client.fly(9050, client.attitude)
    end = client.fly(12000, client.attitude)  # hover thrust, level: altitude holds
    assert abs(end.z - start_pos.z) < 0.3 and abs(end.vz) < 0.2
    end = client.fly(14000, lambda t: client.attitude(t, pitch=0.1, thrust=HOVER / math.cos(0.1)))
    assert end.x < start_pos.x - 0.3 and end.vx < -0.3  # nose up: towards -north
    assert abs(end.y - start_pos.y) < 0.2
    att = client.last["ATTITUDE"]
    assert att.pitch == pytest.approx(0.1, abs=0.02)
    assert client.last["HEARTBEAT"].custom_mode == 6 << 16


def test_position_setpoints_are_flown(start):
    """MAVSDK's set_position_ned: SET_POSITION_TARGET_LOCAL_NED, position and yaw; in lockstep
    its time_boot_ms echoes the telemetry too."""
    client, _ = start("--lockstep")
    mask = 0b0000_1001_1111_1000  # ignore velocity, acceleration, yaw rate

    def goto(t_ms: int) -> None:
        client.mav.set_position_target_local_ned_send(t_ms, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, mask, 1.0, 1.0, -2.0, 0, 0, 0, 0, 0, 0, 0.0, 0)

    client.fly(200, goto)
    assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
    assert client.set_mode(6) == mavlink.MAV_RESULT_ACCEPTED
    end = client.fly(8000, goto)
    assert (end.x, end.y, end.z) == (pytest.approx(1.0, abs=0.1), pytest.approx(1.0, abs=0.1), pytest.approx(-2.0, abs=0.1))


def test_actuator_setpoints_are_flown(start):
    client, _ = start("--lockstep", "--model", "paper")

    def actuators(t_ms: int, thrust: float, pitch: float = 0.0) -> None:
        client.mav.set_actuator_control_target_send(t_ms * 1000, 0, 1, 1, [0.0, pitch, 0.0, thrust, 0, 0, 0, 0])

    client.fly(200, lambda t: actuators(t, 0.0))
    assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
    assert client.set_mode(6) == mavlink.MAV_RESULT_ACCEPTED
    pos = client.fly(1250, lambda t: actuators(t, 1.2 * HOVER))
    # 0.2 g up from t = 0.2 s (the first answer flown in Offboard) to 1.25 s
    assert pos.z == pytest.approx(-0.5 * 0.2 * 9.81 * 1.05**2, abs=0.01)
    client.fly(1450, lambda t: actuators(t, HOVER, pitch=0.01))
    assert client.last["ATTITUDE"].pitch > 0.01


def test_failsafe_after_offboard_loss(start):
    """PX4's default COM_OBL_RC_ACT 0: Position at once; no sticks, so it descends at MPC_LAND_SPEED."""
    client, _ = start("--lockstep")
    _take_off_then_offboard(client)
    client.fly(9500, client.attitude)
    # the client keeps the clock going without setpoints (ticks): no proof of life
    client.fly(10450, lambda t: client.attitude(t, mask=IGNORE_ALL))
    assert client.last["HEARTBEAT"].custom_mode == 6 << 16
    client.fly(10700, lambda t: client.attitude(t, mask=IGNORE_ALL))
    assert any("Failsafe" in text for text in client.texts)
    hb = client.wait_type("HEARTBEAT")
    assert (hb.custom_mode, hb.base_mode, hb.system_status) == (3 << 16, 209, mavlink.MAV_STATE_CRITICAL)  # Position
    before = client.fly(11700, lambda t: client.attitude(t, mask=IGNORE_ALL))
    after = client.fly(12700, lambda t: client.attitude(t, mask=IGNORE_ALL))
    assert after.z - before.z == pytest.approx(0.7, abs=0.1)  # MPC_LAND_SPEED (Hold, before: 0)
    end = client.fly(17600, lambda t: client.attitude(t, mask=IGNORE_ALL))  # a multiple of 200 ms: EXTENDED_SYS_STATE is in the last batch
    assert end.z == pytest.approx(0.0, abs=0.05)
    assert client.wait_type("EXTENDED_SYS_STATE").landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND


def test_failsafe_in_real_time(start):
    client, _ = start("--speed", "2")
    client.wait_type("HEARTBEAT")
    # stream setpoints at ~20 Hz of wall time for a while, arm, enter Offboard, then stop
    deadline = time.monotonic() + 1.0
    while time.monotonic() < deadline:
        client.attitude(0, thrust=0.0)
        client.poll(0.05)
    assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
    client.attitude(0, thrust=0.0)
    assert client.set_mode(6) == mavlink.MAV_RESULT_ACCEPTED
    client.wait_type("STATUSTEXT", timeout=20, where=lambda m: "Failsafe activated" in m.text)
    client.wait_type("HEARTBEAT", where=lambda m: m.custom_mode != 6 << 16)


def test_message_intervals(start):
    client, _ = start("--lockstep", "--lockstep-period", "0.01")
    quaternion = mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION
    assert client.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, quaternion, 100000) == mavlink.MAV_RESULT_ACCEPTED
    assert client.command(mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, quaternion) == mavlink.MAV_RESULT_ACCEPTED
    assert client.wait_type("MESSAGE_INTERVAL").interval_us == 100000

    def samples(start_ms: int, end_ms: int) -> int:
        """Distinct ATTITUDE_QUATERNION samples stamped in (start, end] (keepalive repeats aside)."""
        return sum(start_ms < t <= end_ms for t in client.stamps.get("ATTITUDE_QUATERNION", ()))

    client.fly(1000, lambda t: client.attitude(t, mask=IGNORE_ALL))
    assert samples(0, 1000) == 10  # 10 Hz over one second of simulation
    assert client.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, quaternion, -1) == mavlink.MAV_RESULT_ACCEPTED
    client.fly(2000, lambda t: client.attitude(t, mask=IGNORE_ALL))
    assert samples(1000, 2000) == 0
    assert client.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, quaternion, 0) == mavlink.MAV_RESULT_ACCEPTED  # default: 50 Hz
    client.fly(3000, lambda t: client.attitude(t, mask=IGNORE_ALL))
    assert samples(2000, 3000) == 50
    assert client.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 1000) == mavlink.MAV_RESULT_DENIED


# --- logs and determinism -----------------------------------------------------------------------------


def _scripted_flight(start, log: Path) -> int:
    client, plant = start("--lockstep", "--model", "rigid-body", "--noise", "imu", "--seed", "3", "--log", str(log))

    def on_new(t: int) -> None:
        if t == 100:
            client.mav.param_request_read_send(1, 1, b"SIM_MASS", -1)
        if t == 200:
            client.mav.command_long_send(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        if t == 300:
            client.mav.command_long_send(1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, 1, 6, 0, 0, 0, 0, 0)

    client.fly(2500, lambda t: client.attitude(t, pitch=0.05 if t > 1500 else 0.0, thrust=1.3 * HOVER), on_new)
    code, err = plant.stop()
    assert code == 0, err
    return client.counts["COMMAND_ACK"]


def test_lockstep_runs_are_bit_identical(start, tmp_path):
    a, b = tmp_path / "a.tlog", tmp_path / "b.tlog"
    assert _scripted_flight(start, a) == 3  # the arm's ACK and DO_SET_MODE's two (as PX4)
    assert _scripted_flight(start, b) == 3
    data = a.read_bytes()
    assert len(data) > 10000
    assert data == b.read_bytes()


def test_tlog_reads_back_with_pymavlink(start, tmp_path):
    log = tmp_path / "flight.tlog"
    _scripted_flight(start, log)
    reader = mavutil.mavlink_connection(str(log), dialect="common")
    kinds: Counter[str] = Counter()
    stamps = []
    sent_by_client = 0
    while True:
        msg = reader.recv_match()
        if msg is None:
            break
        kinds[msg.get_type()] += 1
        stamps.append(msg._timestamp)
        sent_by_client += msg.get_srcSystem() == 255
    assert kinds["LOCAL_POSITION_NED"] == 51 and kinds["SET_ATTITUDE_TARGET"] == 50
    assert kinds["COMMAND_LONG"] == 2 and kinds["COMMAND_ACK"] == 3 and kinds["PARAM_VALUE"] == 1
    assert sent_by_client == kinds["SET_ATTITUDE_TARGET"] + 3
    assert stamps == sorted(stamps)
    # lockstep logs are stamped with a fixed epoch (2020-01-01) plus simulation time
    assert stamps[0] == pytest.approx(1_577_836_800.0) and stamps[-1] == pytest.approx(1_577_836_800.0 + 2.5)


def test_sigint_exits_cleanly_and_keeps_the_log(start, tmp_path):
    log = tmp_path / "rt.tlog"
    client, plant = start("--speed", "1", "--log", str(log))
    for _ in range(3):
        client.wait_type("HEARTBEAT")
    code, err = plant.stop(signal.SIGINT)
    assert code == 0 and "Traceback" not in err
    data = log.read_bytes()
    assert len(data) > 1000
    reader = mavutil.mavlink_connection(str(log), dialect="common")
    heartbeats = 0
    while (msg := reader.recv_match()) is not None:
        heartbeats += msg.get_type() == "HEARTBEAT"
    assert heartbeats >= 3


def test_ctrl_c_while_starting_is_one_line(tmp_path):
    """Ctrl-C while the plant still starts, before its run loop takes SIGINT itself: one line and
    exit 130, no traceback (it printed numba's loader's). The vehicle file is a FIFO, so the plant
    is caught reading it, past its imports: our end opens once the plant has opened it, and the
    signal goes once the kernel has it asleep in that read (its wchan). Sent as the open returned,
    a SIGINT could land between Python's last look at its signals and the read, and the read, which
    nothing then interrupts, would hold the KeyboardInterrupt back for good (3 runs in 25 hung so);
    a regular file's read returns at once, so a user's Ctrl-C is never held."""
    fifo = tmp_path / "vehicle.toml"
    os.mkfifo(fifo)
    plant = subprocess.Popen([sys.executable, "-m", "sitl_plant.cli", "--vehicle", str(fifo), "--api-bind", "127.0.0.1:0",
                              "--api-remote", "none", "--gcs-bind", "none"], cwd=REPO, stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True)  # fmt: skip
    fd = None
    try:
        deadline = time.monotonic() + 60
        while fd is None:
            try:
                fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)  # ENXIO until a reader has it open
            except OSError:
                assert time.monotonic() < deadline and plant.poll() is None, "the plant never opened its vehicle file"
                time.sleep(0.01)
        while "pipe_read" not in Path(f"/proc/{plant.pid}/wchan").read_text():  # asleep reading it (we write nothing)
            assert time.monotonic() < deadline and plant.poll() is None, "the plant never blocked reading its vehicle file"
            time.sleep(0.01)
        plant.send_signal(signal.SIGINT)
        _, err = plant.communicate(timeout=30)
    finally:
        if fd is not None:
            os.close(fd)
        if plant.poll() is None:
            plant.kill()
            plant.communicate()
    assert plant.returncode == 130 and err.strip() == "sitl-plant: interrupted while starting", err


#: Runs a module as ``python -m`` does, with a Ctrl-C arriving while it imports the module named
#: by argv[1] (the SIGINT is sent to the process as that import starts, as a user's Ctrl-C is).
_CTRL_C_DURING_IMPORT = """
import importlib.abc, os, runpy, signal, sys
importing = sys.argv[1]
class CtrlC(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == importing:
            sys.meta_path.remove(self)
            os.kill(os.getpid(), signal.SIGINT)
        return None
sys.meta_path.insert(0, CtrlC())
module = sys.argv[2]
sys.argv = [module, *sys.argv[3:]]
runpy.run_module(module, run_name="__main__", alter_sys=True)
"""


@pytest.mark.parametrize(
    ("importing", "command", "line"),
    [
        ("sitl_plant.navigator", ["sitl_plant.cli", "--api-bind", "127.0.0.1:0", "--api-remote", "none", "--gcs-bind", "none"],
         "sitl-plant: interrupted while starting"),
        ("offboard.flight.mission", ["offboard.cli", "fly", "missions/paper-helix.toml", "--connect", "udpin:127.0.0.1:0"],
         "offboard fly: interrupted while starting"),
    ],
    ids=["sitl-plant", "offboard-fly"],
)  # fmt: skip
def test_ctrl_c_while_the_program_loads_is_one_line(importing, command, line):
    """Ctrl-C in the program's first third of a second, while Python imports its modules (before
    any handler of ours runs): one line and exit 130, no traceback (both printed Python's
    KeyboardInterrupt traceback)."""
    done = subprocess.run([sys.executable, "-c", _CTRL_C_DURING_IMPORT, importing, *command], cwd=REPO, capture_output=True,
                          text=True, timeout=60)  # fmt: skip
    assert done.returncode == 130 and done.stderr.strip() == line, done.stderr


# --- bad input ------------------------------------------------------------------------------------------


def test_garbage_on_the_wire_is_survived(start):
    client, plant = start("--speed", "1", quiet=False)
    sock, addr = client.conn.port, next(iter(client.conn.clients))
    good = mavlink.MAVLink_param_request_read_message(1, 1, b"PAP_TO", -1).pack(mavlink.MAVLink(None, 255, 190))
    corrupt = bytearray(good)
    corrupt[-1] ^= 0xFF
    unknown = bytearray(good)
    unknown[7] = 0xEE  # message id 238 (no such message): CRC can't be checked, counted as unknown
    junk = [
        os.urandom(300),
        good[:7],  # truncated
        bytes(corrupt),  # bad CRC
        b"\xfd" + bytes(5),  # a header and nothing else
        bytes(unknown),
        b"",
        b"\xfe\x05" + bytes(20),  # MAVLink 1 garbage
    ]
    for data in junk:
        sock.sendto(data, addr)
    for bad in (NAN, math.inf):
        client.attitude(0, thrust=bad)
        client.mav.set_actuator_control_target_send(0, 0, 1, 1, [bad] * 8)
    # still alive and answering
    assert client.param("PAP_TO") == pytest.approx(0.05)
    client.wait_type("HEARTBEAT")
    code, err = plant.stop()
    assert code == 0 and "Traceback" not in err
    summary = err.strip().splitlines()[-1]
    assert "refused setpoints 4" in summary
    bad_count = int(summary.split("bad packets ")[1].split(",")[0])
    assert bad_count >= 3


# --- the command line -------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--speed", "0"], "--speed"),
        (["--vehicle", "no-such-file.toml"], "no-such-file.toml"),
        (["--home", "1,2"], "--home"),
        (["--lockstep", "--lockstep-period", "0.0015"], "period"),
        (["--wind", "hurricane:9"], "wind"),
        (["--noise", "imu:pos=-1"], "pos"),
        (["--unhealthy", "warp"], "--unhealthy"),
        (["--api-bind", "localhost"], "--api-bind"),
    ],
)
def test_bad_arguments_are_one_line_and_exit_2(args, needle, capsys):
    from sitl_plant.cli import main

    safe = ["--quiet", "--gcs-bind", "none", "--duration", "0.1"] + ([] if "--api-bind" in args else ["--api-bind", "127.0.0.1:0"])
    assert main(args + safe) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0] and err[0].startswith("sitl-plant: error:")


@pytest.mark.parametrize(
    ("instance", "message"),
    [
        (10, "sitl-plant: error: --instance 10: the API link would send to 127.0.0.1:14550, the ground stations' port "
             "(QGroundControl listens there), as PX4 SITL's -i 10 would; choose an instance in 0..9 or 11..39, or give "
             "--api-remote HOST:PORT"),
        (45, "sitl-plant: error: --instance 45: the API link would send to 127.0.0.1:14585, instance 5's own API port (14580 + 5)"),
        (255, "sitl-plant: error: --instance: must be 0..254 (PX4 SITL's -i N flies system id N + 1), got 255"),
    ],
)  # fmt: skip
def test_instances_whose_ports_collide_are_refused(instance, message, capsys):
    """As real processes: PX4's layout sends instance 10's API link to the ground station's port."""
    proc = subprocess.run([sys.executable, "-m", "sitl_plant.cli", "--instance", str(instance), "--api-bind", "127.0.0.1:0",
                           "--gcs-bind", "none", "--duration", "0.1"],
                          cwd=REPO, capture_output=True, text=True, timeout=60)  # fmt: skip
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(message), lines


def test_a_colliding_instance_with_its_own_api_remote_runs_and_the_banner_shows_wind_and_noise():
    proc = subprocess.run([sys.executable, "-m", "sitl_plant.cli", "--instance", "10", "--api-remote", "none",
                           "--api-bind", "127.0.0.1:0", "--gcs-bind", "none", "--duration", "0.2", "--speed", "4",
                           "--wind", "constant:1,0,0", "--noise", "paper", "--seed", "3"],
                          cwd=REPO, capture_output=True, text=True, timeout=60)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "  wind constant:1,0,0, sensors paper (seed 3)" in proc.stderr.splitlines()


def test_bad_argument_as_a_real_process():
    proc = subprocess.run([sys.executable, "-m", "sitl_plant.cli", "--physics-dt", "-1"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == ["sitl-plant: error: --physics-dt: must be > 0, got -1.0"]


def test_port_in_use_is_one_line(capsys):
    import socket

    from sitl_plant.cli import main

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", 0))
        port = busy.getsockname()[1]
        assert main(["--quiet", "--gcs-bind", "none", "--api-bind", f"127.0.0.1:{port}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(port) in err[0]


def test_help_shows_defaults():
    from sitl_plant.cli import build_parser

    text = build_parser().format_help()
    for needle in ("--lockstep-period", "default: 0.05", "--inner-loop", "default: px4", "14580", "14540", "--instance"):
        assert needle in text


def test_lockstep_plant_waiting_to_be_talked_to():
    """``--api-remote none``: the plant sends nothing until a client talks, then the latest
    telemetry reaches it through the keepalive and lockstep starts."""
    client = Client()
    plant = subprocess.Popen(
        [sys.executable, "-m", "sitl_plant.cli", "--lockstep", "--gcs-bind", "none", "--api-remote", "none", "--api-bind", "127.0.0.1:0"],
        cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        port = None
        for line in plant.stderr:  # type: ignore[union-attr]  # the banner names the bound port
            if "api link: UDP 127.0.0.1:" in line:
                port = int(line.split("127.0.0.1:")[1].split()[0])
                break
        assert port is not None
        client.conn.port.sendto(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(mavlink.MAVLink(None, 255, 190)), ("127.0.0.1", port))
        client.wait_type("HEARTBEAT")
        end = client.fly(500, lambda t: client.attitude(t, mask=IGNORE_ALL))
        assert end.time_boot_ms == 500
    finally:
        plant.kill()
        plant.communicate()
        client.close()
