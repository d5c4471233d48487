"""Optical media: water and LAB-based liquid scintillator at a reference wavelength.

Numbers from ``shared/reference/physics.md`` (sections 1 and 6). The single-wavelength
values feed ``default_params``; scintillation properties are used by the particle
generator.
"""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class Medium:
    """Bulk optical properties of a detector medium.

    Attributes:
        name: medium name.
        wavelength: reference wavelength, nm.
        refractive_index: phase refractive index n at ``wavelength``.
        group_index: group index n_g = n - lambda dn/dlambda (photon speed c / n_g).
        absorption_length: m.
        scattering_length: Rayleigh scattering length, m.
        rayleigh_anisotropy: a in the phase function 1 + a cos^2(theta).
        density: g/cm^3.
        light_yield: scintillation photons per MeV (0 for a Cherenkov-only medium).
        birks_constant: Birks kB, g cm^-2 MeV^-1.
        decay_times: scintillation decay constants, ns.
        decay_weights: their weights (sum 1).
        notes: sources.
    """

    name: str
    wavelength: float
    refractive_index: float
    group_index: float
    absorption_length: float
    scattering_length: float
    rayleigh_anisotropy: float
    density: float
    light_yield: float = 0.0
    birks_constant: float = 0.0
    decay_times: tuple[float, ...] = ()
    decay_weights: tuple[float, ...] = ()
    notes: str = ""


WATER = Medium(
    name="water",
    wavelength=400.0,
    refractive_index=1.3442,
    group_index=1.381,
    absorption_length=425.0 * 1.30,
    scattering_length=176.0 * 0.75,
    rayleigh_anisotropy=0.835,
    density=1.0,
    notes=(
        "WCSim water at 400 nm (WCSimConstructMaterials.cc, skdetsim tables): n 1.3442,"
        " group index 1.381 [derived], absorption 425 m x ABWFF 1.30 = 552.5 m, Rayleigh"
        " 176 m x RAYFF 0.75 = 132 m; phase-function a = (1-d)/(1+d) = 0.835 for"
        " depolarisation d = 0.09 (Morel 1974)."
    ),
)

SCINTILLATOR = Medium(
    name="scintillator",
    wavelength=430.0,
    refractive_index=1.5006,
    group_index=1.597,
    absorption_length=62.0,
    scattering_length=27.0,
    rayleigh_anisotropy=0.835,
    density=0.859,
    light_yield=11522.0,
    birks_constant=6.5e-3,
    decay_times=(4.93, 20.6, 190.0),
    decay_weights=(0.799, 0.171, 0.030),
    notes=(
        "JUNO-like LAB + 2.5 g/L PPO + 3 mg/L bis-MSB at 430 nm. n 1.5006 (RAT"
        " OPTICS_LABPPO, Phys.Scripta 84 035701); group index 1.597 derived from n(400) ="
        " 1.5073 and n(430) = 1.5006; LAB absorption 62 m and Rayleigh 27.0 m at 430 nm"
        " (RAT, arXiv:1504.00987); density 0.859 g/cm^3, yield 11522 /MeV, Birks kB"
        " 6.5e-3 g/cm^2/MeV and e/gamma decay times 4.93/20.6/190 ns (0.799/0.171/0.03)"
        " from public JUNO-offline-derived code. The Rayleigh anisotropy of water is used"
        " (LAB's depolarisation is not in the reference sheet)."
    ),
)

MEDIA: dict[str, Medium] = {m.name: m for m in (WATER, SCINTILLATOR)}
