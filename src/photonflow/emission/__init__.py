"""Emission models of particle tracks: the mean light of a particle of kinetic energy E
as a smooth function of the distance s along its initial direction (m), the cosine of
the angle to it and the emission-time offset (ns), fitted to the generator's emission
tables (``photonflow.generator.emission_tables``)."""

from .spline import EmissionSlice, SplineEmission, spline_emission

__all__ = ["EmissionSlice", "SplineEmission", "spline_emission"]
