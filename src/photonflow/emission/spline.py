"""The spline emission model: C2 tensor-product cubic splines through an emission table.

The table (``generator.emission_tables``) gives, per kinetic energy E_k, the photons per
particle per (distance s, cos(angle) to the initial direction) bin and per (s, time
offset) bin, with s binned from 0 to the energy's light extent S_k. The model works in
the fraction x = s / S(E) of the extent (so a muon's end of track sits at the same x at
every energy and interpolates in energy without blurring) and interpolates

- g = sqrt(d^2N / dx dcos) (photons per particle per unit x per unit cos), so that the
  density g^2 is never negative and the splines ring less at the Cherenkov peak, on
  the bin centres in (log E, x, cos); d^2N / ds dcos = g^2 / S(E), scaled so that it
  integrates to the yield;
- the total yield per particle and the extent S in log E;
- the mean and variance of the emission-time offset (t - s / c, ns) per (E, x);
- the density averaged over a sensor's angular footprint: a sensor disc seen from a
  point of the track covers a range of cos around the cos of its centre, as wide as
  the Cherenkov peak or wider (a 0.254 m disc at 16 m spans +-0.01 in cos, the peak
  ~0.02), so the light it catches is the density averaged over that range, not the
  density at its centre. The footprint's marginal in cos is a semicircle of half-width
  w (``footprint_width``); the model keeps the density averaged over semicircles of
  ``FOOTPRINT_WIDTHS`` (computed from the table's bins, exact for its piecewise-constant
  histogram) and interpolates between them in log2(1 + w / w_0) (Catmull-Rom, C1).

Along log E a natural cubic spline (C2) is linear in the node values, so one energy
reduces the table to a weighted sum of its nodes (``energy_weights``), and the
derivatives of the (s, cos) splines, computed once per node, combine with the same
weights: a track's ``EmissionSlice`` costs one (K,)-weighted sum, and each evaluation a
bicubic Hermite patch. A node of zero light at the Cherenkov threshold (``threshold``,
MeV) makes the light vanish smoothly there; energies are clamped to [threshold, the
largest node] (documented: a traced energy beyond the table does not extrapolate).
Written with ``interpax`` for the spline derivatives; the patch evaluation is here
because it runs on precomputed derivatives combined per track (interpax evaluates one
spline from its values; here a track's derivatives are a weighted sum of the nodes').
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ..generator.emission_tables import EmissionTable
from ..numerics import default_float_dtype
from ..pytree import pytree_dataclass, static_field

#: Smallest nonzero footprint half-width w_0 (in cos) of the averaged densities; the
#: widths are w_0 (2^k - 1), k = 0 ... 9: 0 (the density itself), 0.0025, ..., 1.28.
FOOTPRINT_STEP = 0.0025
FOOTPRINT_WIDTHS = FOOTPRINT_STEP * (2.0 ** np.arange(10) - 1.0)


@pytree_dataclass
class EmissionSlice:
    """The emission model at one energy: splines in (x = s / extent, cos) and in x.

    Attributes:
        fraction: (D,) knots in x (bin centres in [0, 1]).
        cos: (A,) knots in cos(angle to the initial direction).
        root: (W, 4, D, A) sqrt(d^2N / dx dcos) averaged over a footprint of each of the
            W ``FOOTPRINT_WIDTHS`` (the first: the density itself), and its
            derivatives d/dx, d/dcos, d^2/dx dcos at the knots (photons^(1/2) per
            particle).
        cells: (W, D - 1, A - 1, 16) the 16 values of ``root`` that the bicubic patch of
            each knot cell reads (``_cell_blocks``), so that a point reads one block.
        time_mean: (2, D) mean emission-time offset t - s / c (ns) and its d/dx.
        time_variance: (2, D) its variance (ns^2) and d/dx.
        extent: the light's extent S along the initial direction, m.
        scale: factor making the density integrate to ``total_yield`` (per m: 1 / S x
            the yield over the knots' sum).
        total_yield: photons per particle.
    """

    fraction: jax.Array
    cos: jax.Array
    root: jax.Array
    cells: jax.Array
    time_mean: jax.Array
    time_variance: jax.Array
    extent: jax.Array
    scale: jax.Array
    total_yield: jax.Array

    def density(self, s, cos, width=None):
        """d^2N / ds dcos at (s m, cos), photons per particle per m per unit cos; 0
        outside 0 <= s <= extent, the last knots' values beyond the cos knots.
        ``width``: None, or the half-width in cos of a semicircle footprint (broadcasting
        with s and cos) that the density is averaged over (module docstring)."""
        x = s / self.extent
        weights, i, j = _bicubic_weights(self.fraction, self.cos, x, cos)
        if width is None:
            root = jnp.sum(weights * self.cells[0, i, j], axis=-1)
        else:
            root = 0.0
            for weight, layer in _footprint_terms(width, self.cells.shape[0]):
                root = root + weight * jnp.sum(weights * self.cells[layer, i, j], axis=-1)
        return jnp.where((x >= 0.0) & (x <= 1.0), self.scale * root * root, 0.0)

    def fraction_profile(self):
        """(D,) light per unit x at the x knots (the cos knots' cells summed), before
        ``scale``."""
        return jnp.sum(self.root[0, 0] ** 2 * _cell_widths(self.cos), axis=1)

    def cos_profile(self):
        """(A,) light per unit cos at the cos knots (the x knots' cells summed), before
        ``scale``."""
        return jnp.sum(self.root[0, 0] ** 2 * _cell_widths(self.fraction)[:, None], axis=0)

    def time_moments(self, s):
        """(mean ns, variance ns^2) of the emission-time offset t - s / c at s (m)."""
        return time_offset_moments(self, s)


def time_offset_moments(piece, s):
    """(mean ns, variance ns^2) of the emission-time offset at s (m) of a slice with
    ``fraction`` knots, ``extent`` (m) and (value, d/dx) rows ``time_mean`` and
    ``time_variance`` (cubic Hermite in x = s / extent; the variance kept >= 0)."""
    x = s / piece.extent
    mean = _cubic(piece.fraction, piece.time_mean[0], piece.time_mean[1], x)
    variance = _cubic(piece.fraction, piece.time_variance[0], piece.time_variance[1], x)
    return mean, jnp.maximum(variance, 0.0)


class EnergyNodes:
    """The energy axis shared by the emission models: nodes ``log_energy`` (K,) log(MeV)
    (the first the Cherenkov threshold) and ``total_yield`` (K,) photons per particle,
    interpolated by a natural cubic spline in log E."""

    @property
    def energy_range(self) -> tuple[float, float]:
        """(threshold, largest node) kinetic energy, MeV."""
        log_energy = np.asarray(self.log_energy)
        return float(np.exp(log_energy[0])), float(np.exp(log_energy[-1]))

    def energy_weights(self, energy):
        """(K,) weights w_k with f(E) = sum_k w_k f_k for the natural cubic spline in
        log E; E (MeV) clamped to ``energy_range``."""
        return natural_energy_weights(self.log_energy, energy)

    def yield_at(self, energy):
        """Photons per particle at kinetic energy ``energy`` (MeV, clamped)."""
        return jnp.maximum(self.energy_weights(energy) @ self.total_yield, 0.0)


@pytree_dataclass
class SplineEmission(EnergyNodes):
    """A C2 spline model of one emission table (module docstring).

    Attributes:
        log_energy: (K,) log of the knots' kinetic energies, log(MeV); the first is the
            Cherenkov threshold (a node of no light).
        fraction: (D,) knots in x = s / extent.
        cos: (A,) knots in cos.
        root: (K, W, 4, D, A) per energy node: sqrt densities and derivatives
            (``EmissionSlice``).
        time_mean, time_variance: (K, 2, D) per node (``EmissionSlice``).
        extent: (K,) light extent per node, m.
        total_yield: (K,) photons per particle.
        particle: the table's particle (static).
        medium: the table's medium (static).
    """

    log_energy: jax.Array
    fraction: jax.Array
    cos: jax.Array
    root: jax.Array
    time_mean: jax.Array
    time_variance: jax.Array
    extent: jax.Array
    total_yield: jax.Array
    particle: str = static_field(default="mu-")
    medium: str = static_field(default="water")

    def at(self, energy) -> EmissionSlice:
        """The model at kinetic energy ``energy`` (MeV, clamped to ``energy_range``)."""
        weights = self.energy_weights(energy)
        combine = lambda table: jnp.tensordot(weights, table, axes=1)  # noqa: E731
        root = combine(self.root)
        total_yield = jnp.maximum(combine(self.total_yield), 0.0)
        extent = combine(self.extent)
        cell = _cell_widths(self.fraction)[:, None] * _cell_widths(self.cos)[None, :]
        knots_sum = jnp.sum(root[0, 0] * root[0, 0] * cell)
        safe = jnp.where(knots_sum > 0, knots_sum, 1.0)
        return EmissionSlice(
            fraction=self.fraction,
            cos=self.cos,
            root=root,
            cells=_cell_blocks(root),
            time_mean=combine(self.time_mean),
            time_variance=combine(self.time_variance),
            extent=extent,
            scale=jnp.where(knots_sum > 0, total_yield / safe, 0.0) / extent,
            total_yield=total_yield,
        )

    def density(self, energy, s, cos):
        """d^2N / ds dcos (photons per particle per m per unit cos) at one energy (MeV)
        and points (s m, cos)."""
        return self.at(energy).density(s, cos)


def natural_energy_weights(log_energy, energy):
    """(K,) weights w_k with f(E) = sum_k w_k f_k for the natural cubic spline through
    nodes at ``log_energy`` (K,) log(MeV); E (MeV) clamped to the nodes' range."""
    import interpax

    log_e = jnp.clip(jnp.log(jnp.asarray(energy, log_energy.dtype)), log_energy[0],
                     log_energy[-1])
    identity = jnp.eye(log_energy.shape[0], dtype=log_energy.dtype)
    with jax.numpy_dtype_promotion("standard"):  # interpax mixes int and float
        return interpax.interp1d(log_e[None], log_energy, identity, method="cubic2",
                                 extrap=True)[0]


#: Distance bins of the table merged into one knot interval of the model: 100 bins -> 25
#: knots, 4 % of the extent each (a muon's range straggles by ~3-4 %), so the splines
#: in x follow the light's shape, not the table's statistical wiggles, and the
#: direct-light quadrature in angle integrates them accurately.
MERGED_DISTANCE_BINS = 4
#: ... except the first ``UNMERGED_START`` bins, kept single: the light of a track's
#: first metre (the ring's sharp outer edge) changes within a few % of the extent.
UNMERGED_START = 4


def distance_groups(bins: int) -> np.ndarray:
    """Bin indices [g_0 = 0, ..., g_D = bins]: the table's distance bins [g_k, g_k+1)
    that make one knot interval of the model (``UNMERGED_START``,
    ``MERGED_DISTANCE_BINS``)."""
    return np.concatenate([np.arange(UNMERGED_START),
                           np.arange(UNMERGED_START, bins + 1, MERGED_DISTANCE_BINS)])


def spline_emission(table: EmissionTable, threshold: float, dtype=None) -> SplineEmission:
    """Fit the spline model to ``table``; ``threshold``: the particle's Cherenkov threshold
    in the table's medium (kinetic MeV, below the table's first energy); arrays of
    ``dtype`` (default JAX's default float). The table's distance bins are merged by
    ``MERGED_DISTANCE_BINS`` after the first ``UNMERGED_START``."""
    import interpax

    table, fraction, cos, averaged = footprint_densities(table, threshold)
    energies = np.asarray(table.energies, np.float64)
    averaged = np.concatenate([np.zeros_like(averaged[:1]), averaged])
    dtype = default_float_dtype() if dtype is None else np.dtype(dtype)
    fraction, cos, root = (np.asarray(x, dtype) for x in (fraction, cos, np.sqrt(averaged)))
    with jax.numpy_dtype_promotion("standard"):  # interpax mixes int and float
        d_ds = np.asarray(interpax.approx_df(fraction, root, method="cubic2", axis=2))
        d_dcos = np.asarray(interpax.approx_df(cos, root, method="cubic2", axis=3))
        d2 = np.asarray(interpax.approx_df(cos, d_ds, method="cubic2", axis=3))
    mean, variance = _time_moments(table)
    mean = np.concatenate([mean[:1], mean])  # the threshold node emits nothing
    variance = np.concatenate([variance[:1], variance])
    mean, variance = np.asarray(mean, dtype), np.asarray(variance, dtype)
    with jax.numpy_dtype_promotion("standard"):
        times = [np.stack([m, np.asarray(interpax.approx_df(fraction, m, method="cubic2",
                                                            axis=1))], axis=1)
                 for m in (mean, variance)]
    extent = np.asarray(table.distance_edges, np.float64)[:, -1]
    cast = lambda x: jnp.asarray(x, dtype)  # noqa: E731
    return SplineEmission(
        log_energy=cast(np.log(np.concatenate([[threshold], energies]))),
        fraction=cast(fraction),
        cos=cast(cos),
        root=cast(np.stack([root, d_ds, d_dcos, d2], axis=2)),
        time_mean=cast(times[0]),
        time_variance=cast(times[1]),
        extent=cast(np.concatenate([extent[:1], extent])),
        total_yield=cast(np.concatenate([[0.0], table.total_yield])),
        particle=table.particle,
        medium=table.medium,
    )


def footprint_densities(table: EmissionTable, threshold: float):
    """The table as the models fit it: its rows above ``threshold`` (MeV), distance bins
    merged (``distance_groups``); returns (that table, (D,) knots in x = s / extent,
    (A,) knots in cos, (E, W, D, A) photons per particle per unit x per unit cos averaged
    over the footprints of ``FOOTPRINT_WIDTHS``, on the knots)."""
    energies = np.asarray(table.energies, np.float64)
    if not 0.0 < threshold < energies[-1]:
        raise ValueError(f"threshold = {threshold:g} MeV: must lie below the table's last"
                         f" energy {energies[-1]:g} MeV")
    table = _above(table, threshold)  # a scintillator's table starts below it
    bins = table.photons.shape[1]
    groups = distance_groups(bins)
    table = _merge_distance_bins(table, groups)
    fraction = 0.5 * (groups[1:] + groups[:-1]) / bins
    cos = 0.5 * (table.cos_edges[1:] + table.cos_edges[:-1])
    widths = np.outer(np.diff(groups) / bins, np.diff(table.cos_edges))
    density = np.maximum(table.photons, 0.0) / widths  # (E, D, A)
    averaged = np.maximum(
        np.einsum("wab,edb->ewda", _footprint_matrices(table.cos_edges), density), 0.0)
    return table, fraction, cos, averaged


def _footprint_matrices(cos_edges) -> np.ndarray:
    """(W, A, A) matrices M_w with (M_w rho)_j the average over a semicircle of half-width
    ``FOOTPRINT_WIDTHS[w]`` centred on bin centre j of a density constant in each of the
    A bins (``cos_edges``, (A + 1,)); zero beyond the edges. The first is the identity."""
    edges = np.asarray(cos_edges, np.float64)
    centres = 0.5 * (edges[1:] + edges[:-1])
    matrices = [np.eye(centres.size)]
    for width in FOOTPRINT_WIDTHS[1:]:
        y = np.clip((edges[None, :] - centres[:, None]) / width, -1.0, 1.0)
        cumulative = 0.5 + (y * np.sqrt(1.0 - y * y) + np.arcsin(y)) / np.pi  # semicircle CDF
        matrices.append(np.diff(cumulative, axis=1))  # kernel mass in each bin
    return np.stack(matrices)


def _footprint_terms(width, layers: int):
    """(weight, layer) pairs: Catmull-Rom interpolation between the ``layers`` footprint
    widths in t = log2(1 + width / ``FOOTPRINT_STEP``) (C1 in the width; layers beyond
    the ends repeat the end ones)."""
    t = jnp.clip(jnp.log2(1.0 + jnp.maximum(width, 0.0) / FOOTPRINT_STEP), 0.0, layers - 1.0)
    base = jnp.clip(jnp.floor(t), 0.0, layers - 2.0)
    tau = t - base
    k = base.astype(jnp.int32)
    tau2, tau3 = tau * tau, tau * tau * tau
    weights = (0.5 * (-tau3 + 2 * tau2 - tau), 0.5 * (3 * tau3 - 5 * tau2 + 2),
               0.5 * (-3 * tau3 + 4 * tau2 + tau), 0.5 * (tau3 - tau2))
    return [(weight, jnp.clip(k + shift, 0, layers - 1))
            for weight, shift in zip(weights, (-1, 0, 1, 2), strict=True)]


def _merge_distance_bins(table: EmissionTable, groups: np.ndarray) -> EmissionTable:
    """``table`` with its distance bins summed into the groups [groups[k], groups[k+1])
    (``groups``: increasing bin indices from 0 to the number of bins)."""
    bins = table.photons.shape[1]
    if groups[0] != 0 or groups[-1] != bins or np.any(np.diff(groups) <= 0):
        raise ValueError(f"distance groups {groups.tolist()} do not partition {bins} bins")

    def merged(array):
        return np.add.reduceat(array, groups[:-1], axis=1)

    return dataclasses.replace(
        table,
        distance_edges=table.distance_edges[:, groups],
        photons=merged(table.photons),
        time_offsets=merged(table.time_offsets),
        offset_sums=merged(table.offset_sums),
    )


def _above(table: EmissionTable, threshold: float) -> EmissionTable:
    """``table`` without its energies at or below ``threshold`` (MeV): rows of no
    Cherenkov light."""
    keep = np.asarray(table.energies) > threshold
    if keep.all():
        return table
    rows = {name: getattr(table, name)[keep] for name in (
        "energies", "distance_edges", "photons", "time_offsets", "offset_sums",
        "total_yield", "yield_spread", "track_length", "particles", "yield_error",
        "angular_error")}
    return dataclasses.replace(table, **rows)


def _time_moments(table: EmissionTable) -> tuple[np.ndarray, np.ndarray]:
    """(E, D) mean and variance of the emission-time offset per distance bin (ns, ns^2),
    from the table's exact sums (``offset_moments``)."""
    return offset_moments(table.photons.sum(axis=2), table.offset_sums)


def offset_moments(weight, sums) -> tuple[np.ndarray, np.ndarray]:
    """(E, D) mean and variance (ns, ns^2) of a time offset from the (E, D) ``weight`` of
    each distance bin and the (E, D, 2) sums of weight x offset and weight x offset^2;
    bins of no weight take the nearest weighted bin's values along s."""
    safe = np.where(weight > 0, weight, 1.0)
    mean = sums[..., 0] / safe
    variance = sums[..., 1] / safe - mean**2
    for row in range(weight.shape[0]):
        lit = np.flatnonzero(weight[row] > 0)
        if lit.size == 0:
            continue
        nearest = lit[np.argmin(np.abs(np.arange(weight.shape[1])[:, None] - lit), axis=1)]
        mean[row], variance[row] = mean[row, nearest], variance[row, nearest]
    return mean, np.maximum(variance, 0.0)


def _cell_widths(knots):
    """Width of the cell around each knot (midpoints between knots; the end cells reach
    as far beyond the end knots as half their neighbouring interval)."""
    gaps = knots[1:] - knots[:-1]
    return 0.5 * (jnp.concatenate([gaps[:1], gaps]) + jnp.concatenate([gaps, gaps[-1:]]))


def _locate(knots, x):
    """Index i of the interval [knots[i], knots[i+1]] holding x (clamped) and t in [0, 1]
    (beyond the ends t extrapolates linearly: callers clamp or mask)."""
    i = jnp.clip(jnp.searchsorted(knots, x, side="right") - 1, 0, knots.shape[0] - 2)
    h = knots[i + 1] - knots[i]
    return i, (x - knots[i]) / h, h


def _hermite(t):
    """Cubic Hermite basis (h00, h10, h01, h11) at t."""
    t2, t3 = t * t, t * t * t
    return 2 * t3 - 3 * t2 + 1, t3 - 2 * t2 + t, -2 * t3 + 3 * t2, t3 - t2


def _cubic(knots, values, slopes, x):
    """Cubic Hermite interpolation of (values, slopes) at x (clamped to the knots)."""
    x = jnp.clip(x, knots[0], knots[-1])
    i, t, h = _locate(knots, x)
    h00, h10, h01, h11 = _hermite(t)
    return h00 * values[i] + h10 * h * slopes[i] + h01 * values[i + 1] + h11 * h * slopes[i + 1]


#: The 16 (corner along x, derivative along x, corner along y, derivative along y) of a
#: bicubic Hermite patch, in the order of a cell block; derivative index dx + dy picks
#: f, df/dx (1), df/dy (2) or d2f/dxdy (3).
_PATCH = [(cx, dx, cy, dy) for cx, dx in ((0, 0), (0, 1), (1, 0), (1, 1))
          for cy, dy in ((0, 0), (0, 2), (1, 0), (1, 2))]


def _cell_blocks(root):
    """(W, X - 1, Y - 1, 16) blocks of the (W, 4, X, Y) ``root``: for each knot cell, the
    values and derivatives at its 4 corners in ``_PATCH`` order."""
    x, y = root.shape[2] - 1, root.shape[3] - 1
    return jnp.stack([root[:, dx + dy, cx:cx + x, cy:cy + y] for cx, dx, cy, dy in _PATCH],
                     axis=-1)


def _bicubic_weights(x_knots, y_knots, x, y):
    """Weights (..., 16) of a cell block's entries (``_PATCH`` order) in the bicubic
    Hermite patch at (x, y) (clamped to the knots), and the cell (i, j)."""
    x = jnp.clip(x, x_knots[0], x_knots[-1])
    y = jnp.clip(y, y_knots[0], y_knots[-1])
    i, u, hx = _locate(x_knots, x)
    j, v, hy = _locate(y_knots, y)
    bx, by = _hermite(u), _hermite(v)
    along_x = {(0, 0): bx[0], (0, 1): bx[1] * hx, (1, 0): bx[2], (1, 1): bx[3] * hx}
    along_y = {(0, 0): by[0], (0, 2): by[1] * hy, (1, 0): by[2], (1, 2): by[3] * hy}
    return jnp.stack([along_x[(cx, dx)] * along_y[(cy, dy)] for cx, dx, cy, dy in _PATCH],
                     axis=-1), i, j
