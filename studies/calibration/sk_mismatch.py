"""Sampled against expected mode on SK, seen through the calibration (~8 min).

``python studies/calibration/sk_mismatch.py [pulses] [component]``: for the 16 sources of
the SK campaign (``photonflow.calibration.campaign``: a downward laser and 15 isotropic
flashes of 10^6 photons) at its true optics, the per-sensor mean photoelectrons of
``pulses`` sampled pulses (default 20) against the expected mode (8 ray keys x 4,096
rays, averaged), and the shift that the difference puts into a fit of the four optical
parameters with every sensor's efficiency free:

    shift = (J_b^T W_b J_a)^-1 J_b^T W_b (n_sampled - M_a),  W_b = diag(1 / M_b),

J the derivatives of M in the optics (and in each sensor's efficiency, profiled out by
the Schur complement), a and b the even and the odd ray keys (and the other way round,
averaged): derivatives and weights from rays independent of the charges they correct,
like the calibration's independent-ray score (``independent_shift``). Printed in units of
the Cramer-Rao sigma of one experiment for all sources together, with its error from
the sampled counts' Poisson noise and the expected mode's ray noise (``shift_noise``),
and one source at a time.
A shift that is not zero within its error is a mismatch of the two modes that the
calibration would turn into a bias. With ``component`` (a name of
``sk_components.COMPONENTS``, e.g. ``scatter``) every other light component is switched
off in both modes, and the bounces are the component's (``scatter1``: single
scattering), which says where a mismatch comes from.
"""

from __future__ import annotations

import dataclasses
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import photonflow as pf
from photonflow.calibration.campaign import OPTICS, TRUE_OPTICS, campaign_sources
from photonflow.calibration.structured import StructuredMatrix
from photonflow.transport.expected import expected
from photonflow.transport.optics import TransportConfig
from photonflow.transport.sampled import grid_for, sample_photons

from sk_components import COMPONENTS

RAY_KEYS = 8
CONFIG = TransportConfig(n_bounces=2, n_rays=4096)


def source_rows(detector, truth, sources, pulses: int, config=CONFIG) -> list[dict]:
    """Per source: expected charges M (N,) p.e. and their optics derivatives J (N, 4)
    (means over ``RAY_KEYS`` ray sets), and the sampled mean photoelectrons n (N,)."""
    grid = grid_for(detector, None)
    x0 = jnp.asarray([float(getattr(truth, k)) for k in OPTICS], jnp.float32)
    tangents = jnp.eye(len(OPTICS), dtype=jnp.float32)
    rows = []
    for index, source in enumerate(sources):
        began = time.perf_counter()
        charges, jacobians = [], []
        for k in range(RAY_KEYS):
            key = jax.random.fold_in(jax.random.key(777), 100 * index + k)

            def charge_of(x, source=source, key=key):
                params = truth.replace(**dict(zip(OPTICS, x, strict=True)))
                return expected(detector, params, source, config=config, key=key,
                                grid=grid).charge

            m, j = jax.vmap(lambda t, f=charge_of: jax.jvp(f, (x0,), (t,)),
                            out_axes=(None, 1))(tangents)
            charges.append(np.asarray(m, np.float64))
            jacobians.append(np.asarray(j, np.float64))
        counts = [
            np.asarray(sample_photons(detector, truth, source,
                                      jax.random.key(5000 + 100 * index + k),
                                      config=config, grid=grid).n_pe, np.float64)
            for k in range(pulses)
        ]
        row = {"M": np.mean(charges, axis=0), "J": np.mean(jacobians, axis=0),
               "n": np.mean(counts, axis=0), "M_sets": np.asarray(charges),
               "J_sets": np.asarray(jacobians)}
        rows.append(row)
        print(f"source {index}: expected {row['M'].sum():.0f} p.e., sampled"
              f" {row['n'].sum():.0f} ({time.perf_counter() - began:.0f} s)", flush=True)
    return rows


def cramer_rao_sigma(rows: list[dict]) -> np.ndarray:
    """(4,) Cramer-Rao sigma of the optics of one experiment, efficiencies profiled,
    physical units: the Fisher matrix sum J^T J / M in the per-sensor block structure of
    the calibration (``StructuredMatrix``: a sensor's efficiency e_j has dM/de_j = M_j,
    so its blocks summed over runs are M and J)."""
    a, b, c = 0.0, 0.0, 0.0
    for row in rows:
        mean = np.maximum(row["M"], 1e-6)
        a = a + row["J"].T @ (row["J"] / mean[:, None])
        b, c = b + mean, c + row["J"]
    fisher = StructuredMatrix(a, c[:, None, :], b[:, None, None])
    return np.sqrt(np.diag(fisher.covariance()[0]))


def independent_shift(rows_a: list[dict], rows_b: list[dict]) -> np.ndarray:
    """(4,) shift of the optics (physical units, efficiencies profiled) that n - M puts
    into a fit, with M, J from ray set a and the score's derivatives and weights from an
    independent set b: g = sum J_b^T (n - M_a) / M_b, D = sum J_b^T J_a / M_b, shift =
    D^-1 g. Set b's noise is independent of n - M_a, so E[g] = 0 wherever the two modes
    agree. (The same set for both would not do: a ray that puts extra light into a
    sensor also puts extra slope there, and those correlations add up coherently over
    11,146 sensors and 16 runs; docs/calibration.md, "Ray noise and the independent-ray
    score". At 8 x 4,096 rays they made a shift of -1.2 / +1.2 / +0.3 / +1.1 sigma from
    expected-mode "data" alone.)"""
    a, gradient, c, upper, b, gradient_sensor = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    for row_a, row_b in zip(rows_a, rows_b, strict=True):
        weight = 1.0 / np.maximum(row_b["M"], 1e-6)
        difference = row_a["n"] - row_a["M"]
        a = a + row_b["J"].T @ (row_a["J"] * weight[:, None])
        gradient = gradient + row_b["J"].T @ (difference * weight)
        c = c + row_a["J"]
        upper = upper + row_b["J"] * (row_a["M"] * weight)[:, None]
        b = b + row_a["M"]
        gradient_sensor = gradient_sensor + difference
    newton = StructuredMatrix(a, c[:, None, :], b[:, None, None], upper[:, None, :])
    return newton.solve(gradient, gradient_sensor[:, None])[0]


def optics_shift(rows: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """(shift (4,), Cramer-Rao sigma (4,)) of the optics, physical units: the mean of
    ``independent_shift`` with the even ray keys as set a and the odd ones as set b, and
    the other way round."""
    def ray_set(parity):
        sets = []
        for row in rows:
            charge = row["M_sets"][parity::2].mean(axis=0)
            counts = charge if row["n"] is None else row["n"]  # None: agreement
            sets.append({"n": counts, "M": charge, "J": row["J_sets"][parity::2].mean(axis=0)})
        return sets

    even, odd = ray_set(0), ray_set(1)
    shift = 0.5 * (independent_shift(even, odd) + independent_shift(odd, even))
    return shift, cramer_rao_sigma(rows)


def shift_noise(rows: list[dict], pulses: int, draws: int = 40, seed: int = 0) -> np.ndarray:
    """(4,) standard deviation of ``optics_shift`` (physical units) from the sampled
    counts' Poisson noise (Gaussian draws of variance n / pulses) and the ray noise of
    the expected charges (each set's per-key deviations from its mean, with random
    signs), ``draws`` redraws. The derivatives' own noise is left out: it scales the
    shift rather than moving it."""
    rng = np.random.default_rng(seed)
    sets = [[{"M": row["M_sets"][p::2].mean(axis=0), "J": row["J_sets"][p::2].mean(axis=0)}
             for row in rows] for p in (0, 1)]

    def ray_draw(parity):
        draws_ = []
        for row in rows:
            deviations = row["M_sets"][parity::2] - row["M_sets"][parity::2].mean(axis=0)
            keys = deviations.shape[0]
            signs = rng.choice([-1.0, 1.0], keys)
            draws_.append(signs @ deviations / np.sqrt(keys * (keys - 1)))
        return draws_

    shifts = []
    for _ in range(draws):
        poisson = [rng.normal(0.0, np.sqrt(np.maximum(row["n"], 0.0) / pulses)) for row in rows]
        both = []
        for parity, (own, other) in enumerate((sets, sets[::-1])):
            noise = [p - r for p, r in zip(poisson, ray_draw(parity), strict=True)]
            both.append(independent_shift(
                [{**x, "n": x["M"] + e} for x, e in zip(own, noise, strict=True)], other))
        shifts.append(0.5 * (both[0] + both[1]))
    return np.std(shifts, axis=0)


def main() -> None:
    pulses = int(sys.argv[1]) if len(sys.argv) > 1 else 20
    detector = pf.load_detector("SK")
    truth = pf.default_params(detector).replace(**TRUE_OPTICS)
    config = CONFIG
    if len(sys.argv) > 2:
        changes, bounces = COMPONENTS[sys.argv[2]]
        truth = truth.replace(**changes)
        config = dataclasses.replace(CONFIG, n_bounces=bounces)
        print(f"{sys.argv[2]} only: {changes}, {bounces} bounce(s)")
    sources = campaign_sources(1e6)
    rows = source_rows(detector, truth, sources, pulses, config)
    shift, sigma = optics_shift(rows)
    noise = shift_noise(rows, pulses)
    print("\nshift / sigma, all sources, +- its error (Poisson and the expected mode's rays):")
    for name, s, e, n in zip(OPTICS, shift, sigma, noise, strict=True):
        print(f"  {name:22s} {s / e:+.2f} +- {n / e:.2f}   (shift {s:+.4g}, sigma {e:.4g})")
    print("one source at a time (the others at their expectation):")
    for index in range(len(rows)):
        alone = [row if k == index else {**row, "n": None} for k, row in enumerate(rows)]
        s, _ = optics_shift(alone)
        print(f"  source {index:2d}: " + " ".join(f"{v:+.2f}" for v in s / sigma))


if __name__ == "__main__":
    main()
