"""The plant's parameter table: names, defaults from the vehicle, PX4-like validation."""

from __future__ import annotations

import math

import pytest

from sitl_plant.params import (
    INT,
    PHYSICAL,
    ParamSpec,
    ParamTable,
    plant_params,
    refresh_derived,
    to_float32,
    vehicle_from_params,
)
from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle
from helpers import REPO

# the names the offboard process reads: they must exist exactly so
CONTRACT_NAMES = [
    "SIM_MASS", "SIM_ARM_LEN", "SIM_IXX", "SIM_IYY", "SIM_IZZ", "SIM_KF", "SIM_KM_KF", "SIM_W_MAX",
    "SIM_MOT_TAU", "SIM_THR_MAX", "SIM_TQ_RP_MAX", "SIM_TQ_Y_MAX", "SIM_KDV", "COM_OF_LOSS_T", "COM_OBL_RC_ACT",
    "PAP_TO", "PAP_IXX", "PAP_IYY", "PAP_IZZ", "MC_ROLL_P", "MC_PITCH_P", "MC_YAW_P",
    "MC_ROLLRATE_P", "MC_ROLLRATE_I", "MC_ROLLRATE_D", "MC_PITCHRATE_P", "MC_PITCHRATE_I",
    "MC_PITCHRATE_D", "MC_YAWRATE_P", "MC_YAWRATE_I", "MC_YAWRATE_D",
]  # fmt: skip


@pytest.fixture
def vehicle():
    return load_vehicle(PAPER_VEHICLE_FILE)


@pytest.fixture
def table(vehicle):
    return plant_params(vehicle)


def test_contract_names_exist_and_fit_mavlink(table):
    for name in CONTRACT_NAMES:
        assert name in table, name
    assert all(len(name) <= 16 for name in table)
    assert len(set(table)) == len(table)


def test_defaults_come_from_the_vehicle(table, vehicle):
    assert table["SIM_MASS"] == to_float32(vehicle.mass_kg)
    assert table["SIM_THR_MAX"] == pytest.approx(vehicle.max_thrust_n, rel=1e-6)
    assert table["SIM_TQ_RP_MAX"] == pytest.approx(vehicle.max_roll_pitch_torque_nm, rel=1e-6)
    assert table["SIM_TQ_Y_MAX"] == pytest.approx(vehicle.max_yaw_torque_nm, rel=1e-6)
    assert (table["PAP_IXX"], table["PAP_IYY"], table["PAP_IZZ"]) == pytest.approx(vehicle.inertia_kg_m2, rel=1e-6)
    assert table["COM_OF_LOSS_T"] == 1.0
    assert table["PAP_TO"] == pytest.approx(0.05)
    assert table["SIM_KDV"] == 0.0  # the paper's quad has no drag


def test_the_linear_drag_is_published_as_px4_sih_publishes_sih_kdv():
    """px4-sih.toml's drag (SIH_KDV 1 N s/m) under SIM_KDV, which the offboard's design and law
    read: without it sitl-plant's twin of PX4 SIH was flown as if it had none (the PX4 helix's
    designed controller flew it 0.73 m RMS off)."""
    sih = load_vehicle(REPO / "sitl_plant" / "vehicles" / "px4-sih.toml")
    table = plant_params(sih)
    assert table["SIM_KDV"] == 1.0
    assert table.spec("SIM_KDV").read_only
    refresh_derived(table, sih.with_changes(linear_drag_n_s_m=(0.5, 0.7, 3.0)))
    assert table["SIM_KDV"] == pytest.approx(0.6)  # a tilt axis's drag: body x and y


@pytest.mark.parametrize(
    ("name", "value", "why"),
    [
        ("COM_OF_LOSS_T", math.nan, "non-finite"),
        ("COM_OF_LOSS_T", math.inf, "non-finite"),
        ("COM_OF_LOSS_T", -1.0, "outside"),
        ("MC_ROLL_P", 100.0, "outside"),
        ("COM_OBL_RC_ACT", 8.0, "not one of"),  # PX4: 0..7
        ("COM_OBL_RC_ACT", 4.5, "integer"),
        ("SIM_THR_MAX", 30.0, "read-only"),
        ("NO_SUCH_PARAM", 1.0, "unknown"),
    ],
)
def test_refused_values_keep_the_old_one(table, name, value, why):
    before = table[name] if name in table else None
    version = table.version
    outcome = table.set(name, value)
    assert not outcome.accepted
    assert why in outcome.reason
    if before is not None:
        assert table[name] == before
    assert table.version == version


def test_accepted_values_are_stored_as_float32(table):
    outcome = table.set("PAP_IXX", 2.7e-3)
    assert outcome.accepted
    assert table["PAP_IXX"] == to_float32(2.7e-3)
    assert table["PAP_IXX"] != 2.7e-3  # float32 rounding happened, as on the wire


def test_version_counts_changes_only(table):
    v0 = table.version
    table.set("COM_OF_LOSS_T", 2.0)
    table.set("COM_OF_LOSS_T", 2.0)
    assert table.version == v0 + 1


def test_integer_parameters(table):
    assert table.spec("COM_OBL_RC_ACT").kind == INT
    assert table.set("COM_OBL_RC_ACT", 5).accepted
    assert table["COM_OBL_RC_ACT"] == 5.0


def test_index_round_trip(table):
    for i, name in enumerate(table):
        assert table.index(name) == i
        assert table.name_at(i) == name
    assert table.name_at(len(table)) is None
    assert table.name_at(-1) is None


def test_physical_change_rebuilds_vehicle_and_maxima(table, vehicle):
    assert set(PHYSICAL) <= set(table)
    assert table.set("SIM_W_MAX", 800.0).accepted
    new = vehicle_from_params(table, vehicle)
    refresh_derived(table, new)
    assert new.rotor_speed_max_rad_s == 800.0
    assert table["SIM_THR_MAX"] == pytest.approx(4 * vehicle.thrust_coeff_n_s2 * 800.0**2, rel=1e-6)


def test_long_names_rejected():
    with pytest.raises(ValueError, match="16"):
        ParamTable([ParamSpec("A_NAME_LONGER_THAN_16", 1.0)])


def test_every_parameter_is_documented(table):

    doc = (REPO / "docs" / "plant.md").read_text()
    rows = {line.split("|")[1].strip().strip("`") for line in doc.splitlines() if line.startswith("| `")}
    # the plant's own parameters each have a row; PX4's others it only publishes are listed, with
    # their provenance, in sitl_plant/px4_params.toml, which the page names
    own = [name for name in table if table.spec(name).description != "PX4 v1.16 SITL's value (published for clients)"]
    missing = [name for name in own if name not in rows]
    assert missing == [] and "px4_params.toml" in doc
