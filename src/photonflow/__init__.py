"""photonflow: differentiable simulation, calibration and reconstruction of large optical
particle detectors (water Cherenkov, liquid scintillator, open media), in JAX.

Units everywhere: metres, nanoseconds, MeV, radians; wavelength in nm.
"""

from ._version import __version__
from .errors import ConfigError, EventFileError, PhotonflowError, SensorFileError
from .geometry import Box, Cylinder, Detector, OpenMedium, Sphere
from .geometry.presets import preset_table
from .params import Params, default_params

__all__ = [
    "Box",
    "ConfigError",
    "Cylinder",
    "Detector",
    "EventFileError",
    "OpenMedium",
    "Params",
    "PhotonflowError",
    "SensorFileError",
    "Sphere",
    "__version__",
    "default_params",
    "preset_table",
]
