"""The primary particle: handed to the generator, and a JAX pytree for the expected mode.

A ``Track`` built from concrete values (numbers, lists, numpy or concrete JAX arrays) is
checked field by field and keeps float64 numpy values (read-only), so the generator sees
them at full precision. A field that is a JAX tracer (``Track(...)`` built inside
``jit``, ``grad`` or ``vmap``) is converted, not checked; a traced direction is
normalised. ``particle`` is static (part of the tree structure); ``position``,
``direction``, ``energy`` and ``time`` are the leaves. A batch of tracks is one
``Track`` whose leaves have a leading axis (``position`` (B, 3), ``energy`` (B,), ...).
JAX rebuilds a ``Track`` from its leaves without running the checks (its leaves may then
be tracers, batched values or ``vmap``'s axis numbers).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from photonflow.errors import ConfigError, format_value

from .particles import PARTICLES

MAXIMUM_ENERGY = 1.0e4
"""Largest kinetic energy the physics tables cover, MeV (validated range: up to 5 GeV)."""

#: A concrete direction is normalised when its length is within this of 1.
DIRECTION_TOLERANCE = 1e-6

_LEAVES = ("position", "direction", "energy", "time")


class Track:
    """A primary particle: species, start point, direction, kinetic energy and start time.

    Attributes:
        particle: "mu-", "mu+", "e-", "e+" or "gamma" (static).
        position: (3,) or (B, 3) start point (x, y, z), m.
        direction: (3,) or (B, 3) unit vector (a concrete one is normalised if within
            1e-6 of unit length, a traced one always).
        energy: () or (B,) kinetic energy, MeV (0 < energy <= 1e4 when concrete).
        time: () or (B,) start time, ns.

    Raises:
        ConfigError: a concrete field out of range, in one line naming the field, the
            index within a batch and the value.
    """

    __slots__ = ("particle", *_LEAVES)

    particle: str
    position: np.ndarray | jax.Array
    direction: np.ndarray | jax.Array
    energy: np.ndarray | jax.Array
    time: np.ndarray | jax.Array

    def __init__(self, particle: str, position, direction, energy, time=0.0) -> None:
        if not isinstance(particle, str) or particle not in PARTICLES:
            raise ConfigError(
                f"track.particle must be one of {sorted(PARTICLES)}, "
                f"got {format_value(particle)}"
            )
        fields = {
            "position": _vectors("track.position", position),
            "direction": _directions(direction),
            "energy": _energies(energy),
            "time": _scalars("track.time", time),
        }
        object.__setattr__(self, "particle", particle)
        for name, value in fields.items():
            object.__setattr__(self, name, value)

    def __setattr__(self, name, value):
        raise AttributeError(f"Track is immutable: use Track.replace({name}=...)")

    def __reduce__(self):
        """Pickle and copy by the fields (already checked), not by attribute setting."""
        return _rebuild, (self.particle, [getattr(self, name) for name in _LEAVES])

    def replace(self, **changes) -> Track:
        """A copy with some fields changed (checked like the constructor's)."""
        values = {name: getattr(self, name) for name in ("particle", *_LEAVES)}
        values.update(changes)
        return Track(**values)

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """Leading axes of a batch of tracks (() for one track)."""
        return tuple(np.shape(self.energy))

    def __len__(self) -> int:
        if not self.batch_shape:
            raise TypeError("a single Track has no len(); batch_shape is ()")
        return self.batch_shape[0]

    def __getitem__(self, index) -> Track:
        """One track (or a sub-batch) of a batch, by index or slice on the leading axis."""
        if not self.batch_shape:
            raise TypeError("a single Track cannot be indexed")
        return _rebuild(self.particle, [getattr(self, n)[index] for n in _LEAVES])

    def __eq__(self, other) -> bool:
        """Same particle and equal values (identity while any field is traced)."""
        if not isinstance(other, Track):
            return NotImplemented
        leaves = [getattr(t, n) for t in (self, other) for n in _LEAVES]
        if not all(_concrete(leaf) for leaf in leaves):
            return self is other
        return self.particle == other.particle and all(
            np.array_equal(getattr(self, n), getattr(other, n)) for n in _LEAVES
        )

    def __hash__(self) -> int:
        leaves = [getattr(self, n) for n in _LEAVES]
        if not all(_concrete(leaf) for leaf in leaves):
            return id(self)
        return hash((self.particle, *(np.asarray(leaf).tobytes() for leaf in leaves)))

    def __repr__(self) -> str:
        values = ", ".join(f"{name}={_short(getattr(self, name))}" for name in _LEAVES)
        return f"Track(particle={self.particle!r}, {values})"


def stack_tracks(tracks) -> Track:
    """One batched ``Track`` (leading axis B) from B tracks of the same particle."""
    tracks = list(tracks)
    if not tracks:
        raise ConfigError("tracks: an empty list cannot be stacked")
    particles = {track.particle for track in tracks}
    if len(particles) != 1:
        raise ConfigError(f"tracks: one particle per batch, got {sorted(particles)}")
    stack = np.stack if all(_concrete(getattr(t, n)) for t in tracks for n in _LEAVES) \
        else jnp.stack
    return _rebuild(tracks[0].particle,
                    [stack([getattr(t, n) for t in tracks]) for n in _LEAVES])


def _rebuild(particle: str, leaves) -> Track:
    """A ``Track`` from its leaves, without checks (JAX's unflatten, indexing)."""
    track = object.__new__(Track)
    object.__setattr__(track, "particle", particle)
    for name, value in zip(_LEAVES, leaves, strict=True):
        object.__setattr__(track, name, value)
    return track


jax.tree_util.register_pytree_with_keys(
    Track,
    lambda track: (
        tuple((jax.tree_util.GetAttrKey(n), getattr(track, n)) for n in _LEAVES),
        track.particle,
    ),
    _rebuild,
    flatten_func=lambda track: (tuple(getattr(track, n) for n in _LEAVES), track.particle),
)


def _concrete(value) -> bool:
    return not isinstance(value, jax.core.Tracer)


def _short(value) -> str:
    if not _concrete(value):
        return f"<traced {value.shape}>"
    array = np.asarray(value)
    return format_value(array.tolist() if array.size <= 6 else f"<{array.shape}>")


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


def _floats(field: str, value) -> np.ndarray:
    """``value`` as a float64 numpy array; ConfigError if it is not numbers."""
    try:
        return np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"{field} must be a number, got {format_value(value)}") from None


def _first_bad(field: str, array: np.ndarray, bad: np.ndarray, reason: str) -> None:
    """Raise for the first entry where ``bad`` (over the batch axes) holds."""
    if np.any(bad):
        index = np.argwhere(bad)[0]
        where = "".join(f"[{i}]" for i in index)
        value = array[tuple(index)]
        raise ConfigError(f"{field}{where} must be {reason}, got {format_value(value.tolist())}")


def _scalars(field: str, value):
    if not _concrete(value):
        return value
    array = _floats(field, value)
    _first_bad(field, array, ~np.isfinite(array), "finite")
    return _read_only(array)


def _vectors(field: str, value):
    if not _concrete(value):
        return value
    array = _floats(field, value)
    if array.ndim == 0 or array.shape[-1] != 3:
        raise ConfigError(f"{field} must be three numbers, got {format_value(value)}")
    _first_bad(field, array, ~np.all(np.isfinite(array), axis=-1), "three finite numbers")
    return _read_only(array)


def _directions(value):
    if not _concrete(value):
        return value / jnp.linalg.norm(value, axis=-1, keepdims=True)
    array = _vectors("track.direction", value)
    norm = np.linalg.norm(array, axis=-1)
    _first_bad("track.direction", array, np.abs(norm - 1.0) > DIRECTION_TOLERANCE,
               "a unit vector")
    return _read_only(array / norm[..., None])


def _energies(value):
    if not _concrete(value):
        return value
    array = _scalars("track.energy", value)
    _first_bad("track.energy", array, ~((array > 0.0) & (array <= MAXIMUM_ENERGY)),
               f"a kinetic energy in (0, {MAXIMUM_ENERGY:g}] MeV")
    return array
