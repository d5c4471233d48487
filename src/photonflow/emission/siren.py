"""The SIREN emission model: a sinusoidal network for the density of Cherenkov light.

A SIREN (a multilayer perceptron with sine activations, Sitzmann et al. 2020,
arXiv:2006.09661) is smooth in every input (C-infinity) and, unlike a ReLU network,
represents sharp features such as the Cherenkov peak with few parameters. Here it learns
the shape of a particle's light over (log E, footprint width, x = s / extent, cos):

    h(z) ~ sqrt(rho_x(x, cos; E, w) / Y(E)),

the square root of the table's density per unit x per unit cos averaged over a
footprint of half-width w (as the spline model's layers, ``spline.FOOTPRINT_WIDTHS``),
per photon of the total yield Y. The inputs are scaled to [-1, 1]: log E over
[log threshold, log of the top node], t = log2(1 + w / w_0) over the footprint layers,
x over [0, 1], cos as it is. The one-dimensional parts stay the spline model's natural
cubic splines in log E (the yield, the extent, the emission-time moments per x): they
pass through the table's values exactly, and a network would only add error there. At
one energy, ``SirenSlice.density`` = Y / S x h^2 / (the sum of h^2 over the knot
cells), so that the density integrates to the yield on the same knot grid as the
spline's. Trained by ``photonflow tables train`` (``emission.training``); the weights of
the shipped models are in the package (``siren_<particle>_<medium>.eqx``).
Lengths m, energies MeV (kinetic).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp

from ..pytree import pytree_dataclass, static_field
from .spline import (
    FOOTPRINT_STEP,
    FOOTPRINT_WIDTHS,
    EnergyNodes,
    SplineEmission,
    _cell_widths,
    time_offset_moments,
)

#: Inputs of the network: (log E, footprint, x, cos), each scaled to [-1, 1].
INPUTS = 4


class Siren(eqx.Module):
    """A SIREN: ``depth`` hidden layers sin(omega (W z + b)) of ``width`` units and a
    linear output unit (initialised as in Sitzmann et al. 2020: the first layer's
    weights uniform in +-1 / inputs, the others' in +-sqrt(6 / width) / omega); float32
    weights, cast to the inputs' dtype when called."""

    weights: tuple
    biases: tuple
    omega: float = eqx.field(static=True)

    def __init__(self, width: int, depth: int, omega: float, key):
        sizes = [INPUTS] + [width] * depth + [1]
        weights, biases = [], []
        for layer, (fan_in, fan_out) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
            key, weight_key, bias_key = jax.random.split(key, 3)
            bound = 1.0 / fan_in if layer == 0 else math.sqrt(6.0 / fan_in) / omega
            weights.append(jax.random.uniform(weight_key, (fan_in, fan_out), jnp.float32,
                                              minval=-bound, maxval=bound))
            reach = 1.0 / math.sqrt(fan_in)
            biases.append(jax.random.uniform(bias_key, (fan_out,), jnp.float32,
                                             minval=-reach, maxval=reach))
        self.weights, self.biases, self.omega = tuple(weights), tuple(biases), float(omega)

    def __call__(self, z):
        """h at inputs z (..., ``INPUTS``) scaled to [-1, 1]: (...)."""
        for weight, bias in zip(self.weights[:-1], self.biases[:-1], strict=True):
            z = jnp.sin(self.omega * (z @ weight.astype(z.dtype) + bias.astype(z.dtype)))
        return (z @ self.weights[-1].astype(z.dtype) + self.biases[-1].astype(z.dtype))[..., 0]


def footprint_input(width, dtype):
    """The network's footprint input (in [-1, 1]) for a footprint half-width ``width``
    in cos (None: 0, the density itself)."""
    if width is None:
        return jnp.asarray(-1.0, dtype)
    t = jnp.log2(1.0 + jnp.maximum(width, 0.0) / FOOTPRINT_STEP)
    return 2.0 * jnp.clip(t / (FOOTPRINT_WIDTHS.size - 1.0), 0.0, 1.0) - 1.0


def energy_input(log_energy, energy):
    """The network's energy input (in [-1, 1]) at kinetic ``energy`` (MeV, clamped to the
    range of the knots ``log_energy``, log MeV)."""
    log_e = jnp.clip(jnp.log(jnp.asarray(energy, log_energy.dtype)), log_energy[0],
                     log_energy[-1])
    return 2.0 * (log_e - log_energy[0]) / (log_energy[-1] - log_energy[0]) - 1.0


@pytree_dataclass
class SirenSlice:
    """The SIREN model at one energy; the interface of ``spline.EmissionSlice``.

    Attributes:
        network: the ``Siren``.
        energy: the network's energy input (in [-1, 1]).
        fraction: (D,) knots in x. cos: (A,) knots in cos (the quadratures' grid).
        grid: (D, A) h^2 on the knots (no footprint), which normalises the density and
            gives the profiles.
        time_mean, time_variance: (2, D) emission-time offset moments and their d/dx
            (ns, ns^2; ``spline.time_offset_moments``).
        extent: the light's extent S, m. scale: Y / S over the knot sum of h^2, per m.
        total_yield: photons per particle.
    """

    network: Siren
    energy: jax.Array
    fraction: jax.Array
    cos: jax.Array
    grid: jax.Array
    time_mean: jax.Array
    time_variance: jax.Array
    extent: jax.Array
    scale: jax.Array
    total_yield: jax.Array

    def density(self, s, cos, width=None):
        """d^2N / ds dcos at (s m, cos), photons per particle per m per unit cos; 0
        outside 0 <= s <= extent. ``width``: None, or the half-width in cos of the
        semicircle footprint the density is averaged over (broadcasting)."""
        x = s / self.extent
        h = _evaluate(self.network, self.energy, footprint_input(width, x.dtype), x, cos)
        return jnp.where((x >= 0.0) & (x <= 1.0), self.scale * h * h, 0.0)

    def fraction_profile(self):
        """(D,) light per unit x at the x knots, before ``scale``."""
        return jnp.sum(self.grid * _cell_widths(self.cos), axis=1)

    def cos_profile(self):
        """(A,) light per unit cos at the cos knots, before ``scale``."""
        return jnp.sum(self.grid * _cell_widths(self.fraction)[:, None], axis=0)

    def time_moments(self, s):
        """(mean ns, variance ns^2) of the emission-time offset t - s / c at s (m)."""
        return time_offset_moments(self, s)


def _evaluate(network, energy, footprint, x, cos):
    """h at broadcast inputs (energy and footprint inputs in [-1, 1], x in [0, 1], cos),
    inputs clamped to the trained ranges."""
    shape = jnp.broadcast_shapes(jnp.shape(footprint), jnp.shape(x), jnp.shape(cos))
    dtype = jnp.result_type(x, cos)
    z = jnp.stack([jnp.broadcast_to(jnp.asarray(v, dtype), shape) for v in (
        energy, footprint, 2.0 * jnp.clip(x, 0.0, 1.0) - 1.0, jnp.clip(cos, -1.0, 1.0))],
        axis=-1)
    return network(z)


@pytree_dataclass
class SirenEmission(EnergyNodes):
    """A SIREN model of one emission table (module docstring); the interface of
    ``spline.SplineEmission``.

    Attributes:
        network: the trained ``Siren``.
        log_energy: (K,) log of the energy nodes of the one-dimensional parts, log(MeV);
            the first is the Cherenkov threshold.
        fraction, cos: (D,), (A,) knots in x and cos.
        time_mean, time_variance: (K, 2, D) per node (``spline.SplineEmission``).
        extent: (K,) light extent per node, m. total_yield: (K,) photons per particle.
        particle, medium: the table's (static).
    """

    network: Siren
    log_energy: jax.Array
    fraction: jax.Array
    cos: jax.Array
    time_mean: jax.Array
    time_variance: jax.Array
    extent: jax.Array
    total_yield: jax.Array
    particle: str = static_field(default="mu-")
    medium: str = static_field(default="water")

    def at(self, energy) -> SirenSlice:
        """The model at kinetic ``energy`` (MeV, clamped to ``energy_range``)."""
        weights = self.energy_weights(energy)
        combine = lambda table: jnp.tensordot(weights, table, axes=1)  # noqa: E731
        code = energy_input(self.log_energy, energy)
        h = _evaluate(self.network, code, jnp.asarray(-1.0, self.cos.dtype),
                      self.fraction[:, None], self.cos[None, :])
        grid = h * h
        cells = _cell_widths(self.fraction)[:, None] * _cell_widths(self.cos)[None, :]
        knots_sum = jnp.sum(grid * cells)
        total_yield = jnp.maximum(combine(self.total_yield), 0.0)
        extent = combine(self.extent)
        safe = jnp.where(knots_sum > 0, knots_sum, 1.0)
        return SirenSlice(
            network=self.network, energy=code, fraction=self.fraction, cos=self.cos,
            grid=grid, time_mean=combine(self.time_mean),
            time_variance=combine(self.time_variance), extent=extent,
            scale=jnp.where(knots_sum > 0, total_yield / safe, 0.0) / extent,
            total_yield=total_yield)

    def density(self, energy, s, cos):
        """d^2N / ds dcos (photons per particle per m per unit cos) at one energy (MeV)
        and points (s m, cos)."""
        return self.at(energy).density(s, cos)


def siren_emission(network: Siren, spline: SplineEmission) -> SirenEmission:
    """The SIREN model of ``network`` with the one-dimensional parts (yield, extent,
    emission-time moments) of ``spline``, the spline model of the same table."""
    cast = lambda x: jnp.asarray(x, spline.cos.dtype)  # noqa: E731
    return SirenEmission(
        network=jax.tree.map(cast, network), log_energy=spline.log_energy,
        fraction=spline.fraction, cos=spline.cos, time_mean=spline.time_mean,
        time_variance=spline.time_variance, extent=spline.extent,
        total_yield=spline.total_yield, particle=spline.particle, medium=spline.medium)


def save_network(path: str | Path, network: Siren, header: dict) -> None:
    """Write ``network`` to ``path``: a one-line JSON ``header`` (its ``width``,
    ``depth`` and ``omega`` included, so that ``load_network`` can rebuild it), then the
    leaves (``equinox.tree_serialise_leaves``)."""
    header = {**header, "width": int(network.weights[0].shape[1]),
              "depth": len(network.weights) - 1, "omega": network.omega}
    path = Path(path)
    temporary = path.with_name(path.name + ".part")
    with open(temporary, "wb") as stream:
        stream.write((json.dumps(header, sort_keys=True) + "\n").encode())
        eqx.tree_serialise_leaves(stream, network)
    temporary.replace(path)


def load_network(path) -> tuple[Siren, dict]:
    """(network, header) from a file of ``save_network`` (a path or an
    ``importlib.resources`` traversable)."""
    with Path(path).open("rb") if isinstance(path, str | Path) else path.open("rb") as stream:
        header = json.loads(stream.readline())
        template = Siren(header["width"], header["depth"], header["omega"],
                         jax.random.key(0))
        return eqx.tree_deserialise_leaves(stream, template), header
