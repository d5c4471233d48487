"""``Params``: every tunable (differentiable) detector quantity in one immutable pytree.

Static configuration (geometry, sensor count, bounce caps) lives in ``Detector`` and
in function arguments; everything here is a leaf, so changing a value never
recompiles a jitted function. Each field has a ``ParamSpec`` with its unit, its
domain and the bijection to unconstrained coordinates used by optimisers
(log for lengths and rates, logit for probabilities).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .errors import ConfigError, format_value
from .geometry.detector import Detector
from .medium import MEDIA
from .numerics import strict_array
from .photosensors import SK_ANGULAR_ACCEPTANCE, sensor_model
from .pytree import pytree_dataclass


@dataclasses.dataclass(frozen=True)
class ParamSpec:
    """Description of one ``Params`` field.

    Attributes:
        name: field name.
        unit: physical unit ("" for dimensionless).
        domain: "length" (> 0, inf allowed; log transform), "positive" (finite > 0;
            log), "probability" (logit), "correlation"
            (open interval (-1, 1), atanh), "above_one" (log(x - 1)) or "real" (identity).
        per_sensor: shape (N,) instead of a scalar.
        size: fixed vector length (0 for scalars or per-sensor fields).
        doc: one-line meaning.
    """

    name: str
    unit: str
    domain: str
    doc: str
    per_sensor: bool = False
    size: int = 0


N_ACCEPTANCE_ANGLES = 10

PARAM_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("absorption_length", "m", "length", "bulk absorption length"),
    ParamSpec("scattering_length", "m", "length", "Rayleigh scattering length"),
    ParamSpec("mie_length", "m", "length", "Mie scattering length (inf = off)"),
    ParamSpec("mie_g", "", "correlation", "Henyey-Greenstein asymmetry of Mie scattering"),
    ParamSpec("refractive_index", "", "above_one", "phase refractive index (Cherenkov angle)"),
    ParamSpec("group_index", "", "above_one", "group index: photons travel at c / group_index"),
    ParamSpec("wall_reflectivity", "", "probability", "reflectivity of the wall (black sheet)"),
    ParamSpec("wall_specular_fraction", "", "probability", "specular share of wall reflection"),
    ParamSpec("sensor_reflectivity", "", "probability", "reflectivity of the sensor glass"),
    ParamSpec("quantum_efficiency", "", "probability", "global photon detection efficiency"),
    ParamSpec("efficiency", "", "positive", "relative efficiency of each sensor", per_sensor=True),
    ParamSpec("time_offset", "ns", "real", "time offset of each sensor", per_sensor=True),
    ParamSpec("tts", "ns", "positive", "transit-time spread (Gaussian sigma)"),
    ParamSpec("spe_width", "p.e.", "positive", "single-p.e. charge width w: Normal(1, w) > 0"),
    ParamSpec("dark_rate", "Hz", "positive", "dark-noise rate per sensor"),
    ParamSpec(
        "angular_acceptance",
        "",
        "positive",
        "relative acceptance at incidence 0, 10, ..., 90 degrees",
        size=N_ACCEPTANCE_ANGLES,
    ),
)

SPECS: dict[str, ParamSpec] = {spec.name: spec for spec in PARAM_SPECS}


@pytree_dataclass
class Params:
    """All tunable detector quantities (every field a JAX array leaf).

    Attributes:
        absorption_length: bulk absorption length, m.
        scattering_length: Rayleigh scattering length, m.
        mie_length: Mie scattering length, m (``inf`` switches Mie scattering off).
        mie_g: Henyey-Greenstein asymmetry g of Mie scattering, in (-1, 1).
        refractive_index: phase refractive index n (sets the Cherenkov angle).
        group_index: group index n_g; photons travel at c / n_g.
        wall_reflectivity: probability that light hitting the wall is reflected.
        wall_specular_fraction: fraction of wall reflections that are specular
            (the rest are diffuse, Lambertian).
        sensor_reflectivity: probability that light hitting a sensor's glass is reflected.
        quantum_efficiency: global detection efficiency (0-1) at normal incidence.
        efficiency: (N,) relative efficiency of each sensor (1 = nominal).
        time_offset: (N,) time offset of each sensor, ns.
        tts: transit-time spread, Gaussian sigma, ns.
        spe_width: width w of the single-p.e. charge Normal(1, w) truncated at 0, p.e.
            (``photonflow.response.spe``).
        dark_rate: dark-noise rate per sensor, Hz.
        angular_acceptance: (10,) relative acceptance at incidence angles 0, 10, ..., 90
            degrees (all ones = flat).
    """

    absorption_length: jax.Array
    scattering_length: jax.Array
    mie_length: jax.Array
    mie_g: jax.Array
    refractive_index: jax.Array
    group_index: jax.Array
    wall_reflectivity: jax.Array
    wall_specular_fraction: jax.Array
    sensor_reflectivity: jax.Array
    quantum_efficiency: jax.Array
    efficiency: jax.Array
    time_offset: jax.Array
    tts: jax.Array
    spe_width: jax.Array
    dark_rate: jax.Array
    angular_acceptance: jax.Array

    @property
    def n_sensors(self) -> int:
        """Number of sensors N (length of the per-sensor fields)."""
        return int(self.efficiency.shape[0])

    def replace(self, **changes: Any) -> Params:
        """A copy with some fields changed (values cast to the field's dtype and shape).

        Raises ``ConfigError`` for an unknown field name or a wrong shape.
        """
        new = {}
        for name, value in changes.items():
            if name not in SPECS:
                raise ConfigError(f"params.{name}: unknown parameter; known: {', '.join(SPECS)}")
            old = getattr(self, name)
            array = jnp.asarray(value, dtype=jnp.result_type(old))
            if array.shape != old.shape:
                if SPECS[name].per_sensor and array.ndim == 0:
                    array = jnp.broadcast_to(array, old.shape)
                else:
                    raise ConfigError(f"params.{name}: shape {array.shape}, expected {old.shape}")
            new[name] = array
        return dataclasses.replace(self, **new)

    def to_dict(self) -> dict[str, np.ndarray]:
        """Field name -> numpy array (for files and printing)."""
        return {spec.name: np.asarray(getattr(self, spec.name)) for spec in PARAM_SPECS}

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> Params:
        """Build from a complete mapping of field name -> value (arrays or numbers)."""
        missing = [spec.name for spec in PARAM_SPECS if spec.name not in values]
        if missing:
            raise ConfigError(f"params.{missing[0]}: missing")
        unknown = sorted(set(values) - set(SPECS))
        if unknown:
            raise ConfigError(f"params.{unknown[0]}: unknown parameter; known: {', '.join(SPECS)}")
        return cls(**{name: strict_array(values[name]) for name in SPECS})

    def to_unconstrained(self) -> Params:
        """The same pytree with every field mapped to unconstrained real coordinates."""
        return to_unconstrained(self)

    @classmethod
    def from_unconstrained(cls, unconstrained: Params) -> Params:
        """Inverse of ``to_unconstrained``."""
        return from_unconstrained(unconstrained)


_FORWARD = {
    "length": jnp.log,
    "positive": jnp.log,
    "probability": lambda x: jnp.log(x) - jnp.log1p(-x),
    "correlation": jnp.arctanh,
    "above_one": lambda x: jnp.log(x - 1.0),
    "real": lambda x: x,
}
_INVERSE = {
    "length": jnp.exp,
    "positive": jnp.exp,
    "probability": jax.nn.sigmoid,
    "correlation": jnp.tanh,
    "above_one": lambda u: 1.0 + jnp.exp(u),
    "real": lambda u: u,
}


def to_unconstrained(params: Params) -> Params:
    """Map every field to unconstrained coordinates (log, logit, atanh, log(x-1), identity)."""
    return Params(**{s.name: _FORWARD[s.domain](getattr(params, s.name)) for s in PARAM_SPECS})


def from_unconstrained(unconstrained: Params) -> Params:
    """Map unconstrained coordinates back to physical values (inverse of ``to_unconstrained``)."""
    return Params(
        **{s.name: _INVERSE[s.domain](getattr(unconstrained, s.name)) for s in PARAM_SPECS}
    )


_DOMAIN_RULES = {
    "length": "must be > 0 (inf allowed)",
    "positive": "must be finite and > 0",
    "probability": "must be in [0, 1]",
    "correlation": "must be in (-1, 1)",
    "above_one": "must be finite and >= 1",
    "real": "must be finite",
}


def _in_domain(domain: str, value: np.ndarray) -> np.ndarray:
    """Element-wise: does each value lie in the field's domain?"""
    ok = ~np.isnan(value)
    if domain == "length":
        return ok & (value > 0)
    ok &= np.isfinite(value)
    if domain == "positive":
        ok &= value > 0
    elif domain == "probability":
        ok &= (value >= 0) & (value <= 1)
    elif domain == "correlation":
        ok &= np.abs(value) < 1
    elif domain == "above_one":
        ok &= value >= 1
    return ok


def _check_shape(spec: ParamSpec, shape: tuple[int, ...], n_sensors: int | None) -> None:
    if spec.per_sensor:
        expected = (n_sensors,) if n_sensors is not None else None
        if len(shape) != 1 or (expected is not None and shape != expected):
            want = f"({n_sensors},)" if n_sensors is not None else "(N,)"
            raise ConfigError(f"params.{spec.name}: shape {shape}, expected {want}")
    elif shape != ((spec.size,) if spec.size else ()):
        want = f"({spec.size},)" if spec.size else "a scalar"
        raise ConfigError(f"params.{spec.name}: shape {shape}, expected {want}")


def validate_params(params: Params, n_sensors: int | None = None) -> Params:
    """Check every field's shape and domain; raise a one-line ``ConfigError`` if bad.

    Lengths may be ``inf`` (e.g. no Mie scattering) but not NaN or <= 0; other
    positive quantities must be finite (a dark rate of 0 is allowed); probabilities
    must lie in [0, 1]; per-sensor fields must have ``n_sensors`` entries. Returns
    ``params`` unchanged.
    """
    for spec in PARAM_SPECS:
        value = np.asarray(getattr(params, spec.name), dtype=np.float64)
        _check_shape(spec, value.shape, n_sensors)
        flat = value.ravel()
        ok = _in_domain(spec.domain, flat)
        if spec.name == "dark_rate":
            ok |= flat == 0
        if ok.all():
            continue
        i = int(np.flatnonzero(~ok)[0])
        where = f"[{i}]" if value.ndim else ""
        unit = f" {spec.unit}" if spec.unit else ""
        rule = "is NaN" if np.isnan(flat[i]) else _DOMAIN_RULES[spec.domain]
        raise ConfigError(
            f"params.{spec.name}{where} = {format_value(float(flat[i]))}{unit}: {rule}"
        )
    return params


#: Wall reflectivity of SK's black sheet at <= 400 nm: 0.045 x BSRFF 2.50 (WCSim).
BLACK_SHEET_REFLECTIVITY = 0.045 * 2.50
#: Reflectivity of the PMT glass / photocathode (WCSim RGCFF = 0.32, flat).
SENSOR_GLASS_REFLECTIVITY = 0.32
#: Specular share of wall reflections. Not in the reference sheet (WCSim's black-sheet
#: surface model is not reproduced); an even split is assumed until measured.
WALL_SPECULAR_FRACTION = 0.5
#: Henyey-Greenstein forward asymmetry of the (commented) skdetsim Mie model (WCSim).
MIE_G = 0.4


def default_params(detector: Detector, medium: str = "water") -> Params:
    """Realistic default ``Params`` for a detector in a medium ("water" or "scintillator").

    Optics come from ``photonflow.medium`` (water at 400 nm, LAB at 430 nm); sensor
    quantities (QE, TTS, charge width, dark rate) from the detector's most common
    sensor model in ``photonflow.photosensors``; reflectivities from WCSim (black sheet
    0.045 x 2.5, glass 0.32); Mie off (``mie_length = inf``); per-sensor efficiencies
    one and time offsets zero; the SK-like angular acceptance curve.
    Arrays use JAX's default float dtype (float32 unless 64-bit mode is on).
    """
    if medium not in MEDIA:
        raise ConfigError(f"medium = {format_value(medium)}: must be one of {', '.join(MEDIA)}")
    optics = MEDIA[medium]
    counts = np.bincount(np.asarray(detector.sensor_type), minlength=len(detector.sensor_models))
    model = sensor_model(detector.sensor_models[int(np.argmax(counts))])
    n = detector.n_sensors
    scalars = {
        "absorption_length": optics.absorption_length,
        "scattering_length": optics.scattering_length,
        "mie_length": math.inf,
        "mie_g": MIE_G,
        "refractive_index": optics.refractive_index,
        "group_index": optics.group_index,
        "wall_reflectivity": BLACK_SHEET_REFLECTIVITY if detector.shape.has_walls else 0.0,
        "wall_specular_fraction": WALL_SPECULAR_FRACTION,
        "sensor_reflectivity": SENSOR_GLASS_REFLECTIVITY,
        "quantum_efficiency": model.quantum_efficiency,
        "tts": model.tts,
        "spe_width": model.spe_width,
        "dark_rate": model.dark_rate,
    }
    return Params(
        **{name: strict_array(value) for name, value in scalars.items()},
        efficiency=strict_array(np.ones(n)),
        time_offset=strict_array(np.zeros(n)),
        angular_acceptance=strict_array(SK_ANGULAR_ACCEPTANCE),
    )
