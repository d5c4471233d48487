"""Sampled against expected mode at SK scale (too heavy for the test suite; ~2 min).

``python studies/transport/sk_consistency.py [n_bounces]``: SK, an isotropic source of 10^6
photons at the centre, float32; for each optics configuration the total expected p.e.
(mean over 4 ray keys at 4,096 rays) against the total detected photons of 10 sampled
pulses (``sample_photons``: no response, no dark noise), with the difference and its
statistical error. The toy-detector tests (tests/test_consistency.py) agree per sensor;
this checks the same at full scale, where float32 and the real geometry matter.
"""

import sys

import jax
import jax.numpy as jnp
import numpy as np

from photonflow.config import load_setup
from photonflow.sources import IsotropicSource
from photonflow.transport.expected import expected
from photonflow.transport.optics import TransportConfig
from photonflow.transport.sampled import sample_photons

CONFIGURATIONS = {
    "direct only": dict(scattering_length=1e9, wall_reflectivity=0.0, sensor_reflectivity=0.0),
    "scattering": dict(wall_reflectivity=0.0, sensor_reflectivity=0.0),
    "diffuse wall": dict(scattering_length=1e9, sensor_reflectivity=0.0,
                         wall_specular_fraction=0.0),
    "glass": dict(scattering_length=1e9, wall_reflectivity=0.0),
    "diffuse wall + glass": dict(scattering_length=1e9, wall_specular_fraction=0.0),
    "all (defaults)": {},
}


def main() -> None:
    n_bounces = int(sys.argv[1]) if len(sys.argv) > 1 else 2
    setup = load_setup("SK")
    detector, params = setup.detector, setup.params
    source = IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=1e6)
    config = TransportConfig(n_bounces=n_bounces, n_rays=4096)
    print(f"SK, centre, {n_bounces} bounces\n")
    print("| optics | expected p.e. | sampled p.e. | difference |")
    print("|---|---:|---:|---:|")
    for label, changes in CONFIGURATIONS.items():
        p = params.replace(**{k: jnp.float32(v) for k, v in changes.items()})
        exp = [float(np.sum(expected(detector, p, source, config=config,
                                     key=jax.random.key(k)).charge)) for k in range(4)]
        smp = [sample_photons(detector, p, source, jax.random.key(200 + k),
                              config=config).n_pe.sum() for k in range(10)]
        error = np.hypot(np.std(smp, ddof=1) / np.sqrt(len(smp)),
                         np.std(exp, ddof=1) / np.sqrt(len(exp)))
        print(f"| {label} | {np.mean(exp):.0f} | {np.mean(smp):.0f} |"
              f" {np.mean(smp) - np.mean(exp):+.0f} +- {error:.0f} |", flush=True)


if __name__ == "__main__":
    main()
