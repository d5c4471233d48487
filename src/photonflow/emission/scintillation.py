"""The scintillation emission model: a track's isotropic light from its visible energy.

A scintillator turns a charged particle's Birks-quenched energy deposit into
``light_yield`` photons per MeV, emitted isotropically where the energy is deposited, at
the deposit's time plus an exponential delay (decay times ``decay_times`` ns with
weights ``decay_weights``; the rise time is neglected, as in the generator,
``generator.scintillation``). The emission tables of a scintillating medium hold, per
kinetic energy, the mean visible energy per distance bin along the initial direction and
its time-offset moments (``EmissionTable.visible_energy``); this module interpolates
them as the Cherenkov spline model does (``spline``): sqrt(dE_vis / dx) by C2 cubic
splines in the fraction x = s / S(E) of the light's extent (distance bins merged as in
``spline``), a natural cubic spline in log E for everything per energy, and the
time-offset mean and variance per (E, x).

Below the table's first energy E_0 one more node at E_0 / 10 carries the first node's
profile with a tenth of its visible energy (the quenched light of a stopping particle is
close to proportional to its energy there); energies are clamped to [E_0 / 10, the
largest node]. A ``ScintillationSlice`` has the interface of the Cherenkov
``EmissionSlice`` (density per m per unit cos, uniform in cos; profiles; time moments
before the decay delay), so the direct-light quadrature (``transport.track_direct``)
and the track's rays (``transport.track_rays``) take either. Lengths m, times ns,
energies MeV.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..generator.emission_tables import EmissionTable
from ..generator.materials import resolve_material
from ..numerics import default_float_dtype
from ..pytree import pytree_dataclass, static_field
from .spline import (
    _cell_widths,
    _cubic,
    distance_groups,
    natural_energy_weights,
    offset_moments,
    time_offset_moments,
)

#: The extra node below the table's first energy, as a fraction of it.
LOW_NODE_FRACTION = 0.1


@pytree_dataclass
class ScintillationSlice:
    """Isotropic scintillation light of one energy (the ``EmissionSlice`` interface).

    Attributes:
        fraction: (D,) knots in x = s / extent.
        cos: (2,) the ends of cos (-1, 1): the light is uniform in cos.
        root: (2, D) sqrt(dN / dx) at the knots (photons^(1/2) per particle per unit x,
            before ``scale``) and its d/dx.
        time_mean: (2, D) mean emission-time offset t - s / c before the decay delay
            (ns) and its d/dx; time_variance: (2, D) its variance (ns^2) and d/dx.
        extent: the light's extent S along the initial direction, m.
        scale: factor making the density integrate to ``total_yield``.
        total_yield: photons per particle.
    """

    fraction: jax.Array
    cos: jax.Array
    root: jax.Array
    time_mean: jax.Array
    time_variance: jax.Array
    extent: jax.Array
    scale: jax.Array
    total_yield: jax.Array

    def _profile(self, x):
        root = _cubic(self.fraction, self.root[0], self.root[1], x)
        return jnp.where((x >= 0.0) & (x <= 1.0), root * root, 0.0)

    def density(self, s, cos, width=None):
        """d^2N / ds dcos at (s m, cos): photons per particle per m per unit cos, the same
        for every cos (``width``, a footprint to average over, changes nothing)."""
        value = 0.5 * self.scale * self._profile(s / self.extent)
        return jnp.broadcast_to(value, jnp.broadcast_shapes(value.shape, jnp.shape(cos)))

    def fraction_profile(self):
        """(D,) light per unit x at the x knots, before ``scale``."""
        return self.root[0] ** 2

    def cos_profile(self):
        """(2,) light per unit cos at cos = -1 and 1 (uniform), before ``scale``."""
        total = jnp.sum(self.root[0] ** 2 * _cell_widths(self.fraction))
        return jnp.full(2, 0.5 * total, total.dtype)

    def time_moments(self, s):
        """(mean ns, variance ns^2) of the emission-time offset t - s / c at s (m),
        before the decay delay."""
        return time_offset_moments(self, s)


@pytree_dataclass
class ScintillationModel:
    """Spline model of a scintillator's visible energy deposit (module docstring).

    Attributes:
        log_energy: (K,) log of the nodes' kinetic energies, log(MeV).
        fraction: (D,) knots in x.
        root: (K, 2, D) sqrt(dE_vis / dx) (MeV^(1/2)) and its d/dx per node.
        time_mean, time_variance: (K, 2, D) time-offset moments and their d/dx per node.
        extent: (K,) the light's extent per node, m.
        visible: (K,) visible energy per particle, MeV (all of it: the light deposited
            beyond the distance range is spread over the range's profile).
        light_yield: photons per MeV of visible energy (static).
        decay_times: decay constants, ns; decay_weights: their shares (static).
    """

    log_energy: jax.Array
    fraction: jax.Array
    root: jax.Array
    time_mean: jax.Array
    time_variance: jax.Array
    extent: jax.Array
    visible: jax.Array
    light_yield: float = static_field(default=0.0)
    decay_times: tuple[float, ...] = static_field(default=())
    decay_weights: tuple[float, ...] = static_field(default=())

    @property
    def energy_range(self) -> tuple[float, float]:
        """(lowest, largest node) kinetic energy, MeV."""
        log_energy = np.asarray(self.log_energy)
        return float(np.exp(log_energy[0])), float(np.exp(log_energy[-1]))

    def visible_at(self, energy):
        """Visible (Birks-quenched) energy per particle at kinetic ``energy``, MeV."""
        return jnp.maximum(natural_energy_weights(self.log_energy, energy) @ self.visible, 0.0)

    def at(self, energy) -> ScintillationSlice:
        """The model at kinetic energy ``energy`` (MeV, clamped to ``energy_range``)."""
        weights = natural_energy_weights(self.log_energy, energy)
        combine = lambda table: jnp.tensordot(weights, table, axes=1)  # noqa: E731
        root = combine(self.root)
        extent = combine(self.extent)
        total_yield = self.light_yield * jnp.maximum(combine(self.visible), 0.0)
        knots_sum = jnp.sum(root[0] ** 2 * _cell_widths(self.fraction))
        safe = jnp.where(knots_sum > 0, knots_sum, 1.0)
        dtype = self.fraction.dtype
        return ScintillationSlice(
            fraction=self.fraction,
            cos=jnp.asarray([-1.0, 1.0], dtype),
            root=root,
            time_mean=combine(self.time_mean),
            time_variance=combine(self.time_variance),
            extent=extent,
            scale=jnp.where(knots_sum > 0, total_yield / safe, 0.0) / extent,
            total_yield=total_yield,
        )


def scintillation_model(table: EmissionTable, dtype=None) -> ScintillationModel:
    """Fit the scintillation model to a scintillating medium's ``table`` (arrays of
    ``dtype``, default JAX's default float).

    Raises:
        ValueError: the table holds no visible energy (not a scintillator's).
    """
    import interpax

    if not table.scintillating:
        raise ValueError(f"the {table.particle} table in {table.medium} holds no visible energy")
    material = resolve_material(table.medium)
    bins = table.visible_energy.shape[1]
    groups = distance_groups(bins)
    visible = np.add.reduceat(np.maximum(table.visible_energy, 0.0), groups[:-1], axis=1)
    sums = np.add.reduceat(table.visible_offset_sums, groups[:-1], axis=1)
    fraction = 0.5 * (groups[1:] + groups[:-1]) / bins
    density = visible / (np.diff(groups) / bins)  # MeV per unit x, (E, D)
    density = np.concatenate([LOW_NODE_FRACTION * density[:1], density])
    mean, variance = offset_moments(visible, sums)
    mean, variance = (np.concatenate([x[:1], x]) for x in (mean, variance))
    energies = np.asarray(table.energies, np.float64)
    extent = np.asarray(table.distance_edges, np.float64)[:, -1]
    dtype = default_float_dtype() if dtype is None else np.dtype(dtype)
    fraction = np.asarray(fraction, dtype)

    def with_slope(values):
        values = np.asarray(values, dtype)
        with jax.numpy_dtype_promotion("standard"):  # interpax mixes int and float
            slope = np.asarray(interpax.approx_df(fraction, values, method="cubic2", axis=1))
        return np.stack([values, slope], axis=1)

    cast = lambda x: jnp.asarray(x, dtype)  # noqa: E731
    total = np.asarray(table.visible_total, np.float64)  # in or out of the range
    return ScintillationModel(
        log_energy=cast(np.log(np.concatenate([[LOW_NODE_FRACTION * energies[0]], energies]))),
        fraction=cast(fraction),
        root=cast(with_slope(np.sqrt(density))),
        time_mean=cast(with_slope(mean)),
        time_variance=cast(with_slope(variance)),
        extent=cast(np.concatenate([extent[:1], extent])),
        visible=cast(np.concatenate([[LOW_NODE_FRACTION * total[0]], total])),
        light_yield=float(material.light_yield),
        decay_times=tuple(float(t) for t in material.decay_times),
        decay_weights=tuple(float(w) / float(np.sum(material.decay_weights))
                            for w in material.decay_weights),
    )
