"""The SK calibration campaign's pseudo-experiments: true parameters, sources, runs and the
fit's start, shared by ``examples/calibration/sk_joint.py`` and the validation studies
under ``studies/calibration/`` (``studies/calibration-validation.md``).

One pseudo-experiment ``seed`` fits the absorption and scattering lengths, the wall and
sensor reflectivities and the efficiency of every one of SK's 11,146 sensors to 16 runs:
a downward laser at the centre and 15 isotropic flashes (``campaign_sources``), one
flash each, sampled photon by photon at ``campaign_truth(detector, seed)``. Seeds fix
everything: the true efficiencies (``campaign_truth``), the pseudo-data
(``campaign_runs``: source k has the data seed ``1000 * seed + k``), and, by the
studies' convention, the fit's ray key ``jax.random.key(seed)``.

Units: m, ns, photons; reflectivities and efficiencies are probabilities / factors.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..geometry.detector import Detector
from ..params import Params, default_params
from ..sources import IsotropicSource, LaserSource
from ..transport import TransportConfig, sample_events

#: The optical parameters the campaign fits (with every sensor's ``efficiency``).
OPTICS = ["absorption_length", "scattering_length", "wall_reflectivity", "sensor_reflectivity"]

#: True optics (m, m, probability, probability): attenuation lengths of the order SK
#: measures (~90-100 m at 400 nm) rather than the preset's 552 m absorption length, which
#: changes the light across the 40 m tank by only a few per cent.
TRUE_OPTICS = {"absorption_length": 90.0, "scattering_length": 70.0,
               "wall_reflectivity": 0.15, "sensor_reflectivity": 0.25}

#: Photons per flash of every campaign source.
PHOTONS_PER_FLASH = 1e6

#: Relative spread (Gaussian sigma) of the true per-sensor efficiencies around 1.
EFFICIENCY_SPREAD = 0.1

#: Factor between a true optical value and the fit's start (``campaign_start``).
START_OFFSET = 0.25


def grid_positions() -> list[list[float]]:
    """The flashes' positions (m), 15 points inside SK's tank: the centre, 2 on the axis
    at z = +-12 m, and 2 radii (6 and 11 m) x 3 azimuths at z = -8 and +8 m."""
    points = [[0.0, 0.0, 0.0], [0.0, 0.0, 12.0], [0.0, 0.0, -12.0]]
    for z in (-8.0, 8.0):
        for radius, phase in ((6.0, 0.0), (11.0, np.pi / 3)):
            for k in range(3):
                angle = phase + 2 * np.pi * k / 3
                points.append([radius * np.cos(angle), radius * np.sin(angle), z])
    return points


def campaign_truth(detector: Detector, seed: int) -> Params:
    """The true ``Params`` of pseudo-experiment ``seed``: the preset's, with
    ``TRUE_OPTICS`` and per-sensor efficiencies drawn from N(1, ``EFFICIENCY_SPREAD``)
    by ``numpy.random.default_rng(seed)``."""
    rng = np.random.default_rng(seed)
    return default_params(detector).replace(
        **TRUE_OPTICS, efficiency=rng.normal(1.0, EFFICIENCY_SPREAD, detector.n_sensors))


def campaign_sources(photons: float = PHOTONS_PER_FLASH) -> list:
    """The campaign's 16 sources, ``photons`` photons per flash each: index 0 a laser at
    the centre pointing down (-z, 0.2 rad cone half-angle), then isotropic flashes at
    ``grid_positions`` (index 1: the centre)."""
    sources = [LaserSource(position=[0.0, 0.0, 0.0], direction=[0.0, 0.0, -1.0],
                           opening_angle=0.2, n_photons=photons)]
    return sources + [IsotropicSource(position=p, n_photons=photons) for p in grid_positions()]


def sampled_events(detector: Detector, truth: Params, source, seed: int,
                   config: TransportConfig) -> list:
    """One event of ``source`` in the sampled mode (photon by photon, with the sensor
    response and dark noise) at ``truth``, from pseudo-data seed ``seed``."""
    return list(sample_events(detector, truth, source, seed, 1, config=config))


def campaign_runs(detector: Detector, truth: Params, seed: int, photons: float,
                  config: TransportConfig,
                  make_events: Callable[..., list] = sampled_events) -> list:
    """The campaign's runs ``[(source, events), ...]`` at ``truth``: one event of every
    ``campaign_sources(photons)`` source, source k from pseudo-data seed
    ``1000 * seed + k``, made by ``make_events(detector, truth, source, data_seed,
    config)`` (default ``sampled_events``)."""
    return [(source, make_events(detector, truth, source, 1000 * seed + k, config))
            for k, source in enumerate(campaign_sources(photons))]


def campaign_start(detector: Detector, truth: Params) -> Params:
    """The fit's start: the preset's parameters (every efficiency 1) with the optics
    ``START_OFFSET`` (25 %) away from ``truth``'s: absorption length (m) and sensor
    reflectivity above, scattering length (m) and wall reflectivity below."""
    up, down = 1.0 + START_OFFSET, 1.0 - START_OFFSET
    return default_params(detector).replace(
        absorption_length=float(truth.absorption_length) * up,
        scattering_length=float(truth.scattering_length) * down,
        wall_reflectivity=float(truth.wall_reflectivity) * down,
        sensor_reflectivity=float(truth.sensor_reflectivity) * up,
    )
