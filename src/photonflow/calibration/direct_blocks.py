"""Blocks a and b of the conventional sequential calibration (``conventional.py``):
isotropic runs reduced to direct light (``DirectRun``), relative sensor efficiencies from
the central run, and the attenuation length from the slope of log charge versus
distance over the other runs, optionally after subtracting the indirect light the
expected mode predicts. Units: m, ns, p.e.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import jax
import numpy as np

from ..errors import ConfigError
from ..geometry.detector import Detector
from ..likelihood import dark_expectation
from ..params import Params
from ..response.spe import single_pe_moments
from ..sources import IsotropicSource
from ..transport.direct import direct_light
from ..transport.expected import expected
from ..transport.optics import TransportConfig
from .runs import RunData

#: An absorption length from a slope that leaves no absorption (1 / L_att at or below
#: 1 / L_scat + 1 / L_mie) is set to this, m.
LONGEST_ABSORPTION = 1e6


@dataclasses.dataclass(frozen=True)
class DirectRun:
    """An isotropic run seen as direct light only (blocks a and b).

    Attributes:
        index: the run's position in the list of runs.
        charge: (N,) photoelectrons summed over the run's events, dark noise subtracted
            (the summed charge divided by the mean single-p.e. charge), p.e.
        variance: (N,) variance of ``charge`` (Poisson count x single-p.e. spread), p.e.^2,
            estimated from the observed charge.
        geometry: (N,) geometric expectation of direct light summed over the run's
            events: photons x emitted fraction towards the disc x quantum efficiency x
            angular acceptance (no attenuation, efficiency 1), p.e.
        distance: (N,) source-to-sensor-centre distance, m.
        indirect: (N,) scattered and reflected light summed over the run's events, per
            unit efficiency, p.e.: zero (the textbook method) or the expected mode's
            prediction at the current values (``indirect="subtract"``).
    """

    index: int
    charge: np.ndarray
    variance: np.ndarray
    geometry: np.ndarray
    distance: np.ndarray
    indirect: np.ndarray


def attenuation_inverse(params: Params) -> float:
    """1 / L_att of direct light, 1/m: 1 / L_abs + 1 / L_scat + 1 / L_mie."""
    return float(
        1.0 / params.absorption_length + 1.0 / params.scattering_length + 1.0 / params.mie_length
    )


def direct_run(detector: Detector, params: Params, run: RunData, index: int,
               window: tuple[float, float]) -> DirectRun:
    """Reduce an isotropic run to direct-light terms at ``params`` (whose quantum
    efficiency, angular acceptance, single-p.e. width and dark rate are used; lengths and
    efficiencies are not). ``window`` is the readout window in ns relative to the source
    time."""
    source = run.source
    geometric = params.replace(
        absorption_length=math.inf, scattering_length=math.inf, mie_length=math.inf,
        efficiency=1.0,
    )
    mu, _ = direct_light(detector, geometric, source)
    distance = np.linalg.norm(
        np.asarray(detector.sensor_positions, np.float64)
        - np.asarray(source.position, np.float64), axis=1,
    )
    mean, variance = (float(x) for x in single_pe_moments(float(params.spe_width)))
    start = float(np.asarray(source.time))
    dark = float(dark_expectation(params, (start + window[0], start + window[1])))
    n_events = run.n_events
    charge = np.asarray(run.charge_sum, np.float64) / mean - n_events * dark
    count_variance = np.maximum(charge, 0.0) * (1.0 + variance / mean**2)
    return DirectRun(
        index=index,
        charge=charge,
        variance=count_variance,
        geometry=n_events * np.asarray(mu, np.float64),
        distance=distance,
        indirect=np.zeros_like(distance),
    )


def predicted_indirect(detector: Detector, params: Params, run: RunData, config: TransportConfig,
                       key) -> np.ndarray:
    """(N,) scattered and reflected light of a run at ``params``, per unit efficiency,
    summed over its events, p.e.: the expected mode's charge minus its direct light
    (``direct.direct_light``), both with efficiency 1."""
    nominal = params.replace(efficiency=1.0)
    total = expected(detector, nominal, run.source, config=config, key=key).charge
    direct, _ = direct_light(detector, nominal, run.source)
    return run.n_events * np.maximum(np.asarray(total, np.float64)
                                     - np.asarray(direct, np.float64), 0.0)


def central_efficiencies(run: DirectRun, inverse_length: float, current: np.ndarray,
                         reference_mean: float, min_charge: float) -> tuple:
    """Block a: relative efficiencies from a central isotropic run.

    efficiency_j = charge_j / (geometry_j exp(-d_j / L_att) + indirect_j) (the indirect
    light zero in the textbook method), normalised so that the
    sensors measured have the mean ``reference_mean`` (among the same sensors);
    ``inverse_length`` is 1 / L_att in 1/m. Sensors whose predicted direct light (at the
    reference efficiency) is below ``min_charge`` p.e., or that saw nothing, keep their
    ``current`` value.

    Returns:
        (efficiency (N,), error (N,) from the charge's variance (0 where not measured),
        measured mask (N,)).
    """
    direct = run.geometry * np.exp(-run.distance * inverse_length)
    expected = direct + run.indirect
    measured = (direct * reference_mean >= min_charge) & (run.charge > 0)
    if not np.any(measured):
        raise ConfigError("efficiency: the central source gives no sensor enough charge")
    raw = np.where(measured, run.charge / np.where(measured, expected, 1.0), 0.0)
    scale = reference_mean / np.mean(raw[measured])
    efficiency = np.where(measured, raw * scale, current)
    relative = np.sqrt(run.variance / np.where(measured, run.charge, 1.0) ** 2)
    error = np.where(measured, efficiency * relative, 0.0)
    return efficiency, error, measured


def attenuation_slope(runs: Sequence[DirectRun], efficiency: np.ndarray, inverse_length: float,
                      min_charge: float, efficiency_error: np.ndarray | None = None
                      ) -> tuple[float, float, int]:
    """Block b: 1 / L_att (1/m) and its error from the slope of log charge vs distance.

    For every run r and sensor j whose predicted direct light at the mean efficiency and
    the current ``inverse_length`` (1/m) is at least ``min_charge`` p.e. (selected on
    the geometry alone: a cut on the observed charge, or on the sensor's own estimated
    efficiency, would favour upward fluctuations far away and flatten the slope),
    y = log(direct / (geometry x efficiency)) + var / (2 direct^2) (the second-order
    correction of the log's bias), direct = charge - efficiency x indirect (the indirect
    light zero in the textbook method), is fitted by weighted least squares to
    c_r - d / L_att (one intercept per run, a common slope). var(y) = var(charge) /
    direct^2 + (efficiency_error / efficiency)^2, var(charge) from the fitted line's own
    charge (two re-weightings).

    Returns:
        (1 / L_att in 1/m, its 1-sigma error in 1/m, number of points).
    """
    if efficiency_error is None:
        efficiency_error = np.zeros_like(efficiency)
    relative = (efficiency_error / efficiency) ** 2
    typical = float(np.mean(efficiency))
    rows, ys, charges, backgrounds, factors, extra, run_of = [], [], [], [], [], [], []
    for column, run in enumerate(runs):
        expected = run.geometry * efficiency
        predicted = run.geometry * typical * np.exp(-run.distance * inverse_length)
        direct = run.charge - efficiency * run.indirect
        use = (predicted >= min_charge) & (direct > 0)
        q = direct[use]
        ys.append(np.log(q / expected[use]) + run.variance[use] / (2.0 * q**2))
        rows.append(run.distance[use])
        charges.append(q)
        backgrounds.append((efficiency * run.indirect)[use])
        factors.append(run.variance[use] / run.charge[use])  # var(charge) per p.e.
        extra.append(relative[use])
        run_of.append(np.full(q.size, column))
    distance, y = np.concatenate(rows), np.concatenate(ys)
    run_of = np.concatenate(run_of)
    charge, background = np.concatenate(charges), np.concatenate(backgrounds)
    factor, extra = np.concatenate(factors), np.concatenate(extra)
    if distance.size < len(runs) + 2:
        raise ConfigError(
            f"absorption_length: {distance.size} sensors with >= {min_charge:g} p.e. in the"
            " isotropic runs: too few for the attenuation slope"
        )
    design = np.zeros((distance.size, len(runs) + 1))
    design[np.arange(distance.size), run_of] = 1.0
    design[:, -1] = -distance
    model = charge
    for _ in range(3):
        # var(log direct) = var(charge) / D^2, var(charge) = (D + indirect) x factor
        weight = 1.0 / ((model + background) * factor / model**2 + extra)
        normal = design.T @ (weight[:, None] * design)
        solution = np.linalg.solve(normal, design.T @ (weight * y))
        fitted = design @ solution
        model = charge * np.exp(fitted - y)  # the line's direct charge
    covariance = np.linalg.inv(normal)
    return float(solution[-1]), float(np.sqrt(covariance[-1, -1])), int(distance.size)


def absorption_from_attenuation(inverse_length: float, error: float, params: Params) -> tuple:
    """L_abs (m) and its error (m) from 1 / L_att (1/m, with error) at the current
    scattering lengths of ``params``: 1 / L_abs = 1 / L_att - 1 / L_scat - 1 / L_mie
    (``LONGEST_ABSORPTION`` when that is not positive)."""
    scattering = float(1.0 / params.scattering_length + 1.0 / params.mie_length)
    inverse_absorption = inverse_length - scattering
    if inverse_absorption <= 1.0 / LONGEST_ABSORPTION:
        return LONGEST_ABSORPTION, math.inf
    length = 1.0 / inverse_absorption
    return length, length**2 * error


def central_index(detector: Detector, runs: Sequence[RunData], isotropic: list[int],
                   central_run: int | None) -> int:
    """The run for block a: ``central_run``, else the isotropic run nearest the centre of
    the sensor array."""
    if central_run is not None:
        if central_run not in isotropic:
            raise ConfigError(f"central_run = {central_run}: not an isotropic run")
        return central_run
    centre = np.mean(np.asarray(detector.sensor_positions, np.float64), axis=0)
    return min(isotropic, key=lambda i: float(
        np.linalg.norm(np.asarray(runs[i].source.position, np.float64) - centre)))


@dataclasses.dataclass
class DirectLightBlocks:
    """The direct-light blocks of the sequential calibration (a: efficiencies from the
    central run, b: the attenuation slope) and the isotropic runs they use, reduced to
    direct light (``DirectRun``); ``refresh`` updates the runs' subtracted indirect
    light for ``indirect="subtract"``."""

    detector: Detector
    prepared: list
    names: tuple
    config: TransportConfig
    key: object
    indirect: str
    min_charge: float
    isotropic: list
    direct: list
    central: DirectRun | None
    reference_mean: float

    @classmethod
    def prepare(cls, detector, prepared, init_params, names, central_run, config, key,
                indirect, min_charge) -> DirectLightBlocks:
        """Reduce the isotropic runs to direct light and pick the central one; one-line
        ``ConfigError`` where the free fields need runs that are not there."""
        isotropic = [i for i, run in enumerate(prepared)
                     if isinstance(run.source, IsotropicSource)]
        if ("efficiency" in names or "absorption_length" in names) and not isotropic:
            raise ConfigError("efficiency and absorption_length need isotropic runs; none given")
        direct = [direct_run(detector, init_params, prepared[i], i, config.window)
                  for i in isotropic]
        central = None
        if "efficiency" in names:
            index = central_index(detector, prepared, isotropic, central_run)
            central = direct[isotropic.index(index)]
        if "absorption_length" in names and len(direct) < 1 + (central is not None):
            raise ConfigError(
                "absorption_length: needs an isotropic run besides the central one the"
                " efficiencies come from (the slope of one run's own efficiency table is no"
                " measurement)"
            )
        reference_mean = float(np.mean(np.asarray(init_params.efficiency, np.float64)))
        return cls(detector, prepared, tuple(names), config, key, indirect, min_charge,
                   isotropic, direct, central, reference_mean)

    def direct_light_blocks(self, params: Params, errors: dict) -> Params:
        """One pass of blocks a and b at ``params`` (each with the others' current
        values); fills ``errors`` and returns the updated parameters."""
        names, min_charge = self.names, self.min_charge
        if self.indirect == "subtract" and self.direct and (
                "efficiency" in names or "absorption_length" in names):
            self.refresh(params)
        if self.central is not None:
            efficiency, error, _ = central_efficiencies(
                self.central, attenuation_inverse(params),
                np.asarray(params.efficiency, np.float64), self.reference_mean, min_charge,
            )
            params = params.replace(efficiency=efficiency)
            errors["efficiency"] = error
        if "absorption_length" in names:
            central = self.central
            slope_runs = [run for run in self.direct
                          if central is None or run.index != central.index]
            inverse, error, _ = attenuation_slope(
                slope_runs, np.asarray(params.efficiency, np.float64),
                attenuation_inverse(params), min_charge, errors.get("efficiency"),
            )
            length, errors["absorption_length"] = absorption_from_attenuation(
                inverse, error, params
            )
            params = params.replace(absorption_length=length)
        return params

    def refresh(self, params: Params) -> None:
        """Subtract the scattered and reflected light the expected mode predicts at
        ``params`` (``predicted_indirect``) in every direct-light run."""
        self.direct = [
            dataclasses.replace(run, indirect=predicted_indirect(
                self.detector, params, self.prepared[run.index], self.config,
                jax.random.fold_in(self.key, run.index)))
            for run in self.direct
        ]
        if self.central is not None:
            self.central = self.direct[self.isotropic.index(self.central.index)]
