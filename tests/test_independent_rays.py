"""The independent-ray stage of the calibration
(``independent_ray_stage.independent_ray_steps``): the averaged ray sets of its second
root and the extrapolation of the two roots to infinitely many rays (docs/calibration.md,
"Ray noise and the independent-ray score")."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

import photonflow as pf
from photonflow.calibration import calibrate
from photonflow.calibration.fit import DEFAULT_JACOBIAN_SETS, EXTRAPOLATION_SETS
from photonflow.calibration.layout import free_layout
from photonflow.calibration.objective import CalibrationProblem, ray_set_keys, summed_charge_nll
from photonflow.calibration.run_terms import mean_jit
from photonflow.calibration.runs import prepare_runs
from photonflow.errors import ConfigError
from photonflow.transport.optics import TransportConfig
from photonflow.transport.pseudo_data import sample_events

pytestmark = pytest.mark.compile_bound

CONFIG = TransportConfig(n_bounces=2, n_rays=256)
FREE = ("absorption_length", "scattering_length")
TRUTH = {"absorption_length": 30.0, "scattering_length": 20.0, "wall_reflectivity": 0.2}


@pytest.fixture(scope="module")
def toy():
    """TOY_CYLINDER with strong scattering, two flashes of 2x10^5 photons (sampled mode),
    and a start 20 % away."""
    detector = pf.load_detector("TOY_CYLINDER")
    truth = pf.default_params(detector).replace(**TRUTH)
    sources = [pf.IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=2e5),
               pf.IsotropicSource(position=[0.8, 0.0, -0.5], n_photons=2e5)]
    runs = [(source, list(sample_events(detector, truth, source, 70 + k, 1, config=CONFIG)))
            for k, source in enumerate(sources)]
    start = truth.replace(absorption_length=24.0, scattering_length=24.0)
    return detector, truth, runs, start


def test_charge_sets_average_the_expected_charges_of_independent_ray_sets(toy):
    """With ``charge_sets`` = 2, -log L is that of the average of the expected charges of
    the run's own rays and of the first further set, and differs from the one-set value
    (the sets are independent)."""
    detector, _, runs, start = toy
    problem = CalibrationProblem(detector, prepare_runs(runs, detector, "charge"), start,
                                 free_layout(list(FREE), detector.n_sensors), "charge",
                                 CONFIG, jax.random.key(3))
    theta = problem.initial_theta()
    losses = []
    for sets in (1, 2):
        total = 0.0
        for data, static in zip(problem.arrays, problem.statics, strict=True):
            means = [np.asarray(mean_jit(theta, problem.base, problem.sensors,
                                          dataclasses.replace(data, key=key), None,
                                          static=static), np.float64)
                     for key in ray_set_keys(data.key, sets)]
            assert len(means) == sets
            total += float(np.sum(summed_charge_nll(
                data.charge_sum, data.hit_any, np.mean(means, axis=0).astype(np.float32),
                float(start.spe_width))))
        parts = problem.independent_ray_curvature(theta, charge_sets=sets)
        np.testing.assert_allclose(parts.loss, total, rtol=1e-5)
        losses.append(parts.loss)
    assert abs(losses[1] - losses[0]) > 1e-2, losses  # float32 terms resolve 1e-3


def test_fit_extrapolates_the_roots_with_one_and_more_ray_sets(toy):
    """With ``ray_extrapolation`` the history has the one-set steps, then the steps with
    ``EXTRAPOLATION_SETS`` sets, then the extrapolated point, which is
    theta_1 + K/(K - 1) (theta_K - theta_1) in the fit's coordinates (log of a length),
    and is the result (the default). Without it the result is theta_1."""
    detector, truth, runs, start = toy
    result = calibrate(detector, runs, start, list(FREE), config=CONFIG, truth=truth,
                       key=jax.random.key(5))
    assert result.converged, result.message
    assert result.settings["ray_extrapolation"] is True
    assert result.settings["jacobian_sets"] == DEFAULT_JACOBIAN_SETS
    stages = [entry.get("stage") for entry in result.history]
    many = f"independent rays, {EXTRAPOLATION_SETS} sets"
    assert stages[-1] == "extrapolated"
    first_many = stages.index(many)
    assert set(stages[stages.index("independent rays"):first_many]) == {"independent rays"}
    assert set(stages[first_many:-1]) == {many}
    one = result.history[first_many - 1]["values"]
    last = result.history[-2]["values"]
    factor = EXTRAPOLATION_SETS / (EXTRAPOLATION_SETS - 1)
    for name in FREE:
        expected = np.exp(np.log(one[name]) + factor * (np.log(last[name]) - np.log(one[name])))
        assert result.history[-1]["values"][name] == pytest.approx(expected, rel=1e-5)
        assert float(getattr(result.params, name)) == pytest.approx(expected, rel=1e-5)
        assert np.isfinite(result.history[-1]["ray_count_extrapolation"][name])

    plain = calibrate(detector, runs, start, list(FREE), config=CONFIG, truth=truth,
                      key=jax.random.key(5), ray_extrapolation=False)
    assert plain.converged and plain.settings["ray_extrapolation"] is False
    assert {entry.get("stage") for entry in plain.history} == {None, "independent rays"}
    assert "ray_noise_share" in plain.history[-1]
    for name in FREE:  # the same one-set root as the extrapolating fit's
        assert plain.history[-1]["values"][name] == pytest.approx(one[name], rel=1e-5)
        assert float(getattr(plain.params, name)) == pytest.approx(one[name], rel=1e-5)


def test_score_weights_averaged_over_ray_sets_are_kept_for_the_stage(toy, monkeypatch):
    """``independent_ray_curvature(jacobians=...)`` uses the given weights J_b: one set of
    ``independent_jacobians`` reproduces the default score exactly, three sets give
    their average and a different score. ``calibrate(jacobian_sets=3)`` converges with
    one Jacobian per run and step, draws the weights once (also for the extrapolation's
    second root), records the setting, and refuses a bad value."""
    detector, truth, runs, start = toy
    problem = CalibrationProblem(detector, prepare_runs(runs, detector, "charge"), start,
                                 free_layout(list(FREE), detector.n_sensors), "charge",
                                 CONFIG, jax.random.key(3))
    theta = problem.initial_theta()
    default = problem.independent_ray_curvature(theta)
    single = problem.independent_jacobians(theta, 1)
    one = problem.independent_ray_curvature(theta, jacobians=single)
    np.testing.assert_allclose(one.grad_dense, default.grad_dense, rtol=1e-6)
    np.testing.assert_allclose(one.newton.a, default.newton.a, rtol=1e-6)

    averaged = problem.independent_jacobians(theta, 3)
    for jac, data, static, key in zip(averaged, problem.arrays, problem.statics,
                                      problem.jacobian_keys, strict=True):
        sets = [np.asarray(problem._jacobian(theta, data, static, k)[1], np.float64)
                for k in ray_set_keys(key, 3)]
        np.testing.assert_allclose(np.asarray(jac, np.float64), np.mean(sets, axis=0),
                                   rtol=1e-5, atol=1e-6 * np.abs(sets).max())
    three = problem.independent_ray_curvature(theta, jacobians=averaged)
    for used, given in zip(three.jacobians, averaged, strict=True):
        assert used is given
    assert np.max(np.abs(three.grad_dense - default.grad_dense)) > 1e-3 * np.max(
        np.abs(default.grad_dense))

    drawn = []
    original = CalibrationProblem.independent_jacobians

    def spy(self, theta, n_sets):
        drawn.append(n_sets)
        return original(self, theta, n_sets)

    monkeypatch.setattr(CalibrationProblem, "independent_jacobians", spy)
    result = calibrate(detector, runs, start, list(FREE), config=CONFIG, truth=truth,
                       key=jax.random.key(5), jacobian_sets=3, ray_extrapolation=True)
    assert result.converged, result.message
    assert result.settings["jacobian_sets"] == 3
    # the weights are drawn once, where the stage starts; the extrapolation's second
    # root keeps them (no fresh EXTRAPOLATION_SETS-set weights), so J_b's noise cancels
    # in the extrapolated shift
    assert drawn == [3]
    assert result.history[-1]["stage"] == "extrapolated"
    for name in FREE:
        assert abs(float(getattr(result.params, name)) - float(getattr(truth, name))) < (
            4 * float(getattr(result.errors, name)))
    with pytest.raises(ConfigError, match="jacobian_sets = 0"):
        calibrate(detector, runs, start, list(FREE), config=CONFIG, jacobian_sets=0)


def test_a_stage_that_runs_off_to_non_finite_charges_is_refused_in_one_line(toy, monkeypatch):
    """When the independent-ray score or its Newton matrix stops being finite (a step to
    a vanishing absorption length with too few rays), ``calibrate`` raises a one-line
    ``ConfigError`` naming the stage, the iteration and the free values, instead of
    failing inside the linear algebra (``LinAlgError`` from the per-sensor blocks)."""
    detector, truth, runs, start = toy
    original = CalibrationProblem.independent_ray_curvature
    calls = []

    def poisoned(self, theta, *args, **kwargs):
        parts = original(self, theta, *args, **kwargs)
        calls.append(1)
        if len(calls) < 2:
            return parts
        newton = dataclasses.replace(parts.newton, a=np.full_like(parts.newton.a, np.nan))
        return dataclasses.replace(parts, newton=newton)

    monkeypatch.setattr(CalibrationProblem, "independent_ray_curvature", poisoned)
    with pytest.raises(ConfigError) as error:
        calibrate(detector, runs, start, list(FREE), config=CONFIG, key=jax.random.key(5))
    message = str(error.value)
    assert "\n" not in message and len(calls) == 2
    assert message.startswith("independent rays, iteration ")
    assert "not finite at absorption_length " in message and "scattering_length" in message
