"""Track as a JAX pytree: jit, grad and vmap through Track(...) built in a traced
function, batches with a leading axis, and checks only on concrete values."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from photonflow import Track
from photonflow.errors import ConfigError
from photonflow.generator import stack_tracks


def _summary(track):
    """A smooth scalar of every leaf (m, ns, MeV): enough to see each one flow."""
    return (jnp.sum(track.position * track.direction) + 2.0 * track.time
            + jnp.sqrt(track.energy))


def test_grad_flows_through_a_track_built_inside_the_function():
    def loss(position, direction, energy, time):
        return _summary(Track("mu-", position, direction, energy, time))

    position, direction = jnp.array([1.0, -2.0, 0.5]), jnp.array([0.0, 3.0, 4.0])
    grads = jax.grad(loss, argnums=(0, 1, 2, 3))(position, direction, 400.0, 7.0)
    unit = direction / 5.0
    np.testing.assert_allclose(grads[0], unit, rtol=1e-6)
    # d/dd of p . d/|d| = (p - (p . u) u) / |d|
    np.testing.assert_allclose(grads[1], (position - position @ unit * unit) / 5.0, rtol=1e-6)
    assert grads[2] == pytest.approx(0.5 / np.sqrt(400.0), rel=1e-6)
    assert grads[3] == pytest.approx(2.0)


def test_a_traced_direction_is_normalised_and_a_track_passes_through_jit():
    direction = jax.jit(lambda d: Track("e-", [0, 0, 0], d, 10.0).direction)(
        jnp.array([0.0, 0.0, 2.0]))
    np.testing.assert_allclose(direction, [0.0, 0.0, 1.0])
    track = Track("e-", [1, 2, 3], [1, 0, 0], 10.0, 4.0)
    value = jax.jit(_summary)(track)
    assert float(value) == pytest.approx(1.0 + 8.0 + np.sqrt(10.0), rel=1e-6)
    leaves, tree = jax.tree.flatten(track)
    assert len(leaves) == 4 and jax.tree.unflatten(tree, leaves) == track


def test_a_batch_is_one_track_with_a_leading_axis():
    tracks = [Track("mu-", [i, 0, 0], [0, 0, 1], 100.0 * (i + 1), i) for i in range(5)]
    batch = stack_tracks(tracks)
    assert batch.batch_shape == (5,) and len(batch) == 5
    assert batch.position.shape == (5, 3) and batch[3] == tracks[3]
    values = jax.vmap(_summary)(batch)
    np.testing.assert_allclose(values, [float(_summary(t)) for t in tracks], rtol=1e-6)
    # vmap over some leaves only, with in_axes given as a Track (axis numbers as leaves)
    axes = Track.__new__(Track)
    for name, axis in (("particle", "mu-"), ("position", 0), ("direction", None),
                       ("energy", 0), ("time", None)):
        object.__setattr__(axes, name, axis)
    single = tracks[0]
    mixed = stack_tracks(tracks)
    mixed = jax.tree.unflatten(jax.tree.structure(mixed), [
        mixed.position, single.direction, mixed.energy, single.time])
    values = jax.vmap(_summary, in_axes=(axes,))(mixed)
    expected = [float(_summary(Track("mu-", t.position, single.direction, t.energy,
                                     single.time))) for t in tracks]
    np.testing.assert_allclose(values, expected, rtol=1e-6)
    with pytest.raises(ConfigError, match="one particle per batch"):
        stack_tracks([tracks[0], Track("e-", [0, 0, 0], [0, 0, 1], 5.0)])


def test_concrete_batches_are_checked_by_index():
    energies = np.array([100.0, 200.0, -3.0, 400.0])
    with pytest.raises(ConfigError) as error:
        Track("mu-", np.zeros((4, 3)), np.tile([0.0, 0.0, 1.0], (4, 1)), energies)
    message = str(error.value)
    assert "track.energy[2]" in message and "-3" in message and "\n" not in message
    directions = np.tile([0.0, 0.0, 1.0], (3, 1))
    directions[1] = [0.0, 1.0, 1.0]
    with pytest.raises(ConfigError, match=r"track.direction\[1\]"):
        Track("e-", np.zeros((3, 3)), directions, np.ones(3))


def test_tracks_pickle_and_copy():
    """Tracks go to worker processes (``simulate --workers``) and get copied."""
    import copy
    import pickle

    track = Track("e-", [1.0, 2.0, 3.0], [0.0, 0.6, 0.8], 250.0, 4.0)
    assert pickle.loads(pickle.dumps(track)) == track
    assert copy.deepcopy(track) == track and copy.copy(track) == track


def test_tracks_are_immutable_and_keep_float64_values():
    track = Track("mu-", [0.1, 0.2, 0.3], [0, 0, 1], 1000.0)
    assert track.position.dtype == np.float64 and not track.position.flags.writeable
    with pytest.raises(AttributeError):
        track.energy = 5.0
    moved = track.replace(energy=500.0)
    assert float(moved.energy) == 500.0 and float(track.energy) == 1000.0
    with pytest.raises(ConfigError, match="track.energy"):
        track.replace(energy=2.0e4)
