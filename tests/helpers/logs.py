"""A synthetic log for the replay tests: a PX4-like vehicle and a ground station, as a tlog."""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

EPOCH_US = 1_700_000_000_000_000
VEHICLE = 42
MODE_HOLD = (4 << 16) | (3 << 24)
MODE_OFFBOARD = 6 << 16
MODE_LAND = (4 << 16) | (6 << 24)
POSITION_AND_YAW = 0b1001_1111_1000  # POSITION_TARGET_LOCAL_NED type_mask: velocity, acceleration, yaw rate ignored
DROPPED = 5  # vehicle packets left out of the log (their sequence numbers skipped)


@dataclass
class ForeignLog:
    path: Path
    offsets: list[int] = field(default_factory=list)  # byte offset of each record
    attitude: list[tuple] = field(default_factory=list)  # (time_boot_ms, roll, pitch, yaw) as float32
    position: list[tuple] = field(default_factory=list)  # (time_boot_ms, x, y, z, vx, vy, vz)
    vehicle_messages: list[tuple[float, str]] = field(default_factory=list)  # (t_s, type) of every vehicle packet written


def f32(value: float) -> float:
    return float(np.float32(value))


def write_foreign_log(path: Path, duration_s: float = 6.0, gap: tuple[float, float] = (3.0, 4.0)) -> ForeignLog:
    """A PX4-like vehicle (system 42) and a ground station (255), 10 ms ticks.

    ATTITUDE at 50 Hz except during ``gap``, LOCAL_POSITION_NED at 25 Hz (stamped 10 ms after
    an ATTITUDE), POSITION_TARGET_LOCAL_NED at 25 Hz, heartbeats at 1 Hz: Hold, then Offboard
    at 1 s, system status CRITICAL at 4 s, a failsafe text at 4.5 s, Land from 5 s and a refused
    disarm (CRITICAL, as PX4 sends it: a refusal, not a failsafe) at 5.5 s.
    """
    log = ForeignLog(path)
    vehicle = mavlink.MAVLink(None, srcSystem=VEHICLE, srcComponent=1)
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    writer = mavutil.mavlogfile(str(path), write=True)
    offset = 0
    dropped = 0
    for tick in range(int(duration_s * 100) + 1):
        t = tick / 100.0
        ms = tick * 10
        out: list[tuple[mavlink.MAVLink, mavlink.MAVLink_message]] = []
        if tick % 100 == 0:
            mode = MODE_HOLD if t < 1.0 else MODE_OFFBOARD if t < 5.0 else MODE_LAND
            state = mavlink.MAV_STATE_CRITICAL if 4.0 <= t < 5.0 else mavlink.MAV_STATE_ACTIVE
            base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED if t >= 1.0 else 0)
            out.append((vehicle, mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base, mode, state, 3)))
            out.append((gcs, mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)))
        if tick == 150:  # the 1 Hz heartbeat would show Offboard at t = 1.0 already; a text at 1.5 s
            out.append((vehicle, mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO, b"Takeoff detected")))
        if tick == 450:
            out.append((vehicle, mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_CRITICAL, b"Failsafe activated: no offboard signal")))
        if tick == 550:
            out.append((vehicle, mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_CRITICAL, b"Disarming denied: not landed")))
        if tick % 2 == 0 and not gap[0] <= t < gap[1]:
            roll, pitch, yaw = 0.1 * math.sin(t), -0.05 * math.cos(t), 0.3 * t
            out.append((vehicle, mavlink.MAVLink_attitude_message(ms, roll, pitch, yaw, 0.1, 0.2, 0.3)))
            log.attitude.append((ms, f32(roll), f32(pitch), f32(yaw)))
        if tick % 4 == 1:
            x, y, z = math.cos(t), math.sin(t), -1.0 - 0.1 * t
            out.append((vehicle, mavlink.MAVLink_local_position_ned_message(ms, x, y, z, -math.sin(t), math.cos(t), -0.1)))
            log.position.append((ms, f32(x), f32(y), f32(z), f32(-math.sin(t)), f32(math.cos(t)), f32(-0.1)))
            out.append((vehicle, mavlink.MAVLink_position_target_local_ned_message(
                ms, mavlink.MAV_FRAME_LOCAL_NED, POSITION_AND_YAW, x + 0.1, y, z, 0, 0, 0, 0, 0, 0, 0.25, 0)))
        for mav, msg in out:
            packet = msg.pack(mav)
            mav.seq = (mav.seq + 1) % 256
            if mav is vehicle and tick in (101, 201, 301, 401, 501) and dropped < DROPPED and msg.get_type() == "LOCAL_POSITION_NED":
                dropped += 1  # a packet lost on the radio: its sequence number is used, the packet never logged
                log.position.pop()
                continue
            record = struct.pack(">Q", EPOCH_US + tick * 10_000) + packet
            writer.write(record)
            log.offsets.append(offset)
            offset += len(record)
            if mav is vehicle:
                log.vehicle_messages.append((t, msg.get_type()))
    writer.close()
    assert dropped == DROPPED
    return log
