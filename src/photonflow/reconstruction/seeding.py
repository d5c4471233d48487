"""Seeds of a track fit from the hits alone (no truth): the pre-fit.

1. Vertex and time as a point source: the hit-time residuals r_i = t_i - t0 -
   n_g |p_i - x| / c of the hits (sensor centres p_i, first-hit times t_i) should gather
   at 0, so the pre-fit maximises the goodness G(x, t0) = sum_i exp(-r_i^2 / (2 w^2)),
   first on a grid of vertices over the detector (t0 from the goodness-weighted residuals
   of each), then by gradient ascent from the best few while the width w shrinks from
   ``WIDTHS[0]`` to ``WIDTHS[-1]`` ns (late light: scattering, reflections and dark
   noise, falls out of the kernel). A track's light arrives as if from a point ahead of
   its start (the particle outruns its light), so the track's starts are placed behind
   that point along the direction (``reconstruct``).
2. Direction: the axis of the Cherenkov cone seen from that vertex, the charge-weighted
   mean of the unit vectors to the hit sensors whose residual is within ``PROMPT`` ns.
3. Energy: from the total charge (``energy_from_charge``: the expected total of a
   prediction at a reference energy, scaled by the emission model's yield; ``reconstruct``
   repeats it from a prediction at each estimate, of a track from behind the vertex,
   since the charge of a track that leaves the detector grows slower than its yield).
Lengths m, times ns, energies MeV.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..constants import SPEED_OF_LIGHT
from ..pytree import pytree_dataclass

#: Kernel widths (ns) of the goodness, from the coarse search to the last refinement.
WIDTHS = (10.0, 5.0, 3.0)
#: Residual window (ns) of the hits that define the direction.
PROMPT = 6.0
#: Vertices of the coarse grid per axis of the detector's bounding box.
GRID = 9
#: Gradient-ascent steps per kernel width.
ASCENT_STEPS = 60
#: Fewest hit slots of the pre-fit's arrays (``padded_hits``).
MIN_SLOTS = 64


@pytree_dataclass
class Seed:
    """A point-source pre-fit: ``vertex`` (3,) m, ``time`` ns, ``direction`` (3,) unit,
    ``goodness`` (the kernel sum at the last width) and ``prompt_charge`` (p.e. within
    ``PROMPT`` ns)."""

    vertex: jax.Array
    time: jax.Array
    direction: jax.Array
    goodness: jax.Array
    prompt_charge: jax.Array


def _residuals(vertex, time, positions, times, group_index):
    """(..., K) hit-time residuals (ns) of the hits at sensor centres (K, 3) for vertices
    (..., 3) and times (...)."""
    distance = jnp.sqrt(jnp.sum((positions - vertex[..., None, :]) ** 2, axis=-1) + 1e-12)
    return times - time[..., None] - group_index * distance / SPEED_OF_LIGHT


def _best_time(vertex, positions, times, weights, group_index, width):
    """(...) the start time (ns) that centres the residuals of each vertex: the
    kernel-weighted mean of t_i - tof_i around their weighted median, twice."""
    shifted = _residuals(vertex, jnp.zeros(vertex.shape[:-1], times.dtype), positions, times,
                         group_index)
    order = jnp.argsort(shifted, axis=-1)
    cumulative = jnp.cumsum(jnp.take_along_axis(jnp.broadcast_to(weights, shifted.shape),
                                                order, axis=-1), axis=-1)
    middle = jnp.argmax(cumulative >= 0.5 * cumulative[..., -1:], axis=-1)
    time = jnp.take_along_axis(jnp.take_along_axis(shifted, order, axis=-1),
                               middle[..., None], axis=-1)[..., 0]
    for _ in range(2):
        kernel = weights * jnp.exp(-0.5 * ((shifted - time[..., None]) / width) ** 2)
        time = jnp.sum(kernel * shifted, axis=-1) / jnp.maximum(jnp.sum(kernel, axis=-1), 1e-30)
    return time


def _goodness(vertex, time, positions, times, weights, group_index, width):
    """Kernel sum of the residuals (the pre-fit's objective, to maximise)."""
    r = _residuals(vertex, time, positions, times, group_index)
    return jnp.sum(weights * jnp.exp(-0.5 * (r / width) ** 2), axis=-1)


@functools.partial(jax.jit, static_argnames=("grid",))
def point_source_seed(positions, times, charges, lows, highs, group_index,
                      grid: int = GRID) -> Seed:
    """The pre-fit (module docstring) of hits at sensor centres ``positions`` (K, 3) m
    with first-hit times ``times`` (K,) ns and charges ``charges`` (K,) p.e., vertices
    searched within the box [``lows``, ``highs``] (3,) m; ``group_index`` the medium's
    group index."""
    dtype = positions.dtype
    weights = jnp.sqrt(jnp.maximum(charges, 0.0))  # bright sensors count, not dominate
    axes = [jnp.linspace(lows[k], highs[k], grid + 2, dtype=dtype)[1:-1] for k in range(3)]
    vertices = jnp.stack(jnp.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    width = WIDTHS[0]
    times0 = _best_time(vertices, positions, times, weights, group_index, width)
    score = _goodness(vertices, times0, positions, times, weights, group_index, width)
    best = jnp.argmax(score)
    vertex, time = vertices[best], times0[best]
    scale = jnp.asarray([1.0, 1.0, 1.0, SPEED_OF_LIGHT / group_index], dtype)  # m, ns

    def ascend(point, width):
        gradient = jax.grad(lambda p: _goodness(p[:3], p[3], positions, times, weights,
                                                group_index, width))

        def step(carry, _):
            point, velocity = carry
            g = gradient(point) * scale * scale
            norm = jnp.sqrt(jnp.sum(g * g / (scale * scale))) + 1e-30
            velocity = 0.7 * velocity + g / norm * (0.05 * width)  # ~cm per ns of width
            return (point + velocity, velocity), None

        (point, _), _ = jax.lax.scan(step, (point, jnp.zeros_like(point)), None,
                                     length=ASCENT_STEPS)
        return point

    point = jnp.concatenate([vertex, time[None]])
    for width in WIDTHS[1:]:
        point = ascend(point, width)
        point = point.at[3].set(_best_time(point[:3], positions, times, weights,
                                           group_index, width))
    vertex, time = point[:3], point[3]
    r = _residuals(vertex, time, positions, times, group_index)
    prompt = jnp.abs(r) < PROMPT
    unit = (positions - vertex) / jnp.sqrt(jnp.sum((positions - vertex) ** 2, axis=-1,
                                                   keepdims=True) + 1e-12)
    axis = jnp.sum(jnp.where(prompt, charges, 0.0)[:, None] * unit, axis=0)
    norm = jnp.sqrt(jnp.sum(axis * axis))
    direction = jnp.where(norm > 0, axis / jnp.where(norm > 0, norm, 1.0),
                          jnp.asarray([0.0, 0.0, 1.0], dtype))
    return Seed(vertex=vertex, time=time, direction=direction,
                goodness=_goodness(vertex, time, positions, times, weights, group_index,
                                   WIDTHS[-1]),
                prompt_charge=jnp.sum(jnp.where(prompt, charges, 0.0)))


def padded_hits(positions, times, charges):
    """The hits (``positions`` (K, 3) m, ``times`` (K,) ns, ``charges`` (K,) p.e., NumPy)
    padded to the next power of two (at least ``MIN_SLOTS``) with empty slots: charge 0
    (weight 0 in every sum of ``point_source_seed``), time 0 ns, at the first hit's
    sensor. Events of similar size then share one compiled pre-fit instead of compiling
    one per hit count (each compilation costs ~1 s and memory that is never returned)."""
    positions, times, charges = (np.asarray(x) for x in (positions, times, charges))
    count = len(times)
    slots = max(MIN_SLOTS, 1 << max(count - 1, 0).bit_length())
    empty = slots - count
    anchor = positions[:1] if count else np.zeros((1, 3), positions.dtype)
    return (np.concatenate([positions, np.repeat(anchor, empty, axis=0)]),
            np.concatenate([times, np.zeros(empty, times.dtype)]),
            np.concatenate([charges, np.zeros(empty, charges.dtype)]))


def energy_from_charge(model, observed: float, predicted: float, reference: float,
                       points: int = 400) -> float:
    """Kinetic energy (MeV) whose yield (``model.yield_at``) is ``observed / predicted``
    times the yield at ``reference`` MeV (``predicted``: the expected total charge at
    ``reference``; charges in p.e.), within the model's energy range."""
    low, high = model.energy_range
    energies = np.geomspace(low * 1.001, high, points)
    yields = np.asarray(jax.vmap(model.yield_at)(jnp.asarray(energies)), np.float64)
    target = float(model.yield_at(reference)) * max(observed, 0.0) / max(predicted, 1e-12)
    return float(np.interp(target, yields, energies, left=energies[0], right=energies[-1]))
