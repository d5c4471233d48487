"""1-D scans of the event likelihood of one sampled track along each track parameter
(issue 24, "Smoothness"):

    python studies/tracks/likelihood_scans.py [--energy 1000] [--particle mu-]
        [--points 41] [--plot docs/figures/track-likelihood-scans.png]

One event of generator + sampled transport (SK, water defaults, a muon from (1, -2, 0.5)
m along (0.6, 0.8, 0)); ``nll`` (charge + first-hit time) of the expected mode along
x, y, z (+-2 m), t (+-10 ns), the polar and azimuthal angles (+-10 degrees) and the
energy (+-30 %), every other parameter at the truth, the indirect light's rays fixed by
the true track (``reference``). Prints each scan's minimum against the truth.
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

import photonflow as pf

NAMES = ("x (m)", "y (m)", "z (m)", "t (ns)", "theta (deg)", "phi (deg)", "E / E_true")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particle", default="mu-")
    parser.add_argument("--energy", type=float, default=1000.0)
    parser.add_argument("--points", type=int, default=41)
    parser.add_argument("--plot", default=None)
    args = parser.parse_args()
    detector = pf.load_detector("SK")
    params = pf.default_params(detector)
    direction = np.array([0.6, 0.8, 0.0])
    truth = pf.Track(args.particle, [1.0, -2.0, 0.5], direction, args.energy, 0.0)
    event = pf.sample(detector, params, truth, seed=7)
    predict = pf.expected_function(detector, config=pf.TransportConfig(n_rays=1024))
    theta0, phi0 = np.arccos(direction[2]), np.arctan2(direction[1], direction[0])

    def track_of(x):
        direction = jnp.stack([jnp.sin(x[4]) * jnp.cos(x[5]), jnp.sin(x[4]) * jnp.sin(x[5]),
                               jnp.cos(x[4])])
        return pf.Track(args.particle, x[:3], direction, args.energy * x[6], x[3])

    loss = jax.jit(lambda x: pf.nll(predict(params, track_of(x), None, truth), event))
    centre = np.array([1.0, -2.0, 0.5, 0.0, theta0, phi0, 1.0])
    spans = np.array([2.0, 2.0, 2.0, 10.0, np.radians(10), np.radians(10), 0.3])
    scans = []
    for k in range(7):
        offsets = np.linspace(-spans[k], spans[k], args.points)
        values = []
        for offset in offsets:
            x = centre.copy()
            x[k] += offset
            values.append(float(loss(jnp.asarray(x, jnp.float32))))
        values = np.array(values) - min(values)
        shown = np.degrees(offsets) if k in (4, 5) else offsets
        scans.append((shown, values))
        step = shown[1] - shown[0]
        print(f"{NAMES[k]:12s} minimum at {shown[np.argmin(values)]:+.3g} from the truth "
              f"(grid step {step:.3g}); nll rise at the ends {values[0]:.0f} / {values[-1]:.0f}")
    if args.plot:
        _plot(scans, args.plot)


def _plot(scans, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(2, 4, figsize=(13, 6))
    for axis, name, (offsets, values) in zip(axes.flat, NAMES, scans, strict=False):
        axis.plot(offsets, values, ".-", ms=3)
        axis.axvline(0.0, color="0.6", lw=0.8)
        axis.set(xlabel=f"{name} - truth" if "E /" not in name else "E / E_true - 1",
                 ylabel="nll - min")
    axes.flat[-1].axis("off")
    figure.tight_layout()
    figure.savefig(path, dpi=100)


if __name__ == "__main__":
    main()
