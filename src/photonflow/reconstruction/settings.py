"""``RecoSettings``: the settings of a reconstruction (``fit.reconstruct``)."""

from __future__ import annotations

import dataclasses
import numbers

from ..errors import ConfigError
from ..likelihood import check_overdispersion

#: Fewest simulated events of a variability matrix (7 x 7: at least 8 for full rank).
MIN_VARIABILITY_EVENTS = 8


@dataclasses.dataclass(frozen=True)
class RecoSettings:
    """Settings of ``reconstruct``.

    Attributes:
        fits: how many of the starts (the likeliest) are fitted.
        restarts: further starts, the next likeliest, fitted one after another while
            none of the fits has converged (a fit that ran off, to a saddle or to the
            iteration limit, is followed by a fit from another start).
        scan_directions: directions spread over the sphere with starts behind the
            point-source vertex (``fit.SCAN_SHARES``) and the detector's centre, besides
            the seeded direction and its opposite.
        max_iterations: optimiser iterations per fit stage.
        tolerance: a fit stage ends when the negative log-likelihood fell by less than
            this in each of the last ``patience`` iterations (0.01: a change of the
            likelihood far below one standard deviation's 0.5, and above float32's
            resolution of an SK event's ~3e4).
        patience: see ``tolerance``.
        frozen_stages: most full-likelihood stages of a fit, refreshed while the track
            moves, with the indirect light held frozen: without its slopes, in the
            stages (the charge-only one too), the Hessian, the polish and the scores
            (``minimisers.fit_stages``); ignored without ``hold_indirect``. 0: the
            held light's slopes everywhere and at most ``refreshes`` refreshes (the fit
            before frozen stages, with ``refresh_distance=0.05, refresh_angle=1.0``).
        refreshes: most reference refreshes with the held light's slopes (unused with
            frozen stages).
        refresh_distance: m, and ``refresh_angle``, degrees: how far the fitted track
            may move from a stage's reference before the reference follows it.
        margin: m, how far inside the walls the vertex is kept.
        dtype: float dtype of the likelihood (None: JAX's default float for the
            gradient method, float64 for MINUIT, whose numerical derivatives need it: in
            float32 it stops short of its tolerance and HESSE's errors are noise).
        overdispersion: r of the likelihood's per-sensor counts (variance mu + r mu^2;
            ``photonflow.likelihood``), dimensionless in [0, 0.5]; 0 is Poisson.
            ``docs/reconstruction.md`` says what it does to SK muons.
        hold_indirect: each fit stage holds the indirect light computed at its
            reference track, frozen (``frozen_stages``) or to first order in the
            track's move
            (``held_indirect_function``; a value and gradient then costs the direct
            light's alone, ~3x less in SK); False traces the indirect light's rays at
            every evaluation.
        score_metric: L-BFGS starts each stage from the inverse of the sum over
            sensors of the outer products of their likelihood terms' gradients at the
            start of the charge-only and the first full stage
            (``_Functions.score_information``; refresh stages reuse the latter's)
            instead of a scaled identity, and goes on without it once a step along it
            finds no lower point (``docs/reconstruction.md``, "Fit").
        threads: threads for independent likelihood calls (the starts' values, the
            Hessian's gradients) and for the simulated events
            (``photonflow.threads``); None: one per core of the
            host (with ``--scheduler``, of each worker's host). The results do not
            depend on it.
        variability_events: events the generator and the sampled mode simulate at the
            fitted track for the covariance's variability matrix (``variability``: the
            reported covariance is the sandwich H^-1 J H^-1); 0: the inverse Fisher
            information H^-1 alone; else at least 8.
        variability_seed: seed (int) of those events, mixed with a checksum of the
            event's hits.
        bias_correction: report a converged fit less its first-order bias -H^-1 E[g]
            over those events, in the coordinates where it is significant
            (``variability.with_variability``), not the likelihood's maximum itself.
    """

    fits: int = 1
    restarts: int = 2
    scan_directions: int = 12
    max_iterations: int = 200
    tolerance: float = 1e-2
    patience: int = 3
    frozen_stages: int = 10
    refreshes: int = 2
    refresh_distance: float = 0.01
    refresh_angle: float = 0.2
    margin: float = 0.0
    dtype: str | None = None
    overdispersion: float = 0.0
    hold_indirect: bool = True
    score_metric: bool = True
    threads: int | None = None
    variability_events: int = 16
    variability_seed: int = 0
    bias_correction: bool = True

    def __post_init__(self):
        check_overdispersion(self.overdispersion)
        for name in ("frozen_stages", "refreshes"):
            if not _is_count(getattr(self, name)):
                raise ConfigError(f"{name} = {getattr(self, name)!r}: must be an integer"
                                  f" >= 0")
        count = self.variability_events
        if not _is_count(count) or 0 < count < MIN_VARIABILITY_EVENTS:
            raise ConfigError(f"variability_events = {count!r}: must be 0 or an integer"
                              f" >= {MIN_VARIABILITY_EVENTS}")


def _is_count(value) -> bool:
    """Whether ``value`` is an integer >= 0 (a bool is not)."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool) and value >= 0
