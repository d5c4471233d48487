"""``photonflow calibrate``: fit a tiny simulated run, bad input, and the report picture.

One TOY_CYLINDER run is simulated once (module fixture) by the real ``simulate``
command; the commands run in-process through typer's ``CliRunner`` (one through the
console script, for its exit code and one-line error).
"""

import json
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

import photonflow as pf
from photonflow.calibration import CalibrationResult
from photonflow.calibration.fit import DEFAULT_JACOBIAN_SETS
from photonflow.cli import app
from photonflow.io import make_event, write_events

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def assert_one_line_error(result, *fragments):
    assert result.exit_code == 2, result.output
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: ")
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


@pytest.fixture(scope="module")
def run_file(tmp_path_factory):
    """A 2-flash isotropic run in TOY_CYLINDER (3000 photons, direct light only: no
    bounces, which keeps compilation short), written by ``simulate``."""
    path = tmp_path_factory.mktemp("calibrate") / "iso.h5"
    result = invoke("simulate", "--detector", "TOY_CYLINDER", "--source", "isotropic",
                    "--position", "0.3,0,0.2", "--photons", "3000", "--events", "2",
                    "--seed", "1", "--bounces", "0", "--out", path)
    assert result.exit_code == 0, result.output
    return path


@pytest.fixture(scope="module")
def fitted(run_file):
    """``calibrate`` of the run's quantum efficiency (512 rays, 3 iterations; the
    absorption length, 552 m, would be unconstrained by a 4 m tank)."""
    out = run_file.with_name("calib.json")
    result = invoke("calibrate", run_file, "--detector", "TOY_CYLINDER",
                    "--free", "quantum_efficiency", "--rays", "512", "--max-iterations", "3",
                    "--out", out)
    assert result.exit_code == 0, result.output
    return out, result


def test_calibrate_writes_a_result_with_the_free_parameter(fitted, run_file):
    out, result = fitted
    loaded = CalibrationResult.load(out)
    assert loaded.free == ("quantum_efficiency",)
    assert loaded.detector["name"] == "TOY_CYLINDER"
    assert loaded.settings["n_rays"] == 512
    assert loaded.settings["n_bounces"] == 0  # the file's 'bounces' run setting
    assert 2 <= len(loaded.history) <= 4  # iteration 0 and at most 3 steps
    # the truth is the file's stored params, and the fit moved from the start
    with pf.read_events(run_file) as events:
        true = float(events.params.quantum_efficiency)
    assert loaded.truth is not None
    assert float(loaded.truth.quantum_efficiency) == pytest.approx(true)
    assert 0 < float(loaded.errors.quantum_efficiency) < 0.5 * true
    assert abs(loaded.pulls()["quantum_efficiency"]) < 5
    assert loaded.runs[0]["source"] == "isotropic"
    assert loaded.runs[0]["position_m"] == pytest.approx([0.3, 0.0, 0.2], abs=1e-6)
    # the final table names the parameter and has a pull column
    assert "quantum_efficiency" in result.stdout and "pull" in result.stdout
    assert json.loads(out.read_text())["format"] == "photonflow-calibration"


def test_estimator_flags_reach_the_fit(run_file, tmp_path):
    """``--no-ray-extrapolation`` and ``--jacobian-sets 0`` (a fresh weight set every
    step) are recorded in the result's settings; without indirect light there is no
    independent-ray stage, so the history has no stage entries either way."""
    out = tmp_path / "calib.json"
    result = invoke("calibrate", run_file, "--detector", "TOY_CYLINDER",
                    "--free", "quantum_efficiency", "--rays", "512", "--max-iterations", "3",
                    "--no-ray-extrapolation", "--jacobian-sets", "0", "--out", out)
    assert result.exit_code == 0, result.output
    loaded = CalibrationResult.load(out)
    assert loaded.settings["ray_extrapolation"] is False
    assert loaded.settings["jacobian_sets"] is None
    assert not [entry for entry in loaded.history if "stage" in entry]


def test_default_fit_records_the_default_estimator(fitted):
    """Without the flags the fit uses ``calibrate``'s defaults: the extrapolated root with
    the score's weights averaged over ``DEFAULT_JACOBIAN_SETS`` ray sets."""
    out, _ = fitted
    settings = CalibrationResult.load(out).settings
    assert settings["ray_extrapolation"] is True
    assert settings["jacobian_sets"] == DEFAULT_JACOBIAN_SETS


def test_report_is_a_png(fitted, tmp_path):
    out, _ = fitted
    picture = tmp_path / "report.png"
    result = invoke("calibrate", "--report", out, "--out", picture)
    assert result.exit_code == 0, result.output
    data = picture.read_bytes()
    assert data[:8] == PNG_SIGNATURE and len(data) > 10_000
    assert [p.name for p in tmp_path.iterdir()] == ["report.png"]


def test_report_of_a_per_sensor_field_draws_a_map(fitted, tmp_path):
    """A result with a free per-sensor field gets a residual map (built from the small
    result, with efficiency marked free and a truth)."""
    from photonflow.geometry.presets import preset_detector
    from photonflow.viz.calibration_report import plot_calibration_report

    out, _ = fitted
    result = CalibrationResult.load(out)
    n = result.detector["n_sensors"]
    params = result.params.replace(efficiency=np.linspace(0.9, 1.1, n))
    errors = result.errors.replace(efficiency=np.full(n, 0.05))
    import dataclasses

    result = dataclasses.replace(result, params=params, errors=errors,
                                 free=(*result.free, "efficiency"))
    figure = plot_calibration_report(result, preset_detector("TOY_CYLINDER"))
    sensors = [c for ax in figure.get_axes() for c in ax.collections if c.get_gid() == "sensors"]
    assert len(sensors) == 1
    assert np.asarray(sensors[0].get_array()) == pytest.approx(np.linspace(-0.1, 0.1, n), abs=1e-6)


def test_report_shades_the_independent_ray_stage(fitted):
    """Iterations with a "stage" (the independent-ray roots, where -log L may rise) are
    shaded on every iteration axis, from half an iteration before the first to half
    after the last."""
    import dataclasses

    from photonflow.geometry.presets import preset_detector
    from photonflow.viz.calibration_report import plot_calibration_report

    out, _ = fitted
    result = CalibrationResult.load(out)
    first = dict(result.history[0])
    history = [{**first, "iteration": k} for k in range(3)] + [
        {**first, "iteration": k, "stage": "independent rays"} for k in range(3, 6)]
    figure = plot_calibration_report(dataclasses.replace(result, history=tuple(history)),
                                     preset_detector("TOY_CYLINDER"))
    spans = [p for ax in figure.get_axes() for p in ax.patches
             if p.get_gid() == "independent-ray stage"]
    assert len(spans) == 1 + len(result.correlation_names)  # convergence + each value
    for span in spans:
        xs = span.get_path().vertices[:, 0] if not hasattr(span, "get_x") else [
            span.get_x(), span.get_x() + span.get_width()]
        assert min(xs) == pytest.approx(2.5) and max(xs) == pytest.approx(5.5)
    unstaged = plot_calibration_report(result, preset_detector("TOY_CYLINDER"))
    assert not [p for ax in unstaged.get_axes() for p in ax.patches
                if p.get_gid() == "independent-ray stage"]


def test_unknown_free_field_is_one_line_and_writes_nothing(run_file, tmp_path):
    out = tmp_path / "calib.json"
    result = subprocess.run(
        [sys.executable, "-m", "photonflow", "calibrate", str(run_file), "--detector",
         "TOY_CYLINDER", "--free", "absorption_length,absorbtion_length", "--out", str(out)],
        capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 2, result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "absorbtion_length" in lines[0]
    assert list(tmp_path.iterdir()) == []


def test_file_from_another_detector_is_refused(run_file, tmp_path):
    sphere = pf.load_detector("TOY_SPHERE")
    other = tmp_path / "sphere.h5"
    write_events(other, [make_event([0, 5], [1.0, 2.0], [10.0, 12.0])], sphere,
                 pf.default_params(sphere))
    out = tmp_path / "calib.json"
    result = invoke("calibrate", run_file, other, "--detector", "TOY_CYLINDER",
                    "--free", "absorption_length", "--out", out)
    assert_one_line_error(result, "sphere.h5", "TOY_SPHERE", "TOY_CYLINDER")
    assert not out.exists()


def test_file_without_run_settings_is_refused(tmp_path):
    detector = pf.load_detector("TOY_CYLINDER")
    bare = tmp_path / "bare.h5"
    write_events(bare, [make_event([0, 5], [1.0, 2.0], [10.0, 12.0])], detector,
                 pf.default_params(detector))
    out = tmp_path / "calib.json"
    result = invoke("calibrate", bare, "--detector", "TOY_CYLINDER",
                    "--free", "absorption_length", "--out", out)
    assert_one_line_error(result, "bare.h5", "run settings")
    assert not out.exists()


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--method", "newton"], "method"),
        (["--likelihood", "time"], "--likelihood"),
        (["--rays", "0"], "--rays"),
        (["--jacobian-sets", "-1"], "--jacobian-sets = -1"),
        (["--rays", "1"], "--rays = 1: must be >= 32"),
        (["--rays", "100000000000"], "--rays = 100000000000: must be <= 1,048,576"),
        (["--bounces", "101"], "--bounces = 101: must be <= 100"),
        (["--mode", "append"], "--mode = 'append'"),
    ],
)
def test_bad_options_are_one_line(run_file, tmp_path, args, fragment):
    out = tmp_path / "calib.json"
    result = invoke("calibrate", run_file, "--detector", "TOY_CYLINDER",
                    "--free", "absorption_length", "--out", out, *args)
    assert_one_line_error(result, fragment)
    assert not out.exists()


def test_report_of_a_missing_result_is_one_line(tmp_path):
    result = invoke("calibrate", "--report", tmp_path / "none.json", "--out",
                    tmp_path / "r.png")
    assert_one_line_error(result, "none.json")
    assert list(tmp_path.iterdir()) == []


def test_an_existing_result_is_refused_before_the_fit_unless_recreate(run_file, tmp_path):
    """--out is checked first: an existing result is refused even before the (missing)
    run file is opened; --mode recreate overwrites it."""
    out = tmp_path / "calib.json"
    out.write_text("{}")
    result = invoke("calibrate", tmp_path / "missing.h5", "--free", "quantum_efficiency",
                    "--out", out)
    assert_one_line_error(result, "--out", "calib.json", "file exists", "--mode recreate")
    assert out.read_text() == "{}"
    result = invoke("calibrate", run_file, "--detector", "TOY_CYLINDER", "--free",
                    "quantum_efficiency", "--rays", "512", "--max-iterations", "3",
                    "--out", out, "--mode", "recreate")
    assert result.exit_code == 0, result.output
    assert CalibrationResult.load(out).free == ("quantum_efficiency",)


def test_a_fit_with_an_infinite_error_is_not_converged(run_file, tmp_path, monkeypatch):
    """A fitted value without a finite error (here forced to inf) is no measurement: the
    result says converged: false, the table and stderr say so, the exit code is 1, and
    the file is valid JSON ("inf" as a string) that loads back with the inf."""
    from photonflow.calibration import fit

    real = fit._physical_errors

    def infinite_errors(problem, theta, curvature):
        errors, correlation = real(problem, theta, curvature)
        return errors.replace(quantum_efficiency=np.inf), correlation

    monkeypatch.setattr(fit, "_physical_errors", infinite_errors)
    out = tmp_path / "calib.json"
    result = invoke("calibrate", run_file, "--detector", "TOY_CYLINDER", "--free",
                    "quantum_efficiency", "--rays", "512", "--max-iterations", "3",
                    "--out", out)
    assert result.exit_code == 1, result.output
    assert "not converged" in result.stdout and "no measurement" in result.stdout
    warning = result.stderr.strip().splitlines()
    assert len(warning) == 1 and warning[0].startswith("warning: the fit did not converge")

    def refuse(constant):
        raise AssertionError(f"{constant} is not JSON")

    data = json.loads(out.read_text(), parse_constant=refuse)
    assert data["converged"] is False and data["errors"]["quantum_efficiency"] == "inf"
    loaded = CalibrationResult.load(out)
    assert not loaded.converged and np.isinf(float(loaded.errors.quantum_efficiency))


@pytest.mark.parametrize("option", ["--report", "--init"])
def test_a_result_without_params_is_one_line(run_file, tmp_path, option):
    bare = tmp_path / "bare.json"
    bare.write_text(json.dumps({"format": "photonflow-calibration", "version": 1}))
    out = tmp_path / ("r.png" if option == "--report" else "calib.json")
    args = ([] if option == "--report" else [run_file, "--free", "quantum_efficiency"])
    result = invoke("calibrate", *args, option, bare, "--out", out)
    assert_one_line_error(result, "bare.json", "'params' is missing")
    assert not out.exists()


def test_report_refuses_the_options_of_a_fit(fitted, tmp_path):
    out, _ = fitted
    result = invoke("calibrate", "--report", out, "--rays", "64", "--out", tmp_path / "r.png")
    assert_one_line_error(result, "--rays = 64", "not with --report")
    assert list(tmp_path.iterdir()) == []
