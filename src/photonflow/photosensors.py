"""Photosensor models: size, efficiency, timing, charge and noise, with sources.

Values are read from the reference sheet ``shared/reference/physics.md`` (section 4,
"Photosensors"); where the sheet has no number the value is marked *assumed* in its
``notes`` and should be replaced by a measurement.
"""

from __future__ import annotations

import dataclasses

import numpy as np

#: Relative angular acceptance at incidence 0, 10, ..., 90 degrees: the older SK-like
#: collection-efficiency curve from WCSim ``src/WCSimPMTObject.cc`` (commented table).
SK_ANGULAR_ACCEPTANCE: tuple[float, ...] = (
    1.00,
    1.00,
    0.99,
    0.95,
    0.90,
    0.85,
    0.80,
    0.69,
    0.35,
    0.13,
)


#: Reference wavelength of the single-wavelength optics and of ``quantum_efficiency``, nm.
REFERENCE_WAVELENGTH = 400.0

#: Wavelengths (nm) of the quantum-efficiency tables below.
QE_WAVELENGTHS: tuple[float, ...] = (300.0, 340.0, 380.0, 400.0, 420.0, 460.0, 500.0, 540.0, 600.0)

#: QE (%) at ``QE_WAVELENGTHS`` of the SK 20-inch R3600: WCSim ``WCSimPMTObject.cc``
#: raw table (before its 1/0.73 factor), reference sheet section 4.
SK_20INCH_QE: tuple[float, ...] = (1.4, 16.9, 20.6, 21.1, 20.2, 16.7, 11.6, 4.3, 0.76)
#: QE (%) of the HK 50 cm box-and-line R12860: WCSim raw table, reference sheet section 4.
BOX_AND_LINE_QE: tuple[float, ...] = (0.08, 25.5, 31.3, 31.3, 29.9, 24.9, 17.6, 7.8, 1.5)
#: QE (%) of the 3-inch mPMT PMT (R12199-02 / R14374): WCSim raw table, reference
#: sheet section 4.
MPMT_3INCH_QE: tuple[float, ...] = (7.9, 24.0, 27.0, 26.8, 25.9, 22.8, 17.8, 10.3, 4.7)


@dataclasses.dataclass(frozen=True)
class SensorModel:
    """A photosensor model.

    Attributes:
        name: model name.
        radius: photocathode disc radius, m.
        quantum_efficiency: detection efficiency at the reference wavelength (0-1).
        tts: transit-time spread, Gaussian sigma at 1 p.e., ns.
        spe_width: width w of the single-p.e. charge Normal(1, w) truncated at 0, p.e.
        dark_rate: dark-noise rate, Hz.
        notes: sources of the numbers.
        qe_spectrum: QE (%) at ``QE_WAVELENGTHS``; only its shape is used (the
            spectral response relative to ``REFERENCE_WAVELENGTH``), the absolute scale
            is ``quantum_efficiency``.
    """

    name: str
    radius: float
    quantum_efficiency: float
    tts: float
    spe_width: float
    dark_rate: float
    notes: str
    qe_spectrum: tuple[float, ...]


SENSOR_MODELS: dict[str, SensorModel] = {
    m.name: m
    for m in (
        SensorModel(
            "R3600",
            0.254,
            0.211,
            2.1,
            1.03,
            4200.0,
            "SK 20-inch. Radius, QE 21.1 % at 400 nm and dark rate 4.2 kHz (SK-I): WCSim"
            " WCSimPMTObject.cc; timing 2.1 ns at 1 p.e.: SK calibration arXiv:1307.0162;"
            " spe_width = RMS/mean 1.03 of WCSim's tabulated 1-p.e. charge.",
            SK_20INCH_QE,
        ),
        SensorModel(
            "R12860",
            0.254,
            0.313,
            4.1 / 2.355,
            0.35,
            4200.0,
            "HK 50 cm box-and-line. Radius, QE 31.3 % at 400 nm, dark rate 4.2 kHz: WCSim"
            " WCSimPMTObject.cc; TTS 4.1 ns FWHM and 1-p.e. charge resolution 35 %:"
            " 'New 50cm-diameter photo-detectors' abstract.",
            BOX_AND_LINE_QE,
        ),
        SensorModel(
            "R14374",
            0.040,
            0.268,
            0.6,
            0.45,
            1000.0,
            "3-inch mPMT PMT (IWCD, WCTE). Radius 40 mm, QE 26.8 % at 400 nm, sigma 0.6 ns,"
            " dark rate 1 kHz: WCSim WCSimPMTObject.cc; spe_width 0.45: WCTE RMS/mean.",
            MPMT_3INCH_QE,
        ),
        SensorModel(
            "R14688",
            0.1016,
            0.268,
            1.0 / 2.355,
            0.45,
            1000.0,
            "Eos 8-inch. Radius = 4 inch; TTS ~1 ns FWHM: arXiv:2311.05080. QE, charge"
            " width and dark rate not in the reference sheet: assumed equal to the 3-inch"
            " R14374 values, and so is the QE spectrum.",
            MPMT_3INCH_QE,
        ),
        SensorModel(
            "SiPM",
            0.0282,
            0.50,
            0.5,
            0.15,
            100.0,
            "TAO SiPM tile, disc of the same area as a 50 mm square tile. PDE > 50 %:"
            " arXiv:2005.08745. Timing, charge width and dark rate per tile not in the"
            " reference sheet: assumed. PDE spectrum assumed of the 3-inch PMT's shape.",
            MPMT_3INCH_QE,
        ),
        SensorModel(
            "R7081",
            0.127,
            0.25,
            2.0,
            0.3,
            500.0,
            "IceCube 10-inch DOM PMT. Not in the reference sheet: radius = 5 inch, other"
            " values assumed typical of 10-inch PMTs; QE spectrum assumed of the SK"
            " 20-inch shape.",
            SK_20INCH_QE,
        ),
    )
}


def sensor_model(name: str) -> SensorModel:
    """Look up a photosensor model by name (raises ``KeyError`` listing known names)."""
    try:
        return SENSOR_MODELS[name]
    except KeyError:
        raise KeyError(
            f"unknown sensor model {name!r}; known: {', '.join(SENSOR_MODELS)}"
        ) from None


def relative_response(model: SensorModel, wavelength) -> np.ndarray:
    """QE(lambda) / QE(``REFERENCE_WAVELENGTH``) of ``model`` at wavelengths (nm, any
    shape): linear interpolation of ``qe_spectrum``, 0 outside the tabulated range."""
    table = np.asarray(model.qe_spectrum, np.float64)
    at_reference = np.interp(REFERENCE_WAVELENGTH, QE_WAVELENGTHS, table)
    values = np.interp(np.asarray(wavelength, np.float64), QE_WAVELENGTHS, table, 0.0, 0.0)
    return values / at_reference


def peak_response(model: SensorModel) -> float:
    """Largest ``relative_response`` of ``model`` (>= 1): QE peak / QE at the reference."""
    return float(np.max(relative_response(model, QE_WAVELENGTHS)))


def spectral_keep_probability(model: SensorModel, wavelength) -> np.ndarray:
    """Probability in [0, 1] of keeping a photon of the given wavelength (nm) before
    single-wavelength transport: ``relative_response / peak_response``. Transported
    with the QE scaled by ``peak_response``, a kept photon is detected with
    QE(reference) x relative_response(lambda) x (efficiency, acceptance), the QE at its
    own wavelength."""
    return relative_response(model, wavelength) / peak_response(model)
