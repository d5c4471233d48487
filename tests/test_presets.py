"""Presets reproduce their published sensor counts and coverage (physics.md section 5)."""

import math

import jax
import numpy as np
import pytest
from scipy.spatial import cKDTree

from photonflow.errors import ConfigError
from photonflow.geometry import PRESETS, preset_detector, preset_table

ALL = list(PRESETS)
WITH_COUNT = [name for name in ALL if PRESETS[name].stated.sensors is not None]
WITH_COVERAGE = [name for name in ALL if PRESETS[name].stated.coverage is not None]
WALLED = [name for name in ALL if preset_detector(name).shape.has_walls]


@pytest.mark.parametrize("name", WITH_COUNT)
def test_sensor_count_matches_stated(name):
    stated = PRESETS[name].stated
    assert preset_detector(name).n_sensors == pytest.approx(stated.sensors, rel=0.01)


@pytest.mark.parametrize("name", WITH_COVERAGE)
def test_coverage_matches_stated(name):
    stated = PRESETS[name].stated
    assert preset_detector(name).coverage == pytest.approx(stated.coverage, rel=0.01)


def test_exact_published_counts():
    """SK: 11,146 ID PMTs (WCSim); JUNO: 17,612 20-inch; IWCD 368 and WCTE 106 mPMTs x 19."""
    assert preset_detector("SK").n_sensors == 11146
    assert preset_detector("JUNO").n_sensors == 17612
    assert preset_detector("IWCD").n_sensors == 368 * 19
    assert preset_detector("WCTE").n_sensors == 106 * 19
    assert preset_detector("EOS").n_sensors == 206


def test_sk_dimensions_and_pitch():
    """SK ID 33.6815 m x 36.2 m; PMTs 70 cm apart (SK site): barrel pitch within 1 %."""
    sk = preset_detector("SK")
    assert 2 * sk.shape.radius == pytest.approx(33.6815)
    assert sk.shape.height == pytest.approx(36.2)
    barrel = np.abs(sk.sensor_normals[:, 2]) < 0.5
    z = np.unique(np.round(sk.sensor_positions[barrel, 2], 6))
    assert np.diff(z).mean() == pytest.approx(0.707, rel=0.01)
    columns = barrel.sum() // len(z)
    assert 2 * math.pi * sk.shape.radius / columns == pytest.approx(0.707, rel=0.01)
    assert np.all(sk.sensor_radius == 0.254)


def test_tao_photosensitive_area():
    """TAO: ~10 m^2 of SiPM (arXiv:2005.08745)."""
    assert preset_detector("TAO").photocathode_area == pytest.approx(10.0, rel=0.01)


@pytest.mark.parametrize("name", ALL)
def test_normals_are_unit_and_point_inward(name):
    det = preset_detector(name)
    np.testing.assert_allclose(np.linalg.norm(det.sensor_normals, axis=1), 1.0, atol=1e-9)
    if not det.shape.has_walls:
        return
    # A step along the normal from every sensor stays inside the detector, and a step
    # against it from a wall-mounted sensor leaves it.
    step = 0.05
    ahead = det.sensor_positions + step * det.sensor_normals
    assert np.all(np.asarray(det.shape.contains(ahead)))
    with jax.enable_x64(True):
        distance = np.asarray(det.shape.distance_to_wall(det.sensor_positions))
    on_wall = distance < 1e-9
    behind = det.sensor_positions[on_wall] - step * det.sensor_normals[on_wall]
    assert not np.any(np.asarray(det.shape.contains(behind)))


@pytest.mark.parametrize("name", WALLED)
def test_sensors_inside_boundary(name):
    det = preset_detector(name)
    with jax.enable_x64(True):
        distance = np.asarray(det.shape.distance_to_wall(det.sensor_positions))
    assert np.all(distance > -1e-9)


@pytest.mark.parametrize("name", ALL)
def test_coplanar_discs_do_not_overlap(name):
    det = preset_detector(name)
    diameter = 2 * det.sensor_radius.max()
    pairs = cKDTree(det.sensor_positions).query_pairs(diameter * 0.999, output_type="ndarray")
    if len(pairs) == 0:
        return
    parallel = np.sum(det.sensor_normals[pairs[:, 0]] * det.sensor_normals[pairs[:, 1]], 1)
    # Neighbours facing the same way closer than a diameter would overlap.
    assert not np.any(parallel > 0.95), f"{(parallel > 0.95).sum()} overlapping pairs"


def test_preset_lookup_is_case_insensitive_and_unknown_lists_known():
    assert preset_detector("sk") is preset_detector("SK")
    with pytest.raises(ConfigError) as info:
        preset_detector("SKK")
    message = str(info.value)
    assert "SKK" in message and "SK" in message and "JUNO" in message and "\n" not in message


def test_preset_table_rows():
    rows = {row["name"]: row for row in preset_table()}
    assert set(rows) == set(PRESETS)
    assert rows["SK"]["sensors"] == 11146
    assert math.isnan(rows["ICECUBE_MINI"]["coverage"])
    assert rows["JUNO"]["medium"] == "scintillator"
