"""Measured sensor-layout files: CSV / NPZ / HDF5 reading, validation and one-line errors."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from photonflow.errors import ConfigError, PhotonflowError, SensorFileError
from photonflow.geometry.layouts import fibonacci_sphere_layout
from photonflow.geometry.sensor_file import (
    SENSOR_FILE_SUFFIXES,
    detector_from_sensor_file,
    load_sensor_file,
    write_sensor_file,
)
from photonflow.geometry.shapes import Cylinder, Sphere

SPHERE = Sphere(radius=2.0)
HEADER = "x,y,z,nx,ny,nz"
GOOD_ROW = "0,0,1.9,0,0,-1"


@pytest.fixture
def layout():
    """20 sensors on the 2 m sphere, radii and types varying (m)."""
    positions, normals = fibonacci_sphere_layout(SPHERE.radius, 20)
    radius = np.linspace(0.05, 0.15, 20)
    types = np.arange(20) % 3
    return positions, normals, radius, types


def write_text(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


def one_line(error: PhotonflowError) -> str:
    message = str(error)
    assert "\n" not in message
    return message


# ---- reading ------------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", SENSOR_FILE_SUFFIXES)
def test_round_trip_every_format(tmp_path, layout, suffix):
    positions, normals, radius, types = layout
    path = write_sensor_file(tmp_path / f"s{suffix}", positions, normals, radius, types)
    got = load_sensor_file(path)
    np.testing.assert_allclose(got[0], positions, atol=1e-8)
    np.testing.assert_allclose(got[1], normals, atol=1e-8)
    np.testing.assert_allclose(got[2], radius, atol=1e-9)
    np.testing.assert_array_equal(got[3], types)
    assert got[0].dtype == np.float64 and got[3].dtype == np.int32


def test_csv_comments_extra_columns_case_and_defaults(tmp_path):
    path = write_text(
        tmp_path,
        "survey.csv",
        "# surveyed 2024\n\nLabel, X, Y, Z, NX, NY, NZ\nA1, 0, 0, 1.9, 0, 0, -1\n\n"
        "B7, 1.9, 0, 0, -1, 0, 0\n",
    )
    positions, normals, radius, types = load_sensor_file(path, default_radius=0.1016)
    np.testing.assert_array_equal(positions, [[0, 0, 1.9], [1.9, 0, 0]])
    np.testing.assert_array_equal(normals, [[0, 0, -1], [-1, 0, 0]])
    np.testing.assert_array_equal(radius, [0.1016, 0.1016])
    np.testing.assert_array_equal(types, [0, 0])


def test_csv_semicolon_delimiter(tmp_path):
    path = write_text(tmp_path, "s.csv", "x;y;z;nx;ny;nz;radius\n0;0;1.9;0;0;-1;0.2\n")
    assert load_sensor_file(path)[2].tolist() == [0.2]


def test_normals_within_tolerance_are_renormalised(tmp_path):
    path = write_text(tmp_path, "s.csv", f"{HEADER}\n0,0,1.9,0,0,-1.0005\n")
    normals = load_sensor_file(path, default_radius=0.1)[1]
    assert np.linalg.norm(normals[0]) == pytest.approx(1.0, abs=1e-12)


def test_hdf5_root_datasets_and_table(tmp_path, layout):
    positions, normals, _, _ = layout
    columns = dict(zip(HEADER.split(","), [*positions.T, *normals.T], strict=True))
    with h5py.File(tmp_path / "root.h5", "w") as handle:
        for name, values in columns.items():
            handle[name] = values
    table = np.zeros(len(positions), dtype=[(name, "f8") for name in columns])
    for name, values in columns.items():
        table[name] = values
    with h5py.File(tmp_path / "table.hdf5", "w") as handle:
        handle["sensors"] = table
    for name in ("root.h5", "table.hdf5"):
        got = load_sensor_file(tmp_path / name, default_radius=0.1)
        np.testing.assert_allclose(got[0], positions)


def test_write_refuses_to_overwrite(tmp_path, layout):
    path = write_sensor_file(tmp_path / "s.npz", *layout)
    with pytest.raises(SensorFileError, match="exists"):
        write_sensor_file(path, *layout)
    write_sensor_file(path, *layout, overwrite=True)


# ---- errors -------------------------------------------------------------------------------

CSV_ERRORS = [
    (
        "missing column",
        f"x,y,z,n_x,ny,nz\n{GOOD_ROW}\n",
        ["missing column nx", "found: x, y, z, n_x, ny, nz"],
    ),
    (
        "non-numeric",
        f"{HEADER}\n{GOOD_ROW}\n{GOOD_ROW}\n0,abc,1.9,0,0,-1\n",
        ["row 3 (line 4)", "y = 'abc'", "not a number"],
    ),
    ("NaN", f"{HEADER}\n{GOOD_ROW}\n0,0,nan,0,0,-1\n", ["row 2 (line 3)", "z = nan", "not finite"]),
    (
        "non-unit normal",
        f"{HEADER}\n{GOOD_ROW}\n0,0,1.9,0,0.5,-1\n",
        ["row 2 (line 3)", "[0.0, 0.5, -1.0]", "not a unit vector", "length 1.118"],
    ),
    ("short row", f"{HEADER}\n{GOOD_ROW}\n0,0,1.9\n", ["row 2 (line 3)", "3 fields", "has 6"]),
    ("no records", f"{HEADER}\n", ["no sensors"]),
    ("empty", "# nothing\n", ["empty"]),
    ("bad radius", f"{HEADER},radius\n{GOOD_ROW},-0.1\n", ["row 1 (line 2)", "radius = -0.1"]),
    ("bad type", f"{HEADER},type\n{GOOD_ROW},1.5\n", ["type = 1.5", "integer"]),
    ("duplicate column", f"{HEADER},x\n{GOOD_ROW},1\n", ["'x' appears twice"]),
]


@pytest.mark.parametrize(
    ("text", "expected"), [case[1:] for case in CSV_ERRORS], ids=[c[0] for c in CSV_ERRORS]
)
def test_csv_errors_are_one_line_and_name_file_row_and_value(tmp_path, text, expected):
    path = write_text(tmp_path, "bad_sensors.csv", text)
    with pytest.raises(SensorFileError) as info:
        load_sensor_file(path, default_radius=0.1)
    message = one_line(info.value)
    assert message.startswith(f"{path}: ")
    for part in expected:
        assert part in message


def test_missing_file_and_unknown_extension(tmp_path):
    with pytest.raises(SensorFileError, match=r"nothere\.csv: no such file"):
        load_sensor_file(tmp_path / "nothere.csv")
    path = write_text(tmp_path, "s.txt", f"{HEADER}\n{GOOD_ROW}\n")
    with pytest.raises(SensorFileError, match=r"s\.txt: unknown sensor-file extension '\.txt'"):
        load_sensor_file(path)


def test_no_radius_column_needs_a_default(tmp_path):
    path = write_text(tmp_path, "s.csv", f"{HEADER}\n{GOOD_ROW}\n")
    with pytest.raises(SensorFileError, match="no 'radius' column and no default radius"):
        load_sensor_file(path)


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_corrupt_binary_files(tmp_path, suffix):
    path = write_text(tmp_path, f"s{suffix}", "not a binary file\n")
    with pytest.raises(SensorFileError) as info:
        load_sensor_file(path)
    assert one_line(info.value).startswith(f"{path}: ")


def test_npz_column_problems(tmp_path):
    good = {"x": [0.0], "y": [0.0], "z": [1.9], "nx": [0.0], "ny": [0.0], "nz": [-1.0]}
    cases = [
        ({**good, "x": ["a"]}, "column 'x' has dtype <U1, must be numeric"),
        ({**good, "x": [0.0, 1.0]}, "column 'y' has 1 entries, 'x' has 2"),
        ({k: v for k, v in good.items() if k != "nz"}, "missing column nz (found: x, y, z, nx, ny"),
        ({**good, "nz": [-1.3]}, "index 0: (nx, ny, nz) = [0.0, 0.0, -1.3]: not a unit vector"),
        ({**good, "y": [np.inf]}, "index 0: y = inf: not finite"),
    ]
    for i, (arrays, expected) in enumerate(cases):
        path = tmp_path / f"case{i}.npz"
        np.savez(path, **arrays)
        with pytest.raises(SensorFileError) as info:
            load_sensor_file(path, default_radius=0.1)
        assert expected in one_line(info.value), expected


# ---- checks against the detector shape ---------------------------------------------------


def test_sensor_outside_the_shape_names_file_and_index(tmp_path):
    path = write_text(tmp_path, "s.csv", f"{HEADER}\n{GOOD_ROW}\n0,0,2.5,0,0,-1\n")
    assert len(load_sensor_file(path, default_radius=0.1)[0]) == 2  # no shape: no check
    with pytest.raises(ConfigError) as info:
        load_sensor_file(path, SPHERE, default_radius=0.1)
    message = one_line(info.value)
    assert message.startswith(f"{path}: sensors.positions[1] = [0.0, 0.0, 2.5]")
    assert "outside the sphere" in message


def test_outward_facing_sensor_is_rejected(tmp_path):
    path = write_text(tmp_path, "s.csv", f"{HEADER}\n0,0,1.995,0,0,1\n")
    with pytest.raises(ConfigError, match=r"sensors\.normals\[0\].*points out of the detector"):
        load_sensor_file(path, SPHERE, default_radius=0.1)


def test_detector_from_sensor_file(tmp_path, layout):
    path = write_sensor_file(tmp_path / "tank.csv", *layout)
    detector = detector_from_sensor_file(path, SPHERE, sensor_models=("R3600", "R14688", "R14374"))
    assert detector.name == "tank" and detector.n_sensors == 20
    assert detector.sensor_models == ("R3600", "R14688", "R14374")
    np.testing.assert_array_equal(detector.sensor_type, layout[3])
    with pytest.raises(ConfigError, match=r"tank\.csv: sensors\.type\[2\] = 2: must be in 0\.\.1"):
        detector_from_sensor_file(path, SPHERE, sensor_models=("R3600", "R14688"))
    with pytest.raises(ConfigError, match=r"sensors\.positions\[\d+\].*outside the cylinder"):
        detector_from_sensor_file(
            path, Cylinder(radius=1.0, height=1.0), sensor_models=("R3600",) * 3
        )
