"""Vectorised rejection sampling: redraw only the rejected entries until all are accepted."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

MAXIMUM_ROUNDS = 10_000
"""Rounds after which a sampler is considered broken (acceptance zero for some sample)."""


def sample_by_rejection(
    rng: np.random.Generator,
    count: int,
    propose: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
) -> np.ndarray:
    """Draw ``count`` values; ``propose(indices)`` returns (candidates, acceptance in [0, 1]).

    ``indices`` are the positions (into the caller's arrays of per-sample parameters) that
    still need a value, so the proposal can use per-sample parameters.
    """
    values = np.empty(count)
    pending = np.arange(count)
    for _ in range(MAXIMUM_ROUNDS):
        if pending.size == 0:
            return values
        candidates, acceptance = propose(pending)
        accepted = rng.random(pending.size) < acceptance
        values[pending[accepted]] = candidates[accepted]
        pending = pending[~accepted]
    if pending.size:
        raise RuntimeError(f"rejection sampling did not converge for {pending.size} samples")
    return values
