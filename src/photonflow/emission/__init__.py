"""Emission models of particle tracks: the mean light of a particle of kinetic energy E
as a smooth function of the distance s along its initial direction (m), the cosine of
the angle to it and the emission-time offset (ns), fitted to the generator's emission
tables (``photonflow.generator.emission_tables``). The SIREN model and its training
(equinox, optax) are imported on first use."""

from ..lazy_names import lazy_names
from .models import EMISSION_MODELS, emission_model, scintillation_emission, threshold_energy
from .scintillation import ScintillationModel, ScintillationSlice, scintillation_model
from .spline import EmissionSlice, SplineEmission, spline_emission

_LAZY = {"Siren": "siren", "SirenEmission": "siren", "SirenSlice": "siren",
         "siren_emission": "siren", "SirenSettings": "training", "fit_report": "training",
         "train_siren": "training"}
__getattr__, __dir__ = lazy_names(__name__, _LAZY)

__all__ = [
    "EMISSION_MODELS",
    "EmissionSlice",
    "ScintillationModel",
    "ScintillationSlice",
    "Siren",
    "SirenEmission",
    "SirenSettings",
    "SirenSlice",
    "SplineEmission",
    "emission_model",
    "fit_report",
    "scintillation_emission",
    "scintillation_model",
    "siren_emission",
    "spline_emission",
    "threshold_energy",
    "train_siren",
]
