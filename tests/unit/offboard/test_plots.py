"""The paper's figures: files are real PNGs, and what is drawn is the record's data."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from matplotlib.image import imread
from numpy.testing import assert_allclose

from offboard.plots import FIGURE_NAMES, actions_figure, make_figures, position_figure, write_figures
from offboard.record import COLUMNS, FlightRecord, RecordBuilder
from offboard.trajectory.base import Phase

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def synthetic_record(samples: int = 200, nan_columns: tuple[str, ...] = ()) -> FlightRecord:
    """A helix-like flight with distinct values in every column, so a swapped axis shows."""
    rng = np.random.default_rng(7)
    rows = RecordBuilder()
    for n in range(samples):
        t = 0.05 * n
        ref = np.array([2 * math.cos(t), 2 * math.sin(t), -0.8 * t])
        pos = ref + rng.normal(0.0, 0.05, 3)
        values = {
            "t_s": t,
            "pos_ned_m": pos,
            "vel_ned_m_s": rng.normal(0.0, 1.0, 3),
            "euler_rad": np.array([0.1 * math.sin(t), -0.2 * math.cos(t), 3.0 + 0.05 * t]),
            "ref_pos_ned_m": ref,
            "ref_yaw_rad": -3.1 + 0.02 * t,  # across the +-pi seam from the flown yaw
            "ref_euler_rad": np.array([0.12 * math.sin(t), -0.25 * math.cos(t), 0.3]),
            "thrust_n": 4.9 + math.sin(3 * t),
            "torques_nm": np.array([1e-3 * t, -2e-3 * t, 3e-4 * math.cos(t)]),
            "tau_tilde": rng.normal(0.0, 1.0, 3),
        }
        for name in nan_columns:
            values[name] = np.full(COLUMNS[name], np.nan) if COLUMNS[name] > 1 else math.nan
        rows.append(**values)
    phases = [Phase("helix", 0.0, 4.0), Phase("hold", 4.0, 8.0, "hold"), Phase("descent", 8.0, 10.0)]
    return rows.build(phases=phases)


@pytest.fixture(scope="module")
def drawn():
    """One synthetic record and its figures, built once for the data checks."""
    record = synthetic_record()
    return record, make_figures(record)


def line(ax, label: str):
    matches = [ln for ln in ax.get_lines() if ln.get_label() == label]
    assert len(matches) == 1, [ln.get_label() for ln in ax.get_lines()]
    return matches[0]


def test_position_figure_draws_north_east_up_and_references(drawn):
    record, figures = drawn
    axes = figures["position"].axes
    pos, ref = record["pos_ned_m"], record["ref_pos_ned_m"]
    for i, sign in enumerate((1.0, 1.0, -1.0)):  # z is up = -down
        assert_allclose(line(axes[i], "flown").get_xdata(), record["t_s"])
        assert_allclose(line(axes[i], "flown").get_ydata(), sign * pos[:, i])
        assert_allclose(line(axes[i], "reference").get_ydata(), sign * ref[:, i])
    assert "north" in axes[0].get_ylabel() and "up" in axes[2].get_ylabel()


def test_path3d_figure_draws_the_path_with_z_up(drawn):
    record, figures = drawn
    ax = figures["path3d"].axes[0]
    x, y, z = line(ax, "flown").get_data_3d()
    assert_allclose(np.column_stack([x, y, -np.asarray(z)]), record["pos_ned_m"])
    x, y, z = line(ax, "reference").get_data_3d()
    assert_allclose(np.column_stack([x, y, -np.asarray(z)]), record["ref_pos_ned_m"])
    assert "up" in ax.get_zlabel() and "north" in ax.get_xlabel()


def test_attitude_figure_in_degrees_with_the_law_references(drawn):
    record, figures = drawn
    axes = figures["attitude"].axes
    euler, ref_euler = np.degrees(record["euler_rad"]), np.degrees(record["ref_euler_rad"])
    for i in range(3):
        assert_allclose(line(axes[i], "flown").get_ydata(), euler[:, i])
    assert_allclose(line(axes[0], "x7ez (roll ref.)").get_ydata(), ref_euler[:, 0])
    assert_allclose(line(axes[1], "x9ez (pitch ref.)").get_ydata(), ref_euler[:, 1])
    assert_allclose(line(axes[2], "yaw ref.").get_ydata(), np.degrees(record["ref_yaw_rad"]))


def test_errors_figure_is_reference_minus_flown_and_wraps_yaw(drawn):
    record, figures = drawn
    axes = figures["errors"].axes
    err = record["ref_pos_ned_m"] - record["pos_ned_m"]
    assert_allclose(line(axes[0], "e_x north [m]").get_ydata(), err[:, 0])
    assert_allclose(line(axes[1], "e_y east [m]").get_ydata(), err[:, 1])
    assert_allclose(line(axes[2], "e_z up [m]").get_ydata(), -err[:, 2])
    yaw_err = line(axes[3], "e_psi [deg]").get_ydata()
    # flown ~ +3.0 rad, reference ~ -3.1 rad: the short way round is ~ +0.18 rad, not -6.1
    assert np.all(np.abs(yaw_err) < 180.0)
    assert_allclose(yaw_err[0], math.degrees(-3.1 - 3.0 + 2 * math.pi), atol=1e-9)


def test_actions_figure_draws_thrust_and_torques(drawn):
    record, figures = drawn
    axes = figures["actions"].axes
    assert_allclose(line(axes[0], "u [N]").get_ydata(), record["thrust_n"])
    for i, label in enumerate(("tau_phi [N m]", "tau_theta [N m]", "tau_psi [N m]")):
        assert_allclose(line(axes[i + 1], label).get_ydata(), record["torques_nm"][:, i])


def test_phase_boundaries_are_vertical_lines_on_every_time_axis(drawn):
    _, figures = drawn
    for name in ("position", "attitude", "errors", "actions"):
        for ax in figures[name].axes:
            vertical = sorted(
                float(ln.get_xdata()[0]) for ln in ax.get_lines()
                if len(ln.get_xdata()) == 2 and ln.get_xdata()[0] == ln.get_xdata()[1]
            )
            assert vertical == [4.0, 8.0], name


def test_write_figures_writes_valid_pngs(tmp_path):
    record = synthetic_record(800)
    paths = write_figures(record, tmp_path / "run", title="synthetic")
    assert [p.name for p in paths] == [f"{name}.png" for name in FIGURE_NAMES]
    for path in paths:
        data = path.read_bytes()
        assert data[:8] == PNG_SIGNATURE
        assert len(data) > 20_000  # lines, ticks and labels, not a blank canvas
        height, width, _ = imread(path).shape
        assert 500 <= width <= 1200 and 500 <= height <= 1200
        pixels = imread(path)[:, :, :3]
        assert np.ptp(pixels) > 0.5  # something dark drawn on white


@pytest.mark.parametrize(
    "samples, nan_columns",
    [
        (1, ()),
        (1, ("ref_pos_ned_m", "ref_yaw_rad", "ref_euler_rad", "thrust_n", "torques_nm", "tau_tilde")),
        (50, ("ref_pos_ned_m", "ref_yaw_rad", "ref_euler_rad", "thrust_n", "torques_nm", "tau_tilde")),
    ],
)
def test_short_and_partial_records_still_plot(tmp_path, samples, nan_columns):
    record = synthetic_record(samples, nan_columns)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no RuntimeWarning/UserWarning from empty or NaN data
        paths = write_figures(record, tmp_path, title="partial")
    assert all(p.read_bytes()[:8] == PNG_SIGNATURE for p in paths)
    flown = line(position_figure(record).axes[0], "flown")
    assert_allclose(flown.get_ydata(), record["pos_ned_m"][:, 0])
    if samples == 1:
        assert flown.get_marker() == "o"  # a single sample shows as a point
    if "thrust_n" in nan_columns:
        assert np.all(np.isnan(line(actions_figure(record).axes[0], "u [N]").get_ydata()))


def test_empty_record_plots_without_failing(tmp_path):
    record = RecordBuilder().build()
    paths = write_figures(record, tmp_path)
    assert len(paths) == len(FIGURE_NAMES) and all(p.stat().st_size > 0 for p in paths)


def _texts(fig) -> list[str]:
    return [t.get_text() for ax in fig.axes for t in ax.texts]


def test_empty_panels_say_why():
    """A log replayed without references, or attitude setpoints without torques: no blank panel."""
    from offboard.plots import actions_figure, errors_figure

    record = synthetic_record(nan_columns=("ref_pos_ned_m", "torques_nm"))
    assert any("--mission FILE" in text for text in _texts(errors_figure(record)))
    assert sum("replay --rerun recomputes them" in text for text in _texts(actions_figure(record))) == 3
    full = synthetic_record()
    assert not any("--mission" in text or "--rerun" in text for text in _texts(errors_figure(full)) + _texts(actions_figure(full)))


def test_a_flight_that_did_not_complete_is_marked_where_it_ended():
    from offboard.plots import errors_figure, position_figure
    from offboard.record import FlightStatus

    record = synthetic_record()
    record.status = FlightStatus.DIVERGED
    for fig in (position_figure(record), errors_figure(record)):
        assert any(text.startswith("diverged at 9.95 s") for text in _texts(fig))
    assert not any("diverged" in text for text in _texts(position_figure(synthetic_record())))
