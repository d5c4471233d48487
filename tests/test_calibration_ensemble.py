"""Issue 5's pull criterion on the toy detector: the optical parameters fitted to
independent sampled-mode pseudo-experiments have pulls with mean within +-0.3 and width
within [0.8, 1.2] (the SK campaign is examples/calibration/sk_joint.py).

The design is that of ``examples/calibration/optical_pulls.py`` (a downward laser and
two isotropic flashes in TOY_CYLINDER, 2 bounces, 1,024 rays, a start 25 % away, a fresh
ray key per experiment, the independent-ray stage). Its own module, so that a parallel
test run can give it a worker of its own."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import photonflow as pf
from photonflow.calibration import calibrate
from photonflow.transport.optics import TransportConfig
from photonflow.transport.pseudo_data import sample_events

#: Pseudo-experiments of the ensemble (the issue asks for >= 20). With n of them a
#: sample mean of unit-width pulls has error 1/sqrt(n) = 0.2 and a sample width
#: 1/sqrt(2(n - 1)) = 0.15: the criterion is the issue's, at seeds fixed in advance.
N_EXPERIMENTS = 24
#: True optics (m, m, probability, probability) and the start of every fit (25 % away).
TRUTH = {"absorption_length": 30.0, "scattering_length": 40.0,
         "wall_reflectivity": 0.2, "sensor_reflectivity": 0.3}
START_FACTORS = {"absorption_length": 1.25, "scattering_length": 0.75,
                 "wall_reflectivity": 0.75, "sensor_reflectivity": 1.25}
FREE = ("absorption_length", "scattering_length", "wall_reflectivity")
PHOTONS = 5e5
CONFIG = TransportConfig(n_bounces=2, n_rays=1024)


def _sources(detector) -> list:
    """A laser at 80 % of the half height pointing down, flashes at the centre and
    off-centre low (m)."""
    half, radius = 0.5 * float(detector.shape.height), float(detector.shape.radius)
    return [
        pf.LaserSource(position=[0.0, 0.0, 0.8 * half], direction=[0.0, 0.0, -1.0],
                       opening_angle=0.1, n_photons=PHOTONS),
        pf.IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=PHOTONS),
        pf.IsotropicSource(position=[0.5 * radius, 0.0, -0.5 * half], n_photons=PHOTONS),
    ]


@pytest.fixture(scope="module")
def ensemble_pulls() -> dict[str, np.ndarray]:
    """Per free parameter, the pulls (fitted - true) / error of every experiment."""
    detector = pf.load_detector("TOY_CYLINDER")
    truth = pf.default_params(detector).replace(**TRUTH)
    start = truth.replace(**{k: TRUTH[k] * START_FACTORS[k] for k in FREE})
    sources = _sources(detector)
    pulls = {name: [] for name in FREE}
    for experiment in range(N_EXPERIMENTS):
        runs = [(source, list(sample_events(detector, truth, source, 1000 * experiment + k, 1,
                                            config=CONFIG)))
                for k, source in enumerate(sources)]
        result = calibrate(detector, runs, start, list(FREE), config=CONFIG, truth=truth,
                           key=jax.random.key(10_000 + experiment))
        assert result.converged, (experiment, result.message)
        for name, value in result.pulls().items():
            pulls[name].append(float(value))
    return {name: np.array(values) for name, values in pulls.items()}


@pytest.mark.parametrize("name", FREE)
def test_optical_pulls_have_unit_width_and_no_bias(ensemble_pulls, name):
    """Mean within +-0.3 and sample width (ddof 1) within [0.8, 1.2], every pull finite."""
    pulls = ensemble_pulls[name]
    assert pulls.size == N_EXPERIMENTS and np.all(np.isfinite(pulls)), pulls
    assert abs(np.mean(pulls)) <= 0.3, (np.mean(pulls), pulls)
    assert 0.8 <= np.std(pulls, ddof=1) <= 1.2, (np.std(pulls, ddof=1), pulls)
