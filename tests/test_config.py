"""Configuration files: schema, building, one-line errors, and the command line on bad input."""

from __future__ import annotations

import copy
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from photonflow.config import Config, load_config, load_detector
from photonflow.errors import ConfigError, PhotonflowError, SensorFileError
from photonflow.geometry.presets import PRESETS, preset_detector
from photonflow.geometry.sensor_file import write_sensor_file
from photonflow.medium import WATER

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "configs"
KNOWN_PRESETS = ", ".join(PRESETS)


def custom(shape=None, layout=None, **detector):
    """A custom-detector config dict (small sphere with a Fibonacci layout by default)."""
    spec = {
        "shape": shape or {"kind": "sphere", "radius": 2.0},
        "layout": layout or {"kind": "fibonacci", "count": 50},
        **detector,
    }
    return {"detector": {key: value for key, value in spec.items() if value is not None}}


def with_params(**params):
    return {"detector": {"preset": "TOY_SPHERE"}, "params": params}


def error_of(config, **kwargs) -> str:
    with pytest.raises(PhotonflowError) as info:
        load_config(config, **kwargs)
    message = str(info.value)
    assert "\n" not in message
    return message


# ---- the examples and valid configurations -------------------------------------------------


def test_example_preset():
    config = load_config(EXAMPLES / "sk_preset.yaml")
    assert isinstance(config, Config)
    assert config.detector is preset_detector("SK") and config.detector.n_sensors == 11146
    assert config.medium == "water"
    assert float(config.params.absorption_length) == 80.0
    assert float(config.params.wall_reflectivity) == pytest.approx(0.1)
    assert config.model.detector.preset == "SK"


def test_example_custom_cylinder_with_coverage_layout():
    config = load_config(EXAMPLES / "cylinder_coverage.yaml")
    detector = config.detector
    assert detector.name == "my_tank"
    assert (detector.shape.radius, detector.shape.height) == (5.0, 10.0)
    assert detector.coverage == pytest.approx(0.2, rel=0.03)
    assert detector.sensor_models == ("R14688",)
    np.testing.assert_allclose(detector.sensor_radius, 0.1016)
    assert float(config.params.tts) == 1.5 and float(config.params.dark_rate) == 2000.0
    assert config.params.efficiency.shape == (detector.n_sensors,)


def test_example_sphere_with_sensor_file():
    config = load_config(EXAMPLES / "sphere_sensor_file.yaml")
    detector = config.detector
    assert detector.name == "surveyed_sphere" and detector.n_sensors == 120
    assert detector.shape.kind == "sphere" and detector.shape.radius == 3.0
    assert config.medium == "scintillator"
    assert float(config.params.absorption_length) == pytest.approx(62.0)  # LAB default
    assert float(config.params.quantum_efficiency) == pytest.approx(0.3)
    distance = np.asarray(detector.shape.distance_to_wall(detector.sensor_positions))
    assert np.all((distance > 0) & (distance < 0.02))


def test_yaml_and_json_give_the_same_config(tmp_path):
    data = custom(name="twin", sensor_model="R14688")
    data["params"] = {"absorption_length": 30.0, "angular_acceptance": [1.0] * 10}
    (tmp_path / "a.json").write_text(json.dumps(data))
    (tmp_path / "a.yml").write_text(
        "detector:\n  name: twin\n  shape: {kind: sphere, radius: 2.0}\n"
        "  layout: {kind: fibonacci, count: 50}\n  sensor_model: R14688\n"
        "params:\n  absorption_length: 30.0\n  angular_acceptance: [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]\n"
    )
    a, b = load_config(tmp_path / "a.json"), load_config(tmp_path / "a.yml")
    np.testing.assert_array_equal(a.detector.sensor_positions, b.detector.sensor_positions)
    assert a.model == b.model
    np.testing.assert_array_equal(a.params.angular_acceptance, np.ones(10))


@pytest.mark.parametrize(
    ("shape", "layout", "check"),
    [
        (
            {"kind": "sphere", "radius": 2.0},
            {"kind": "fibonacci", "count": 77},
            lambda d: d.n_sensors == 77,
        ),
        (
            {"kind": "sphere", "radius": 2.0},
            {"kind": "coverage", "coverage": 0.3},
            lambda d: abs(d.coverage - 0.3) < 0.01,
        ),
        (
            {"kind": "sphere", "radius": 2.0},
            {"kind": "spacing", "spacing": 0.6},
            lambda d: d.n_sensors == round(16 * math.pi / (0.36 * math.sqrt(3) / 2)),
        ),
        (
            {"kind": "cylinder", "radius": 2.0, "height": 4.0},
            {"kind": "spacing", "spacing": 0.7, "cap_grid": "hex"},
            lambda d: d.n_sensors > 100,
        ),
        (
            {"kind": "box", "size_x": 2.0, "size_y": 2.0, "size_z": 2.0},
            {"kind": "box_grid", "spacing": 1.0},
            lambda d: d.n_sensors == 24,
        ),
        (
            {"kind": "open", "world_radius": 400.0, "world_height": 1500.0},
            {
                "kind": "strings",
                "strings": 7,
                "string_spacing": 125,
                "sensors_per_string": 60,
                "sensor_spacing": 17,
            },
            lambda d: d.n_sensors == 420 and math.isnan(d.coverage),
        ),
    ],
    ids=["fibonacci", "sphere-coverage", "sphere-spacing", "cylinder-spacing", "box", "strings"],
)
def test_every_layout_kind_builds(shape, layout, check):
    detector = load_config(custom(shape, layout)).detector
    assert detector.shape.kind == shape["kind"]
    assert check(detector)


def test_sensor_radius_defaults_to_the_sensor_model():
    detector = load_config(custom(sensor_model="R14374")).detector
    np.testing.assert_allclose(detector.sensor_radius, 0.040)
    layout = {"kind": "fibonacci", "count": 50, "sensor_radius": 0.2}
    np.testing.assert_allclose(load_config(custom(layout=layout)).detector.sensor_radius, 0.2)


def test_preset_shorthand_case_and_default_medium():
    config = load_config({"detector": "tao"})
    assert config.detector.name == "TAO" and config.medium == "scintillator"
    assert load_config({"detector": "TAO", "medium": "water"}).medium == "water"
    assert load_config(custom()).medium == "water"


def test_param_overrides_scalar_broadcast_and_empty_section():
    config = load_config(with_params(efficiency=0.9, time_offset=[0.5] * 300, mie_length="inf"))
    np.testing.assert_allclose(config.params.efficiency, np.full(300, 0.9), rtol=1e-6)
    np.testing.assert_allclose(config.params.time_offset, 0.5)
    assert math.isinf(float(config.params.mie_length))
    default = load_config({"detector": "TOY_SPHERE", "params": None}).params
    assert float(default.absorption_length) == pytest.approx(WATER.absorption_length)


def test_sensor_file_relative_to_config_or_base_dir(tmp_path):
    positions = np.array([[0.0, 0.0, 1.99], [1.99, 0.0, 0.0]])
    normals = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])
    write_sensor_file(tmp_path / "pmts.csv", positions, normals)
    data = custom(layout=None, sensors="pmts.csv", sensor_model="R14688")
    del data["detector"]["layout"]
    (tmp_path / "tank.yaml").write_text(json.dumps(data))  # JSON is valid YAML
    from_file = load_config(tmp_path / "tank.yaml")
    assert from_file.detector.name == "tank" and from_file.detector.n_sensors == 2
    np.testing.assert_allclose(from_file.detector.sensor_radius, 0.1016)
    from_dict = load_config(data, base_dir=tmp_path)
    np.testing.assert_array_equal(from_dict.detector.sensor_positions, positions)
    with pytest.raises(SensorFileError, match=r"pmts\.csv: no such file"):
        load_config(data)  # relative to the current directory, where it is not


# ---- one-line errors from load_config ------------------------------------------------------

EXACT_ERRORS = [
    (
        "negative length",
        custom(
            {"kind": "cylinder", "radius": -3, "height": 10.0},
            {"kind": "coverage", "coverage": 0.2},
        ),
        "detector.shape.radius = -3: must be a positive, finite length in m",
    ),
    (
        "NaN length",
        custom({"kind": "sphere", "radius": float("nan")}),
        "detector.shape.radius = nan: must be a positive, finite length in m",
    ),
    (
        "text length",
        custom({"kind": "box", "size_x": 1, "size_y": "tall", "size_z": 1}),
        "detector.shape.size_y = 'tall': must be a number",
    ),
    (
        "NaN param",
        with_params(absorption_length=float("nan")),
        "params.absorption_length = nan m: is NaN",
    ),
    (
        "probability",
        with_params(wall_reflectivity=1.5),
        "params.wall_reflectivity = 1.5: must be in [0, 1]",
    ),
    (
        "negative param",
        with_params(scattering_length=-1),
        "params.scattering_length = -1 m: must be > 0 (inf allowed)",
    ),
    (
        "text param",
        with_params(tts="fast"),
        "params.tts = 'fast': must be a number or a list of numbers",
    ),
    (
        "param shape",
        with_params(efficiency=[1.0, 1.0]),
        "params.efficiency: shape (2,), expected (300,)",
    ),
    (
        "unknown preset",
        {"detector": {"preset": "SKK"}},
        f"detector.preset = 'SKK': unknown preset; known: {KNOWN_PRESETS}",
    ),
    (
        "unknown key",
        {"detector": {"shap": {"kind": "sphere", "radius": 1.0}}},
        "detector.shap: unknown field; did you mean 'shape'?",
    ),
    (
        "unknown shape key",
        custom({"kind": "sphere", "radus": 1.0}),
        "detector.shape.radus: unknown field; did you mean 'radius'?",
    ),
    (
        "unknown param",
        with_params(absorbtion_length=3.0),
        "params.absorbtion_length: unknown field; did you mean 'absorption_length'?",
    ),
    ("unknown top key", {"detektor": "SK"}, "detektor: unknown field; did you mean 'detector'?"),
    (
        "unknown key, nothing close",
        {"detector": "SK", "zzz": 1},
        "zzz: unknown field; known: detector, medium, params",
    ),
    (
        "shape kind",
        custom({"kind": "cone", "radius": 1.0}),
        "detector.shape.kind = 'cone': must be one of cylinder, sphere, box, open",
    ),
    (
        "no shape kind",
        custom({"radius": 1.0}),
        "detector.shape.kind: missing (one of cylinder, sphere, box, open)",
    ),
    (
        "missing dimension",
        custom({"kind": "cylinder", "radius": 1.0}),
        "detector.shape.height: missing",
    ),
    (
        "coverage",
        custom(layout={"kind": "coverage", "coverage": 1.2}),
        "detector.layout.coverage = 1.2: must be a fraction in (0, 0.9)",
    ),
    (
        "count",
        custom(layout={"kind": "fibonacci", "count": 2.5}),
        "detector.layout.count = 2.5: must be an integer",
    ),
    (
        "zero count",
        custom(layout={"kind": "fibonacci", "count": 0}),
        "detector.layout.count = 0: must be a positive integer",
    ),
    (
        "cap grid",
        custom(
            {"kind": "cylinder", "radius": 2.0, "height": 2.0},
            {"kind": "spacing", "spacing": 1.0, "cap_grid": "tri"},
        ),
        "detector.layout.cap_grid = 'tri': must be 'square' or 'hex'",
    ),
    (
        "spacing",
        custom(
            {"kind": "cylinder", "radius": 2.0, "height": 2.0}, {"kind": "spacing", "spacing": 0.3}
        ),
        "detector.layout.spacing = 0.3: must exceed the sensor diameter 0.508 m",
    ),
    (
        "layout for shape",
        custom(layout={"kind": "box_grid", "spacing": 1.0}),
        "detector.layout.kind = 'box_grid': needs a box shape, not a sphere",
    ),
    (
        "medium",
        {"detector": "SK", "medium": "oil"},
        "medium = 'oil': must be one of water, scintillator",
    ),
    (
        "params type",
        {"detector": "SK", "params": 3},
        "params = 3: must be a mapping (key: value pairs)",
    ),
    ("no detector", {"medium": "water"}, "detector: missing"),
    (
        "custom, no shape",
        {"detector": {"name": "x"}},
        "detector.shape: missing (give detector.preset, or detector.shape with detector.layout"
        " or detector.sensors)",
    ),
]


@pytest.mark.parametrize(
    ("config", "expected"), [c[1:] for c in EXACT_ERRORS], ids=[c[0] for c in EXACT_ERRORS]
)
def test_config_errors_are_one_exact_line(config, expected):
    with pytest.raises(ConfigError):
        load_config(config)
    assert error_of(config) == expected


@pytest.mark.parametrize(
    ("config", "parts"),
    [
        (custom(sensor_model="R999"), ["detector.sensor_model = 'R999'", "known: R3600"]),
        (
            {"detector": {"preset": "SK", "layout": {"kind": "fibonacci", "count": 5}}},
            ["detector.layout: not allowed with detector.preset"],
        ),
        (custom(sensors="s.csv"), ["detector.sensors: not allowed with detector.layout"]),
        (
            custom(layout={"kind": "coverage", "coverage": 0.5, "sensor_radius": 1e-4}),
            ["detector.layout: would place about 8e+08 sensors", "more than 1,000,000"],
        ),
        (
            custom(
                {"kind": "open", "world_radius": 100.0, "world_height": 100.0},
                {
                    "kind": "strings",
                    "strings": 7,
                    "string_spacing": 125,
                    "sensors_per_string": 60,
                    "sensor_spacing": 17,
                },
            ),
            ["detector.layout.positions[0] = ", "outside the open medium"],
        ),
    ],
    ids=["sensor model", "preset plus layout", "layout plus sensors", "too many", "outside"],
)
def test_more_config_errors(config, parts):
    message = error_of(config)
    for part in parts:
        assert part in message


def write_sensor_case(tmp_path, case):
    """A sphere config whose sensor file has one problem (or none); returns the config path."""
    rows = {
        "columns": "x,y,z,n_x,ny,nz\n0,0,1.9,0,0,-1\n",
        "normals": "x,y,z,nx,ny,nz\n0,0,1.9,0,0,-1\n0,0,1.9,0,0.5,-1\n",
        "outside": "x,y,z,nx,ny,nz\n0,0,1.9,0,0,-1\n0,0,2.5,0,0,-1\n",
    }[case]
    (tmp_path / f"{case}.csv").write_text(rows)
    config = tmp_path / f"{case}.yaml"
    config.write_text(f"detector:\n  shape: {{kind: sphere, radius: 2.0}}\n  sensors: {case}.csv\n")
    return config


@pytest.mark.parametrize(
    ("case", "error", "parts"),
    [
        ("columns", SensorFileError, ["columns.csv: missing column nx", "found: x, y, z, n_x"]),
        (
            "normals",
            SensorFileError,
            ["normals.csv: row 2 (line 3): (nx, ny, nz) = [0.0, 0.5, -1.0]: not a unit vector"],
        ),
        (
            "outside",
            ConfigError,
            ["outside.csv: sensors.positions[1] = [0.0, 0.0, 2.5]: outside the sphere"],
        ),
    ],
)
def test_bad_sensor_file_in_config(tmp_path, case, error, parts):
    config = write_sensor_case(tmp_path, case)
    with pytest.raises(error):
        load_config(config)
    message = error_of(config)
    for part in parts:
        assert part in message


@pytest.mark.parametrize(
    ("name", "text", "parts"),
    [
        (
            "syntax.yaml",
            "detector:\n  preset: SK\n params: [\n",
            ["syntax.yaml: line 3, column 2: YAML syntax error"],
        ),
        (
            "syntax.json",
            '{"detector": "SK",}',
            ["syntax.json: line 1, column 19: JSON syntax error"],
        ),
        (
            "dup.yaml",
            "detector: SK\nmedium: water\nmedium: scintillator\n",
            ["dup.yaml: line 3: duplicate key 'medium' (first on line 2)"],
        ),
        ("list.yaml", "- SK\n", ["list.yaml: the top level must be a mapping", "not list"]),
        ("empty.yml", "# nothing yet\n", ["empty.yml: empty"]),
        (
            "config.toml",
            "detector = 'SK'\n",
            ["config.toml: unknown config-file extension '.toml'"],
        ),
    ],
)
def test_file_errors_name_the_file(tmp_path, name, text, parts):
    (tmp_path / name).write_text(text)
    message = error_of(tmp_path / name)
    for part in parts:
        assert part in message
    assert "nothere.yaml: no such file" in error_of(tmp_path / "nothere.yaml")


VALID_BASE = {
    "detector": {
        "name": "fuzz",
        "shape": {"kind": "cylinder", "radius": 1.5, "height": 2.0},
        "layout": {"kind": "coverage", "coverage": 0.1, "sensor_radius": 0.1, "cap_grid": "hex"},
        "sensor_model": "R14688",
    },
    "medium": "water",
    "params": {"absorption_length": 50.0, "wall_reflectivity": 0.2, "efficiency": 1.0},
}


def _leaf_paths(node, prefix=()):
    if isinstance(node, dict):
        for key, value in node.items():
            yield from _leaf_paths(value, (*prefix, key))
    yield prefix


WEIRD = [
    None,
    -1,
    0,
    1e30,
    -1e-30,
    float("nan"),
    float("inf"),
    "abc",
    "",
    [],
    [1, 2],
    {},
    {"kind": "box"},
    True,
    3,
]


@given(
    path=st.sampled_from(list(_leaf_paths(VALID_BASE))[:-1]),
    value=st.sampled_from(WEIRD),
)
def test_any_bad_value_gives_a_one_line_photonflow_error(path, value):
    config = copy.deepcopy(VALID_BASE)
    node = config
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    try:
        load_config(config)
    except PhotonflowError as error:
        message = str(error)
        assert "\n" not in message and message
    # any other exception type escapes and fails the test


# ---- load_detector -------------------------------------------------------------------------


def test_load_detector_accepts_preset_names_and_config_files(tmp_path):
    assert load_detector("toy_cylinder") is preset_detector("TOY_CYLINDER")
    assert load_detector(EXAMPLES / "cylinder_coverage.yaml").name == "my_tank"
    assert load_detector(str(EXAMPLES / "sk_preset.yaml")).n_sensors == 11146


def test_load_detector_errors(tmp_path):
    with pytest.raises(ConfigError) as expected:
        preset_detector("NOPE")
    with pytest.raises(ConfigError) as got:
        load_detector("NOPE")
    assert str(got.value) == str(expected.value)
    assert f"known: {KNOWN_PRESETS}" in str(got.value)
    sensors = write_sensor_file(tmp_path / "pmts.csv", [[0, 0, 1.0]], [[0, 0, -1.0]], 0.1)
    with pytest.raises(ConfigError, match=r"pmts\.csv: a sensor-layout file alone has no detector"):
        load_detector(sensors)
    with pytest.raises(ConfigError, match=r"nothere\.yaml: no such file.*known presets: SK"):
        load_detector("nothere.yaml")


# ---- the command line: `photonflow geometry BAD --out FILE.png` -----------------------------

CLI_CASES = {
    "negative_length": (
        "bad.yaml",
        "detector:\n  shape: {kind: cylinder, radius: -3, height: 10}\n"
        "  layout: {kind: coverage, coverage: 0.2}\n",
        ["detector.shape.radius", "-3"],
    ),
    "nan_param": (
        "bad.yaml",
        "detector: TOY_SPHERE\nparams:\n  absorption_length: .nan\n",
        ["params.absorption_length", "nan"],
    ),
    "probability": (
        "bad.yaml",
        "detector: TOY_SPHERE\nparams:\n  wall_reflectivity: 1.5\n",
        ["params.wall_reflectivity", "1.5"],
    ),
    "unknown_preset_in_config": (
        "bad.yaml",
        "detector:\n  preset: SKK\n",
        ["detector.preset", "'SKK'", "known: SK"],
    ),
    "unknown_key": (
        "bad.yaml",
        "detector:\n  shap: {kind: sphere, radius: 2}\n",
        ["detector.shap", "did you mean 'shape'"],
    ),
    "yaml_syntax": (
        "bad.yaml",
        "detector:\n  preset: SK\n params: [\n",
        ["bad.yaml", "line 3", "YAML"],
    ),
    "missing_file": (None, "nothere.yaml", ["nothere.yaml", "no such file"]),
    "unknown_preset_name": (None, "SKK", ["'SKK'", "unknown preset", "known: SK"]),
    "sensor_columns": ("columns", None, ["columns.csv", "missing column nx", "n_x"]),
    "sensor_normals": ("normals", None, ["normals.csv", "row 2", "[0.0, 0.5, -1.0]", "unit"]),
    "sensor_outside": ("outside", None, ["outside.csv", "sensors.positions[1]", "[0.0, 0.0, 2.5]"]),
}


@pytest.fixture(scope="module")
def cli_results(tmp_path_factory):
    """Run every bad-input case through `python -m photonflow geometry` at once (in parallel)."""
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    running = {}
    for name, (file_name, text, _) in CLI_CASES.items():
        folder = tmp_path_factory.mktemp(name)
        if file_name in ("columns", "normals", "outside"):
            argument = str(write_sensor_case(folder, file_name))
        elif file_name is not None:
            (folder / file_name).write_text(text)
            argument = str(folder / file_name)
        else:
            argument = text
        picture = folder / "out.png"
        command = [sys.executable, "-m", "photonflow", "geometry", argument, "--out", str(picture)]
        process = subprocess.Popen(
            command, cwd=folder, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        running[name] = (process, picture)
    results = {}
    for name, (process, picture) in running.items():
        stdout, stderr = process.communicate(timeout=120)
        results[name] = (process.returncode, stdout, stderr, picture.exists())
    return results


@pytest.mark.parametrize("case", list(CLI_CASES))
def test_cli_reports_bad_input_in_one_line_with_exit_code_2(cli_results, case):
    returncode, stdout, stderr, wrote_picture = cli_results[case]
    assert "Traceback" not in stderr and "Traceback" not in stdout
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    for part in CLI_CASES[case][2]:
        assert part in lines[0], (part, lines[0])
    assert returncode == 2
    assert not wrote_picture
