"""The primary particle handed to the generator."""

from __future__ import annotations

import dataclasses
import math

from photonflow.errors import ConfigError, format_value

from .particles import PARTICLES

MAXIMUM_ENERGY = 1.0e4
"""Largest kinetic energy the physics tables cover, MeV (validated range: up to 5 GeV)."""


@dataclasses.dataclass(frozen=True)
class Track:
    """A primary particle: species, start point, direction, kinetic energy and start time.

    Attributes:
        particle: "mu-", "mu+", "e-", "e+" or "gamma".
        position: start point (x, y, z), m.
        direction: unit vector (normalised here if within 1e-6 of unit length).
        energy: kinetic energy, MeV (0 < energy <= 1e4).
        time: start time, ns.
    """

    particle: str
    position: tuple[float, float, float]
    direction: tuple[float, float, float]
    energy: float
    time: float = 0.0

    def __post_init__(self) -> None:
        if self.particle not in PARTICLES:
            raise ConfigError(
                f"track.particle must be one of {sorted(PARTICLES)}, "
                f"got {format_value(self.particle)}"
            )
        position = _three_floats("track.position", self.position)
        direction = _three_floats("track.direction", self.direction)
        norm = math.sqrt(sum(c * c for c in direction))
        if abs(norm - 1.0) > 1e-6:
            raise ConfigError(
                f"track.direction must be a unit vector, got {format_value(self.direction)} "
                f"(length {format_value(norm)})"
            )
        energy = _finite_float("track.energy", self.energy)
        if not 0.0 < energy <= MAXIMUM_ENERGY:
            raise ConfigError(
                f"track.energy must be a kinetic energy in (0, {MAXIMUM_ENERGY:g}] MeV, "
                f"got {format_value(energy)}"
            )
        time = _finite_float("track.time", self.time)
        object.__setattr__(self, "position", position)
        object.__setattr__(self, "direction", tuple(c / norm for c in direction))
        object.__setattr__(self, "energy", energy)
        object.__setattr__(self, "time", time)


def _finite_float(field: str, value: object) -> float:
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ConfigError(f"{field} must be a number, got {format_value(value)}") from None
    if not math.isfinite(number):
        raise ConfigError(f"{field} must be finite, got {format_value(value)}")
    return number


def _three_floats(field: str, value: object) -> tuple[float, float, float]:
    try:
        items = [float(v) for v in value]  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise ConfigError(f"{field} must be three numbers, got {format_value(value)}") from None
    if len(items) != 3 or not all(math.isfinite(v) for v in items):
        raise ConfigError(f"{field} must be three finite numbers, got {format_value(value)}")
    return (items[0], items[1], items[2])
