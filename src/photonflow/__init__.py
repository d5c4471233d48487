"""photonflow: differentiable simulation, calibration and reconstruction of large optical
particle detectors (water Cherenkov, liquid scintillator, open media), in JAX.

Units everywhere: metres, nanoseconds, MeV, radians; wavelength in nm.
"""

from typing import TYPE_CHECKING

from . import _startup as _startup  # first: the command exits 130 on Ctrl-C while JAX loads
from .host_allocator import configure_host_allocator
from .xla_settings import configure_reduction_fusion, configure_xla_flags

configure_reduction_fusion()  # right batched sums on jaxlib 0.10's CPU (xla_settings)
configure_xla_flags()  # opt-in, before any JAX backend starts (photonflow.xla_settings)
configure_host_allocator()  # large buffers reused between calls (photonflow.host_allocator)

# ruff: noqa: E402 (the flags above must be set before the rest is imported)
from ._version import __version__
from .compilation_cache import configure_from_environment, enable_compilation_cache
from .config import load_config, load_detector
from .errors import (
    CalibrationError,
    ConfigError,
    EventFileError,
    PhotonflowError,
    SensorFileError,
)
from .generator import Photons, Track, generate, generate_together
from .geometry import Box, Cylinder, Detector, OpenMedium, Sphere, make_detector
from .geometry.presets import preset_table
from .io import Event, Truth
from .lazy_names import lazy_names
from .likelihood import nll, sensor_nll
from .params import Params, default_params
from .prediction import Prediction
from .sources import DiffuserSource, IsotropicSource, LaserSource
from .transport import (
    TransportConfig,
    expected,
    expected_function,
    sample,
    sample_events,
    sample_together,
)

configure_from_environment()  # persistent compilation cache (photonflow.compilation_cache)

#: Names imported when first used: the calibration (and what it imports) and the event
#: files (h5py) are not needed to simulate or predict, and importing them costs ~0.1 s
#: of every process's start.
_LAZY = {"CalibrationResult": "calibration", "calibrate": "calibration",
         "load_params": "calibration", "EventFile": "io", "read_events": "io",
         "write_events": "io", "RecoResult": "reconstruction",
         "RecoSettings": "reconstruction", "reconstruct": "reconstruction"}

if TYPE_CHECKING:  # what static tools (type checkers, the API reference) see of them
    from .calibration import CalibrationResult, calibrate, load_params
    from .io import EventFile, read_events, write_events
    from .reconstruction import RecoResult, RecoSettings, reconstruct


__getattr__, __dir__ = lazy_names(__name__, _LAZY)


def presets() -> dict[str, dict[str, object]]:
    """The detector presets: name -> row with ``shape``, ``dimensions`` (text, m),
    ``sensors`` (count), ``coverage`` (photocathode fraction of the wall, nan for an
    open medium), ``sensor_model``, ``medium`` and ``source`` (where the published
    figures it reproduces come from). Iterating gives the names."""
    return {row["name"]: row for row in preset_table()}


__all__ = [
    "Box",
    "CalibrationError",
    "CalibrationResult",
    "ConfigError",
    "Cylinder",
    "Detector",
    "DiffuserSource",
    "Event",
    "EventFile",
    "EventFileError",
    "IsotropicSource",
    "LaserSource",
    "OpenMedium",
    "Params",
    "PhotonflowError",
    "Photons",
    "Prediction",
    "RecoResult",
    "RecoSettings",
    "SensorFileError",
    "Sphere",
    "Track",
    "TransportConfig",
    "Truth",
    "__version__",
    "calibrate",
    "default_params",
    "enable_compilation_cache",
    "expected",
    "expected_function",
    "generate",
    "generate_together",
    "load_config",
    "load_detector",
    "load_params",
    "make_detector",
    "nll",
    "presets",
    "read_events",
    "reconstruct",
    "sample",
    "sample_events",
    "sample_together",
    "sensor_nll",
    "write_events",
]
