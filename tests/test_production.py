"""Event production (issue 4): resumable writes, resuming an interrupted ``simulate`` and
parallel production on Dask giving the same file as a serial run."""

import json
import os
import signal

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

import photonflow as pf
from photonflow.cli import app, terminate_as_interrupt
from photonflow.errors import ConfigError, EventFileError
from photonflow.io import EventWriter, Truth, make_event
from photonflow.io.partial_files import checkpoint_path
from photonflow.sources import IsotropicSource
from photonflow.transport import production
from photonflow.transport.production import produce_events

pytestmark = pytest.mark.compile_bound

TOY = ["--detector", "TOY_CYLINDER", "--photons", "1e4"]


@pytest.fixture(scope="module")
def toy():
    detector = pf.load_detector("TOY_CYLINDER")
    return detector, pf.default_params(detector)


def fake_events(n, seed=0):
    """``n`` small events with distinct hits and truth (no transport)."""
    rng = np.random.default_rng(seed)
    events = []
    for index in range(n):
        k = int(rng.integers(0, 9))
        truth = Truth(source_kind="isotropic", position=np.array([0.1 * index, 0.0, 0.0]),
                      time=float(index), seed=seed)
        events.append(make_event(rng.integers(0, 200, k), rng.random(k) + 0.5,
                                 rng.random(k) * 50, truth))
    return events


def interrupted_after(events, k):
    """Yield the first ``k`` events, then raise ``KeyboardInterrupt`` (Ctrl-C)."""
    yield from events[:k]
    raise KeyboardInterrupt


def event_datasets(path):
    """Every dataset under /events of an event file, by name."""
    found = {}
    with h5py.File(path, "r") as h5:
        h5["events"].visititems(
            lambda name, item: found.__setitem__(name, item[()])
            if isinstance(item, h5py.Dataset) else None
        )
    return found


def assert_same_events(path_a, path_b):
    a, b = event_datasets(path_a), event_datasets(path_b)
    assert sorted(a) == sorted(b) and "hits/charge" in a and "truth/seed" in a
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


def one_line(result, code):
    assert result.exit_code == code, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1, result.output
    return lines[0]


def invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


# ---- resumable writer -------------------------------------------------------------------
RUN = {"seed": 3, "n_events": 10, "source": "fake"}


@pytest.mark.parametrize("mode", ["create", "append"])
def test_interrupted_write_resumes_to_the_uninterrupted_file(tmp_path, toy, mode):
    detector, params = toy
    events = fake_events(10)
    earlier = fake_events(3, seed=9)
    reference, target = tmp_path / "ref.h5", tmp_path / "run.h5"
    if mode == "append":
        for path in (reference, target):
            pf.write_events(path, earlier, detector, params)
    pf.write_events(reference, events, detector, params, mode=mode)
    with pytest.raises(KeyboardInterrupt):  # 7 events: 3 checkpoints of 2, 1 buffered
        with EventWriter(target, detector, params, mode=mode, chunk_events=2, run=RUN) as w:
            w.extend(interrupted_after(events, 7))
    partial = checkpoint_path(target)
    assert partial.exists()
    assert mode == "append" or not target.exists()
    with EventWriter(target, detector, params, mode=mode, run=RUN, resume=True) as writer:
        assert writer.n_run_events == 7
        writer.extend(events[writer.n_run_events:])
    assert not partial.exists()
    assert_same_events(reference, target)
    with h5py.File(target, "r") as h5:
        assert json.loads(h5.attrs["run"]) == RUN
        assert int(h5.attrs["run_first_event"]) == (3 if mode == "append" else 0)


def test_resume_cuts_a_partial_file_back_to_its_last_checkpoint(tmp_path, toy):
    """A process killed during a write may leave datasets longer than the committed
    ``n_events``: resuming drops the uncommitted rows."""
    detector, params = toy
    events = fake_events(6)
    target = tmp_path / "run.h5"
    with pytest.raises(KeyboardInterrupt):
        with EventWriter(target, detector, params, chunk_events=2, run=RUN) as writer:
            writer.extend(interrupted_after(events, 4))
    with h5py.File(checkpoint_path(target), "r+") as h5:  # half-written 5th event
        for name in ("hits/charge", "hits/time", "hits/sensor_id", "truth/energy", "offsets"):
            h5["events"][name].resize((h5["events"][name].shape[0] + 3,))
    with EventWriter(target, detector, params, run=RUN, resume=True) as writer:
        assert writer.n_run_events == 4
        writer.extend(events[4:])
    pf.write_events(tmp_path / "ref.h5", events, detector, params)
    assert_same_events(tmp_path / "ref.h5", target)


def test_resume_refuses_other_settings_and_missing_or_blocking_partials(tmp_path, toy):
    detector, params = toy
    target = tmp_path / "run.h5"
    with pytest.raises(EventFileError, match="no interrupted run to resume"):
        EventWriter(target, detector, params, run=RUN, resume=True).__enter__()
    with pytest.raises(KeyboardInterrupt):
        with EventWriter(target, detector, params, chunk_events=1, run=RUN) as writer:
            writer.extend(interrupted_after(fake_events(5), 2))
    partial = checkpoint_path(target)
    before = partial.read_bytes()
    with pytest.raises(EventFileError, match=r"settings differ .*\(seed = 3, not 4\)"):
        with EventWriter(target, detector, params, run={**RUN, "seed": 4}, resume=True):
            pass
    with pytest.raises(EventFileError, match="parameters differ"):
        with EventWriter(target, detector, params.replace(tts=2.5), run=RUN, resume=True):
            pass
    assert partial.read_bytes() == before  # a refused resume keeps the partial file
    with pytest.raises(EventFileError, match="an interrupted run left"):
        with EventWriter(target, detector, params, run=RUN):
            pass
    with EventWriter(target, detector, params, mode="recreate", run=RUN) as writer:
        writer.extend(fake_events(1))
    assert not partial.exists() and len(pf.read_events(target)) == 1


def test_failure_before_the_first_event_keeps_nothing(tmp_path, toy):
    detector, params = toy
    with pytest.raises(KeyboardInterrupt):
        with EventWriter(tmp_path / "run.h5", detector, params, run=RUN) as writer:
            writer.extend(interrupted_after(fake_events(3), 0))
    assert list(tmp_path.iterdir()) == []


def test_sigterm_is_an_interrupt_only_inside_the_block():
    previous = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt), terminate_as_interrupt():
        os.kill(os.getpid(), signal.SIGTERM)
    assert signal.getsignal(signal.SIGTERM) is previous


# ---- simulate: interrupt and resume -----------------------------------------------------
def test_simulate_interrupted_then_resumed_equals_an_uninterrupted_run(tmp_path, monkeypatch):
    run = [*TOY, "--events", 6, "--seed", 7]
    assert invoke("simulate", *run, "--out", tmp_path / "ref.h5").exit_code == 0
    real = production.sample_events

    def interrupted_at_4(*args, **kwargs):
        events = list(real(*args, **kwargs))
        yield from interrupted_after(events, 4 - kwargs["first_event"])

    monkeypatch.setattr(production, "sample_events", interrupted_at_4)
    out = tmp_path / "run.h5"
    line = one_line(invoke("simulate", *run, "--out", out), 130)
    assert line.startswith("interrupted after 4 of 6 events") and "--resume" in line
    assert checkpoint_path(out).exists() and not out.exists()
    monkeypatch.undo()
    refused = one_line(invoke("simulate", *run, "--photons", "2e4", "--out", out, "--resume"), 2)
    assert refused.startswith("error: ") and "n_photons = 10000.0, not 20000.0" in refused
    assert "--resume" in one_line(invoke("simulate", *run, "--out", out), 2)
    result = invoke("simulate", *run, "--out", out, "--resume")
    assert result.exit_code == 0, result.output
    assert "resumed at event 4" in result.output
    assert not checkpoint_path(out).exists()
    assert_same_events(tmp_path / "ref.h5", out)
    with h5py.File(out, "r") as h5:
        settings = json.loads(h5.attrs["run"])
    assert settings["seed"] == 7 and settings["n_events"] == 6
    assert settings["source"] == "IsotropicSource" and settings["n_photons"] == 1e4


# ---- parallel production ----------------------------------------------------------------
def test_two_workers_write_the_same_file_as_a_serial_run(tmp_path):
    """One local Dask cluster (2 processes) against the serial command, event by event."""
    run = [*TOY, "--position", "0.3,0,0.5", "--events", 9, "--seed", 11]
    assert invoke("simulate", *run, "--out", tmp_path / "serial.h5").exit_code == 0
    result = invoke("simulate", *run, "--workers", 2, "--out", tmp_path / "parallel.h5")
    assert result.exit_code == 0, result.output
    assert_same_events(tmp_path / "serial.h5", tmp_path / "parallel.h5")


def test_a_local_cluster_collects_garbage_as_the_command_does():
    """The workers of ``--workers`` trace programs as the command does: Python's
    collector with ``garbage_collection.THRESHOLDS`` (the default (700, 10, 10) traces
    ~20 % slower)."""
    import gc

    from photonflow.cluster import dask_client
    from photonflow.garbage_collection import THRESHOLDS

    with dask_client(workers=1) as client:
        assert list(client.run(gc.get_threshold).values()) == [THRESHOLDS]


def test_existing_cluster_gives_per_event_sources_in_order(toy):
    """``--scheduler``'s path, with per-event sources cut into uneven blocks and a run
    that starts part way (as a resumed one does)."""
    from distributed import LocalCluster

    detector, params = toy
    sources = [IsotropicSource(position=[0.2 * k - 0.5, 0.0, 0.1 * k], n_photons=1e4)
               for k in range(7)]
    serial = list(pf.sample_events(detector, params, sources, 5, 7))
    with LocalCluster(n_workers=1, threads_per_worker=1, dashboard_address=None) as cluster:
        parallel = list(produce_events(detector, params, sources[2:], 5, 5, first_event=2,
                                       scheduler=cluster.scheduler_address, block_events=2))
    assert len(parallel) == 5
    for a, b in zip(serial[2:], parallel, strict=True):
        for field in ("sensor_ids", "charge", "time"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
        np.testing.assert_array_equal(a.truth.position, b.truth.position)


def test_parallel_options_are_checked_before_any_cluster(tmp_path, toy):
    detector, params = toy
    source = IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=1e4)
    with pytest.raises(ConfigError, match="workers = 0"):
        produce_events(detector, params, source, 1, 3, workers=0)
    with pytest.raises(ConfigError, match="choose one"):
        produce_events(detector, params, source, 1, 3, workers=2, scheduler="tcp://x:1")
    with pytest.raises(ConfigError, match="source.position"):
        outside = IsotropicSource(position=[0.0, 0.0, 9.0], n_photons=1e4)
        produce_events(detector, params, outside, 1, 3, workers=2)
    out = tmp_path / "x.h5"
    for extra, named in ((["--workers", 0], "--workers = 0"),
                         (["--workers", 2, "--scheduler", "tcp://x:1"], "--scheduler"),
                         (["--scheduler", "nonsense"], "scheduler = 'nonsense'")):
        line = one_line(invoke("simulate", *TOY, "--out", out, *extra), 2)
        assert line.startswith("error: ") and named in line
    assert list(tmp_path.iterdir()) == []
