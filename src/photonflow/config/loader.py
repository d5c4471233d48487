"""Load configuration files (YAML or JSON) into a built ``Detector`` and validated ``Params``.

Every problem (missing file, syntax error, schema violation, bad sensor file, sensor
outside the detector, parameter out of its domain) raises a one-line
``photonflow.errors.PhotonflowError`` (``ConfigError`` or ``SensorFileError``) that
names the file or the dotted field and the value; no pydantic or YAML traceback escapes.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from ..errors import ConfigError, format_value
from ..geometry.detector import Detector, make_detector
from ..geometry.presets import PRESETS, preset_detector
from ..geometry.sensor_file import SENSOR_FILE_SUFFIXES, detector_from_sensor_file
from ..geometry.shapes import Shape, shape_from_dict
from ..params import Params, default_params, validate_params
from ..photosensors import sensor_model
from .messages import one_line_error
from .schema import ConfigModel, DetectorSpec

#: File name suffixes of configuration files.
CONFIG_SUFFIXES: tuple[str, ...] = (".yaml", ".yml", ".json")
#: Photosensor model of a custom detector that names none.
DEFAULT_SENSOR_MODEL = "R3600"
#: Medium of a custom detector that names none.
DEFAULT_MEDIUM = "water"


@dataclasses.dataclass(frozen=True)
class Config:
    """A loaded configuration.

    Attributes:
        detector: the built ``Detector`` (lengths in m).
        params: ``default_params(detector, medium)`` with the file's overrides applied,
            validated (units as in ``photonflow.params.PARAM_SPECS``).
        medium: medium name ("water" or "scintillator").
        model: the validated ``ConfigModel`` (the file's contents, with defaults).
        source: the file it came from (None for a dict).
    """

    detector: Detector
    params: Params
    medium: str
    model: ConfigModel
    source: Path | None = None


# ---- reading files ------------------------------------------------------------------------


class _UniqueKeyLoader(yaml.SafeLoader):
    """A safe YAML loader that rejects duplicate keys (PyYAML keeps the last silently)."""


def _construct_unique_mapping(loader: _UniqueKeyLoader, node: yaml.MappingNode, deep=False):
    seen: dict[Any, int] = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if not isinstance(key, str | int | float | bool | None):
            continue  # unhashable keys are reported by construct_mapping below
        if key in seen:
            raise ConfigError(
                f"line {key_node.start_mark.line + 1}: duplicate key {format_value(key)}"
                f" (first on line {seen[key]})"
            )
        seen[key] = key_node.start_mark.line + 1
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(
    yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_unique_mapping
)


def _parse_yaml(path: Path, text: str) -> Any:
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 (a SafeLoader subclass)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = exc.problem or exc.context or "invalid YAML"
        raise ConfigError(f"{path}: {where}YAML syntax error: {problem}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: YAML error: {str(exc).splitlines()[0]}") from None


def _parse_json(path: Path, text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(
            f"{path}: line {exc.lineno}, column {exc.colno}: JSON syntax error: {exc.msg}"
        ) from None


def read_config_file(path: str | Path) -> dict[str, Any]:
    """The raw contents (a mapping) of a YAML (``.yaml``, ``.yml``) or JSON file.

    Raises a one-line ``ConfigError`` naming the file for an unknown extension, a
    missing or unreadable file, a syntax error (with line and column), a duplicate
    YAML key, or a top level that is not a mapping.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in CONFIG_SUFFIXES:
        raise ConfigError(
            f"{path}: unknown config-file extension '{path.suffix}';"
            f" expected {', '.join(CONFIG_SUFFIXES)}"
        )
    if not path.is_file():
        raise ConfigError(f"{path}: no such file")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read ({str(exc).splitlines()[0]})") from None
    data = _parse_json(path, text) if suffix == ".json" else _parse_yaml(path, text)
    if data is None:
        raise ConfigError(f"{path}: empty; expected a mapping with a 'detector' key")
    if not isinstance(data, dict):
        raise ConfigError(
            f"{path}: the top level must be a mapping with a 'detector' key,"
            f" not {type(data).__name__}"
        )
    return data


# ---- validating and building --------------------------------------------------------------


def validate_config(data: Mapping[str, Any]) -> ConfigModel:
    """Validate raw configuration contents against the schema (``ConfigModel``).

    Raises a one-line ``ConfigError`` ``<dotted.field> = <value>: <rule>`` for the
    first problem found.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"config = {format_value(data)}: must be a mapping")
    try:
        return ConfigModel.model_validate(dict(data))
    except ValidationError as exc:
        raise one_line_error(exc, ConfigModel) from None


def _shape(spec: DetectorSpec) -> Shape:
    return shape_from_dict(spec.shape.model_dump())


def _sensor_file_path(spec: DetectorSpec, base_dir: Path) -> Path:
    path = Path(os.path.expanduser(spec.sensors))
    return path if path.is_absolute() else base_dir / path


def build_detector(
    spec: DetectorSpec, base_dir: str | Path = ".", name: str = "custom"
) -> Detector:
    """The ``Detector`` described by a validated ``detector`` section.

    Args:
        spec: the validated section.
        base_dir: directory that relative ``sensors`` paths are relative to.
        name: detector name when the section gives none.

    Raises:
        ConfigError: a sensor outside the boundary or facing outward (naming
            ``detector.layout.positions[i]`` or ``<file>: sensors.positions[i]``).
        SensorFileError: the sensor file cannot be read or fails validation.
    """
    if spec.preset is not None:
        return preset_detector(spec.preset)
    shape = _shape(spec)
    models = spec.sensor_model or (DEFAULT_SENSOR_MODEL,)
    name = spec.name or name
    if spec.sensors is not None:
        return detector_from_sensor_file(
            _sensor_file_path(spec, Path(base_dir)),
            shape,
            name=name,
            sensor_models=models,
            default_radius=sensor_model(models[0]).radius,
        )
    layout = spec.layout
    radius = layout.sensor_radius or sensor_model(models[0]).radius
    layout.check(shape, radius)
    try:
        positions, normals = layout.positions_normals(shape, radius)
    except ConfigError as error:  # the generators name fields relative to the layout
        message = str(error)
        prefixed = f"detector.{message}" if message.startswith("layout.") else message
        raise ConfigError(prefixed) from None
    if len(positions) == 0:
        raise ConfigError(f"detector.layout: places no sensors on the {shape.describe()}")
    return make_detector(
        shape,
        positions,
        normals,
        radius,
        0,
        name=name,
        sensor_models=models,
        source="detector.layout",
    )


def build_params(detector: Detector, medium: str, overrides: Mapping[str, Any]) -> Params:
    """``default_params(detector, medium)`` with ``overrides`` applied, then validated.

    Overrides are ``Params`` field name -> value in the field's unit (m, ns, Hz, or
    dimensionless); a scalar sets every sensor of a per-sensor field.
    """
    params = default_params(detector, medium)
    if overrides:
        params = params.replace(**overrides)
    return validate_params(params, detector.n_sensors)


def _medium(model: ConfigModel) -> str:
    if model.medium is not None:
        return model.medium
    if model.detector.preset is not None:
        return PRESETS[model.detector.preset].medium
    return DEFAULT_MEDIUM


def load_config(path_or_dict: str | Path | Mapping[str, Any], *, base_dir=None) -> Config:
    """Load a configuration from a YAML/JSON file or from an already parsed mapping.

    Args:
        path_or_dict: a ``.yaml``, ``.yml`` or ``.json`` file, or a mapping with the
            same contents.
        base_dir: for a mapping, the directory relative sensor-file paths are
            relative to (default: the current directory). For a file it is the
            file's directory.

    Returns:
        A ``Config`` with the built detector, validated params and the medium.

    Raises:
        ConfigError / SensorFileError: one line naming the file or dotted field and value.
    """
    if isinstance(path_or_dict, Mapping):
        data, source = path_or_dict, None
        base, default_name = Path(base_dir or "."), "custom"
    else:
        source = Path(path_or_dict)
        data = read_config_file(source)
        base, default_name = source.parent, source.stem
    model = validate_config(data)
    detector = build_detector(model.detector, base, default_name)
    medium = _medium(model)
    params = build_params(detector, medium, model.param_overrides())
    return Config(detector=detector, params=params, medium=medium, model=model, source=source)


def _looks_like_path(text: str) -> bool:
    suffix = Path(text).suffix.lower()
    return suffix in CONFIG_SUFFIXES + SENSOR_FILE_SUFFIXES or "/" in text or os.sep in text


def load_detector(name_or_path: str | Path) -> Detector:
    """A ``Detector`` from a preset name (case-insensitive) or a configuration file.

    A sensor-layout file alone is refused (it has no detector shape): write a
    configuration with ``detector.shape`` and ``detector.sensors``. A name that is
    neither a file nor a preset raises the preset error listing the known presets.

    Raises:
        ConfigError / SensorFileError: a one-line message.
    """
    path = Path(name_or_path)
    suffix = path.suffix.lower()
    if path.is_file():
        if suffix in CONFIG_SUFFIXES:
            return load_config(path).detector
        if suffix in SENSOR_FILE_SUFFIXES:
            raise ConfigError(
                f"{path}: a sensor-layout file alone has no detector shape; write a config"
                f" file with detector.shape and detector.sensors: {path.name}"
                " (see docs/configuration.md)"
            )
        raise ConfigError(
            f"{path}: unknown file type '{path.suffix}'; expected a preset name or a"
            f" config file ({', '.join(CONFIG_SUFFIXES)})"
        )
    text = str(name_or_path)
    if isinstance(name_or_path, Path) or _looks_like_path(text):
        raise ConfigError(
            f"{path}: no such file (and not a preset; known presets: {', '.join(PRESETS)})"
        )
    return preset_detector(text)


def load_setup(name_or_path: str | Path) -> Config:
    """Detector, medium and parameters from a preset name or a configuration file.

    A preset gets ``default_params`` in the preset's medium; a configuration file is
    read with ``load_config``. Errors as ``load_detector`` (one line, known presets
    listed for an unknown name).
    """
    path = Path(name_or_path)
    if path.is_file() and path.suffix.lower() in CONFIG_SUFFIXES:
        return load_config(path)
    detector = load_detector(name_or_path)
    return load_config({"detector": {"preset": detector.name}})
