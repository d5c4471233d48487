"""Physical constants used by the particle generator (units: MeV, cm, ns, g).

Values are CODATA 2018 / PDG Review of Particle Physics ("Physical constants" and
"Passage of particles through matter"). Lengths are in cm inside the generator because
stopping powers and cross sections are tabulated per g/cm^2; outputs are converted to m.
"""

from __future__ import annotations

import math

from ..constants import SPEED_OF_LIGHT as _SPEED_OF_LIGHT_M_PER_NS

ELECTRON_MASS = 0.51099895  # MeV
MUON_MASS = 105.6583755  # MeV
MUON_LIFETIME = 2196.9811  # ns (free muon; mu- capture on oxygen is not modelled)
FINE_STRUCTURE = 1.0 / 137.035999084
ELECTRON_RADIUS = 2.8179403262e-13  # classical electron radius r_e, cm
AVOGADRO = 6.02214076e23  # 1/mol
BETHE_K = 0.307075  # K = 4 pi N_A r_e^2 m_e c^2, MeV cm^2/mol (PDG)
CM_PER_M = 100.0
SPEED_OF_LIGHT = _SPEED_OF_LIGHT_M_PER_NS * CM_PER_M  # cm/ns
EV_PER_MEV = 1.0e6
BREMS_PREFACTOR = FINE_STRUCTURE * ELECTRON_RADIUS**2  # alpha r_e^2, cm^2
COMPTON_PREFACTOR = math.pi * ELECTRON_RADIUS**2  # pi r_e^2, cm^2
