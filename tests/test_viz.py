"""Flat wall maps (projections) and detector pictures."""

import math

import numpy as np
import pytest
from matplotlib.figure import Figure

from photonflow.errors import PhotonflowError
from photonflow.geometry import Box, Cylinder, Sphere, make_detector, preset_detector
from photonflow.geometry.layouts import (
    barrel_caps_layout,
    box_grid_layout,
    expand_modules,
    fibonacci_sphere_layout,
)
from photonflow.viz import plot_detector, save_figure, sensor_map
from photonflow.viz.projections import BOX_FACES, box_map, cylinder_map, sphere_map

CYLINDER = Cylinder(radius=3.0, height=5.0)


def _cylinder_detector():
    positions, normals = barrel_caps_layout(CYLINDER.radius, CYLINDER.height, 5, 24, 30,
                                            cap_margin=0.1)
    return make_detector(CYLINDER, positions, normals, 0.1, name="CYL")


def test_cylinder_barrel_preserves_arc_length_and_caps_are_isometric():
    detector = _cylinder_detector()
    positions = np.asarray(detector.sensor_positions)
    flat = sensor_map(detector)
    barrel = flat.face == 0
    assert barrel.sum() == 5 * 24 and (flat.face == 1).sum() == 30 == (flat.face == 2).sum()
    phi = np.arctan2(positions[barrel, 1], positions[barrel, 0])
    np.testing.assert_allclose(flat.x[barrel], CYLINDER.radius * phi, atol=1e-12)
    np.testing.assert_allclose(flat.y[barrel], positions[barrel, 2], atol=1e-12)
    assert flat.regions[0].contains(flat.x[barrel], flat.y[barrel]).all()
    rho = np.hypot(positions[:, 0], positions[:, 1])
    for face in (1, 2):
        region = flat.regions[face]
        on = flat.face == face
        assert region.kind == "ellipse" and region.half_width == region.half_height == 3.0
        assert region.contains(flat.x[on], flat.y[on]).all()
        distance = np.hypot(flat.x[on] - region.centre[0], flat.y[on] - region.centre[1])
        np.testing.assert_allclose(distance, rho[on], atol=1e-12)  # cap drawn true to size
        assert not flat.regions[0].contains(flat.x[on], flat.y[on], tolerance=-1e-6).any()
    np.testing.assert_array_equal(flat.jacobian, np.broadcast_to(np.eye(2), (len(rho), 2, 2)))


def test_cylinder_caps_hinge_on_the_barrel_at_phi_zero():
    """The rim point (R, 0, +-H/2) maps to the same spot as a barrel or as a cap point."""
    half = 0.5 * CYLINDER.height
    rim = np.array([[3.0, 0.0, half], [3.0, 0.0, -half]])
    as_barrel = cylinder_map(CYLINDER, rim, np.array([[-1.0, 0, 0], [-1.0, 0, 0]]))
    as_caps = cylinder_map(CYLINDER, rim, np.array([[0, 0, -1.0], [0, 0, 1.0]]))
    np.testing.assert_array_equal(as_barrel.face, [0, 0])
    np.testing.assert_array_equal(as_caps.face, [1, 2])
    np.testing.assert_allclose(as_barrel.x, as_caps.x, atol=1e-12)
    np.testing.assert_allclose(as_barrel.y, as_caps.y, atol=1e-12)
    np.testing.assert_allclose(as_barrel.y, [half, -half])


def test_off_wall_module_pmts_stay_on_their_module_face():
    modules, module_normals = barrel_caps_layout(3.0, 5.0, 3, 12, 10, cap_margin=0.3)
    positions, normals, module = expand_modules(modules, module_normals, 0.25)
    flat = cylinder_map(CYLINDER, positions, normals)
    module_face = cylinder_map(CYLINDER, modules, module_normals).face
    np.testing.assert_array_equal(flat.face, module_face[module])
    for face, region in enumerate(flat.regions):
        on = flat.face == face
        assert region.contains(flat.x[on], flat.y[on]).all()
    barrel = flat.face == 0
    phi = np.arctan2(positions[barrel, 1], positions[barrel, 0])
    np.testing.assert_allclose(flat.x[barrel], 3.0 * phi, atol=1e-12)  # nearest wall point


def _inverse_mollweide(x, y, radius):
    theta = np.arcsin(y / (math.sqrt(2.0) * radius))
    latitude = np.arcsin((2 * theta + np.sin(2 * theta)) / math.pi)
    longitude = math.pi * x / (2 * math.sqrt(2.0) * radius * np.cos(theta))
    return longitude, latitude


def test_sphere_map_longitude_latitude_match_positions():
    sphere = Sphere(radius=7.0)
    positions, _ = fibonacci_sphere_layout(sphere.radius, 2000)
    flat = sphere_map(sphere, positions)
    longitude, latitude = _inverse_mollweide(flat.x, flat.y, sphere.radius)
    np.testing.assert_allclose(longitude, np.arctan2(positions[:, 1], positions[:, 0]),
                               atol=1e-7)
    np.testing.assert_allclose(latitude, np.arcsin(positions[:, 2] / sphere.radius), atol=1e-9)
    assert flat.regions[0].contains(flat.x, flat.y).all()
    # equal-area map: unit Jacobian determinant everywhere, poles included
    np.testing.assert_allclose(np.linalg.det(flat.jacobian), 1.0, atol=1e-6)


def test_sphere_map_jacobian_matches_finite_differences():
    sphere = Sphere(radius=5.0)
    longitude = np.array([-2.9, -1.0, 0.3, 2.5])
    latitude = np.array([-1.3, -0.2, 0.7, 1.45])
    step = 1e-6  # m along the sphere

    def point(lon, lat):
        return sphere.radius * np.stack(
            [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=1)

    base = sphere_map(sphere, point(longitude, latitude))
    east = sphere_map(sphere, point(longitude + step / (sphere.radius * np.cos(latitude)),
                                    latitude))
    north = sphere_map(sphere, point(longitude, latitude + step / sphere.radius))
    numeric = np.stack([
        np.stack([(east.x - base.x) / step, (north.x - base.x) / step], axis=1),
        np.stack([(east.y - base.y) / step, (north.y - base.y) / step], axis=1),
    ], axis=1)
    np.testing.assert_allclose(base.jacobian, numeric, atol=2e-4)


def test_box_unfolding_keeps_each_face_inside_its_rectangle():
    box = Box(6.0, 4.0, 3.0)
    positions, normals = box_grid_layout(6.0, 4.0, 3.0, 0.5)
    flat = box_map(box, positions, normals)
    axis = np.argmax(np.abs(normals), axis=1)
    expected = [f"{'+' if normals[i, a] < 0 else '-'}{'xyz'[a]}" for i, a in enumerate(axis)]
    np.testing.assert_array_equal(np.asarray(BOX_FACES)[flat.face], expected)
    for face, region in enumerate(flat.regions):
        on = flat.face == face
        assert on.sum() > 0 and region.contains(flat.x[on], flat.y[on]).all()
        for other, other_region in enumerate(flat.regions):
            if other != face:
                assert not other_region.contains(flat.x[on], flat.y[on], tolerance=-1e-6).any()
    # the same points without normals: the nearest face gives the same unfolding
    nearest = box_map(box, positions)
    np.testing.assert_array_equal(nearest.face, flat.face)
    np.testing.assert_allclose(nearest.x, flat.x)
    # neighbouring faces share their edge: (hx, hy, z) on +x and on +y maps to one point
    edge = np.array([[3.0, 2.0, 0.7]])
    on_x = box_map(box, edge, np.array([[-1.0, 0.0, 0.0]]))
    on_y = box_map(box, edge, np.array([[0.0, -1.0, 0.0]]))
    np.testing.assert_allclose([on_x.x, on_x.y], [on_y.x, on_y.y])


def _sensor_markers(figure):
    return sum(len(c.get_offsets()) for ax in figure.axes for c in ax.collections
               if c.get_gid() == "sensors")


@pytest.mark.parametrize("name", ["TOY_CYLINDER", "TOY_SPHERE", "ICECUBE_MINI", "WCTE"])
def test_plot_detector_draws_one_marker_per_sensor(name):
    detector = preset_detector(name)
    figure = plot_detector(detector)
    assert isinstance(figure, Figure)
    assert _sensor_markers(figure) == detector.n_sensors
    assert detector.name in figure.get_suptitle()
    assert f"{detector.n_sensors:,} sensors" in figure.get_suptitle()


def test_plot_detector_values_colour_the_sensors(tmp_path):
    detector = _cylinder_detector()
    values = np.linspace(0.0, 5.0, detector.n_sensors)
    values[3] = np.nan
    figure = plot_detector(detector, tmp_path / "event.png", values=values,
                           label="charge (p.e.)", title="event 7")
    sensors = [c for c in figure.axes[0].collections if c.get_gid() == "sensors"][0]
    np.testing.assert_array_equal(sensors.get_array().filled(-1.0)[:3], values[:3])
    assert sensors.get_array().mask[3]
    assert len(figure.axes) == 2 and figure.axes[1].get_ylabel() == "charge (p.e.)"
    assert figure.get_suptitle() == "event 7"
    assert (tmp_path / "event.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(PhotonflowError, match=r"values: shape \(3,\)"):
        plot_detector(detector, values=[1.0, 2.0, 3.0])


def test_save_figure_writes_atomically_and_refuses_unknown_formats(tmp_path):
    figure = plot_detector(preset_detector("TOY_SPHERE"))
    target = tmp_path / "new" / "folder" / "sphere.svg"
    assert save_figure(figure, target) == target
    assert target.read_text().lstrip().startswith("<?xml")
    assert sorted(p.name for p in target.parent.iterdir()) == ["sphere.svg"]
    with pytest.raises(PhotonflowError, match=r"unknown picture format \.txt"):
        save_figure(figure, tmp_path / "sphere.txt")
    assert not (tmp_path / "sphere.txt").exists()
