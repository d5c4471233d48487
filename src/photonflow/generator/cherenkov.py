"""Cherenkov emission: Frank-Tamm yield with n(lambda), thresholds, angles and photon sampling.

Frank-Tamm (PDG): d^2N/dx dlambda = (2 pi alpha z^2 / lambda^2) (1 - 1/(beta^2 n(lambda)^2))
where beta n(lambda) > 1; cos(theta_c) = 1/(n beta). In a normally dispersive medium n
falls with lambda, so a particle radiates at wavelengths below lambda_c(beta), where
n(lambda_c) = 1/beta.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .constants import CM_PER_M, FINE_STRUCTURE
from .directions import rotate
from .materials import Material, refractive_index
from .rejection import sample_by_rejection

NM_PER_CM = 1.0e7


def cherenkov_threshold(mass, index):
    """Kinetic-energy threshold (MeV) for a particle of ``mass`` (MeV) in refractive ``index``."""
    return mass * (1.0 / np.sqrt(1.0 - 1.0 / np.square(index)) - 1.0)


def cherenkov_threshold_momentum(mass, index):
    """Momentum threshold (MeV/c): p = m / sqrt(n^2 - 1)."""
    return mass / np.sqrt(np.square(index) - 1.0)


def cherenkov_angle(beta, index):
    """Cherenkov angle (rad) for speed ``beta`` in refractive ``index`` (nan below threshold)."""
    cosine = 1.0 / (np.asarray(index, dtype=np.float64) * beta)
    return np.where(cosine <= 1.0, np.arccos(np.minimum(cosine, 1.0)), np.nan)


@dataclasses.dataclass(frozen=True)
class CherenkovSpectrum:
    """Frank-Tamm integrals of a material over a wavelength band, tabulated for fast lookup.

    Attributes:
        wavelength: grid over the band, nm (increasing).
        index: n at the grid points (decreasing).
        inverse_square: cumulative integral of dlambda / lambda^2 from the band start, 1/nm.
        inverse_square_index: cumulative integral of dlambda / (lambda^2 n^2), 1/nm.
    """

    wavelength: np.ndarray
    index: np.ndarray
    inverse_square: np.ndarray
    inverse_square_index: np.ndarray

    def cutoff_wavelength(self, beta):
        """Longest wavelength (nm) emitted at ``beta`` (the band start if below threshold)."""
        inverse_beta = 1.0 / np.asarray(beta, dtype=np.float64)
        return np.interp(inverse_beta, self.index[::-1], self.wavelength[::-1])

    def photons_per_cm(self, beta):
        """Mean number of Cherenkov photons per cm in the band for a unit-charge particle."""
        beta = np.asarray(beta, dtype=np.float64)
        cutoff = self.cutoff_wavelength(beta)
        a = np.interp(cutoff, self.wavelength, self.inverse_square)
        b = np.interp(cutoff, self.wavelength, self.inverse_square_index)
        return np.maximum(2.0 * math.pi * FINE_STRUCTURE * NM_PER_CM * (a - b / beta**2), 0.0)

    def sample_wavelength(self, rng: np.random.Generator, beta: np.ndarray) -> np.ndarray:
        """Photon wavelengths (nm) for emitters of speed ``beta`` (one each, above threshold)."""
        low = self.wavelength[0]
        high = self.cutoff_wavelength(beta)
        top = 1.0 - 1.0 / (beta * self.index[0]) ** 2

        def propose(indices):
            inverse = 1.0 / low - rng.random(indices.size) * (1.0 / low - 1.0 / high[indices])
            wavelength = 1.0 / inverse
            n = np.interp(wavelength, self.wavelength, self.index)
            b = beta[indices]
            return wavelength, (1.0 - 1.0 / (b * n) ** 2) / top[indices]

        return sample_by_rejection(rng, beta.size, propose)


def cherenkov_spectrum(material: Material, band: tuple[float, float], points: int = 2001):
    """Tabulate the Frank-Tamm integrals of ``material`` over ``band`` (nm)."""
    wavelength = np.linspace(band[0], band[1], points)
    index = refractive_index(material, wavelength)
    integrand_a = wavelength**-2.0
    integrand_b = integrand_a / index**2
    step = np.diff(wavelength)
    cumulative_a = np.concatenate(
        [[0.0], np.cumsum(0.5 * step * (integrand_a[1:] + integrand_a[:-1]))]
    )
    cumulative_b = np.concatenate(
        [[0.0], np.cumsum(0.5 * step * (integrand_b[1:] + integrand_b[:-1]))]
    )
    return CherenkovSpectrum(wavelength, index, cumulative_a, cumulative_b)


@dataclasses.dataclass(frozen=True)
class EmissionPhotons:
    """Photons from one emission process (internal units converted: m, ns, nm)."""

    position: np.ndarray
    direction: np.ndarray
    time: np.ndarray
    wavelength: np.ndarray
    parent: np.ndarray


def cherenkov_photons(
    rng, spectrum: CherenkovSpectrum, steps, yield_scale: float
) -> EmissionPhotons:
    """Cherenkov photons of all charged steps.

    Each step (straight segment, cm, with mid-step speed beta) emits a Poisson number of
    photons with mean yield_scale x length x dN/dx(beta), uniformly along the segment,
    with wavelengths from the Frank-Tamm spectrum and directions on the cone
    cos(theta) = 1/(n(lambda) beta) around the step direction (uniform azimuth).
    """
    mean = yield_scale * steps.length * spectrum.photons_per_cm(steps.beta)
    counts = rng.poisson(mean)
    owner = np.repeat(np.arange(counts.size), counts)
    fraction = rng.random(owner.size)
    beta = steps.beta[owner]
    wavelength = spectrum.sample_wavelength(rng, beta)
    cos_theta = 1.0 / (beta * np.interp(wavelength, spectrum.wavelength, spectrum.index))
    phi = 2.0 * math.pi * rng.random(owner.size)
    direction = rotate(steps.direction[owner], cos_theta, phi)
    position = (
        steps.start[owner] + (fraction * steps.length[owner])[:, None] * steps.direction[owner]
    )
    time = steps.start_time[owner] + fraction * (steps.end_time[owner] - steps.start_time[owner])
    return EmissionPhotons(
        position=position / CM_PER_M,
        direction=direction,
        time=time,
        wavelength=wavelength,
        parent=steps.track[owner],
    )
