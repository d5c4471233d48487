"""Photosensor models: size, efficiency, timing, charge and noise, with sources.

Values are read from the reference sheet ``shared/reference/physics.md`` (section 4,
"Photosensors"); where the sheet has no number the value is marked *assumed* in its
``notes`` and should be replaced by a measurement.
"""

from __future__ import annotations

import dataclasses

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
    """

    name: str
    radius: float
    quantum_efficiency: float
    tts: float
    spe_width: float
    dark_rate: float
    notes: str


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
            " R14374 values.",
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
            " reference sheet: assumed.",
        ),
        SensorModel(
            "R7081",
            0.127,
            0.25,
            2.0,
            0.3,
            500.0,
            "IceCube 10-inch DOM PMT. Not in the reference sheet: radius = 5 inch, other"
            " values assumed typical of 10-inch PMTs.",
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
