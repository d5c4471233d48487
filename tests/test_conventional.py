"""The conventional sequential calibration (issue 5): its scan and slope pieces, the
analytic case it must get right (no scattered or reflected light), and the bias that
scattered and reflected light give its attenuation slope while the joint fit stays
unbiased on the same pseudo-data."""

from __future__ import annotations

import math

import jax
import numpy as np
import pytest

import photonflow as pf
from photonflow.calibration import calibrate, sequential_calibration
from photonflow.calibration.conventional import (
    DirectRun,
    attenuation_inverse,
    attenuation_slope,
    direct_run,
    predicted_indirect,
)
from photonflow.calibration.runs import prepare_runs
from photonflow.calibration.scans import scan_minimum
from photonflow.errors import ConfigError
from photonflow.io import make_event
from photonflow.transport.optics import TransportConfig
from photonflow.transport.pseudo_data import sample_events

CONFIG = TransportConfig(n_bounces=3, n_rays=4096)
POSITIONS = ([0.0, 0.0, 0.0], [0.0, 0.0, 1.4], [0.0, 0.0, -1.4], [1.3, 0.3, 0.5])


def test_scan_finds_the_vertex_and_curvature_of_a_parabola():
    """-log L = (u - 1.3)^2 / (2 0.2^2): minimum 1.3, 1-sigma 0.2, found from 0 after
    extending the grid (analytic)."""
    result = scan_minimum(lambda u: 0.5 * ((u - 1.3) / 0.2) ** 2 + 7.0, 0.0, 0.25)
    assert result.value == pytest.approx(1.3, abs=1e-9)
    assert result.sigma == pytest.approx(0.2, rel=1e-9)
    assert not result.at_edge


def test_slope_of_exact_exponentials_is_exact():
    """Noise-free charges geometry x efficiency x e^{c_r - d / 7 m}: 1 / L_att = 1/7 per m
    whatever the per-run intercepts c_r and the efficiencies."""
    rng = np.random.default_rng(2)
    efficiency = rng.uniform(0.8, 1.2, 50)
    runs = []
    for index, intercept in enumerate((0.0, 0.4, -0.3)):
        distance = rng.uniform(0.5, 4.0, 50)
        geometry = rng.uniform(1e5, 1e6, 50)
        charge = geometry * efficiency * np.exp(intercept - distance / 7.0)
        runs.append(DirectRun(index, charge, charge * 1e-12, geometry, distance,
                              np.zeros(50)))
    inverse, error, points = attenuation_slope(runs, efficiency, 1.0 / 7.0, 10.0)
    assert inverse == pytest.approx(1.0 / 7.0, rel=1e-6)
    assert points == 150 and error < 1e-6


def _runs(detector, truth, seed, photons=1e5):
    """Ten flashes of the central source (the efficiency run), five of each other."""
    runs = []
    for k, position in enumerate(POSITIONS):
        source = pf.IsotropicSource(position=position, n_photons=photons)
        n_events = 10 if k == 0 else 5
        runs.append((source, list(sample_events(detector, truth, source, seed + k, n_events,
                                                config=CONFIG))))
    return runs


@pytest.fixture(scope="module")
def toy():
    detector = pf.load_detector("TOY_CYLINDER")
    rng = np.random.default_rng(4)
    efficiency = rng.normal(1.0, 0.1, detector.n_sensors)
    return detector, pf.default_params(detector).replace(efficiency=efficiency)


def test_sequential_recovers_the_absorption_length_without_indirect_light(toy):
    """No scattering, no reflection: all light is direct, the textbook chain is exact and
    recovers L_abs (8 m, from 12 m) within 3 of its own errors, and the efficiencies with
    unit pulls."""
    detector, nominal = toy
    truth = nominal.replace(absorption_length=8.0, scattering_length=math.inf,
                            wall_reflectivity=0.0, sensor_reflectivity=0.0)
    runs = _runs(detector, truth, 300)
    start = truth.replace(absorption_length=12.0, efficiency=1.0)
    result = sequential_calibration(detector, runs, start, ["absorption_length", "efficiency"],
                                    config=CONFIG, truth=truth)
    assert result.method == "sequential"
    pulls = result.pulls()
    assert abs(float(pulls["absorption_length"])) < 3.0, (
        float(result.params.absorption_length), float(result.errors.absorption_length))
    assert np.all(np.asarray(result.errors.efficiency) > 0)
    assert abs(np.mean(pulls["efficiency"])) < 0.3
    assert 0.8 <= np.std(pulls["efficiency"]) <= 1.25
    assert len(result.history) >= 2 and result.history[-1]["loss"] <= result.history[0]["loss"]


def test_indirect_light_biases_the_slope_but_not_the_joint_fit(toy):
    """Scattering (30 m) and wall reflection (0.05) inflate far sensors' charge: the slope
    of log charge versus distance, even with the true efficiencies, gives 1 / L_att more
    than 5 sigma too small (too long an attenuation length); with the indirect light the
    expected mode predicts subtracted it is within 3 sigma; the joint fit of L_abs on the
    same runs is within 3 sigma."""
    detector, nominal = toy
    truth = nominal.replace(absorption_length=10.0, scattering_length=30.0,
                            wall_reflectivity=0.05)
    runs = _runs(detector, truth, 500)
    prepared = prepare_runs(runs, detector, "charge")
    direct = [direct_run(detector, truth, run, k, CONFIG.window)
              for k, run in enumerate(prepared)][1:]  # the runs away from the centre
    efficiency = np.asarray(truth.efficiency, np.float64)
    true_inverse = attenuation_inverse(truth)
    inverse, error, _ = attenuation_slope(direct, efficiency, true_inverse, 20.0)
    assert (true_inverse - inverse) / error > 5.0, (inverse, error, true_inverse)

    key = jax.random.key(0)  # the rays of calibrate's default key, run by run
    subtracted = [
        DirectRun(run.index, run.charge, run.variance, run.geometry, run.distance,
                  predicted_indirect(detector, truth, prepared[run.index], CONFIG,
                                     jax.random.fold_in(key, run.index)))
        for run in direct
    ]
    inverse, error, _ = attenuation_slope(subtracted, efficiency, true_inverse, 20.0)
    assert abs(inverse - true_inverse) / error < 3.0, (inverse, error, true_inverse)

    start = truth.replace(absorption_length=12.5)
    joint = calibrate(detector, runs, start, ["absorption_length"], config=CONFIG, truth=truth)
    assert abs(float(joint.pulls()["absorption_length"])) < 3.0


def test_bad_input_is_one_line(toy):
    detector, nominal = toy
    source = pf.IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=1e3)
    events = [make_event([0], [1.0], [10.0])]
    with pytest.raises(ConfigError, match="sequential calibration fits only"):
        sequential_calibration(detector, [(source, events)], nominal, ["time_offset"])
    with pytest.raises(ConfigError, match="indirect"):
        sequential_calibration(detector, [(source, events)], nominal, ["efficiency"],
                               indirect="model")
    laser = pf.LaserSource(position=[0.0, 0.0, 0.0], direction=[0.0, 0.0, -1.0],
                           opening_angle=0.3, n_photons=1e3)
    with pytest.raises(ConfigError, match="isotropic"):
        sequential_calibration(detector, [(laser, events)], nominal, ["absorption_length"])
