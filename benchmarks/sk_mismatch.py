"""Sampled against expected mode on SK, seen through the calibration (~8 min).

``python benchmarks/sk_mismatch.py [pulses] [component]``: for the 16 sources of the SK campaign
(``examples/calibration/sk_joint.py``: a downward laser and 15 isotropic flashes of 10^6
photons) at its true optics, the per-sensor mean photoelectrons of ``pulses`` sampled
pulses (default 20) against the expected mode (8 ray keys x 4,096 rays, averaged), and
the shift that the difference puts into a fit of the four optical parameters with every
sensor's efficiency free:

    shift = (J^T W J)^-1 J^T W (n_sampled - M_expected),  W = diag(1 / M),

J the derivatives of M in the optics (and in each sensor's efficiency, profiled out by
the Schur complement). Printed in units of the Cramer-Rao sigma of one experiment, with
its statistical error 1/sqrt(pulses), for all sources together and one source at a time.
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
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import photonflow as pf
from photonflow.calibration.structured import StructuredMatrix
from photonflow.transport.expected import expected
from photonflow.transport.optics import TransportConfig
from photonflow.transport.sampled import grid_for, sample_photons

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples" / "calibration"))
from sk_joint import OPTICS, TRUE_OPTICS, campaign_sources  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sk_components import COMPONENTS  # noqa: E402

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
               "n": np.mean(counts, axis=0)}
        rows.append(row)
        print(f"source {index}: expected {row['M'].sum():.0f} p.e., sampled"
              f" {row['n'].sum():.0f} ({time.perf_counter() - began:.0f} s)", flush=True)
    return rows


def optics_shift(rows: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """(shift (4,), sigma (4,)) of the optics, efficiencies profiled, physical units:
    the weighted normal equations in the per-sensor block structure of the calibration
    (``StructuredMatrix``: a sensor's efficiency e_j has dM/de_j = M_j, so its blocks
    summed over runs are M, J and n - M)."""
    a, gradient = 0.0, 0.0
    b, c, gradient_sensor = 0.0, 0.0, 0.0
    for row in rows:
        mean = np.maximum(row["M"], 1e-6)
        difference = row["n"] - row["M"]
        a = a + row["J"].T @ (row["J"] / mean[:, None])
        gradient = gradient + row["J"].T @ (difference / mean)
        b, c = b + mean, c + row["J"]
        gradient_sensor = gradient_sensor + difference
    normal = StructuredMatrix(a, c[:, None, :], b[:, None, None])
    shift, _ = normal.solve(gradient, gradient_sensor[:, None])
    return shift, np.sqrt(np.diag(normal.covariance()[0]))


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
    sources = campaign_sources(detector, 1e6)
    rows = source_rows(detector, truth, sources, pulses, config)
    shift, sigma = optics_shift(rows)
    print(f"\nshift / sigma, all sources (statistical error {1 / np.sqrt(pulses):.2f}):")
    for name, s, e in zip(OPTICS, shift, sigma, strict=True):
        print(f"  {name:22s} {s / e:+.2f}   (shift {s:+.4g}, sigma {e:.4g})")
    print("one source at a time (the others at their expectation):")
    for index in range(len(rows)):
        alone = [row if k == index else {**row, "n": row["M"]} for k, row in enumerate(rows)]
        s, _ = optics_shift(alone)
        print(f"  source {index:2d}: " + " ".join(f"{v:+.2f}" for v in s / sigma))


if __name__ == "__main__":
    main()
