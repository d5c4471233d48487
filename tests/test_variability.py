"""The sandwich covariance and the first-order bias from scores, and the seeds of the
simulated events (photonflow.reconstruction.variability); the fits that use them are
tested in test_reconstruction.py."""

from __future__ import annotations

import numpy as np
import pytest

from photonflow.errors import ConfigError
from photonflow.io import make_event
from photonflow.reconstruction import RecoSettings
from photonflow.reconstruction.variability import (
    event_seed,
    sandwich_covariance,
    score_bias,
)


def test_the_sandwich_is_the_inverse_information_where_the_scores_scatter_as_it_says():
    """Scores drawn with covariance H (the model describes the data: J = H) give
    H^-1 J H^-1 = H^-1 within the sampling error of 20,000 draws, and a mean score m
    gives the bias -H^-1 m."""
    rng = np.random.default_rng(1)
    root = rng.normal(size=(7, 7))
    hessian = root @ root.T + 7 * np.eye(7)
    covariance = np.linalg.inv(hessian)
    mean = rng.normal(size=7)
    scores = rng.multivariate_normal(mean, hessian, size=20_000)
    sandwich = sandwich_covariance(covariance, scores)
    scale = np.sqrt(np.outer(np.diag(covariance), np.diag(covariance)))
    assert np.abs((sandwich - covariance) / scale).max() < 0.05
    bias = score_bias(covariance, scores)
    np.testing.assert_allclose(bias, -covariance @ mean,
                               atol=0.05 * np.sqrt(np.diag(covariance)).max())


def test_event_seeds_follow_the_hits_and_the_seed():
    """The same hits give the same seed; other hits or another seed give another."""
    event = make_event([3, 5, 8], [1.0, 2.5, 0.7], [10.0, 12.5, 11.0])
    again = make_event([3, 5, 8], [1.0, 2.5, 0.7], [10.0, 12.5, 11.0])
    other = make_event([3, 5, 8], [1.0, 2.5, 0.7], [10.0, 12.5, 11.5])
    assert event_seed(event) == event_seed(again)
    assert event_seed(event) != event_seed(other)
    assert event_seed(event, 1) != event_seed(event, 0)
    assert 0 <= event_seed(event) < 2**31 - 1


@pytest.mark.parametrize("count", [1, 7, -1, 2.5, True])
def test_settings_refuse_too_few_variability_events(count):
    with pytest.raises(ConfigError, match="variability_events"):
        RecoSettings(variability_events=count)
