"""Where is the expected mode's light early? Per hit sensor, the sampled first-hit time
against the expected mode's first-hit distribution, in SK.

40 events (the sampled mode, the preset's parameters, 1,024 rays) of an isotropic
source of 10^5 photons at (1.0, 0.0, 1.3) m (``sk_point_time_offset.py``'s), or with
``--source muon`` of the 1 GeV muon of ``sk_muon_time_offset.py`` (the tables). For
every hit sensor of every event: u = F_first(t_hit), the expected mode's first-hit CDF
(the likelihood's, ``photonflow.likelihood``, Poisson) at the sampled first-hit time.
With a faithful model u is uniform: mean 1/2, standard error 1/sqrt(12 n). Per bin of
the expected signal (p.e.), of the share of direct light and (point source) of the
distance and the incidence angle, prints n, mean(u) - 1/2 (positive: the sampled hits
come later than the model's) and the best common shift of the model's times in that
bin (ns; the maximum of the summed first-hit log-density over shifts in 5 ps steps;
positive: the model's light is early).

    python studies/reconstruction/sk_first_hit_times.py [--source point|muon]
        [--light all|direct|scattered|reflected] [--indirect-shape SHAPE]
        [--direct-variance F] [--overdispersion R]

- ``--light``: the light kept: ``direct`` without scattering and reflection,
  ``scattered`` without reflection, ``reflected`` without scattering.
- ``--indirect-shape`` (point source): the indirect components (one per bounce order,
  Gaussian in the expected mode) redrawn with the same mean: ``gamma``, the track
  light's rule (``track_expected._skewed_indirect``, three moments of a gamma
  distribution from the direct time); ``exponential``, an exponential delay after the
  direct light of the rays' mean delay (the rays' variance dropped).
- ``--direct-variance F``: the direct light's own variance (before the transit-time
  spread) times F.
- ``--overdispersion R``: the first-hit density of the likelihood's overdispersed
  counts (variance mu + R mu^2) instead of Poisson.
"""

from __future__ import annotations

import argparse
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

import photonflow as pf
from photonflow.likelihood import (
    _log_intensity_and_integral,
    dark_expectation,
    first_hit_logpdf,
    log_no_photoelectron,
)
from photonflow.transport.pseudo_data import sample_events
from photonflow.transport.track_direct import DIRECT_COMPONENTS

POSITION = (1.0, 0.0, 1.3)
PHOTONS = 1.0e5
EVENTS = 40
SHIFTS = np.arange(-0.4, 0.4001, 0.005)
#: Shortest exponential delay of a redrawn component, ns.
SHORTEST_TAIL = 1e-3


def _bins(name, values, edges):
    return [(f"{name} {lo:g}-{hi:g}", (values >= lo) & (values < hi))
            for lo, hi in zip(edges[:-1], edges[1:], strict=True)]


def _redrawn(prediction, tts, shape):
    """The point source's indirect components (1..K) as exponentially modified
    Gaussians of their mean, starting from the direct time (component 0)."""
    variance = jnp.maximum(prediction.time_sigma ** 2 - tts * tts, 0.0)  # before the tts
    spread = jnp.sqrt(variance)
    delay = jnp.maximum(prediction.time_mean - prediction.time_mean[:, :1], SHORTEST_TAIL)
    if shape == "gamma":
        narrow = spread < delay
        tau = jnp.where(narrow, spread * jnp.cbrt(jnp.where(narrow, spread / delay, 1.0)),
                        delay)
        gaussian = jnp.where(narrow, jnp.maximum(variance - tau * tau, 0.0), 0.0)
    else:  # exponential
        tau, gaussian = delay, jnp.broadcast_to(variance[:, :1], delay.shape)
    tau = tau.at[:, 0].set(0.0)
    gaussian = gaussian.at[:, 0].set(variance[:, 0])
    return dataclasses.replace(prediction, time_mean=prediction.time_mean - tau,
                               time_sigma=jnp.sqrt(gaussian + tts * tts), time_tau=tau)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", choices=("point", "muon"), default="point")
    parser.add_argument("--light", choices=("all", "direct", "scattered", "reflected"),
                        default="all")
    parser.add_argument("--indirect-shape", choices=("gaussian", "gamma", "exponential"),
                        default="gaussian")
    parser.add_argument("--direct-variance", type=float, default=1.0)
    parser.add_argument("--overdispersion", type=float, default=0.0)
    args = parser.parse_args()
    detector = pf.load_detector("SK")
    params = pf.default_params(detector)
    if args.light in ("direct", "reflected"):
        params = params.replace(scattering_length=1e9, mie_length=1e9)
    if args.light in ("direct", "scattered"):
        params = params.replace(wall_reflectivity=0.0, sensor_reflectivity=0.0)
    if args.source == "muon":
        from sk_muon_extent_scale import TRUTH  # the study beside this one

        source, n_direct = TRUTH, DIRECT_COMPONENTS
        config = pf.TransportConfig(n_rays=1024, emission_model="tables")
    else:
        source = pf.IsotropicSource(position=jnp.asarray(POSITION), n_photons=PHOTONS)
        n_direct, config = 1, pf.TransportConfig(n_rays=1024)
    prediction = pf.expected(detector, params, source, config=config, key=jax.random.key(3))
    tts2 = params.tts * params.tts
    own = (prediction.time_sigma ** 2 - tts2).at[:, :n_direct].multiply(args.direct_variance)
    prediction = dataclasses.replace(prediction, time_sigma=jnp.sqrt(own + tts2))
    if args.indirect_shape != "gaussian":
        if args.source != "point":
            parser.error("--indirect-shape: the point source only")
        prediction = _redrawn(prediction, params.tts, args.indirect_shape)
    window = config.window
    mu_dark = dark_expectation(params, window)
    mu = prediction.charge

    @jax.jit
    def cdf_and_logpdf(ids, times):
        """(u, log p_first) of the chosen sensors at their times: the likelihood's
        first-hit CDF and density (Poisson, or the Polya process of overdispersion r)."""
        part = jax.tree.map(lambda x: x[ids] if jnp.ndim(x) and x.shape[0] == mu.size
                            else x, prediction)
        r = args.overdispersion
        big_lambda = _log_intensity_and_integral(part, times, mu_dark, window)[1]
        unhit = log_no_photoelectron(part.charge + mu_dark, r)  # log P(no hit)
        before = log_no_photoelectron(big_lambda, r)  # log P(no hit before t)
        u = jnp.expm1(before) / jnp.expm1(unhit)
        return u, first_hit_logpdf(part, times, mu_dark, window, r)

    offset = np.asarray(detector.sensor_positions) - np.asarray(POSITION)
    distance = np.linalg.norm(offset, axis=1)
    cos_incidence = (-np.sum(offset * np.asarray(detector.sensor_normals), axis=1)
                     / distance)
    direct_share = np.asarray(jnp.sum(prediction.time_weight[:, :n_direct], axis=1))
    rows = []
    for event in sample_events(detector, params, source, 5, EVENTS, config=config):
        ids = jnp.asarray(event.sensor_ids)
        times = np.asarray(event.time, np.float64)
        u = cdf_and_logpdf(ids, jnp.asarray(times, jnp.float32))[0]
        logs = np.stack([np.asarray(cdf_and_logpdf(ids, jnp.asarray(times - s,
                                                                     jnp.float32))[1])
                         for s in SHIFTS])
        rows.append((np.asarray(ids), np.asarray(u), logs))
    ids, u = (np.concatenate([r[k] for r in rows]) for k in (0, 1))
    logs = np.concatenate([r[2] for r in rows], axis=1)
    groups = [("all", np.ones(ids.size, bool))]
    groups += _bins("mu", np.asarray(mu)[ids], [0, 0.3, 1, 3, 10, 30, 1e9])
    groups += _bins("direct share", direct_share[ids], [0, 0.5, 0.8, 0.9, 0.95, 1.01])
    if args.source == "point":
        groups += _bins("distance m", distance[ids], [0, 10, 15, 20, 25, 50])
        groups += _bins("cos incidence", cos_incidence[ids], [-1, 0.5, 0.7, 0.85, 0.95, 1.01])
    print(f"{args.source}, light {args.light}, indirect {args.indirect_shape}, direct"
          f" variance x {args.direct_variance:g}, overdispersion {args.overdispersion:g}:"
          f" {EVENTS} events, {ids.size} hits")
    print(f"{'bin':28s} {'n':>7s} {'mean u - 1/2':>16s} {'best shift ns':>14s}")
    for name, mask in groups:
        n = int(mask.sum())
        if n < 20:
            continue
        best = SHIFTS[int(np.argmax(logs[:, mask].sum(axis=1)))]
        print(f"{name:28s} {n:7d} {u[mask].mean() - 0.5:+8.4f}+-{1 / np.sqrt(12 * n):.4f}"
              f" {best:+14.3f}")


if __name__ == "__main__":
    main()
