"""Generator settings: production and tracking cuts, step control, photon band and scale."""

from __future__ import annotations

import dataclasses
import math

from photonflow.errors import ConfigError, format_value


@dataclasses.dataclass(frozen=True)
class GeneratorSettings:
    """Static configuration of :func:`photonflow.generator.generate`.

    Attributes:
        band: Cherenkov wavelength band (low, high), nm.
        yield_scale: multiplies every photon yield (Cherenkov and scintillation); use
            < 1 for quick tests, 0 for transport only.
        electron_cut: kinetic-energy cut for e-/e+, MeV: knock-on electrons are produced
            above it, and electrons and positrons are tracked down to it. None: the
            medium's Cherenkov threshold at the shortest band wavelength (0.243 MeV in
            water for 300 nm), so that no Cherenkov light is lost.
        photon_cut: gamma production cut (bremsstrahlung) and tracking cut, MeV.
        muon_cut: kinetic energy at which muons stop being tracked, MeV.
        muon_decay: if True a stopped muon decays into a Michel electron (positron).
        step_fraction: largest step as a fraction of the residual range.
        max_step: largest charged-particle step, m.
        min_step: smallest step set by the range fraction, m.
    """

    band: tuple[float, float] = (300.0, 600.0)
    yield_scale: float = 1.0
    electron_cut: float | None = None
    photon_cut: float = 0.1
    muon_cut: float = 1.0
    muon_decay: bool = False
    step_fraction: float = 0.1
    max_step: float = 0.1
    min_step: float = 1.0e-4

    def __post_init__(self) -> None:
        low, high = _pair("band", self.band)
        if not 100.0 <= low < high <= 2000.0:
            raise ConfigError(
                f"band must satisfy 100 <= low < high <= 2000 nm, got {format_value(self.band)}"
            )
        object.__setattr__(self, "band", (low, high))
        _check_range("yield_scale", self.yield_scale, 0.0, math.inf, low_open=False)
        if self.electron_cut is not None:
            _check_range("electron_cut", self.electron_cut, 0.01, 100.0)
        _check_range("photon_cut", self.photon_cut, 0.01, 100.0)
        _check_range("muon_cut", self.muon_cut, 0.1, 50.0)
        _check_range("step_fraction", self.step_fraction, 0.0, 0.5)
        _check_range("max_step", self.max_step, 0.0, 10.0)
        _check_range("min_step", self.min_step, 0.0, self.max_step)
        if not isinstance(self.muon_decay, bool):
            raise ConfigError(
                f"muon_decay must be True or False, got {format_value(self.muon_decay)}"
            )


def _pair(field: str, value: object) -> tuple[float, float]:
    try:
        low, high = (float(v) for v in value)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise ConfigError(f"{field} must be two numbers, got {format_value(value)}") from None
    return low, high


def _check_range(field, value, low, high, low_open=True):
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    ok = ok and (value > low if low_open else value >= low) and value <= high
    if not ok:
        bracket = "(" if low_open else "["
        raise ConfigError(
            f"{field} must lie in {bracket}{low:g}, {high:g}], got {format_value(value)}"
        )
