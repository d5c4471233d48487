"""Sampled against expected mode on SK through the calibration, source by source, with
bright pulses (~25 min alone).

``python studies/calibration/sk_mismatch_sources.py [pulses] [sources] [components]``: the
projection of ``sk_mismatch.py`` (the shift that the per-sensor difference n - M puts
into a fit of the four optics with every efficiency profiled, in Cramer-Rao sigma of one
campaign experiment), with three changes that make each source's share measurable:

- the sampled counts n come from ``pulses`` pulses (default 10) of ``BRIGHTNESS`` times
  the campaign's 10^6 photons, scaled back to 10^6: 10^8 photons per source by default,
  100 campaign experiments' worth;
- the expected charges M of the difference come from ``KEYS`` ray sets of their own
  (16 x 4,096 rays), independent of the 8 sets that give the projection's derivatives
  and weights (``sk_mismatch.source_rows``), so no ray is used twice;
- ``sources`` (comma-separated indices of ``campaign.campaign_sources``: 0 the laser,
  1 the central flash; default all 16) and ``components`` (``full`` and names of
  ``sk_components.COMPONENTS``, e.g. ``scatter``; default ``full``) choose what is
  compared. A component switches the other light off in the difference only; the
  projection always uses the full light's derivatives and weights, so the shares of the
  components add up to the full shift (to first order).

Each line's error is the sampled counts' Poisson noise and M's ray noise, from the
per-sensor variance over the ray sets. A heavy-tailed ray noise makes that error too
small; repeating a source with other keys shows it.
"""

from __future__ import annotations

import dataclasses
import sys
import time

import jax
import numpy as np

import photonflow as pf
from photonflow.calibration.campaign import TRUE_OPTICS, campaign_sources
from photonflow.transport.expected import expected
from photonflow.transport.optics import TransportConfig
from photonflow.transport.sampled import grid_for, sample_photons

import sk_mismatch
from sk_components import COMPONENTS

BRIGHTNESS = 10.0
KEYS = 16
NOISE_DRAWS = 30


def difference(detector, params, source, config, pulses: int, tag: int):
    """(n - M, its variance), (N,) p.e. per campaign pulse each: ``pulses`` sampled
    pulses of ``BRIGHTNESS`` x ``source`` against ``KEYS`` fresh ray sets."""
    grid = grid_for(detector, None)
    bright = dataclasses.replace(source, n_photons=source.n_photons * BRIGHTNESS)
    charges = np.stack([
        np.asarray(expected(detector, params, bright, config=config,
                            key=jax.random.key(31_000 + k), grid=grid).charge, np.float64)
        for k in range(KEYS)
    ]) / BRIGHTNESS
    counts = np.mean([
        np.asarray(sample_photons(detector, params, bright, jax.random.key(91_000 + tag + k),
                                  config=config, grid=grid).n_pe, np.float64)
        for k in range(pulses)
    ], axis=0) / BRIGHTNESS
    variance = counts / (pulses * BRIGHTNESS) + charges.var(axis=0, ddof=1) / KEYS
    return counts - charges.mean(axis=0), variance


def shift(rows: list[dict], differences: dict[int, np.ndarray]) -> np.ndarray:
    """(4,) optics shift (physical units) that ``differences`` (source index -> n - M)
    put into the fit: ``sk_mismatch.independent_shift`` with derivatives and weights from
    the even and the odd ray sets of ``rows``, both ways round, averaged."""
    halves = [[{"M": row["M_sets"][p::2].mean(axis=0), "J": row["J_sets"][p::2].mean(axis=0)}
               for row in rows] for p in (0, 1)]
    both = []
    for own, other in (halves, halves[::-1]):
        data = [{**x, "n": x["M"] + differences.get(k, 0.0)} for k, x in enumerate(own)]
        both.append(sk_mismatch.independent_shift(data, other))
    return 0.5 * (both[0] + both[1])


def shift_noise(rows, variances: dict[int, np.ndarray], rng) -> np.ndarray:
    """(4,) standard deviation of ``shift`` from Gaussian differences of ``variances``."""
    return np.std([
        shift(rows, {k: rng.normal(0.0, np.sqrt(v)) for k, v in variances.items()})
        for _ in range(NOISE_DRAWS)
    ], axis=0)


def main() -> None:
    pulses = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    detector = pf.load_detector("SK")
    truth = pf.default_params(detector).replace(**TRUE_OPTICS)
    sources = campaign_sources(1e6)
    chosen = ([int(s) for s in sys.argv[2].split(",")] if len(sys.argv) > 2
              else list(range(len(sources))))
    components = sys.argv[3].split(",") if len(sys.argv) > 3 else ["full"]
    began = time.perf_counter()
    rows = sk_mismatch.source_rows(detector, truth, sources, 1)
    sigma = sk_mismatch.cramer_rao_sigma(rows)
    print(f"derivatives and weights of {len(rows)} sources in"
          f" {time.perf_counter() - began:.0f} s; Cramer-Rao sigma {np.round(sigma, 4)}")
    rng = np.random.default_rng(1)
    full, full_variance = {}, {}
    print("shift / sigma (absorption, scattering, wall, sensor) +- Poisson and ray noise")
    for index in chosen:
        for name in components:
            began = time.perf_counter()
            changes, bounces = ({}, sk_mismatch.CONFIG.n_bounces) if name == "full" \
                else COMPONENTS[name]
            config = TransportConfig(n_bounces=bounces, n_rays=sk_mismatch.CONFIG.n_rays)
            d, variance = difference(detector, truth.replace(**changes), sources[index],
                                     config, pulses, 1000 * index)
            if name == "full":
                full[index], full_variance[index] = d, variance
            s = shift(rows, {index: d}) / sigma
            e = shift_noise(rows, {index: variance}, rng) / sigma
            print(f"  source {index:2d} {name:8s} n - M {d.sum():+8.1f} p.e. | "
                  + " ".join(f"{a:+.3f} +- {b:.3f}" for a, b in zip(s, e, strict=True))
                  + f"  ({time.perf_counter() - began:.0f} s)", flush=True)
    if len(full) > 1:
        s, e = shift(rows, full) / sigma, shift_noise(rows, full_variance, rng) / sigma
        print("  all chosen sources, full light: "
              + " ".join(f"{a:+.3f} +- {b:.3f}" for a, b in zip(s, e, strict=True)))


if __name__ == "__main__":
    main()
