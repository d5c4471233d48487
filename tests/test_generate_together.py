"""Several primaries generated together (``generate_together``, ``sample_together``):
one stack for every event's particles, events that stay apart and are distributed as
those generated one at a time."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import photonflow as pf
from photonflow.errors import ConfigError
from photonflow.generator import Track, generate, generate_together
from photonflow.generator.particles import PARTICLES
from photonflow.transport.pseudo_data import sample_events, sample_together

#: Three different primaries in one stack: each event's records must stay its own.
MIXED = (Track("mu-", [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 300.0, 1.0),
         Track("e-", [50.0, 0.0, 0.0], [1.0, 0.0, 0.0], 100.0, 2.0),
         Track("gamma", [0.0, 50.0, 0.0], [0.0, 1.0, 0.0], 50.0, 3.0))


def test_one_track_together_is_the_track_alone():
    """A list of one gives exactly ``generate``'s event for the same seed (one code path)."""
    track = Track("e+", [0.1, 0.2, 0.3], [0.0, 0.6, 0.8], 80.0, 1.0)
    alone = generate(track, 11)
    (together,) = generate_together([track], 11)
    for name in ("position", "direction", "time", "wavelength", "process", "parent"):
        np.testing.assert_array_equal(getattr(together, name), getattr(alone, name), name)
    for record in ("steps", "deposits", "tracks"):
        for field in dataclasses.fields(getattr(alone, record)):
            np.testing.assert_array_equal(getattr(getattr(together, record), field.name),
                                          getattr(getattr(alone, record), field.name),
                                          f"{record}.{field.name}")
    assert together.budget.deposited == pytest.approx(alone.budget.deposited, rel=1e-12)


def test_events_generated_together_keep_their_own_records():
    """Each event of a mixed list: its energy budget closes on its own primary's energy,
    its tracks count from its primary (id 0, parents before children), and its steps and
    photons lie near its own start (the starts are 50 m apart)."""
    events = list(generate_together(MIXED, 5))
    assert len(events) == len(MIXED)
    for track, photons in zip(MIXED, events, strict=True):
        budget = photons.budget
        assert budget.initial == track.energy
        assert abs(budget.relative_imbalance) < 1e-9, (track.particle, budget)
        tracks = photons.tracks
        assert tracks.parent[0] == -1
        assert np.all(tracks.parent[1:] < np.arange(1, tracks.parent.size))
        assert np.all(tracks.parent[1:] >= 0)
        assert PARTICLES[track.particle].species == tracks.particle[0]
        assert tracks.energy[0] == track.energy
        reach = 2.0 if track.particle == "mu-" else 1.5  # m: a 300 MeV muon's range ~1.2 m
        for points in (photons.steps.start, photons.position, photons.deposits.start):
            assert np.all(np.linalg.norm(points - np.asarray(track.position), axis=1) < reach)
        assert photons.steps.track.max() < tracks.particle.size
        assert len(photons) > 1000


def test_events_together_are_distributed_as_events_alone():
    """32 electrons of 200 MeV together and 32 alone: the mean photon count and the mean
    number of tracks agree within 3 standard errors."""
    track = Track("e-", [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 200.0)
    together = list(generate_together([track] * 32, 3))
    alone = [generate(track, 1000 + k) for k in range(32)]

    def compare(quantity):
        a = np.array([quantity(p) for p in together], float)
        b = np.array([quantity(p) for p in alone], float)
        error = np.hypot(a.std(ddof=1), b.std(ddof=1)) / np.sqrt(32)
        assert abs(a.mean() - b.mean()) < 3.0 * error, (a.mean(), b.mean(), error)
        assert a.std() > 0  # the events differ from each other

    compare(len)
    compare(lambda p: p.tracks.particle.size)


def test_bad_lists_are_refused_in_one_line():
    """A wrong entry or a batched ``Track`` is named with its index (or as ``track``)."""
    with pytest.raises(ConfigError, match=r"tracks\[1\] must be a photonflow.generator.Track"):
        generate_together([MIXED[0], "mu-"], 1)
    batch = Track("mu-", [[0.0, 0.0, 0.0]] * 2, [[0.0, 0.0, 1.0]] * 2, [100.0, 200.0])
    with pytest.raises(ConfigError, match=r"tracks\[1\] is a batch of 2 tracks"):
        generate_together([MIXED[0], batch], 1)
    with pytest.raises(ConfigError, match=r"^track is a batch of 2 tracks"):
        generate(batch, 1)


def test_sample_together_gives_events_like_sample_events():
    """Eight 100 MeV electrons in the toy cylinder sampled together and one at a time:
    the truths are the tracks', the mean total charge agrees within 3 standard errors,
    one thread or two give the same events, and a wrong entry is refused."""
    detector = pf.load_detector("TOY_CYLINDER")
    params = pf.default_params(detector)
    track = pf.Track("e-", [0.1, 0.0, 0.2], [0.0, 0.6, 0.8], 100.0, 5.0)
    together = sample_together(detector, params, [track] * 8, 4, threads=2)
    alone = list(sample_events(detector, params, track, 4, 8))
    again = sample_together(detector, params, [track] * 8, 4, threads=1)
    for a, b in zip(together, again, strict=True):  # the same events on any thread count
        for field in ("sensor_ids", "charge", "time"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    for event in together:
        np.testing.assert_allclose(event.truth.position, track.position)
        assert event.truth.energy == 100.0 and event.truth.particle == "e-"
    a = np.array([float(np.sum(e.charge)) for e in together])
    b = np.array([float(np.sum(e.charge)) for e in alone])
    error = np.hypot(a.std(ddof=1), b.std(ddof=1)) / np.sqrt(8)
    assert abs(a.mean() - b.mean()) < 3.0 * error, (a.mean(), b.mean(), error)
    assert not np.array_equal(a, b)  # other events, as documented
    with pytest.raises(ConfigError, match=r"tracks\[1\]"):
        sample_together(detector, params, [track, "e-"], 4)
