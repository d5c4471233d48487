"""Layout generators: counts, pitch, coverage, spacing guarantees."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from photonflow.errors import ConfigError
from photonflow.geometry.layouts import (
    MPMT_RINGS,
    barrel_caps_layout,
    barrel_caps_layout_for_coverage,
    barrel_caps_layout_for_spacing,
    box_grid_layout,
    disc_grid,
    expand_modules,
    fibonacci_sphere_layout,
    latitude_rings_sphere_layout,
    string_layout,
)


def _coverage(positions, sensor_radius, area):
    return len(positions) * math.pi * sensor_radius**2 / area


def test_barrel_caps_counts_and_positions():
    positions, normals = barrel_caps_layout(2.0, 4.0, 4, 30, 40)
    assert len(positions) == 4 * 30 + 2 * 40
    barrel = positions[:120]
    np.testing.assert_allclose(np.hypot(barrel[:, 0], barrel[:, 1]), 2.0)
    np.testing.assert_allclose(
        np.sort(np.unique(np.round(barrel[:, 2], 9))), [-1.5, -0.5, 0.5, 1.5]
    )
    caps = positions[120:]
    np.testing.assert_allclose(np.abs(caps[:, 2]), 2.0)
    np.testing.assert_allclose(normals[120:160], np.tile([0, 0, -1.0], (40, 1)))


@pytest.mark.parametrize("grid", ["square", "hex"])
@given(count=st.integers(1, 400), limit=st.floats(0.5, 20.0))
def test_disc_grid_exact_count_inside_limit(grid, count, limit):
    points = disc_grid(count, limit, grid)
    assert len(points) == count
    assert np.all(np.hypot(points[:, 0], points[:, 1]) <= limit + 1e-9)
    assert len(np.unique(np.round(points, 9), axis=0)) == count


@pytest.mark.parametrize("grid", ["square", "hex"])
@pytest.mark.parametrize("coverage", [0.05, 0.2, 0.4])
def test_coverage_front_end_hits_target(grid, coverage):
    radius, height, sensor_radius = 10.0, 20.0, 0.254
    positions, _ = barrel_caps_layout_for_coverage(
        radius, height, coverage, sensor_radius, cap_grid=grid
    )
    area = 2 * math.pi * radius * height + 2 * math.pi * radius**2
    assert _coverage(positions, sensor_radius, area) == pytest.approx(coverage, rel=0.01)


def test_spacing_front_end_pitch_and_bad_spacing():
    positions, normals = barrel_caps_layout_for_spacing(16.84, 36.2, 0.707, 0.254)
    barrel = np.abs(normals[:, 2]) < 0.5
    distance, _ = cKDTree(positions[barrel]).query(positions[barrel], k=2)
    assert np.median(distance[:, 1]) == pytest.approx(0.707, rel=0.01)
    with pytest.raises(ConfigError, match="layout.spacing = 0.3"):
        barrel_caps_layout_for_spacing(16.84, 36.2, 0.3, 0.254)


def test_fibonacci_is_uniform():
    positions, normals = fibonacci_sphere_layout(3.0, 2000)
    np.testing.assert_allclose(np.linalg.norm(positions, axis=1), 3.0)
    np.testing.assert_allclose(normals, -positions / 3.0)
    # Uniform on the sphere: mean of the unit vectors ~ 0 and <z^2> = 1/3.
    unit = positions / 3.0
    assert np.all(np.abs(unit.mean(axis=0)) < 2e-3)
    assert np.mean(unit[:, 2] ** 2) == pytest.approx(1 / 3, rel=0.01)


@given(count=st.integers(20, 3000))
def test_latitude_rings_exact_count_and_pitch(count):
    radius = 5.0
    positions, _ = latitude_rings_sphere_layout(radius, count)
    assert len(positions) == count
    # Largest pitch that fits count sensors: no two closer than ~ the square-packing pitch.
    distance, _ = cKDTree(positions).query(positions, k=2)
    square_pitch = math.sqrt(4 * math.pi * radius**2 / count)
    # Few rings waste some area near the poles; dense layouts approach square packing.
    assert distance[:, 1].min() > (0.95 if count >= 500 else 0.85) * square_pitch


def test_latitude_rings_refuse_impossible_packing():
    with pytest.raises(ConfigError, match="layout.count"):
        latitude_rings_sphere_layout(1.0, 1000, min_pitch=0.2)


def test_box_grid_faces():
    positions, normals = box_grid_layout(2.0, 4.0, 6.0, 1.0)
    assert len(positions) == 2 * (2 * 4 + 4 * 6 + 2 * 6)
    # Each sensor lies on the face its normal points away from.
    half = np.array([1.0, 2.0, 3.0])
    axis = np.argmax(np.abs(normals), axis=1)
    np.testing.assert_allclose(np.abs(positions[np.arange(len(axis)), axis]), half[axis])
    assert np.all(np.sum(positions * normals, axis=1) < 0)


def test_strings_hexagon():
    positions, normals = string_layout(7, 125.0, 60, 17.0)
    assert len(positions) == 420
    xy = np.unique(np.round(positions[:, :2], 6), axis=0)
    assert len(xy) == 7
    radii = np.sort(np.hypot(xy[:, 0], xy[:, 1]))
    np.testing.assert_allclose(radii, [0] + [125.0] * 6, atol=1e-9)
    z = np.sort(np.unique(np.round(positions[:, 2], 6)))
    np.testing.assert_allclose(np.diff(z), 17.0)
    assert z.mean() == pytest.approx(0.0)
    np.testing.assert_allclose(normals, np.tile([0, 0, -1.0], (420, 1)))


def test_expand_modules_tilts():
    centre = np.array([[0.0, 0.0, -2.0]])
    up = np.array([[0.0, 0.0, 1.0]])
    positions, normals, module = expand_modules(centre, up, 0.254)
    assert len(positions) == sum(count for _, count in MPMT_RINGS) == 19
    np.testing.assert_array_equal(module, 0)
    np.testing.assert_allclose(np.linalg.norm(positions - centre, axis=1), 0.254)
    tilt = np.degrees(np.arccos(np.clip(normals @ up[0], -1, 1)))
    np.testing.assert_allclose(np.sort(tilt), [0] + [20] * 6 + [40] * 12, atol=1e-9)
