"""Tables of an emission model's moments along the track, by energy node, footprint
width and the geometry of a point seen from the track: the direct light of sensors seen
from afar in O(1) reads per sensor (``transport.track_moments``).

For a point at distance R0 from the track's start, at cos(theta0) to its direction
(rho' = R0 / S in units of the light's extent S; along a' = rho' cos(theta0), across
b' = rho' sin(theta0)), the moments

    T_j(rho', cos(theta0)) = rho'^2 int_0^1 dx x^j rho^(x, u(x)) / ((a' - x)^2 + b'^2),
    j = 0 ... 3,   u(x) = (a' - x) / sqrt((a' - x)^2 + b'^2),

of the model's density rho^ (normalised to one photon, averaged over each of the first
``FOOTPRINT_LAYERS`` footprint widths; stored as T_0, T_1 and the second and third
moments about the entry's own mean T_1 / T_0, which float32 keeps where the light comes
from a short stretch and raw moments would cancel) are integrated once per energy node by
Gauss-Legendre panels in u that end at the model's cos knots and at the cosines under
which the point sees its knots along the track. A ``TabulatedEmission`` carries the
spline model with its table; its ``at`` gives the model's ``EmissionSlice`` together
with the table at that energy (cubic Hermite weights in log E over 4 nodes, on the
shared rho' axis, the way the model combines its densities along x = s / S), which the
direct light reads.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..numerics import where
from ..pytree import pytree_dataclass
from .spline import EmissionSlice, SplineEmission, _bicubic_weights, _cell_blocks, _cell_widths

#: Moments of the emission weight along the track (a two-node Gauss rule): T_0, T_1 =
#: int x w, and int (x - T_1 / T_0)^k w for k = 2, 3.
MOMENTS = 4
#: Distance axis: rho' = R0 / S, log-spaced in two pieces, steps of ``DISTANCE_STEPS``
#: in log rho' below and above ``DISTANCE_RANGE[1]``: fine where the sensor sits beside
#: the track (the light of the track's end and start sweeps across the sensors there),
#: coarse where it sees the whole track from afar; beyond the range the end values hold
#: (rho'^2 T_j tends to the angular profile).
DISTANCE_RANGE = (0.05, 2.0, 500.0)
DISTANCE_STEPS = (0.06, 0.23)
#: Footprint widths tabulated: the first this many of ``FOOTPRINT_WIDTHS`` (half-widths
#: up to 0.64 in cos: a disc of radius r seen from 1.6 r).
FOOTPRINT_LAYERS = 9


@pytree_dataclass
class MomentTable:
    """Moments of an emission model's light along the track, by energy node, footprint
    width and geometry (module docstring).

    Attributes:
        log_energy: (K,) the model's energy nodes, log(MeV).
        log_distance: (R,) knots in log(rho'), rho' = R0 / S.
        cos: (A,) knots in cos(theta0) (the model's cos knots).
        values: (K, W, R, A, MOMENTS) rho'^2 x (T_0, T_1, the second and third moments
            about T_1 / T_0) of the whole track, per node, footprint layer and knot (per
            photon emitted; x in units of the extent). One set per track, not per
            stretch of it: a sensor seen from afar sees a short stretch.
    """

    log_energy: jax.Array
    log_distance: jax.Array
    cos: jax.Array
    values: jax.Array


def moment_table(model: SplineEmission) -> MomentTable:
    """The ``MomentTable`` of ``model`` (arrays of the model's dtype), built once per
    model object: K x ``FOOTPRINT_LAYERS`` x R x A integrals of the model's density along
    the track by Gauss-Legendre panels in u that end at the model's cos knots and at the
    cosines of its knots along the track."""
    return _cached_table(model)


@functools.cache
def _cached_table(model: SplineEmission) -> MomentTable:
    with jax.ensure_compile_time_eval():
        dtype = model.root.dtype
        log_distance = distance_knots()
        cos = model.cos
        rows = []
        for k in range(model.log_energy.shape[0]):
            rows.append(_node_moments(model.root[k, :FOOTPRINT_LAYERS], model.fraction,
                                      model.cos, jnp.asarray(log_distance, dtype), cos))
        return MomentTable(
            log_energy=model.log_energy,
            log_distance=jnp.asarray(log_distance, dtype),
            cos=cos,
            values=jnp.stack(rows),
        )


@jax.jit
def _node_moments(root, fraction, cos, log_distance, table_cos):
    """(W, R, A', MOMENTS) table values of one energy node's ``root`` (W, 4, D, A) at the
    knots ``log_distance`` (R,) and ``table_cos`` (A',)."""
    cells = _cell_blocks(root)
    knots_sum = jnp.sum(root[0, 0] ** 2 * _cell_widths(fraction)[:, None]
                        * _cell_widths(cos)[None, :])
    norm = jnp.where(knots_sum > 0, 1.0 / jnp.where(knots_sum > 0, knots_sum, 1.0), 0.0)
    rho = jnp.exp(log_distance)[:, None]  # (R, 1)
    c = table_cos[None, :]  # (1, A')
    sine = jnp.sqrt(1.0 - c * c)
    a, b = rho * c, rho * sine  # (R, A)
    u_start = jnp.broadcast_to(c, a.shape)
    u_end = (a - 1.0) / jnp.sqrt((a - 1.0) ** 2 + b * b)
    seen = (a[..., None] - fraction) / jnp.sqrt((a[..., None] - fraction) ** 2
                                                 + (b * b)[..., None])
    fixed = jnp.clip(jnp.broadcast_to(cos, a.shape + cos.shape), u_end[..., None],
                     u_start[..., None])
    ends = jnp.sort(jnp.concatenate([fixed, seen, u_end[..., None], u_start[..., None]],
                                    axis=-1), axis=-1)
    low, high = ends[..., :-1], ends[..., 1:]
    nodes, weights = np.polynomial.legendre.leggauss(2)
    nodes, weights = jnp.asarray(0.5 * (nodes + 1.0), a.dtype), jnp.asarray(0.5 * weights, a.dtype)
    width = (high - low)[..., None]
    u = (low[..., None] + width * nodes).reshape(a.shape + (-1,))  # (R, A, M)
    du = (width * weights).reshape(u.shape)
    sin_u = jnp.sqrt(jnp.maximum(1.0 - u * u, jnp.finfo(a.dtype).tiny))
    x = a[..., None] - b[..., None] * u / sin_u
    inside = (x >= 0.0) & (x <= 1.0)
    x = jnp.clip(x, 0.0, 1.0)
    patch, i, j = _bicubic_weights(fraction, cos, x, u)
    factor = du / sin_u * (rho / sine)[..., None] * norm

    def layer(block):
        value = jnp.sum(patch * block[i, j], axis=-1)
        weight = where(inside, value * value * factor, 0.0)  # (R, A, M)
        total = jnp.sum(weight, axis=2)
        first = jnp.sum(weight * x, axis=2)
        mean = first / jnp.where(total > 0, total, 1.0)
        centred = x - mean[:, :, None]  # about each entry's own mean
        moments = [total, first, jnp.sum(weight * centred**2, axis=2),
                   jnp.sum(weight * centred**3, axis=2)]
        return jnp.stack(moments, axis=-1)

    return jax.lax.map(layer, cells)


def distance_knots() -> np.ndarray:
    """Knots in log(rho') of the table's distance axis (``DISTANCE_RANGE``,
    ``DISTANCE_STEPS``)."""
    low, middle, high = (math.log(x) for x in DISTANCE_RANGE)
    fine = np.linspace(low, middle, round((middle - low) / DISTANCE_STEPS[0]) + 1)
    coarse = np.linspace(middle, high, round((high - middle) / DISTANCE_STEPS[1]) + 1)
    return np.concatenate([fine, coarse[1:]])


def _energy_terms(log_energy, energy):
    """(weights (4,), node indices (4,)) of cubic Hermite interpolation in log E between
    the nodes ``log_energy`` (finite-difference slopes, C1); E (MeV) clamped to the
    nodes."""
    count = log_energy.shape[0]
    x = jnp.clip(jnp.log(energy), log_energy[0], log_energy[-1])
    i = jnp.clip(jnp.searchsorted(log_energy, x, side="right") - 1, 0, count - 2)
    h = log_energy[i + 1] - log_energy[i]
    t = (x - log_energy[i]) / h
    t2, t3 = t * t, t * t * t
    h00, h10, h01, h11 = 2 * t3 - 3 * t2 + 1, t3 - 2 * t2 + t, -2 * t3 + 3 * t2, t3 - t2
    idx = jnp.clip(i + jnp.arange(-1, 3, dtype=i.dtype), 0, count - 1)  # nodes i-1, i, i+1, i+2
    xs = log_energy[idx]
    # slope at node i: (f[i+1] - f[i-1]) / (x[i+1] - x[i-1]), one-sided at the ends
    left = (xs[2] - xs[0])
    right = (xs[3] - xs[1])
    w_left = jnp.stack([-1.0 / left, 0.0 * h, 1.0 / left, 0.0 * h]) * h
    w_right = jnp.stack([0.0 * h, -1.0 / right, 0.0 * h, 1.0 / right]) * h
    base = jnp.stack([0.0 * h, h00, h01, 0.0 * h])
    return base + h10 * w_left + h11 * w_right, idx


def _slopes(values, knots, axis):
    """Slopes of ``values`` along ``axis`` at the ``knots`` of a natural cubic spline
    (C2: the likelihood's curvature, which the reconstruction's Hessian measures, is
    continuous across the table's cells; ``interpax``)."""
    import interpax

    with jax.numpy_dtype_promotion("standard"):  # interpax mixes int and float
        return interpax.approx_df(knots, values, method="cubic2", axis=axis)


def track_table(table: MomentTable, energy):
    """The moment table at ``energy`` (MeV, clamped to the nodes): (W, 4, R, A, MOMENTS)
    values and their derivatives d/dlog(rho'), d/dcos and d^2/dlog(rho')dcos
    (natural cubic splines) at the knots, for bicubic Hermite patches in (log rho',
    cos)."""
    weights, idx = _energy_terms(table.log_energy, energy)
    values = jnp.tensordot(weights, table.values[idx], axes=1)  # (W, R, A, MOMENTS)
    d_r = _slopes(values, table.log_distance, 1)
    d_c = _slopes(values, table.cos, 2)
    d_rc = _slopes(d_r, table.cos, 2)
    return jnp.stack([values, d_r, d_c, d_rc], axis=1)


@pytree_dataclass
class TabulatedEmission:
    """A ``SplineEmission`` with its ``MomentTable`` (``emission_model(..., kind="tables")``):
    the same light, whose direct part at sensors seen from afar is read from the table.

    Attributes:
        spline: the model. table: its ``MomentTable``.
    """

    spline: SplineEmission
    table: MomentTable

    def __getattr__(self, name):
        if name in ("spline", "table"):  # not yet set (copying, unpickling)
            raise AttributeError(name)
        return getattr(self.spline, name)

    def at(self, energy) -> TabulatedSlice:
        """The model and its table at kinetic energy ``energy`` (MeV, clamped)."""
        return TabulatedSlice(self.spline.at(energy), self.table.log_distance,
                              self.table.cos, track_table(self.table, energy))


@pytree_dataclass
class TabulatedSlice:
    """An ``EmissionSlice`` with the moment table at its energy.

    Attributes:
        slice: the model at the energy (its attributes and methods are this object's).
        log_distance: (R,) knots in log(rho'). table_cos: (A,) knots in cos(theta0).
        moment_root: (W, 4, R, A, MOMENTS) the table's values and derivatives
            (``track_table``).
    """

    slice: EmissionSlice
    log_distance: jax.Array
    table_cos: jax.Array
    moment_root: jax.Array

    def __getattr__(self, name):
        if name in ("slice", "log_distance", "table_cos", "moment_root"):
            raise AttributeError(name)
        return getattr(self.slice, name)

    def density(self, s, cos, width=None):
        """``EmissionSlice.density``."""
        return self.slice.density(s, cos, width)

    def time_moments(self, s):
        """``EmissionSlice.time_moments``."""
        return self.slice.time_moments(s)

    def cos_profile(self):
        """``EmissionSlice.cos_profile``."""
        return self.slice.cos_profile()

    def fraction_profile(self):
        """``EmissionSlice.fraction_profile``."""
        return self.slice.fraction_profile()


def tabulated_emission(model: SplineEmission) -> TabulatedEmission:
    """``model`` with its ``MomentTable`` (built once per model object)."""
    return TabulatedEmission(model, moment_table(model))
