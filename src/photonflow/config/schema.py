"""The configuration-file schema (pydantic v2 models); lengths in m.

A configuration has three sections::

    detector:  {preset: SK}  or  {name, shape, layout | sensors, sensor_model}
    medium:    water | scintillator        (optional)
    params:    {<Params field>: value}     (optional overrides of default_params)

Unknown keys are rejected (``extra="forbid"``) so that a misspelt key is an error,
never silently ignored. Field validators raise ``ValueError`` with the rule alone
("must be ..."); ``photonflow.config.messages`` turns a ``ValidationError`` into the
one-line ``ConfigError`` ``<dotted.field> = <value>: <rule>``. Checks that involve
several fields raise ``ConfigError`` with the full message, passed through as is.

Each layout model knows which shapes it applies to and builds its sensor positions
(``positions_normals``), so adding a layout is adding one small class.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    create_model,
    model_validator,
)

from ..errors import ConfigError, format_value
from ..geometry import layouts
from ..geometry.presets import PRESETS
from ..geometry.shapes import Shape
from ..medium import MEDIA
from ..params import PARAM_SPECS
from ..photosensors import SENSOR_MODELS

# ---- value types ------------------------------------------------------------------------


def _positive_length(value: float) -> float:
    if not (math.isfinite(value) and value > 0):
        raise ValueError("must be a positive, finite length in m")
    return value


def _positive_count(value: int) -> int:
    if value < 1:
        raise ValueError("must be a positive integer")
    return value


def _coverage_fraction(value: float) -> float:
    if not 0 < value < 0.9:  # also rejects NaN; discs cannot tile more than ~0.9
        raise ValueError("must be a fraction in (0, 0.9)")
    return value


def _known_preset(value: str) -> str:
    if value.upper() not in PRESETS:
        raise ValueError(f"unknown preset; known: {', '.join(PRESETS)}")
    return value.upper()


def _known_medium(value: str) -> str:
    if value not in MEDIA:
        raise ValueError(f"must be one of {', '.join(MEDIA)}")
    return value


def _sensor_model_names(value: Any) -> tuple[str, ...]:
    names = (value,) if isinstance(value, str) else value
    if not isinstance(names, list | tuple) or not names:
        raise ValueError("must be a sensor model name or a list of names")
    for name in names:
        if name not in SENSOR_MODELS:
            raise ValueError(f"unknown sensor model {name!r}; known: {', '.join(SENSOR_MODELS)}")
    return tuple(names)


def _number(value: Any) -> float:
    if isinstance(value, bool):
        raise ValueError("not a number")
    return float(value)  # accepts ints, floats and strings such as "80", "inf", "nan"


def _param_value(value: Any) -> float | tuple[float, ...]:
    """A parameter override: a number, or a list of numbers (per-sensor / vector fields)."""
    try:
        if isinstance(value, list | tuple):
            return tuple(_number(item) for item in value)
        return _number(value)
    except (TypeError, ValueError):
        raise ValueError("must be a number or a list of numbers") from None


Length = Annotated[float, AfterValidator(_positive_length)]
"""A positive, finite length in m."""
Count = Annotated[int, AfterValidator(_positive_count)]
"""A positive integer."""
CoverageFraction = Annotated[float, AfterValidator(_coverage_fraction)]
"""Photocathode coverage: summed disc area / wall area, in (0, 0.9)."""
PresetName = Annotated[str, AfterValidator(_known_preset)]
"""A preset name (case-insensitive; stored upper-case)."""
MediumName = Annotated[str, AfterValidator(_known_medium)]
"""A medium of ``photonflow.medium.MEDIA``."""
SensorModelNames = Annotated[tuple[str, ...], BeforeValidator(_sensor_model_names)]
"""One photosensor model name, or a list of them (indexed by a sensor file's ``type``)."""
ParamValue = Annotated[Any, BeforeValidator(_param_value)]
"""A number, or a list of numbers, in the unit of the ``Params`` field."""


class _Strict(BaseModel):
    """Base of all sections: unknown keys are errors; validated models are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True)


# ---- shapes -----------------------------------------------------------------------------


class CylinderSpec(_Strict):
    """Upright cylinder centred on the origin: radius and height in m."""

    kind: Literal["cylinder"]
    radius: Length
    height: Length


class SphereSpec(_Strict):
    """Sphere centred on the origin: radius in m."""

    kind: Literal["sphere"]
    radius: Length


class BoxSpec(_Strict):
    """Axis-aligned box centred on the origin: full edge lengths in m."""

    kind: Literal["box"]
    size_x: Length
    size_y: Length
    size_z: Length


class OpenSpec(_Strict):
    """Open medium (no walls); the simulated world is a cylinder of these sizes in m."""

    kind: Literal["open"]
    world_radius: Length
    world_height: Length


ShapeSpec = Annotated[CylinderSpec | SphereSpec | BoxSpec | OpenSpec, Field(discriminator="kind")]


# ---- layouts ----------------------------------------------------------------------------


#: Most sensors a layout may place (HK has ~2e4); guards against unit slips (mm as m).
MAX_LAYOUT_SENSORS = 1_000_000


class _Layout(_Strict):
    """Base of the layout sections: ``positions_normals`` builds the sensor array."""

    #: Shape kinds this layout applies to.
    shapes: ClassVar[tuple[str, ...]] = ()
    #: Disc radius in m (default: the radius of the detector's first sensor model).
    sensor_radius: Length | None = None

    def positions_normals(self, shape: Shape, sensor_radius: float) -> tuple[np.ndarray, ...]:
        """Sensor positions (N, 3) in m and inward unit normals (N, 3) on ``shape``."""
        raise NotImplementedError

    def estimated_count(self, shape: Shape, sensor_radius: float) -> float:
        """Roughly how many sensors the layout places (checked before building it)."""
        raise NotImplementedError

    def check(self, shape: Shape, sensor_radius: float) -> None:
        """Raise a ``ConfigError`` if the layout cannot hold discs of ``sensor_radius`` (m)
        or would place more than ``MAX_LAYOUT_SENSORS`` sensors (a unit slip, usually)."""
        count = self.estimated_count(shape, sensor_radius)
        if not count <= MAX_LAYOUT_SENSORS:
            raise ConfigError(
                f"detector.layout: would place about {count:.3g} sensors on the"
                f" {shape.describe()}, more than {MAX_LAYOUT_SENSORS:,}; lengths are in m"
            )


def _check_spacing(spacing: float, sensor_radius: float) -> None:
    if not spacing > 2 * sensor_radius:
        raise ConfigError(
            f"detector.layout.spacing = {format_value(spacing)}: must exceed the sensor"
            f" diameter {2 * sensor_radius:.4g} m"
        )


class CoverageLayout(_Layout):
    """Sensors filling a photocathode coverage fraction (cylinder: barrel + caps grid;
    sphere: Fibonacci lattice, or latitude rings above 60 %)."""

    shapes: ClassVar[tuple[str, ...]] = ("cylinder", "sphere")
    kind: Literal["coverage"]
    coverage: CoverageFraction
    cap_grid: Literal["square", "hex"] = "square"

    def estimated_count(self, shape, sensor_radius):
        return self.coverage * shape.wall_area / (math.pi * sensor_radius**2)

    def positions_normals(self, shape, sensor_radius):
        if shape.kind == "sphere":
            try:
                return layouts.fibonacci_sphere_layout_for_coverage(
                    shape.radius, self.coverage, sensor_radius
                )
            except ConfigError:  # the dense (latitude-ring) packing does not fit
                raise ConfigError(
                    f"detector.layout.coverage = {format_value(self.coverage)}: discs of"
                    f" radius {sensor_radius:.4g} m do not fit on a sphere of radius"
                    f" {shape.radius:.4g} m at this coverage"
                ) from None
        return layouts.barrel_caps_layout_for_coverage(
            shape.radius, shape.height, self.coverage, sensor_radius, cap_grid=self.cap_grid
        )


class SpacingLayout(_Layout):
    """Sensors at a pitch ``spacing`` in m (cylinder: barrel + caps grid; sphere: a
    Fibonacci lattice with one sensor per hexagonal cell of that pitch)."""

    shapes: ClassVar[tuple[str, ...]] = ("cylinder", "sphere")
    kind: Literal["spacing"]
    spacing: Length
    cap_grid: Literal["square", "hex"] = "square"

    def check(self, shape, sensor_radius):
        _check_spacing(self.spacing, sensor_radius)
        super().check(shape, sensor_radius)

    def estimated_count(self, shape, sensor_radius):
        return shape.wall_area / self.spacing**2

    def positions_normals(self, shape, sensor_radius):
        if shape.kind == "sphere":
            cell = self.spacing**2 * math.sqrt(3.0) / 2.0  # m^2 per sensor
            count = max(1, round(shape.wall_area / cell))
            return layouts.fibonacci_sphere_layout(shape.radius, count)
        return layouts.barrel_caps_layout_for_spacing(
            shape.radius, shape.height, self.spacing, sensor_radius, cap_grid=self.cap_grid
        )


class FibonacciLayout(_Layout):
    """``count`` sensors on a sphere on a Fibonacci lattice (discs touch above ~70 %
    coverage; use a ``coverage`` layout, which switches to latitude rings, for more)."""

    shapes: ClassVar[tuple[str, ...]] = ("sphere",)
    kind: Literal["fibonacci"]
    count: Count

    def estimated_count(self, shape, sensor_radius):
        return self.count

    def positions_normals(self, shape, sensor_radius):
        return layouts.fibonacci_sphere_layout(shape.radius, self.count)


class BoxGridLayout(_Layout):
    """A square grid of pitch ``spacing`` (m) on each of a box's six faces."""

    shapes: ClassVar[tuple[str, ...]] = ("box",)
    kind: Literal["box_grid"]
    spacing: Length

    def check(self, shape, sensor_radius):
        _check_spacing(self.spacing, sensor_radius)
        super().check(shape, sensor_radius)

    def estimated_count(self, shape, sensor_radius):
        return shape.wall_area / self.spacing**2

    def positions_normals(self, shape, sensor_radius):
        return layouts.box_grid_layout(shape.size_x, shape.size_y, shape.size_z, self.spacing)


class StringsLayout(_Layout):
    """Vertical strings on a triangular lattice (m), sensors looking down (IceCube-like)."""

    shapes: ClassVar[tuple[str, ...]] = ("open",)
    kind: Literal["strings"]
    strings: Count
    string_spacing: Length
    sensors_per_string: Count
    sensor_spacing: Length

    def estimated_count(self, shape, sensor_radius):
        return self.strings * self.sensors_per_string

    def positions_normals(self, shape, sensor_radius):
        return layouts.string_layout(
            self.strings, self.string_spacing, self.sensors_per_string, self.sensor_spacing
        )


LayoutSpec = Annotated[
    CoverageLayout | SpacingLayout | FibonacciLayout | BoxGridLayout | StringsLayout,
    Field(discriminator="kind"),
]


# ---- detector ---------------------------------------------------------------------------


def _preset_shorthand(value: Any) -> Any:
    """``detector: SK`` is short for ``detector: {preset: SK}``."""
    return {"preset": value} if isinstance(value, str) else value


_CUSTOM_FIELDS = ("name", "shape", "layout", "sensors", "sensor_model")


class DetectorSpec(_Strict):
    """Either a preset (``preset``) or a custom detector (``shape`` + ``layout`` or ``sensors``).

    ``sensors`` is a sensor-layout file (CSV, NPZ or HDF5; relative paths are relative
    to the configuration file). ``sensor_model`` names the photosensor model (or a
    list, one per sensor-file ``type``); it defaults to R3600.
    """

    preset: PresetName | None = None
    name: str | None = None
    shape: ShapeSpec | None = None
    layout: LayoutSpec | None = None
    sensors: str | None = None
    sensor_model: SensorModelNames | None = None

    @model_validator(mode="after")
    def _one_kind_of_detector(self) -> DetectorSpec:
        if self.preset is not None:
            extra = [name for name in _CUSTOM_FIELDS if getattr(self, name) is not None]
            if extra:
                raise ConfigError(
                    f"detector.{extra[0]}: not allowed with detector.preset"
                    " (a preset fixes the geometry; drop one of them)"
                )
            return self
        if self.shape is None:
            raise ConfigError(
                "detector.shape: missing (give detector.preset, or detector.shape with"
                " detector.layout or detector.sensors)"
            )
        if (self.layout is None) == (self.sensors is None):
            both = self.layout is not None
            raise ConfigError(
                "detector.sensors: not allowed with detector.layout (give one of them)"
                if both
                else "detector.layout: missing (give detector.layout or detector.sensors)"
            )
        if self.layout is not None and self.shape.kind not in self.layout.shapes:
            raise ConfigError(
                f"detector.layout.kind = {format_value(self.layout.kind)}: needs a"
                f" {' or '.join(self.layout.shapes)} shape, not a {self.shape.kind}"
            )
        return self


# ---- params and the whole file ----------------------------------------------------------

ParamOverrides = create_model(
    "ParamOverrides",
    __base__=_Strict,
    __doc__="Overrides of ``default_params`` by ``Params`` field name (units as in PARAM_SPECS).",
    **{spec.name: (ParamValue, None) for spec in PARAM_SPECS},
)


def _empty_if_none(value: Any) -> Any:
    """An empty section (``params:`` with everything commented out) means no overrides."""
    return {} if value is None else value


class ConfigModel(_Strict):
    """A whole configuration file: ``detector``, optional ``medium`` and ``params``."""

    detector: Annotated[DetectorSpec, BeforeValidator(_preset_shorthand)]
    medium: MediumName | None = None
    params: Annotated[ParamOverrides, BeforeValidator(_empty_if_none)] = Field(  # type: ignore[valid-type]
        default_factory=ParamOverrides
    )

    def param_overrides(self) -> dict[str, float | tuple[float, ...]]:
        """The parameter values set in the file, by ``Params`` field name."""
        return self.params.model_dump(exclude_unset=True)
