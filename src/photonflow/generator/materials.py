"""Materials for particle transport: composition, ionisation and optical constants.

A :class:`Material` holds everything the generator needs about a medium: its elements
(for bremsstrahlung and pair production), the mean excitation energy and Sternheimer
density-effect parameters (for ionisation), the radiation length (for multiple
scattering and shower units), a refractive index n(lambda) (for Cherenkov light) and
scintillation properties (yield, Birks constants, decay-time profile).

Sources (``shared/reference/physics.md`` unless stated):

- water: <Z/A> 0.55509, I = 79.7 eV and Sternheimer a, k, x0, x1, C, delta0 from the
  PDG-format muon table of PUMAS (section 3, "PU"); X0 = 36.08 g/cm^2 (section 3);
  n(lambda) is a three-term Cauchy fit (this module) to the WCSim water indices of
  section 1 ("WM", 300-700 nm; residuals < 4e-4). The fit reproduces the sheet's
  Frank-Tamm yields: 341.7 photons/cm in 300-600 nm and 389.4 in 300-700 nm for beta = 1,
  and n(400 nm) = 1.3443.
- LAB scintillator (JUNO-like, section 6): density 0.859 g/cm^3, yield 11522 /MeV, Birks
  kB1 = 6.5e-3 g cm^-2 MeV^-1 and kB2 = 1.5e-6 (g cm^-2 MeV^-1)^2, e/gamma decay times
  4.93/20.6/190 ns with weights 0.799/0.171/0.030 (the yield, kB1 and decay profile are
  read from :data:`photonflow.medium.SCINTILLATOR`); n(lambda) is the two-term Cauchy
  form through n(400 nm) = 1.5073 and n(430 nm) = 1.5006. Not in the sheet, stated here
  as assumptions: LAB taken as C18H30 (dodecylbenzene); I = 59.2 eV from Bragg
  additivity with I_H = 19.2 eV and I_C = 81 eV (ICRU 37 values, quoted from memory);
  Sternheimer parameters from the Sternheimer-Peierls (1971) rules for liquids;
  X0 from elemental radiation lengths X0(H) = 63.04 and X0(C) = 42.70 g/cm^2 (PDG,
  quoted from memory; the same rule with X0(O) = 34.24 g/cm^2 gives 36.08 for water);
  emission spectrum a Gaussian at 430 nm with 20 nm sigma (bis-MSB emission; the sheet
  has no JUNO emission spectrum).
- water-based scintillator: :func:`water_based_scintillator` mixes the two by mass
  fraction (Bragg additivity for I, 1/X0 and 1/density additive by mass, n and the
  scintillation yield scaled with the LAB fraction, an assumption: measured WbLS yields
  are not linear in loading).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from photonflow.errors import ConfigError, format_value
from photonflow.medium import SCINTILLATOR

from .constants import AVOGADRO


@dataclasses.dataclass(frozen=True)
class Element:
    """A chemical element in a material: atomic number, molar mass (g/mol), mass fraction."""

    atomic_number: int
    molar_mass: float
    mass_fraction: float


@dataclasses.dataclass(frozen=True)
class Sternheimer:
    """Sternheimer density-effect parameters (PDG convention, x = log10(beta gamma))."""

    a: float
    k: float
    x0: float
    x1: float
    c_bar: float
    delta0: float = 0.0


@dataclasses.dataclass(frozen=True)
class Material:
    """A homogeneous medium for particle transport and light emission.

    Attributes:
        name: material name.
        elements: composition (mass fractions sum to 1).
        density: g/cm^3.
        z_over_a: <Z/A>, mol/g.
        mean_excitation: mean excitation energy I, eV.
        sternheimer: density-effect parameters.
        radiation_length: X0, g/cm^2.
        cauchy: refractive-index coefficients c_i of n = sum_i c_i lambda^(-2 i), lambda in nm.
        light_yield: scintillation photons per MeV of Birks-quenched deposit (0: none).
        birks: (kB1 in g cm^-2 MeV^-1, kB2 in (g cm^-2 MeV^-1)^2).
        decay_times: scintillation decay constants, ns.
        decay_weights: their weights (sum 1).
        emission_peak: scintillation emission-spectrum mean, nm.
        emission_width: its Gaussian sigma, nm.
    """

    name: str
    elements: tuple[Element, ...]
    density: float
    z_over_a: float
    mean_excitation: float
    sternheimer: Sternheimer
    radiation_length: float
    cauchy: tuple[float, ...]
    light_yield: float = 0.0
    birks: tuple[float, float] = (0.0, 0.0)
    decay_times: tuple[float, ...] = ()
    decay_weights: tuple[float, ...] = ()
    emission_peak: float = 430.0
    emission_width: float = 20.0

    def atoms_per_gram(self) -> np.ndarray:
        """Number of atoms of each element per gram, 1/g (shape: elements)."""
        return np.array([AVOGADRO * e.mass_fraction / e.molar_mass for e in self.elements])

    def electrons_per_gram(self) -> float:
        """Electron density per unit mass, 1/g."""
        return AVOGADRO * self.z_over_a


def refractive_index(material: Material, wavelength):
    """Phase refractive index n at ``wavelength`` (nm; scalar or array)."""
    inverse_square = np.asarray(wavelength, dtype=np.float64) ** -2.0
    return sum(c * inverse_square**i for i, c in enumerate(material.cauchy))


def density_effect(material: Material, beta_gamma):
    """Sternheimer density-effect correction delta (dimensionless) at ``beta_gamma``."""
    s = material.sternheimer
    x = np.log10(np.maximum(np.asarray(beta_gamma, dtype=np.float64), 1e-12))
    two_ln10 = 2.0 * math.log(10.0)
    high = two_ln10 * x - s.c_bar
    middle = high + s.a * np.clip(s.x1 - x, 0.0, None) ** s.k
    low = s.delta0 * 10.0 ** (2.0 * (x - s.x0))
    return np.where(x >= s.x1, high, np.where(x >= s.x0, middle, low))


def sternheimer_peierls(density: float, z_over_a: float, mean_excitation: float) -> Sternheimer:
    """Density-effect parameters of a liquid from the Sternheimer-Peierls (1971) rules.

    Args:
        density: g/cm^3.
        z_over_a: <Z/A>, mol/g.
        mean_excitation: I, eV.
    """
    plasma_energy = 28.816 * math.sqrt(density * z_over_a)  # eV (PDG)
    c_bar = 2.0 * math.log(mean_excitation / plasma_energy) + 1.0
    if mean_excitation < 100.0:
        x0 = 0.2 if c_bar < 3.681 else 0.326 * c_bar - 1.0
        x1 = 2.0
    else:
        x0 = 0.2 if c_bar < 5.215 else 0.326 * c_bar - 1.5
        x1 = 3.0
    k = 3.0
    a = (c_bar - 2.0 * math.log(10.0) * x0) / (x1 - x0) ** k
    return Sternheimer(a=a, k=k, x0=x0, x1=x1, c_bar=c_bar)


HYDROGEN_MOLAR_MASS = 1.008
CARBON_MOLAR_MASS = 12.011
OXYGEN_MOLAR_MASS = 15.999


def _water() -> Material:
    molar_mass = 2 * HYDROGEN_MOLAR_MASS + OXYGEN_MOLAR_MASS
    return Material(
        name="water",
        elements=(
            Element(1, HYDROGEN_MOLAR_MASS, 2 * HYDROGEN_MOLAR_MASS / molar_mass),
            Element(8, OXYGEN_MOLAR_MASS, OXYGEN_MOLAR_MASS / molar_mass),
        ),
        density=1.0,
        z_over_a=0.55509,
        mean_excitation=79.7,
        sternheimer=Sternheimer(a=0.0912, k=3.4773, x0=0.2400, x1=2.8004, c_bar=3.5017),
        radiation_length=36.08,
        cauchy=(1.324783, 3144.883, -3.744905e6),
    )


def _lab() -> Material:
    carbons, hydrogens = 18, 30
    carbon_mass = carbons * CARBON_MOLAR_MASS
    hydrogen_mass = hydrogens * HYDROGEN_MOLAR_MASS
    molar_mass = carbon_mass + hydrogen_mass
    z_over_a = (6 * carbons + hydrogens) / molar_mass
    fraction_h, fraction_c = hydrogen_mass / molar_mass, carbon_mass / molar_mass
    ln_i = (
        fraction_h * 1.0 / HYDROGEN_MOLAR_MASS * math.log(19.2)
        + fraction_c * 6.0 / CARBON_MOLAR_MASS * math.log(81.0)
    ) / z_over_a
    mean_excitation = math.exp(ln_i)
    density = SCINTILLATOR.density
    n400, n430 = 1.5073, 1.5006
    b = (n400 - n430) / (400.0**-2 - 430.0**-2)
    return Material(
        name="scintillator",
        elements=(
            Element(1, HYDROGEN_MOLAR_MASS, fraction_h),
            Element(6, CARBON_MOLAR_MASS, fraction_c),
        ),
        density=density,
        z_over_a=z_over_a,
        mean_excitation=mean_excitation,
        sternheimer=sternheimer_peierls(density, z_over_a, mean_excitation),
        radiation_length=1.0 / (fraction_h / 63.04 + fraction_c / 42.70),
        cauchy=(n430 - b / 430.0**2, b),
        light_yield=SCINTILLATOR.light_yield,
        birks=(SCINTILLATOR.birks_constant, 1.5e-6),
        decay_times=SCINTILLATOR.decay_times,
        decay_weights=SCINTILLATOR.decay_weights,
    )


WATER = _water()
LAB = _lab()
MATERIALS: dict[str, Material] = {"water": WATER, "scintillator": LAB, "lab": LAB}


def water_based_scintillator(lab_fraction: float) -> Material:
    """Water-based liquid scintillator with ``lab_fraction`` (0..1) of LAB by mass.

    Composition, <Z/A>, ln I (Bragg), 1/X0 and 1/density are mass-weighted; n(lambda) and
    the light yield are scaled linearly with the fraction (an approximation); the Birks
    constants, time profile and emission spectrum are those of LAB.
    """
    if not 0.0 <= lab_fraction <= 1.0:
        raise ConfigError(f"lab_fraction must lie in [0, 1], got {format_value(lab_fraction)}")
    weights = {WATER: 1.0 - lab_fraction, LAB: lab_fraction}
    fractions: dict[tuple[int, float], float] = {}
    for material, weight in weights.items():
        for element in material.elements:
            key = (element.atomic_number, element.molar_mass)
            fractions[key] = fractions.get(key, 0.0) + weight * element.mass_fraction
    elements = tuple(Element(z, a, f) for (z, a), f in sorted(fractions.items()) if f > 0)
    z_over_a = sum(w * m.z_over_a for m, w in weights.items())
    ln_i = sum(w * m.z_over_a * math.log(m.mean_excitation) for m, w in weights.items())
    mean_excitation = math.exp(ln_i / z_over_a)
    density = 1.0 / sum(w / m.density for m, w in weights.items())
    order = max(len(WATER.cauchy), len(LAB.cauchy))
    cauchy = tuple(
        sum(w * (m.cauchy[i] if i < len(m.cauchy) else 0.0) for m, w in weights.items())
        for i in range(order)
    )
    return Material(
        name=f"wbls{100 * lab_fraction:g}",
        elements=elements,
        density=density,
        z_over_a=z_over_a,
        mean_excitation=mean_excitation,
        sternheimer=sternheimer_peierls(density, z_over_a, mean_excitation),
        radiation_length=1.0 / sum(w / m.radiation_length for m, w in weights.items()),
        cauchy=cauchy,
        light_yield=lab_fraction * LAB.light_yield,
        birks=LAB.birks,
        decay_times=LAB.decay_times,
        decay_weights=LAB.decay_weights,
    )


def resolve_material(medium: str | Material) -> Material:
    """The :class:`Material` named ``medium`` ("water", "scintillator" or "lab"), or itself."""
    if isinstance(medium, Material):
        return medium
    if medium not in MATERIALS:
        raise ConfigError(
            f"medium must be one of {sorted(MATERIALS)} or a Material, got {format_value(medium)}"
        )
    return MATERIALS[medium]
