"""Direction sampling and rotation for stacks of unit vectors (numpy, vectorised)."""

from __future__ import annotations

import numpy as np


def perpendicular_basis(direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (N, 3) that with ``direction`` (N, 3, unit) form a right-handed basis.

    The first is direction x e_x normalised (direction x e_y when direction is within
    ~25 degrees of the x axis); the second is direction x first.
    """
    x, y, z = direction[:, 0], direction[:, 1], direction[:, 2]
    near_x = np.abs(x) > 0.9
    first = np.empty_like(direction)
    first[:, 0] = np.where(near_x, -z, 0.0)
    first[:, 1] = np.where(near_x, 0.0, z)
    first[:, 2] = np.where(near_x, x, -y)
    first /= np.sqrt(np.einsum("ij,ij->i", first, first))[:, None]
    a, b, c = first[:, 0], first[:, 1], first[:, 2]
    second = np.empty_like(direction)
    second[:, 0] = y * c - z * b
    second[:, 1] = z * a - x * c
    second[:, 2] = x * b - y * a
    return first, second


def rotate(direction: np.ndarray, cos_theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Unit vectors at polar angle acos(cos_theta) and azimuth ``phi`` (rad) about ``direction``.

    Args:
        direction: (N, 3) unit vectors (the rotation axes).
        cos_theta: (N,) cosines of the polar angle to the axis.
        phi: (N,) azimuths, rad.
    """
    first, second = perpendicular_basis(direction)
    sin_theta = np.sqrt(np.maximum(1.0 - cos_theta * cos_theta, 0.0))
    rotated = (
        cos_theta[:, None] * direction
        + (sin_theta * np.cos(phi))[:, None] * first
        + (sin_theta * np.sin(phi))[:, None] * second
    )
    return unit(rotated)


def isotropic(rng: np.random.Generator, count: int) -> np.ndarray:
    """``count`` unit vectors uniformly distributed on the sphere, shape (count, 3)."""
    cos_theta = 2.0 * rng.random(count) - 1.0
    phi = 2.0 * np.pi * rng.random(count)
    sin_theta = np.sqrt(1.0 - cos_theta * cos_theta)
    return np.stack([sin_theta * np.cos(phi), sin_theta * np.sin(phi), cos_theta], axis=1)


def unit(vectors: np.ndarray) -> np.ndarray:
    """Rows of ``vectors`` (N, 3) scaled to unit length."""
    return vectors / np.sqrt(np.einsum("ij,ij->i", vectors, vectors))[:, None]
