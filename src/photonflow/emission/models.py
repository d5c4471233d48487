"""The emission models that ship with photonflow, by particle and medium."""

from __future__ import annotations

import functools

import jax
import numpy as np

from ..errors import ConfigError
from ..generator.cherenkov import cherenkov_threshold
from ..generator.emission_tables import SHIPPED, shipped_table
from ..generator.materials import refractive_index, resolve_material
from ..generator.particles import PARTICLES
from ..generator.settings import GeneratorSettings
from ..numerics import default_float_dtype
from .scintillation import ScintillationModel, scintillation_model
from .spline import SplineEmission, spline_emission

#: Particles whose light is modelled with another's table: mu+ as mu- (the same light
#: within the tables' errors), e+ as e- (an approximation: e+ gives ~2 % more light at
#: 20 MeV from its annihilation photons; docs/tracks.md).
SAME_LIGHT = {"mu+": "mu-", "e+": "e-"}


def threshold_energy(particle: str, medium: str) -> float:
    """Cherenkov threshold (kinetic MeV) of ``particle`` in ``medium`` at the shortest
    wavelength of the generator's band (where the refractive index is largest)."""
    material = resolve_material(medium)
    shortest = GeneratorSettings().band[0]
    return float(cherenkov_threshold(PARTICLES[particle].mass,
                                     float(refractive_index(material, shortest))))


#: The emission models, by the name ``TransportConfig.emission_model`` gives them:
#: "tables" is the spline model with its moment tables, from which the direct light of
#: sensors seen from afar is read (``emission.moments``; faster, ``docs/tracks.md``).
EMISSION_MODELS = ("spline", "siren", "tables")


def emission_model(particle: str, medium: str = "water", dtype=None,
                   kind: str = "spline"):
    """The shipped emission model of ``particle`` in ``medium`` (arrays of ``dtype``,
    default JAX's default float), built once per process: ``kind`` "spline" (the
    ``SplineEmission``, the default), "siren" (the ``SirenEmission`` of the shipped
    trained network; ``docs/tracks.md`` compares them) or "tables" (the spline model
    with its moment tables, ``emission.moments.TabulatedEmission``; built in ~10-20 s).

    Raises:
        ConfigError: an unknown ``kind``, or no model ships for that particle and medium
            (one line).
    """
    if kind not in EMISSION_MODELS:
        raise ConfigError(f"emission_model = {kind!r}: must be one of"
                          f" {', '.join(EMISSION_MODELS)}")
    dtype = default_float_dtype() if dtype is None else jax.dtypes.canonicalize_dtype(dtype)
    particle = SAME_LIGHT.get(particle, particle)
    if kind == "siren":
        return _siren(particle, medium, dtype.name)
    if kind == "tables":
        return _tabulated(particle, medium, dtype.name)
    return _model(particle, medium, dtype.name)


def scintillation_emission(particle: str, medium: str = "water",
                           dtype=None) -> ScintillationModel | None:
    """The shipped ``ScintillationModel`` of ``particle`` in ``medium`` (arrays of
    ``dtype``), built once per process; None for a medium that does not scintillate.

    Raises:
        ConfigError: no table ships for that particle and medium (one line).
    """
    if resolve_material(medium).light_yield <= 0:
        return None
    dtype = default_float_dtype() if dtype is None else jax.dtypes.canonicalize_dtype(dtype)
    return _scintillation(SAME_LIGHT.get(particle, particle), medium, dtype.name)


@functools.cache
def _scintillation(particle: str, medium: str, dtype_name: str) -> ScintillationModel:
    _check_shipped(particle, medium)
    with jax.ensure_compile_time_eval():
        return scintillation_model(shipped_table(particle, medium), np.dtype(dtype_name))


def _check_shipped(particle: str, medium: str) -> None:
    if (particle, medium) not in SHIPPED:
        raise ConfigError(
            f"track.particle = {particle!r} in {medium!r}: no emission model ships for it"
            f" (shipped: {', '.join(f'{p} in {m}' for p, m in sorted(SHIPPED))})"
        )


@functools.cache
def _model(particle: str, medium: str, dtype_name: str) -> SplineEmission:
    _check_shipped(particle, medium)
    table = shipped_table(particle, medium)
    with jax.ensure_compile_time_eval():  # built eagerly even when first asked in a trace
        return spline_emission(table, threshold_energy(particle, medium), np.dtype(dtype_name))


@functools.cache
def _tabulated(particle: str, medium: str, dtype_name: str):
    from .moments import tabulated_emission

    return tabulated_emission(_model(particle, medium, dtype_name))


#: The shipped SIREN networks, by (particle, medium), in ``photonflow/data``.
SHIPPED_NETWORKS = {key: f"siren_{key[0]}_{key[1]}.eqx" for key in SHIPPED}


@functools.cache
def _siren(particle: str, medium: str, dtype_name: str):
    from importlib.resources import files

    from .siren import load_network, siren_emission  # equinox: imported when first asked

    _check_shipped(particle, medium)
    with jax.ensure_compile_time_eval():  # built eagerly even when first asked in a trace
        network, _ = load_network(files("photonflow") / "data"
                                  / SHIPPED_NETWORKS[(particle, medium)])
        return siren_emission(network, _model(particle, medium, dtype_name))


def scintillation_spectral_factor(sensor, medium: str, points: int = 601) -> float:
    """Mean relative spectral response (``photosensors.relative_response``) of ``sensor``
    over the scintillation spectrum of ``medium`` (a Gaussian of mean ``emission_peak``
    and width ``emission_width`` nm, as the generator draws it): the factor by which the
    QE at the reference wavelength turns into the detection probability of a
    scintillation photon."""
    material = resolve_material(medium)
    wavelength = material.emission_peak + material.emission_width * np.linspace(-6, 6, points)
    return _mean_response(sensor, wavelength, np.exp(-0.5 * np.linspace(-6, 6, points) ** 2))


def cherenkov_spectral_factor(sensor, medium: str, points: int = 601) -> float:
    """Mean relative spectral response (``photosensors.relative_response``) of ``sensor``
    over the Cherenkov spectrum of a beta = 1 particle in ``medium`` within the
    generator's band (dN/dlambda ~ (1 - 1 / n(lambda)^2) / lambda^2): the factor by which
    the QE at the reference wavelength turns into the detection probability of a table
    photon (the sampled mode keeps photons by their own wavelength)."""
    material = resolve_material(medium)
    low, high = GeneratorSettings().band
    wavelength = np.linspace(low, high, points)
    index = np.asarray(refractive_index(material, wavelength), np.float64)
    return _mean_response(sensor, wavelength, (1.0 - 1.0 / index**2) / wavelength**2)


def _mean_response(sensor, wavelength, spectrum) -> float:
    """The spectrum-weighted mean of ``relative_response`` of ``sensor`` over
    ``wavelength`` (nm; trapezoids)."""
    from ..photosensors import relative_response

    response = np.asarray(relative_response(sensor, wavelength), np.float64)
    return float(np.trapezoid(response * spectrum, wavelength)
                 / np.trapezoid(spectrum, wavelength))
