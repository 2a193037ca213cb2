"""Every valid frame the fuzzer throws (tests/helpers/fuzz.py: every common.xml message, random
field values, MAVLink 1 and 2), handled by a disarmed plant without sockets: its whole state
stays as it was. tests/e2e/test_fuzz.py throws the same at a plant process and looks from outside
at a few parameters; here every parameter, the mode, arming, home, the mission, the streams and
signing are compared.

What reaches a handler is random: a PARAM_SET addressed to the vehicle names a parameter of
random bytes, which names none (the plant says "[pm] unknown param" and changes nothing); one that
named a real parameter would be a well-formed command, which PX4 takes from anyone on an unsigned
link (docs/plant.md, "Who may talk to the vehicle"), not fuzz. SETUP_SIGNING is ignored by a plant
that does not sign, as by PX4 v1.16."""

from __future__ import annotations

from collections import Counter

from pymavlink.dialects.v20 import common as mavlink

from helpers.fuzz import Fuzzer
from offboard.model.vehicle import DEFAULT_VEHICLE_FILE, load_vehicle
from sitl_plant import codec
from sitl_plant.autopilot import Autopilot
from sitl_plant.params import plant_params
from sitl_plant.server import API, Plant, PlantConfig


def state(plant: Plant) -> tuple:
    """What a frame could change (the parameters by their table's count of changes: each value is
    compared once, at the end)."""
    return (
        plant.autopilot.status(),
        plant.params.version,
        tuple(plant.autopilot.home_ned_m),
        plant.missions.mission_current(),
        [dict(s.interval_us) for s in plant.streams],
        plant.signing,
        plant.signing_change,
    )


def test_no_fuzzed_frame_changes_a_disarmed_plant():
    vehicle = load_vehicle(DEFAULT_VEHICLE_FILE)
    params = plant_params(vehicle)
    plant = Plant(PlantConfig(), vehicle, params, Autopilot(params))
    before, values = state(plant), dict(params._values)
    fuzzer = Fuzzer(20)
    parser = mavlink.MAVLink(None)
    addressed: Counter[str] = Counter()
    for frame in fuzzer.valid + fuzzer.v1:
        for msg in parser.parse_buffer(frame) or []:
            if codec.addressed_to(msg, plant.config.sysid, plant.config.compid):
                addressed[msg.get_type()] += 1
            plant.handle(API, msg)
            assert state(plant) == before, msg
    assert params._values == values
    assert plant.counters.internal_errors == 0, plant.counters.last_error
    # the frames that could change it reached their handlers
    assert all(addressed[kind] > 0 for kind in ("PARAM_SET", "SETUP_SIGNING", "SET_MODE", "COMMAND_LONG", "COMMAND_INT")), addressed
    assert plant.counters.ignored.get("SETUP_SIGNING", 0) > 0
