"""Multiple Coulomb scattering of charged particles (Highland, accumulated along the track).

The Highland formula (PDG) gives the projected-plane width after a path x:
theta0 = 13.6 MeV / (beta c p) sqrt(x/X0) [1 + 0.038 ln(x / (X0 beta^2))]. Its logarithm
makes theta0^2 non-additive, so summing per-step Highland widths would depend on the step
size. Here each step of length s after a path L adds the increment of the Highland
variance between L and L + s at the current momentum,

    dtheta0^2 = (13.6 MeV / (beta c p))^2 [g(L + s) - g(L)] / X0,
    g(x) = x [1 + 0.038 ln(x / (X0 beta^2))]^2,

so that for constant momentum the total over any path reproduces Highland for that path
whatever the steps. The deflection is drawn from two independent projected Gaussians.
"""

from __future__ import annotations

import numpy as np

from .directions import rotate

HIGHLAND_SCALE = 13.6  # MeV
HIGHLAND_LOG = 0.038


def _highland_path_function(path, radiation_length, beta_sq):
    ratio = np.maximum(path / radiation_length, 1e-9)
    return path * (1.0 + HIGHLAND_LOG * np.log(ratio / beta_sq)) ** 2


def highland_variance_increment(momentum, beta_sq, path_before, step, radiation_length):
    """Increase of the projected-angle variance theta0^2 (rad^2) over one step.

    Args:
        momentum: particle momentum, MeV/c.
        beta_sq: beta^2.
        path_before: path length travelled before the step, cm.
        step: step length, cm.
        radiation_length: X0, cm.
    """
    scale = HIGHLAND_SCALE / (momentum * np.sqrt(beta_sq))
    after = _highland_path_function(path_before + step, radiation_length, beta_sq)
    before = _highland_path_function(path_before, radiation_length, beta_sq)
    return scale * scale * np.maximum(after - before, 0.0) / radiation_length


def scatter(rng: np.random.Generator, direction: np.ndarray, variance: np.ndarray) -> np.ndarray:
    """Directions (N, 3) deflected by Gaussian projected angles of variance ``variance`` (rad^2)."""
    width = np.sqrt(variance)
    theta_x = width * rng.standard_normal(width.size)
    theta_y = width * rng.standard_normal(width.size)
    theta = np.minimum(np.hypot(theta_x, theta_y), np.pi)
    return rotate(direction, np.cos(theta), np.arctan2(theta_y, theta_x))
