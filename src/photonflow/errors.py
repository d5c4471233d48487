"""Exceptions raised for bad input.

Every message is one line that names the offending field (or file) and its value,
so that the command line can print it as is and exit with code 2.
"""

from __future__ import annotations


class PhotonflowError(ValueError):
    """Base class of photonflow's input errors (a one-line, user-facing message)."""


class ConfigError(PhotonflowError):
    """A configuration value (detector, medium, parameter) is invalid."""


class SensorFileError(PhotonflowError):
    """A measured sensor-layout file cannot be read or fails validation."""


class CalibrationError(PhotonflowError):
    """A calibration fit failed numerically (the stage and the cause in one line)."""


class EventFileError(PhotonflowError):
    """An event file is missing, malformed or of an unsupported format version."""


def format_value(value: object) -> str:
    """Render a value compactly for an error message (floats with 6 significant digits)."""
    if isinstance(value, float):
        return f"{value:.6g}"
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."
