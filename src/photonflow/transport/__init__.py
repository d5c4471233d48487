"""Light transport: direct light by quadrature, indirect light by weighted rays (expected
mode) and photon-by-photon Monte Carlo (sampled mode), on one description of the optics
(``optics``). See docs/transport.md."""

from ..constants import SPEED_OF_LIGHT
from ..geometry.solid_angle import disc_solid_angle, plane_basis
from .direct import direct_light, direct_light_jit, interpolate_acceptance
from .expected import expected, expected_function, sensor_light
from .optics import TransportConfig
from .production import produce_events
from .pseudo_data import sample, sample_events, sample_together
from .sampled import sample_photon_bundle, sample_photons
from .tracks import PhotonBundle, random_tracks

__all__ = [
    "SPEED_OF_LIGHT",
    "PhotonBundle",
    "TransportConfig",
    "direct_light",
    "direct_light_jit",
    "disc_solid_angle",
    "expected",
    "expected_function",
    "interpolate_acceptance",
    "plane_basis",
    "produce_events",
    "random_tracks",
    "sample",
    "sample_events",
    "sample_together",
    "sample_photon_bundle",
    "sample_photons",
    "sensor_light",
]
