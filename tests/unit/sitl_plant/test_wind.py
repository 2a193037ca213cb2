"""Wind models: constant, 1-cosine gusts, Dryden turbulence, their sum, and how users write them."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from numpy.testing import assert_allclose

from sitl_plant.dynamics import rigid_body as rb
from sitl_plant.dynamics.wind import (
    FT,
    CompositeWind,
    ConstantWind,
    DrydenTurbulence,
    Gust,
    GustWind,
    WindSpecError,
    dryden_parameters,
    wind_from_spec,
    wind_from_table,
)
from offboard.model.errors import ParameterFileError, UserError
from sitl_plant.simulation import HeldActuation, VehicleSim
from offboard.model.tomlfile import Fields
from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle

PAPER = load_vehicle(PAPER_VEHICLE_FILE)
HERE = np.zeros(3)


def hovering(params, wind) -> VehicleSim:
    sim = VehicleSim(rb.RigidBodyModel(params), wind=wind, ground=False, initial_pos_ned_m=np.array([0, 0, -10.0]))
    sim.x[rb.ROTORS] = rb.hover_rotor_speed(params)
    sim.actuation = HeldActuation(params.mass_kg * params.gravity_m_s2, np.zeros(3))
    return sim


def test_constant_wind_pushes_a_hovering_vehicle_with_drag_downwind() -> None:
    drag = 0.1
    params = PAPER.with_changes(linear_drag_n_s_m=(drag, drag, drag))
    sim = hovering(params, ConstantWind((3.0, -1.0, 0.0)))
    sim.step(4000)
    truth = sim.truth()
    # level hover: m v' = D (w - v), so v = w (1 - exp(-D t / m))
    expected = np.array([3.0, -1.0, 0.0]) * (1.0 - math.exp(-drag * 4.0 / params.mass_kg))
    assert_allclose(truth.vel_ned_m_s, expected, atol=1e-6)
    assert truth.pos_ned_m[0] > 1.0 and truth.pos_ned_m[1] < -0.3


def test_wind_does_nothing_to_a_vehicle_without_drag() -> None:
    sim = hovering(PAPER, ConstantWind((3.0, 0.0, 0.0)))
    sim.step(1000)
    assert_allclose(sim.truth().vel_ned_m_s, 0.0, atol=1e-12)


def test_gust_has_the_one_minus_cosine_shape() -> None:
    wind = GustWind((Gust(start_s=10.0, amplitude_m_s=4.0, duration_s=2.0, direction_deg=90.0),))
    assert_allclose(wind.velocity_ned(9.99, HERE), 0.0)
    assert_allclose(wind.velocity_ned(10.5, HERE), [0.0, 2.0, 0.0], atol=1e-12)  # a quarter: half way up
    assert_allclose(wind.velocity_ned(11.0, HERE), [0.0, 4.0, 0.0], atol=1e-12)  # peak towards the east
    assert_allclose(wind.velocity_ned(12.0, HERE), 0.0, atol=1e-12)
    assert_allclose(wind.velocity_ned(12.01, HERE), 0.0)
    times = np.linspace(10.0, 12.0, 201)
    speeds = np.array([wind.velocity_ned(t, HERE)[1] for t in times])
    assert np.all(np.diff(speeds[:101]) > 0) and np.all(np.diff(speeds[100:]) < 0)


def test_gusts_and_winds_add_up() -> None:
    wind = wind_from_spec("constant:1,2,0.5 + gust:t=0,amp=2,dur=4,dir=180 + gust:t=1,amp=1,dur=2,dir=0", seed=0)
    # at t = 2 both gusts peak: 2 south and 1 north
    assert_allclose(wind.velocity_ned(2.0, HERE), [1.0 - 2.0 + 1.0, 2.0, 0.5], atol=1e-12)
    composite = CompositeWind((ConstantWind((1.0, 0.0, 0.0)), ConstantWind((0.0, 0.0, -2.0))))
    assert_allclose(composite.velocity_ned(5.0, HERE), [1.0, 0.0, -2.0])


# --- Dryden -------------------------------------------------------------------------------------


def test_dryden_scales_meet_the_medium_altitude_model_at_1000_ft() -> None:
    """MIL-F-8785C: at 1000 ft the low-altitude model joins L_u = L_v = L_w = 1000 ft, sigma_u = sigma_w."""
    high = dryden_parameters(10.0, 1000.0 * FT)
    assert high.length_u_m == pytest.approx(1000.0 * FT) and high.length_w_m == pytest.approx(1000.0 * FT)
    assert high.sigma_u_m_s == pytest.approx(1.0) and high.sigma_w_m_s == pytest.approx(1.0)
    low = dryden_parameters(10.0, 10.0)
    assert low.length_w_m == pytest.approx(10.0)  # L_w = h
    assert low.length_u_m > 5 * low.length_w_m and low.sigma_u_m_s > 1.5 * low.sigma_w_m_s
    assert dryden_parameters(10.0, 0.5).length_w_m == pytest.approx(10.0 * FT)  # clamped to 10 ft


def autocorrelation(series: np.ndarray, lag: int) -> float:
    centred = series - series.mean()
    return float(centred[:-lag] @ centred[lag:] / (centred @ centred))


def test_dryden_statistics_match_the_model() -> None:
    dt = 0.05
    wind = DrydenTurbulence(6.0, direction_deg=90.0, altitude_m=10.0, airspeed_m_s=40.0, seed=11, sample_dt_s=dt)
    times = np.arange(60000) * dt  # 3000 s, > 1000 time constants of u
    samples = np.array([wind.velocity_ned(t, HERE) for t in times])
    par = wind.parameters
    t_u, _, t_w = wind.time_constants_s
    # the mean wind blows towards the east: u is east, v is south (to its right), w is down
    assert_allclose(samples.mean(axis=0), [0.0, 6.0, 0.0], atol=0.16)  # 4 standard errors of a mean
    east, north, down = samples[:, 1], samples[:, 0], samples[:, 2]
    assert east.std() == pytest.approx(par.sigma_u_m_s, rel=0.06)
    assert north.std() == pytest.approx(par.sigma_v_m_s, rel=0.06)
    assert down.std() == pytest.approx(par.sigma_w_m_s, rel=0.06)
    # u: exp(-tau/T); w: (1 - tau/2T) exp(-tau/T)
    assert autocorrelation(east, round(t_u / dt)) == pytest.approx(math.exp(-1.0), abs=0.06)
    lag = round(t_w / dt)
    tau = lag * dt
    assert autocorrelation(down, lag) == pytest.approx((1 - tau / (2 * t_w)) * math.exp(-tau / t_w), abs=0.05)
    assert autocorrelation(down, 2 * lag) == pytest.approx(0.0, abs=0.05)
    assert abs(np.corrcoef(east, down)[0, 1]) < 0.05  # independent components


def test_dryden_is_reproducible_and_independent_of_the_sampling_rate() -> None:
    fine = DrydenTurbulence(5.0, seed=3)
    coarse = DrydenTurbulence(5.0, seed=3)
    other = DrydenTurbulence(5.0, seed=4)
    a = np.array([fine.velocity_ned(k * 1e-3, HERE) for k in range(3000)])
    b = np.array([coarse.velocity_ned(k * 0.05, HERE) for k in range(60)])
    assert_allclose(a[::50], b, atol=1e-12)
    assert np.std(a[:, 0]) > 0.0
    assert not np.allclose(a[::50], [other.velocity_ned(k * 0.05, HERE) for k in range(60)])
    # asking for an earlier time replays the same sequence from the seed
    assert_allclose(fine.velocity_ned(0.5, HERE), a[500], atol=1e-12)
    assert_allclose(fine.velocity_ned(1.234, HERE), a[1234], atol=1e-12)


def test_calm_dryden_is_calm() -> None:
    assert_allclose(DrydenTurbulence(0.0, seed=1).velocity_ned(3.0, HERE), 0.0)


# --- the spec string ------------------------------------------------------------------------


def test_spec_builds_each_kind() -> None:
    assert wind_from_spec("none", 0).velocity_ned(1.0, HERE).tolist() == [0.0, 0.0, 0.0]
    assert wind_from_spec("constant:3,0,-1", 0).velocity_ned(1.0, HERE).tolist() == [3.0, 0.0, -1.0]
    dryden = wind_from_spec("dryden:5,dir=90,alt=20,airspeed=8", 0)
    assert isinstance(dryden, DrydenTurbulence)
    assert (dryden.mean_speed_m_s, dryden.direction_deg, dryden.altitude_m, dryden.airspeed_m_s) == (5, 90, 20, 8)
    gust = wind_from_spec("gust:t=10,amp=4,dur=2,dir=90", 0)
    assert gust == GustWind((Gust(10.0, 4.0, 2.0, 90.0),))


def test_spec_seeds_make_runs_reproducible() -> None:
    def run(seed: int) -> np.ndarray:
        wind = wind_from_spec("dryden:5+dryden:3,dir=45", seed)
        return np.array([wind.velocity_ned(t, HERE) for t in np.arange(0.0, 5.0, 0.01)])

    assert_allclose(run(7), run(7), atol=0)
    assert not np.allclose(run(7), run(8))


@pytest.mark.parametrize(
    ("spec", "names"),
    [
        ("", "empty"),
        ("breeze:3", "'breeze:3'"),
        ("constant:1,2", "'constant:1,2'"),
        ("constant:1,2,x", "'constant:1,2,x'"),
        ("dryden:fast", "'dryden:fast'"),
        ("dryden:-2", "'dryden:-2'"),
        ("dryden:5,alt=0", "'dryden:5,alt=0'"),
        ("dryden:5,height=3", "'height'"),
        ("gust:t=1,amp=2", "missing dur"),
        ("gust:t=1,amp=2,dur=-1", "'gust:t=1,amp=2,dur=-1'"),
        ("gust:t=1,t=2,amp=2,dur=1", "twice"),
        ("constant:1,2,3++gust:t=1,amp=1,dur=1", "empty part"),
        ("constant:1,2,nan", "finite"),
    ],
)
def test_bad_specs_give_one_line_naming_the_part(spec: str, names: str) -> None:
    with pytest.raises(WindSpecError) as info:
        wind_from_spec(spec, 0)
    message = str(info.value)
    assert names in message and "\n" not in message
    assert isinstance(info.value, ValueError) and isinstance(info.value, UserError)


# --- the TOML table ---------------------------------------------------------------------------


def test_table_builds_the_sum() -> None:
    table = {
        "constant_ned_m_s": [1.0, 0.0, 0.0],
        "dryden": {"mean_speed_m_s": 4.0, "direction_deg": 180.0, "altitude_m": 15.0},
        "gusts": [
            {"start_s": 2.0, "amplitude_m_s": 3.0, "duration_s": 1.0, "direction_deg": 90.0},
            {"start_s": 5.0, "amplitude_m_s": 1.0, "duration_s": 2.0},
        ],
    }
    wind = wind_from_table(Fields(table, "scenario.toml", "wind."), seed=5)
    assert isinstance(wind, CompositeWind)
    dryden = next(p for p in wind.parts if isinstance(p, DrydenTurbulence))
    gusts = next(p for p in wind.parts if isinstance(p, GustWind))
    assert dryden.altitude_m == 15.0 and len(gusts.gusts) == 2
    expected = [1.0, 0.0, 0.0] + dryden.velocity_ned(2.5, HERE) + [0.0, 3.0, 0.0]
    assert_allclose(wind.velocity_ned(2.5, HERE), expected, atol=1e-12)
    assert_allclose(wind_from_table(Fields({}, "s.toml", "wind."), 0).velocity_ned(1.0, HERE), 0.0)


@pytest.mark.parametrize(
    ("table", "where"),
    [
        ({"constant_ned_m_s": [1.0, 2.0]}, "scenario.toml: wind.constant_ned_m_s"),
        ({"dryden": {"mean_speed_m_s": -1.0}}, "scenario.toml: wind.dryden.mean_speed_m_s"),
        ({"dryden": {"mean_speed_m_s": 1.0, "alt": 3}}, "scenario.toml: wind.dryden.alt"),
        ({"gusts": [{"start_s": 1.0, "amplitude_m_s": 1.0}]}, "scenario.toml: wind.gusts[0].duration_s"),
        ({"gusts": {"start_s": 1.0}}, "scenario.toml: wind.gusts"),
        ({"turbulence": 3}, "scenario.toml: wind.turbulence"),
    ],
)
def test_bad_tables_name_the_file_and_field(table: dict, where: str) -> None:
    with pytest.raises(ParameterFileError, match=f"^{re.escape(where)}: "):
        wind_from_table(Fields(table, "scenario.toml", "wind."), 0)
