"""The top-level public API named in issue 2 is a contract: names and signatures."""

import inspect

import numpy as np
import pytest

import photonflow as pf


def test_top_level_names():
    for name in (
        "presets",
        "load_detector",
        "Params",
        "default_params",
        "Event",
        "read_events",
        "write_events",
        "IsotropicSource",
        "LaserSource",
        "expected",
        "sample",
        "nll",
    ):
        assert hasattr(pf, name), name


def test_nll_contract_needs_only_prediction_and_event():
    """``nll(prediction, event)`` (issue 3): the prediction carries its response settings;
    a prediction without them is refused in one line. The detector, source and (default)
    transport settings are the README example's, so that the two tests share compiled
    code (one compilation of ``sample`` and of ``expected`` instead of two each)."""
    detector = pf.load_detector("TOY_CYLINDER")
    params = pf.default_params(detector)
    source = pf.IsotropicSource(position=[0.3, 0.0, 0.5], n_photons=1e5)
    event = pf.sample(detector, params, source, seed=2)
    prediction = pf.expected(detector, params, source)
    value = float(pf.nll(prediction, event))
    explicit = float(pf.nll(prediction, event, params, window=prediction.window))
    assert np.isfinite(value) and value == explicit
    bare = pf.Prediction.from_components(
        prediction.charge, prediction.time_weight, prediction.time_mean, prediction.time_sigma
    )
    with pytest.raises(pf.ConfigError, match="nll: no"):
        pf.nll(bare, event)


def test_presets_returns_rows_by_name():
    table = pf.presets()
    assert "SK" in table and "TOY_SPHERE" in table
    assert table["SK"]["sensors"] == 11146
    assert table["JUNO"]["shape"] == "sphere"


def test_load_detector_attributes():
    detector = pf.load_detector("TOY_SPHERE")
    n = detector.n_sensors
    assert detector.sensor_positions.shape == (n, 3)
    assert detector.sensor_normals.shape == (n, 3)
    assert detector.sensor_radius.shape == (n,)
    assert detector.shape == pf.Sphere(radius=2.0)


def test_default_params_signature_and_event_fields(tmp_path):
    assert list(inspect.signature(pf.default_params).parameters) == ["detector", "medium"]
    assert inspect.signature(pf.default_params).parameters["medium"].default == "water"
    event = pf.Event(
        np.array([1, 2], np.int32),
        np.array([1.0, 2.5], np.float32),
        np.array([10.0, 12.0], np.float32),
    )
    assert event.truth is None
    detector = pf.load_detector("TOY_CYLINDER")
    path = pf.write_events(tmp_path / "e.h5", [event], detector, pf.default_params(detector))
    with pf.read_events(path) as events:
        np.testing.assert_array_equal(events[0].sensor_ids, [1, 2])
        np.testing.assert_array_equal(events[0].charge, [1.0, 2.5])


def test_readme_python_example_runs(capsys):
    """The README's Python example is real code: run it and check what it prints."""
    from pathlib import Path

    readme = (Path(__file__).parents[1] / "README.md").read_text()
    code = readme.split("```python\n", 1)[1].split("```", 1)[0]
    exec(compile(code, "README.md", "exec"), {})
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].startswith("SK: cylinder 33.68 m diameter x 36.20 m, 11146 sensors")
    assert printed[1] == "60.000 m"
    assert printed[2] == "40.3 % coverage, 11146 sensors"
    assert "JUNO" in printed[3]
