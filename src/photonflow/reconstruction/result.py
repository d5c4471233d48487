"""The result of one event's reconstruction."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .coordinates import LOCAL


@dataclasses.dataclass(frozen=True)
class RecoResult:
    """A fitted track and what is known about the fit.

    Attributes:
        position: (3,) vertex (the track's start), m.
        time: start time, ns.
        direction: (3,) unit vector.
        energy: kinetic energy, MeV.
        covariance: (7, 7) covariance of the fitted track in the coordinates
            ``coordinates.LOCAL``: x, y, z (m), t (ns), two angles about the fitted
            direction (rad), ln E. The sandwich H^-1 J H^-1 of ``variability`` (H the
            Hessian of the negative log-likelihood at the optimum, the observed Fisher
            information; J the variability of its gradient over events simulated at the
            fit) where ``RecoSettings.variability_events`` > 0, else H^-1; NaN when the
            Hessian is not positive definite.
        nll: the minimum negative log-likelihood.
        particle: the particle of the fit ("mu-" or "e-").
        converged: the fit ended at a minimum (a small step and gradient, and a
            positive-definite Hessian there).
        iterations: optimiser iterations (summed over the starts fitted).
        seconds: wall time of the whole reconstruction, s.
        failure: None, or why the fit failed (one line).
        log_likelihood_ratio: for ``particle="auto"``, nll(mu-) - nll(e-) at the two
            minima (positive: the event is more e-like); else None.
        method: "gradient" or "minuit".
        evaluations: likelihood evaluations (value or value and gradient).
        fisher_covariance: (7, 7) H^-1 in ``LOCAL`` coordinates (the covariance when
            the model describes the data's fluctuations), or None (no fit).
        bias: (7,) the fit's bias to first order in ``LOCAL`` coordinates, -H^-1 E[g]
            over the simulated events (``variability``), or None (not computed).
        correction: (7,) what was subtracted from the likelihood's minimum in ``LOCAL``
            coordinates to give the reported track (``RecoSettings.bias_correction``;
            0 in each coordinate not corrected), or None (not computed): the minimum
            is the reported track plus it.
    """

    position: np.ndarray
    time: float
    direction: np.ndarray
    energy: float
    covariance: np.ndarray
    nll: float
    particle: str
    converged: bool
    iterations: int
    seconds: float
    failure: str | None = None
    log_likelihood_ratio: float | None = None
    method: str = "gradient"
    evaluations: int = 0
    fisher_covariance: np.ndarray | None = None
    bias: np.ndarray | None = None
    correction: np.ndarray | None = None

    @property
    def errors(self) -> dict[str, float]:
        """1-sigma errors from the covariance (``covariance_errors``)."""
        return covariance_errors(self.covariance)

    @classmethod
    def failed(cls, reason: str, particle: str, method: str, seconds: float) -> RecoResult:
        """A result of no fit: NaN values and ``failure`` = ``reason``."""
        nan3 = np.full(3, np.nan)
        return cls(position=nan3, time=math.nan, direction=nan3, energy=math.nan,
                   covariance=np.full((len(LOCAL), len(LOCAL)), np.nan), nll=math.nan,
                   particle=particle, converged=False, iterations=0, seconds=seconds,
                   failure=reason, method=method)


def covariance_errors(covariance) -> dict[str, float]:
    """1-sigma errors of a (7, 7) covariance in ``LOCAL`` coordinates: ``x``, ``y``,
    ``z`` (m), ``time`` (ns), ``direction_deg`` (the rms of the two angle errors,
    degrees: the 1-sigma error of the direction along any one axis across it) and
    ``energy_frac`` (the fractional energy error); NaN where a variance is negative."""
    variance = np.diag(np.asarray(covariance, np.float64))
    sd = np.sqrt(np.where(variance >= 0, variance, np.nan))
    return {
        "x": float(sd[0]), "y": float(sd[1]), "z": float(sd[2]), "time": float(sd[3]),
        "direction_deg": math.degrees(math.sqrt(0.5 * (variance[4] + variance[5])))
        if variance[4] >= 0 and variance[5] >= 0 else math.nan,
        "energy_frac": float(sd[6]),
    }
