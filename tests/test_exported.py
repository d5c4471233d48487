"""Traced programs kept on disk (``photonflow.exported``): the sampled mode's batches give
the same photons, bit for bit, through a fresh export, through the artifact a later
process would load, and without any; a broken artifact is replaced."""

from __future__ import annotations

import numpy as np
import pytest

import photonflow as pf
from photonflow import exported
from photonflow.transport.sampled import sample_photons

pytestmark = pytest.mark.compile_bound


@pytest.fixture
def artifacts(tmp_path, monkeypatch):
    """Artifacts in a temporary directory, none loaded yet (JAX's own compilation cache
    stays off, as in the rest of the suite)."""
    monkeypatch.setattr(exported, "artifact_directory", lambda: tmp_path)
    monkeypatch.setattr(exported, "_LOADED", {})
    return tmp_path


def _tally(seed=3):
    detector = pf.load_detector("TOY_CYLINDER")
    params = pf.default_params(detector).replace(sensor_reflectivity=0.2)
    source = pf.IsotropicSource(position=[0.3, 0.1, 0.5], n_photons=5e3)
    return sample_photons(detector, params, source, seed)


def _same(a, b):
    return (np.array_equal(a.photon_sensor, b.photon_sensor)
            and np.array_equal(a.photon_time, b.photon_time)
            and (a.detected, a.absorbed, a.lost) == (b.detected, b.absorbed, b.lost))


def test_exported_batches_give_the_same_photons(artifacts, monkeypatch):
    fresh = _tally()  # exported now and written to the directory
    files = list(artifacts.glob("transport_source_batch-*.jax"))
    assert len(files) == 1 and files[0].stat().st_size > 1000
    monkeypatch.setattr(exported, "_LOADED", {})  # as a new process: read from disk
    reloaded = _tally()
    assert list(artifacts.glob("*.jax")) == files  # nothing new written
    monkeypatch.setattr(exported, "artifact_directory", lambda: None)
    plain = _tally()  # the ordinary jitted call
    assert plain.detected > 0
    assert _same(fresh, plain) and _same(reloaded, plain)


def test_a_broken_artifact_is_replaced(artifacts, monkeypatch):
    reference = _tally()
    (path,) = artifacts.glob("*.jax")
    path.write_bytes(b"not an exported program")
    monkeypatch.setattr(exported, "_LOADED", {})
    assert _same(_tally(), reference)
    assert path.read_bytes() != b"not an exported program"


def test_other_static_settings_get_their_own_artifact(artifacts):
    _tally()
    detector = pf.load_detector("TOY_CYLINDER")
    params = pf.default_params(detector)
    source = pf.IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=5e3)
    sample_photons(detector, params, source, 1,
                   config=pf.TransportConfig(n_bounces=1))
    assert len(list(artifacts.glob("transport_source_batch-*.jax"))) == 2


def test_without_a_cache_directory_nothing_is_written(tmp_path, monkeypatch):
    monkeypatch.setattr(exported, "artifact_directory", lambda: None)
    monkeypatch.setattr(exported, "_LOADED", {})
    _tally()
    assert exported._LOADED == {}
