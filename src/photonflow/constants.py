"""Physical constants shared by the light transport and the emission tables (SI-derived
units of the project: metres, nanoseconds). The particle generator keeps its own
constants in cm (``photonflow.generator.constants``), derived from these where they
overlap."""

from __future__ import annotations

#: Speed of light in vacuum, m/ns (exact, SI definition of the metre).
SPEED_OF_LIGHT = 0.299792458
