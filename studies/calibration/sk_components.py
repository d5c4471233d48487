"""Sampled against expected mode on SK, one light component at a time (~2 min each).

``python studies/calibration/sk_components.py [pulses] [components] [position]``: for an isotropic
flash of 10^7 photons (default at the centre, ``position`` as "x,y,z" in m) at the SK
campaign's true optics (``photonflow.calibration.campaign``), the summed photoelectrons
of ``pulses`` sampled pulses (default 40) against the expected mode (4 ray keys x 4,096
rays), with every other light component switched off:

- ``direct``: no scattering, no reflection;
- ``scatter``: bulk scattering only (walls and glass black); ``scatter1``: the same with
  one vertex at most (single scattering);
- ``wall``: the wall only (specular and Lambertian), ``glass``: the sensor glass only;
- ``mirror``: the wall as a perfect mirror (reflectivity 1, specular), one bounce:
  the first-order mirror light of ``transport/mirror.py`` at its largest.

Printed per component: the totals, their difference with its statistical error (Poisson
of the sampled counts) and the expected mode's ray noise (spread over the keys), the
difference on the caps and the barrel, and chi^2 / N of the per-sensor differences. A
difference beyond its errors is a disagreement of the two modes, which a calibration
would turn into a bias (studies/calibration-validation.md).
"""

from __future__ import annotations

import sys
import time

import jax
import numpy as np

import photonflow as pf
from photonflow.calibration.campaign import TRUE_OPTICS
from photonflow.transport.expected import expected
from photonflow.transport.optics import TransportConfig
from photonflow.transport.sampled import grid_for, sample_photons

PHOTONS = 1e7
RAY_KEYS = 4
DARK = float("inf")  # a length at which nothing scatters
COMPONENTS = {
    "direct": ({"scattering_length": DARK, "mie_length": DARK, "wall_reflectivity": 0.0,
                "sensor_reflectivity": 0.0}, 2),
    "scatter": ({"wall_reflectivity": 0.0, "sensor_reflectivity": 0.0}, 2),
    "scatter1": ({"wall_reflectivity": 0.0, "sensor_reflectivity": 0.0}, 1),
    "wall": ({"scattering_length": DARK, "mie_length": DARK, "sensor_reflectivity": 0.0}, 2),
    "glass": ({"scattering_length": DARK, "mie_length": DARK, "wall_reflectivity": 0.0}, 2),
    "mirror": ({"scattering_length": DARK, "mie_length": DARK, "sensor_reflectivity": 0.0,
                "wall_reflectivity": 1.0, "wall_specular_fraction": 1.0}, 1),
}


def compare(detector, params, source, config, pulses: int) -> dict:
    """Expected charges (mean over ``RAY_KEYS`` keys, and their per-key totals) and the
    sampled mean photoelectrons per sensor, (N,) p.e. each."""
    grid = grid_for(detector, None)
    charges = np.stack([
        np.asarray(expected(detector, params, source, config=config,
                            key=jax.random.key(900 + k), grid=grid).charge, np.float64)
        for k in range(RAY_KEYS)
    ])
    counts = np.mean([
        np.asarray(sample_photons(detector, params, source, jax.random.key(70_000 + k),
                                  config=config, grid=grid).n_pe, np.float64)
        for k in range(pulses)
    ], axis=0)
    return {"M": charges.mean(axis=0), "M_sets": charges, "n": counts}


def main() -> None:
    pulses = int(sys.argv[1]) if len(sys.argv) > 1 else 40
    names = sys.argv[2].split(",") if len(sys.argv) > 2 else list(COMPONENTS)
    position = [float(v) for v in sys.argv[3].split(",")] if len(sys.argv) > 3 else [0.0] * 3
    detector = pf.load_detector("SK")
    truth = pf.default_params(detector).replace(**TRUE_OPTICS)
    source = pf.IsotropicSource(position=position, n_photons=PHOTONS)
    barrel = np.abs(np.asarray(detector.sensor_normals)[:, 2]) < 0.5
    print(f"isotropic flash of {PHOTONS:.0e} photons at {position} m, {pulses} pulses")
    for name in names:
        began = time.perf_counter()
        changes, bounces = COMPONENTS[name]
        config = TransportConfig(n_bounces=bounces, n_rays=4096)
        row = compare(detector, truth.replace(**changes), source, config, pulses)
        difference = row["n"] - row["M"]
        statistical = np.sqrt(row["n"].sum() / pulses)
        rays = np.std(row["M_sets"].sum(axis=1), ddof=1) / np.sqrt(RAY_KEYS)
        variance = row["n"] / pulses + np.var(row["M_sets"], axis=0, ddof=1) / RAY_KEYS
        seen = variance > 0
        chi2 = np.mean(difference[seen] ** 2 / variance[seen])
        print(f"{name:8s} expected {row['M'].sum():10.1f}  sampled {row['n'].sum():10.1f}"
              f"  difference {difference.sum():+8.1f} ± {statistical:.1f} (rays ± {rays:.1f})"
              f"  caps {difference[~barrel].sum():+8.1f}  barrel {difference[barrel].sum():+8.1f}"
              f"  chi2/N {chi2:.2f}  ({time.perf_counter() - began:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
