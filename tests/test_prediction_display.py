"""Predicted-versus-observed display of track events: the panels hold the event's and the
prediction's values, and ``photonflow display --predicted`` draws a track event and
refuses any other in one line with exit code 2."""

import numpy as np
import pytest
from typer.testing import CliRunner

import photonflow as pf
from photonflow.cli import app
from photonflow.response.spe import single_pe_moments
from photonflow.viz.prediction_display import plot_prediction

pytestmark = pytest.mark.compile_bound


def _sensor_values(ax):
    sensors = next(c for c in ax.collections if c.get_gid() == "sensors")
    return np.ma.getdata(sensors.get_array())


def test_panels_hold_observed_predicted_and_residual_charges(tmp_path):
    detector = pf.load_detector("TOY_CYLINDER")
    params = pf.default_params(detector)
    track = pf.Track("mu-", [0.1, 0.0, -0.2], [0.0, 0.6, 0.8], 300.0)
    event = pf.sample(detector, params, track, seed=2)
    config = pf.TransportConfig(n_rays=256)
    prediction = pf.expected(detector, params, track, config=config)
    spe_mean = float(single_pe_moments(params.spe_width)[0])
    figure = plot_prediction(detector, event, prediction, tmp_path / "p.png", spe_mean=spe_mean)
    assert (tmp_path / "p.png").stat().st_size > 10_000
    observed_ax, predicted_ax, residual_ax, _ = figure.axes[:4]
    observed = np.zeros(detector.n_sensors)
    observed[np.asarray(event.sensor_ids)] = np.asarray(event.charge)
    predicted = np.asarray(prediction.charge) * spe_mean
    np.testing.assert_allclose(np.nan_to_num(_sensor_values(observed_ax)), observed, rtol=1e-6)
    np.testing.assert_allclose(_sensor_values(predicted_ax), predicted, rtol=1e-6)
    np.testing.assert_allclose(_sensor_values(residual_ax),
                               (observed - predicted) / np.sqrt(predicted + 1.0), rtol=1e-5,
                               atol=1e-6)


def test_display_predicted_command(tmp_path):
    runner = CliRunner()
    tracks = tmp_path / "mu.h5"
    made = runner.invoke(app, ["simulate", "--out", str(tracks), "--detector", "TOY_CYLINDER",
                               "--particle", "mu-", "--energy", "300", "--events", "1",
                               "--seed", "4"])
    assert made.exit_code == 0, made.output
    picture = tmp_path / "mu.png"
    drawn = runner.invoke(app, ["display", str(tracks), "--predicted", "--out", str(picture)])
    assert drawn.exit_code == 0, drawn.output
    assert picture.stat().st_size > 10_000
    flashes = tmp_path / "iso.h5"
    assert runner.invoke(app, ["simulate", "--out", str(flashes), "--detector", "TOY_CYLINDER",
                               "--events", "1", "--seed", "1"]).exit_code == 0
    refused = runner.invoke(app, ["display", str(flashes), "--predicted",
                                  "--out", str(tmp_path / "iso.png")])
    assert refused.exit_code == 2
    assert "needs a track event" in refused.output and refused.output.count("\n") == 1
    assert not (tmp_path / "iso.png").exists()
