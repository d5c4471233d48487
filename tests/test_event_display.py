"""Event display: dense per-sensor arrays, the truth marker, and the figure content."""

import numpy as np
import pytest

import photonflow as pf
from photonflow.viz import dense_hits, plot_event, truth_wall_point


def _event(truth=None):
    return pf.Event(
        np.array([3, 7, 11], np.int32),
        np.array([1.0, 2.5, 40.0], np.float32),
        np.array([12.0, 9.0, 30.0], np.float32),
        truth,
    )


def test_dense_hits_places_values_and_nan_elsewhere():
    charge, time = dense_hits(_event(), 20)
    assert np.isnan(charge).sum() == 17 and np.isnan(time).sum() == 17
    np.testing.assert_array_equal(charge[[3, 7, 11]], [1.0, 2.5, 40.0])
    np.testing.assert_array_equal(time[[3, 7, 11]], [12.0, 9.0, 30.0])


def test_laser_truth_marker_is_where_the_axis_leaves_the_tank():
    detector = pf.load_detector("TOY_CYLINDER")
    truth = pf.Truth(source_kind="laser", position=np.array([0.5, 0.0, 0.0]),
                     direction=np.array([0.0, 0.0, -1.0]), time=0.0, seed=1)
    point = truth_wall_point(detector, _event(truth))
    np.testing.assert_allclose(point, [0.5, 0.0, -2.0], atol=1e-6)


def test_isotropic_truth_marker_projects_radially_and_centre_has_none():
    detector = pf.load_detector("TOY_SPHERE")
    off = pf.Truth(source_kind="isotropic", position=np.array([0.0, 1.0, 0.0]), time=0.0, seed=1)
    np.testing.assert_allclose(truth_wall_point(detector, _event(off)), [0, 2.0, 0], atol=1e-6)
    centre = pf.Truth(source_kind="isotropic", position=np.zeros(3), time=0.0, seed=1)
    assert truth_wall_point(detector, _event(centre)) is None


@pytest.mark.parametrize("name", ["TOY_CYLINDER", "TOY_SPHERE"])
def test_plot_event_has_two_maps_with_all_sensors_and_one_marker_each(name, tmp_path):
    detector = pf.load_detector(name)
    truth = pf.Truth(source_kind="laser", position=np.array([0.0, 0.0, 0.5]),
                     direction=np.array([1.0, 0.0, 0.0]), time=0.0, seed=1)
    figure = plot_event(detector, _event(truth), tmp_path / "event.png")
    assert (tmp_path / "event.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    maps = [ax for ax in figure.axes if any(c.get_gid() == "sensors" for c in ax.collections)]
    assert len(maps) == 2
    for ax in maps:
        sensors = next(c for c in ax.collections if c.get_gid() == "sensors")
        assert len(sensors.get_offsets()) == detector.n_sensors
        values = np.ma.getdata(sensors.get_array())
        assert np.isfinite(values).sum() == 3
        assert sum(line.get_gid() == "truth" for line in ax.lines) == 1
