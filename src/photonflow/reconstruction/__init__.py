"""Event reconstruction: the vertex, time, direction, energy and particle type of a
track fitted to an event's hits by maximum likelihood on the expected mode, with a
MINUIT baseline (``fit``; ``settings``), its seeding (``seeding``), coordinates
(``coordinates``), the reported covariance and bias from events simulated at the fit
(``variability``) and the Cramér-Rao bound at a known track (``bounds``)."""

from .bounds import cramer_rao_covariance
from .coordinates import LOCAL
from .fit import reconstruct
from .result import RecoResult, covariance_errors
from .settings import RecoSettings

__all__ = ["LOCAL", "RecoResult", "RecoSettings", "covariance_errors",
           "cramer_rao_covariance", "reconstruct"]
