"""Event reconstruction: the vertex, time, direction, energy and particle type of a
track fitted to an event's hits by maximum likelihood on the expected mode, with a
MINUIT baseline (``fit``), its seeding (``seeding``) and coordinates
(``coordinates``)."""

from .coordinates import LOCAL
from .fit import RecoSettings, reconstruct
from .result import RecoResult

__all__ = ["LOCAL", "RecoResult", "RecoSettings", "reconstruct"]
