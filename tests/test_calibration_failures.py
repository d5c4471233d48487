"""``calibrate`` never lets a raw numpy, scipy or JAX exception reach the user: a run it
cannot predict and a numerical failure inside the fit are one-line ``PhotonflowError``s
naming the run or the stage (issue 22)."""

from __future__ import annotations

import numpy as np
import pytest

import photonflow as pf
from photonflow.calibration import objective
from photonflow.calibration.structured import StructuredMatrix
from photonflow.transport.optics import TransportConfig
from photonflow.transport.pseudo_data import sample_events

pytestmark = pytest.mark.compile_bound

CONFIG = TransportConfig(n_bounces=2, n_rays=256)
#: The sources at which the expected mode once gave NaN charges on TOY_CYLINDER's cap
#: sensors, so that calibrate died with "LinAlgError: Eigenvalues did not converge".
DEGENERATE = ([0.0, -0.8, 0.4], [-0.6, 0.6, -0.6])


@pytest.fixture(scope="module")
def degenerate_runs():
    detector = pf.load_detector("TOY_CYLINDER")
    truth = pf.default_params(detector).replace(absorption_length=30.0)
    runs = [
        (source, list(sample_events(detector, truth, source, 40 + k, 2, config=CONFIG)))
        for k, source in enumerate(pf.IsotropicSource(position=p, n_photons=4e5)
                                   for p in DEGENERATE)
    ]
    return detector, truth, runs


def test_runs_at_the_degenerate_positions_calibrate(degenerate_runs):
    """The runs of the issue now fit: finite, converged, within 5 sigma of the truth."""
    detector, truth, runs = degenerate_runs
    start = truth.replace(absorption_length=24.0)
    result = pf.calibrate(detector, runs, start, ["absorption_length"], config=CONFIG,
                          max_iterations=10)
    value = float(result.params.absorption_length)
    error = float(result.errors.absorption_length)
    assert result.converged, result.message
    assert np.isfinite(value) and 0 < error < 0.2 * value
    assert abs(value - 30.0) < 5 * error


def test_a_run_with_a_non_finite_prediction_is_named(degenerate_runs, monkeypatch):
    """A run whose expected charge is not finite stops the fit before it starts, in one
    line naming the run, the sensors and the source."""
    detector, truth, runs = degenerate_runs
    original = objective.mean_jit
    calls = []

    def poisoned(*args, **kwargs):
        mean = original(*args, **kwargs)
        calls.append(1)
        return mean.at[7].set(np.nan) if len(calls) == 2 else mean

    monkeypatch.setattr(objective, "mean_jit", poisoned)
    with pytest.raises(pf.ConfigError) as error:
        pf.calibrate(detector, runs, truth, ["absorption_length"], config=CONFIG)
    message = str(error.value)
    assert "\n" not in message
    assert message.startswith("runs[1] ") and "1 sensors (first: 7)" in message
    assert "[-0.6, 0.6, -0.6]" in message


def test_a_numerical_failure_is_one_calibration_error_naming_the_stage(degenerate_runs,
                                                                        monkeypatch):
    """A linear-algebra failure inside the fit (the eigen-decomposition of the old
    report) is a ``CalibrationError`` naming the stage and the cause, not a LinAlgError."""
    detector, truth, runs = degenerate_runs

    def broken(self):
        raise np.linalg.LinAlgError("Eigenvalues did not converge")

    monkeypatch.setattr(StructuredMatrix, "positive", broken)
    with pytest.raises(pf.CalibrationError) as error:
        pf.calibrate(detector, runs, truth, ["absorption_length"], config=CONFIG)
    message = str(error.value)
    assert "\n" not in message and isinstance(error.value, pf.PhotonflowError)
    assert "the Fisher information at the starting parameters failed" in message
    assert "LinAlgError: Eigenvalues did not converge" in message
