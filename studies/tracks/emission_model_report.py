"""Fit quality of the emission models against their table (issue 24, item 3):

    python studies/tracks/emission_model_report.py [--particle mu-] [--model spline|siren]
        [--plot FILE.png]

- yield: the model's total yield at each energy node when that node is left out of the
  fit (leave-one-out: the interpolation error between nodes), relative to the table's
  yield and in units of its standard error (at the nodes themselves the spline passes
  through the table's yields exactly; the SIREN model shares the spline's yield, and
  its network's own normalisation error is ``photonflow tables train``'s report);
- angular profile: the model's photons per cos bin (density integrated over s and the
  bin) against the table's, chi2 per bin with the table's standard errors, over the bins
  holding 99 % of the light;
- the derivatives of the yield in log E and of the density in cos at the Cherenkov peak
  (plot), and the time of one density evaluation at 10^6 points (float32, jit).
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

from photonflow.emission import emission_model, spline_emission
from photonflow.emission.models import threshold_energy
from photonflow.generator import emission_tables as tables


def _without(table, k):
    """``table`` without energy node k."""
    keep = np.arange(table.energies.size) != k
    fields = {f.name: getattr(table, f.name) for f in dataclasses.fields(table)}
    for name, value in fields.items():
        if isinstance(value, np.ndarray) and value.shape[:1] == table.energies.shape \
                and name != "cos_edges":
            fields[name] = value[keep]
    return dataclasses.replace(table, **{k_: v for k_, v in fields.items()
                                         if isinstance(v, np.ndarray)})


def _profile(piece, extent, cos_edges, s_points, per_bin):
    """Photons per cos bin of one ``EmissionSlice`` (trapezoids on a fine grid)."""
    s = np.linspace(0.0, extent, s_points)
    cos = np.concatenate([np.linspace(lo, hi, per_bin) for lo, hi in
                          zip(cos_edges[:-1], cos_edges[1:], strict=True)])
    grid_s, grid_c = np.meshgrid(s, cos, indexing="ij")
    density = np.asarray(piece.density(jnp.asarray(grid_s), jnp.asarray(grid_c)), float)
    along = np.trapezoid(density, s, axis=0).reshape(-1, per_bin)
    return np.trapezoid(along, cos.reshape(-1, per_bin), axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particle", default="mu-")
    parser.add_argument("--model", default="spline", choices=["spline", "siren"])
    parser.add_argument("--s-points", type=int, default=801,
                        help="points along s of the profile's trapezoids")
    parser.add_argument("--per-bin", type=int, default=7,
                        help="points per cos bin of the profile's trapezoids")
    parser.add_argument("--plot", default=None)
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    table = tables.shipped_table(args.particle)
    threshold = threshold_energy(args.particle, "water")
    model = emission_model(args.particle, "water", np.float64, kind=args.model)
    rows = []
    for k, energy in enumerate(table.energies):
        inner = 0 < k < table.energies.size - 1
        if inner:
            left_out = spline_emission(_without(table, k), threshold, np.float64)
            loo = float(left_out.yield_at(energy)) / table.total_yield[k] - 1.0
        else:
            loo = np.nan
        piece = model.at(float(energy))
        profile = _profile(piece, float(table.distance_edges[k, -1]), table.cos_edges,
                           args.s_points, args.per_bin)
        reference = table.photons[k].sum(axis=0)
        error = np.maximum(table.angular_error[k], 1e-12)
        order = np.argsort(reference)[::-1]
        main = order[: np.searchsorted(np.cumsum(reference[order]), 0.99 * reference.sum()) + 1]
        chi2 = float(np.mean(((profile - reference)[main] / error[main]) ** 2))
        rows.append((energy, loo, loo * table.total_yield[k] / table.yield_error[k], chi2,
                     profile.sum() / table.total_yield[k] - 1.0))
    print(f"{args.particle}, {args.model} model: {table.energies.size} energies, "
          f"{int(table.particles.sum())} particles")
    print("| E MeV | yield, node left out | in table errors | profile chi2/bin (99 % of light)"
          " | profile integral - yield |")
    print("|---:|---:|---:|---:|---:|")
    for energy, loo, pull, chi2, integral in rows:
        print(f"| {energy:.4g} | {loo:+.3%} | {pull:+.1f} | {chi2:.2f} | {integral:+.3%} |")
    loo = np.array([r[1] for r in rows])
    print(f"leave-one-out yield error: median |.| {np.nanmedian(np.abs(loo)):.3%}, "
          f"max |.| {np.nanmax(np.abs(loo)):.3%}")
    print(f"profile chi2/bin: median {np.median([r[3] for r in rows]):.2f}, "
          f"max {np.max([r[3] for r in rows]):.2f}")

    jax.config.update("jax_enable_x64", False)
    fast = emission_model(args.particle, "water", np.float32, kind=args.model).at(1000.0)
    points = jnp.asarray(np.random.default_rng(0).uniform([0, 0.5], [3, 0.95], (10**6, 2)),
                         jnp.float32)
    plain = jax.jit(lambda p: fast.density(p[:, 0], p[:, 1]))
    wide = jax.jit(lambda p: fast.density(p[:, 0], p[:, 1], jnp.full(p.shape[0], 0.01)))
    for name, function in (("density", plain), ("density over a footprint", wide)):
        function(points).block_until_ready()
        times = []
        for _ in range(5):
            began = time.perf_counter()
            function(points).block_until_ready()
            times.append(time.perf_counter() - began)
        print(f"{name}: {np.median(times) * 1e3:.0f} ns per point (10^6 points, float32)")
    if args.plot:
        _plot(model, args.plot)


def _plot(model, path):
    """Yield derivative in log E and density derivative in cos at the peak, per energy."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    low, high = model.energy_range
    energies = np.geomspace(low * 1.001, high, 800)
    slope = jax.vmap(jax.grad(lambda e: jnp.log(model.yield_at(jnp.exp(e)))))(
        jnp.log(jnp.asarray(energies)))
    figure, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    left.plot(energies, np.asarray(slope))
    for log_e in np.asarray(model.log_energy):
        left.axvline(np.exp(log_e), color="0.85", lw=0.5)
    left.set(xscale="log", yscale="log", xlabel="kinetic energy (MeV)",
             ylabel="d ln(yield) / d ln E")
    cos = np.linspace(0.6, 0.9, 1200)
    for energy in (0.5 * (low + high) / 10, 1000.0, high):
        piece = model.at(energy)
        s = 0.3 * float(piece.extent)
        derivative = jax.vmap(jax.grad(lambda c, p=piece, s=s: p.density(s, c)))(jnp.asarray(cos))
        right.plot(cos, np.asarray(derivative), label=f"{energy:.0f} MeV, s = {s:.2f} m")
    right.set(xlabel="cos(angle to the track)", ylabel="d rho / d cos (per m per unit cos^2)")
    right.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
