"""What the plant sends, held against PX4 v1.16 SITL's (measured: docs/parity/wire.md): the stream
set and rates of both links, AUTOPILOT_VERSION, and parameter types and values — without sockets."""

from __future__ import annotations

import json
import struct

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl_plant import codec
from sitl_plant.autopilot import Autopilot
from sitl_plant.params import INT, plant_params, px4_published
from sitl_plant.server import API, GCS, STREAMS, Plant, PlantConfig
from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle
from helpers import PX4_PARAMS_JSON


#: PX4 v1.16 SITL's message types per link, as a common.xml client names them (measured with
#: pymavlink's common.xml on the bundled PX4; UNKNOWN_411, CURRENT_EVENT_SEQUENCE, left out: the
#: plant has no events service, docs/parity/wire.md).
PX4_API_TYPES = {
    "ALTITUDE", "ATTITUDE", "ATTITUDE_QUATERNION", "ATTITUDE_TARGET", "BATTERY_STATUS", "DISTANCE_SENSOR",
    "ESTIMATOR_STATUS", "EXTENDED_SYS_STATE", "GLOBAL_POSITION_INT", "GPS_RAW_INT", "HEARTBEAT", "HIGHRES_IMU",
    "HOME_POSITION", "LOCAL_POSITION_NED", "MISSION_CURRENT", "ODOMETRY", "OPEN_DRONE_ID_LOCATION",
    "OPEN_DRONE_ID_SYSTEM", "PING", "POSITION_TARGET_LOCAL_NED", "SCALED_PRESSURE", "SERVO_OUTPUT_RAW",
    "SYSTEM_TIME", "SYS_STATUS", "TIMESYNC", "VFR_HUD", "VIBRATION", "UNKNOWN_8", "UNKNOWN_380", "UNKNOWN_436",
}  # fmt: skip
PX4_GCS_TYPES = (PX4_API_TYPES - {"HIGHRES_IMU", "ODOMETRY", "SYSTEM_TIME", "TIMESYNC"})


def run_streams(seconds: float = 10.0) -> tuple[Plant, list[dict[str, int]]]:
    vehicle = load_vehicle(PAPER_VEHICLE_FILE)
    params = plant_params(vehicle)
    plant = Plant(PlantConfig(), vehicle, params, Autopilot(params))
    packer = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    counts: list[dict[str, int]] = [{}, {}]
    while plant.time_s < seconds - 1e-9:
        plant.advance(plant.tick_steps)
        for link in (API, GCS):
            for msg in plant.telemetry(link):
                (decoded,) = parser.parse_buffer(msg.pack(packer))  # packs and parses as a client would
                counts[link][decoded.get_type()] = counts[link].get(decoded.get_type(), 0) + 1
    return plant, counts


@pytest.fixture(scope="module")
def streamed():
    return run_streams()


def test_the_plant_streams_px4s_message_set_on_each_link(streamed):
    _, counts = streamed
    assert set(counts[API]) == PX4_API_TYPES
    assert set(counts[GCS]) == PX4_GCS_TYPES


@pytest.mark.parametrize("link, column", [(API, 1), (GCS, 2)])
def test_each_stream_comes_at_its_px4_rate(streamed, link, column):
    plant, counts = streamed
    by_name = {("UNKNOWN_%d" % mid if mid in (8, 380, 436) else spec[0]): spec[column] for mid, spec in STREAMS.items()}
    for name, count in counts[link].items():
        rate = by_name[name]
        assert abs(count - rate * plant.time_s) <= 1, f"{name}: {count} in {plant.time_s} s, expected {rate} Hz"


def test_dialect_frames_carry_px4s_crc_extras():
    """A frame PX4 v1.16 sent (TIME_ESTIMATE_TO_TARGET, seq 0xf6) and the plant's of the same content are the same bytes."""
    px4 = bytes.fromhex("fd140000f601017c010000000000ffffffffffffffffffffffffffffffffd5d3")
    packer = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    packer.seq = 0xF6
    assert codec.time_estimate_to_target((0, -1, -1, -1, -1)).pack(packer) == px4
    mode = bytes.fromhex("fd080000800101b4010000000403000004031753")  # CURRENT_MODE, Hold
    packer.seq = 0x80
    assert codec.current_mode(50593792, 50593792).pack(packer) == mode


def test_autopilot_version_is_px4_v1_16s():
    msg = codec.autopilot_version(1)
    # PX4 v1.16.0 SITL answered (measured): capabilities 59647, versions 17826047, board 1
    assert msg.capabilities == 59647 == 0xE8FF
    assert msg.flight_sw_version == msg.middleware_sw_version == 17826047
    assert (msg.flight_sw_version >> 24, msg.flight_sw_version >> 16 & 0xFF, msg.flight_sw_version >> 8 & 0xFF) == (1, 16, 0)
    assert msg.board_version == 1 and list(msg.flight_custom_version) == [0, 0, 0, 87, 145, 83, 163, 110]
    assert msg.uid != 0 and list(msg.uid2) == [0] * 18
    assert msg.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE  # what the plant does


def test_published_parameters_have_px4s_types_and_values():
    table = plant_params(load_vehicle(PAPER_VEHICLE_FILE))
    published = px4_published()
    assert len(published) > 300 and list(table) == sorted(table)
    px4 = json.loads(PX4_PARAMS_JSON.read_text()) if PX4_PARAMS_JSON.is_file() else None
    for name, (kind, value) in published.items():
        spec = table.spec(name)
        assert spec.kind == (INT if kind == "int" else REAL_KIND), name
        if px4 is not None:
            assert {6: "int", 9: "real"}[px4[name]["type"]] == kind, name
            if spec.description.startswith("PX4 v1.16"):
                assert table[name] == pytest.approx(px4[name]["value"], rel=1e-6, nan_ok=True), name
    for name in ("SYS_AUTOSTART", "MAV_SYS_ID", "COM_OF_LOSS_T", "NAV_DLL_ACT", "RTL_RETURN_ALT", "MIS_TAKEOFF_ALT",
                 "MPC_XY_CRUISE", "GF_ACTION", "BAT1_N_CELLS", "CAL_ACC0_ID", "COM_RC_IN_MODE"):  # fmt: skip
        assert name in table, name
    assert table["SYS_AUTOSTART"] == 10040


def test_an_int_parameter_travels_bytewise():
    msg = codec.param_value("SYS_AUTOSTART", 10040, True, 1, 0)
    assert msg.param_type == mavlink.MAV_PARAM_TYPE_INT32
    assert struct.unpack("<i", struct.pack("<f", msg.param_value))[0] == 10040


REAL_KIND = "real"


def test_the_vehicle_files_hover_as_px4_sitl():
    from dataclasses import replace

    from sitl_plant.cli import build_parser
    from offboard.model.vehicle import DEFAULT_VEHICLE_FILE, PX4_SIH_VEHICLE_FILE

    sih = load_vehicle(PX4_SIH_VEHICLE_FILE)
    # PX4 SIH (its README): 1 kg, 4 x 5 N, 0.1 N m per rotor, inertia, T_TAU, KDV; hover 0.49
    assert (sih.mass_kg, sih.max_thrust_n, sih.max_yaw_torque_nm) == (1.0, pytest.approx(20.0), pytest.approx(0.2))
    assert sih.inertia_kg_m2 == (0.025, 0.025, 0.03) and sih.motor_time_constant_s == 0.05
    assert sih.linear_drag_n_s_m == (1.0, 1.0, 1.0) and sih.max_roll_pitch_torque_nm == pytest.approx(2 * 0.2 * 5.0)
    default = load_vehicle(DEFAULT_VEHICLE_FILE)
    assert build_parser().parse_args([]).vehicle == DEFAULT_VEHICLE_FILE
    assert default.mass_kg * default.gravity_m_s2 / default.max_thrust_n == pytest.approx(0.5, abs=0.002)
    paper = load_vehicle(PAPER_VEHICLE_FILE)  # the paper's reproduction flies this one, unchanged
    assert paper.max_thrust_n == pytest.approx(19.6)
    assert replace(default, rotor_speed_max_rad_s=paper.rotor_speed_max_rad_s) == paper  # only the top speed differs


def test_position_target_is_empty_on_the_ground_as_px4s():
    """PX4 v1.16 disarmed in Hold sent type_mask 63 with NaN position and velocity (measured)."""
    vehicle = load_vehicle(PAPER_VEHICLE_FILE)
    params = plant_params(vehicle)
    plant = Plant(PlantConfig(), vehicle, params, Autopilot(params))
    msg = plant._build(mavlink.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED)
    assert msg.type_mask & 0b111111 == 0b111111 and all(v != v for v in (msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz))
    assert msg.coordinate_frame == mavlink.MAV_FRAME_LOCAL_NED
