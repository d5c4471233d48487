"""Emission models of particle tracks: the mean light of a particle of kinetic energy E
as a smooth function of the distance s along its initial direction (m), the cosine of
the angle to it and the emission-time offset (ns), fitted to the generator's emission
tables (``photonflow.generator.emission_tables``)."""

from .models import emission_model, threshold_energy
from .spline import EmissionSlice, SplineEmission, spline_emission

__all__ = [
    "EmissionSlice",
    "SplineEmission",
    "emission_model",
    "spline_emission",
    "threshold_energy",
]
