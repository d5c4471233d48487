"""Emission models of particle tracks: the mean light of a particle of kinetic energy E
as a smooth function of the distance s along its initial direction (m), the cosine of
the angle to it and the emission-time offset (ns), fitted to the generator's emission
tables (``photonflow.generator.emission_tables``)."""

from .models import emission_model, scintillation_emission, threshold_energy
from .scintillation import ScintillationModel, ScintillationSlice, scintillation_model
from .spline import EmissionSlice, SplineEmission, spline_emission

__all__ = [
    "EmissionSlice",
    "ScintillationModel",
    "ScintillationSlice",
    "SplineEmission",
    "emission_model",
    "scintillation_emission",
    "scintillation_model",
    "spline_emission",
    "threshold_energy",
]
