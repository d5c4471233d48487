"""Configuration files: a detector (preset or custom), a medium and parameter overrides.

``load_config(path_or_dict)`` reads YAML or JSON into a ``Config`` (built ``Detector``,
validated ``Params``, medium name, and the validated ``ConfigModel``);
``load_detector(name_or_path)`` accepts a preset name or a configuration file. Every
problem raises a one-line ``photonflow.errors.ConfigError`` (or ``SensorFileError``)
naming the dotted field and the value. The schema is described in
``docs/configuration.md``.
"""

from .loader import (
    CONFIG_SUFFIXES,
    Config,
    build_detector,
    build_params,
    load_config,
    load_detector,
    load_setup,
    read_config_file,
    validate_config,
)
from .schema import ConfigModel, DetectorSpec

__all__ = [
    "CONFIG_SUFFIXES",
    "Config",
    "ConfigModel",
    "DetectorSpec",
    "build_detector",
    "build_params",
    "load_config",
    "load_detector",
    "load_setup",
    "read_config_file",
    "validate_config",
]
