"""Event files: exact round trips, lazy access, append, crash safety, provenance, errors."""

import os
import signal
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import h5py
import jax
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from photonflow.errors import ConfigError, EventFileError
from photonflow.geometry import make_detector, preset_detector
from photonflow.io import (
    Event,
    EventFile,
    EventWriter,
    Truth,
    format_summary,
    make_event,
    read_events,
    summarize_events,
    write_events,
)
from photonflow.io.hdf5 import FORMAT_VERSION
from photonflow.params import PARAM_SPECS, default_params
from photonflow.pytree import replace

N_BIG = 100_000


@pytest.fixture(scope="module")
def detector():
    return preset_detector("TOY_CYLINDER")


@pytest.fixture(scope="module")
def params(detector):
    return default_params(detector)


def make_flat(n_events, seed=0, mean_hits=6.0, n_sensors=200):
    """Flat ragged hit arrays plus per-event truth, ~10 % zero-hit events."""
    rng = np.random.default_rng(seed)
    counts = rng.poisson(mean_hits, n_events)
    counts[rng.random(n_events) < 0.1] = 0
    counts[:3] = (0, 1, 0)
    total = int(counts.sum())
    truth = {
        "source_kind": rng.choice(["isotropic", "laser", "track"], n_events),
        "particle": rng.choice(["mu-", "e-", "μ+"], n_events),  # non-ASCII on purpose
        "position": rng.normal(size=(n_events, 3)),
        "direction": rng.normal(size=(n_events, 3)),
        "energy": rng.exponential(500.0, n_events),
        "time": rng.normal(size=n_events),
        "seed": rng.integers(0, 2**62, n_events),
        "known": rng.random(n_events) < 0.7,
    }
    return {
        "counts": counts,
        "offsets": np.concatenate([[0], np.cumsum(counts)]),
        "sensor_id": rng.integers(0, n_sensors, total).astype(np.int32),
        "charge": rng.exponential(1.0, total).astype(np.float32),
        "time": rng.normal(100.0, 30.0, total).astype(np.float32),
        "truth": truth,
    }


def event_stream(flat):
    """A generator of Events over flat arrays (truth None where not ``known``)."""
    offsets, truth = flat["offsets"], flat["truth"]
    for i in range(len(flat["counts"])):
        a, b = offsets[i], offsets[i + 1]
        event_truth = None
        if truth["known"][i]:
            event_truth = Truth(
                source_kind=str(truth["source_kind"][i]),
                particle=str(truth["particle"][i]),
                position=truth["position"][i],
                direction=truth["direction"][i],
                energy=float(truth["energy"][i]),
                time=float(truth["time"][i]),
                seed=int(truth["seed"][i]),
            )
        yield Event(flat["sensor_id"][a:b], flat["charge"][a:b], flat["time"][a:b], event_truth)


def assert_events_match(events, flat):
    """Every hit array, every count and every truth field equal exactly."""
    events = list(events)
    assert [e.n_hits for e in events] == flat["counts"].tolist()
    for name, attr in (("sensor_id", "sensor_ids"), ("charge", "charge"), ("time", "time")):
        got = [getattr(e, attr) for e in events]
        assert all(a.dtype == flat[name].dtype for a in got)
        np.testing.assert_array_equal(np.concatenate(got), flat[name])
    truth = flat["truth"]
    known = np.array([e.truth is not None for e in events])
    np.testing.assert_array_equal(known, truth["known"])
    kept = [e.truth for e in events if e.truth is not None]
    for name in ("source_kind", "particle", "position", "direction", "energy", "time", "seed"):
        got = np.array([getattr(t, name) for t in kept])
        np.testing.assert_array_equal(got, truth[name][truth["known"]])


def assert_same_event(a, b):
    np.testing.assert_array_equal(a.sensor_ids, b.sensor_ids)
    np.testing.assert_array_equal(a.charge, b.charge)
    np.testing.assert_array_equal(a.time, b.time)
    assert (a.truth is None) == (b.truth is None)
    if a.truth is not None:
        assert (a.truth.source_kind, a.truth.seed) == (b.truth.source_kind, b.truth.seed)
        np.testing.assert_array_equal(a.truth.position, b.truth.position)


def one_line_error(excinfo, path):
    message = str(excinfo.value)
    assert "\n" not in message
    assert str(path) in message or Path(path).name in message
    return message


@pytest.fixture(scope="module")
def big_file(tmp_path_factory, detector, params):
    flat = make_flat(N_BIG)
    path = tmp_path_factory.mktemp("big") / "events.h5"
    assert write_events(path, event_stream(flat), detector, params, chunk_events=7_000) == path
    return path, flat


# ---- round trip and lazy access ------------------------------------------------------


def test_round_trip_100k_ragged_events_exactly(big_file):
    path, flat = big_file
    assert (flat["counts"] == 0).sum() > 5000
    with read_events(path) as f:
        assert len(f) == N_BIG
        assert f.n_hits == flat["offsets"][-1]
        assert_events_match(f, flat)


def test_schema_datasets_dtypes_and_attributes(big_file):
    path, flat = big_file
    with h5py.File(path, "r") as h5:
        assert h5.attrs["format"] == "photonflow-events"
        assert h5.attrs["format_version"] == FORMAT_VERSION
        assert h5["events"].attrs["n_events"] == N_BIG
        np.testing.assert_array_equal(h5["events/offsets"][()], flat["offsets"])
        assert h5["events/offsets"].dtype == np.int64
        assert h5["events/hits/sensor_id"].dtype == np.int32
        assert h5["events/hits/charge"].dtype == np.float32
        assert h5["events/hits/charge"].compression in ("gzip", "lzf")
        assert h5["events/hits/time"].maxshape == (None,)
        assert h5["events/truth/position"].shape == (N_BIG, 3)
        assert h5["events/truth/seed"].dtype == np.int64
        assert h5["events/truth/particle"].asstr()[2] == flat["truth"]["particle"][2]
        unknown = int(np.flatnonzero(~flat["truth"]["known"])[0])
        assert h5["events/truth/seed"][unknown] == -1
        assert np.isnan(h5["events/truth/energy"][unknown])


def test_random_access_negative_index_and_slices(big_file):
    path, flat = big_file
    all_events = list(event_stream(flat))
    with read_events(path) as f:
        for i in (0, 1, 2, 12_345, N_BIG - 1):
            assert_same_event(f[i], all_events[i])
        assert_same_event(f[-1], all_events[-1])
        assert_same_event(f[-N_BIG], all_events[0])
        assert_same_event(f[np.int64(-7)], all_events[-7])
        for got, want in zip(f[500:520], all_events[500:520], strict=True):
            assert_same_event(got, want)
        assert len(f[10:40:3]) == 10
        for bad in (N_BIG, -N_BIG - 1):
            with pytest.raises(IndexError, match=rf"-{N_BIG}\.\.{N_BIG - 1}"):
                f[bad]
        assert not f[0].sensor_ids.flags.writeable


@pytest.mark.parametrize("n", [1, 333, 10_000, 10**6])
def test_iter_chunks_equals_full_iteration(tmp_path, detector, params, n):
    flat = make_flat(2_500, seed=3)
    path = write_events(tmp_path / "c.h5", event_stream(flat), detector, params)
    with read_events(path) as f:
        chunks = list(f.iter_chunks(n))
        assert [len(c) for c in chunks[:-1]] == [n] * (len(chunks) - 1)
        assert 1 <= len(chunks[-1]) <= n
        flattened = [e for chunk in chunks for e in chunk]
        assert_events_match(flattened, flat)
        for a, b in zip(flattened, f, strict=True):
            assert_same_event(a, b)
        with pytest.raises(EventFileError):
            next(f.iter_chunks(0))


@given(
    st.lists(
        st.lists(
            st.tuples(
                st.integers(0, 199),
                st.floats(width=32, allow_nan=False),
                st.floats(width=32, allow_nan=True),
            ),
            max_size=6,
        ),
        max_size=12,
    )
)
def test_arbitrary_ragged_hit_lists_round_trip(hit_lists):
    detector = preset_detector("TOY_CYLINDER")
    params = default_params(detector)
    events = [
        make_event([h[0] for h in hits], [h[1] for h in hits], [h[2] for h in hits])
        for hits in hit_lists
    ]
    with tempfile.TemporaryDirectory() as tmp:
        path = write_events(Path(tmp) / "h.h5", iter(events), detector, params, chunk_events=5)
        with read_events(path) as f:
            back = list(f)
    assert len(back) == len(events)
    for got, want in zip(back, events, strict=True):
        assert got.truth is None
        for name in ("sensor_ids", "charge", "time"):
            a, b = getattr(got, name), getattr(want, name)
            assert a.dtype == b.dtype
            assert a.tobytes() == b.tobytes()  # bit-exact, NaN and -0.0 included


def test_empty_file_reads_and_summarizes(tmp_path, detector, params):
    path = write_events(tmp_path / "empty.h5", [], detector, params)
    with read_events(path) as f:
        assert len(f) == 0 and list(f) == []
        with pytest.raises(IndexError, match="empty"):
            f[0]
    summary = summarize_events(path)
    assert summary["n_events"] == 0 and summary["hits_per_event"]["mean"] is None
    assert "events" in format_summary(summary)


# ---- modes ---------------------------------------------------------------------------


def test_append_preserves_order(tmp_path, detector, params):
    first, second = make_flat(1_500, seed=1), make_flat(900, seed=2)
    path = tmp_path / "a.h5"
    write_events(path, event_stream(first), detector, params, chunk_events=400)
    write_events(path, event_stream(second), detector, params, mode="append", chunk_events=256)
    with read_events(path) as f:
        assert len(f) == 2_400
        events = list(f)
    assert_events_match(events[:1_500], first)
    assert_events_match(events[1_500:], second)
    with h5py.File(path, "r") as h5:
        assert h5["events"].attrs["n_events"] == 2_400
        assert "modified" in h5.attrs


def test_append_to_missing_file_errors(tmp_path, detector, params):
    path = tmp_path / "missing.h5"
    with pytest.raises(EventFileError) as excinfo:
        write_events(path, [], detector, params, mode="append")
    assert "create" in one_line_error(excinfo, path)
    assert os.listdir(tmp_path) == []


def test_append_with_different_detector_errors(tmp_path, detector, params):
    path = write_events(tmp_path / "d.h5", event_stream(make_flat(10)), detector, params)
    before = path.read_bytes()
    moved = make_detector(
        detector.shape,
        np.asarray(detector.sensor_positions) * 0.99,
        detector.sensor_normals,
        detector.sensor_radius,
        name=detector.name,
        sensor_models=detector.sensor_models,
    )
    renamed = replace(detector, name="OTHER")
    other = preset_detector("TOY_SPHERE")
    for bad in (moved, renamed, other):
        with pytest.raises(EventFileError) as excinfo:
            write_events(path, [], bad, default_params(bad), mode="append")
        assert "detector differs" in one_line_error(excinfo, path)
    with pytest.raises(EventFileError, match="parameters differ"):
        write_events(path, [], detector, params.replace(tts=9.0), mode="append")
    assert path.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["d.h5"]


def test_create_refuses_overwrite_and_recreate_replaces(tmp_path, detector, params):
    path = write_events(tmp_path / "r.h5", event_stream(make_flat(20)), detector, params)
    before = path.read_bytes()
    with pytest.raises(EventFileError) as excinfo:
        write_events(path, [], detector, params)
    assert 'mode="recreate"' in one_line_error(excinfo, path)
    assert path.read_bytes() == before
    fresh = make_flat(7, seed=9)
    write_events(path, event_stream(fresh), detector, params, mode="recreate")
    with read_events(path) as f:
        assert_events_match(f, fresh)
    with pytest.raises(EventFileError, match="mode"):
        write_events(path, [], detector, params, mode="overwrite")


# ---- crash safety ----------------------------------------------------------------------


def failing_stream(flat, n_ok, error):
    for i, event in enumerate(event_stream(flat)):
        if i == n_ok:
            raise error
        yield event


@pytest.mark.parametrize("error", [RuntimeError("boom"), KeyboardInterrupt()])
def test_interrupted_create_leaves_no_files(tmp_path, detector, params, error):
    path = tmp_path / "x.h5"
    with pytest.raises(type(error)):
        write_events(path, failing_stream(make_flat(3_000), 2_000, error), detector, params,
                     chunk_events=500)
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("error", [RuntimeError("boom"), KeyboardInterrupt()])
def test_interrupted_append_leaves_original_byte_identical(tmp_path, detector, params, error):
    path = write_events(tmp_path / "x.h5", event_stream(make_flat(800)), detector, params)
    before = path.read_bytes()
    with pytest.raises(type(error)):
        write_events(path, failing_stream(make_flat(3_000, seed=5), 2_000, error), detector,
                     params, mode="append", chunk_events=500)
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ["x.h5"]


def test_invalid_event_aborts_write_with_one_line_error(tmp_path, detector, params):
    path = tmp_path / "bad.h5"
    good = list(event_stream(make_flat(30)))
    out_of_range = Event(np.array([3, 200], np.int32), np.ones(2, np.float32), np.ones(2))
    with pytest.raises(EventFileError) as excinfo:
        write_events(path, [*good, out_of_range], detector, params, chunk_events=8)
    assert "events[30]" in one_line_error(excinfo, path) and "200" in str(excinfo.value)
    ragged = Event(np.array([3, 4]), np.ones(3), np.ones(2))
    with pytest.raises(EventFileError, match=r"events\[0\].*charge"):
        write_events(path, [ragged], detector, params)
    with pytest.raises(EventFileError, match="iterable"):
        write_events(path, good[0], detector, params)
    assert os.listdir(tmp_path) == []


KILL_SCRIPT = textwrap.dedent(
    """
    import sys
    import numpy as np
    from photonflow.geometry import preset_detector
    from photonflow.io import Event, write_events
    from photonflow.params import default_params

    detector = preset_detector("TOY_CYLINDER")
    ids = np.arange(64, dtype=np.int32)
    charge = np.ones(64, np.float32)

    def endless():
        i = 0
        while True:
            yield Event(ids, charge, charge + i)
            i += 1
            if i == 5_000:
                print("writing", flush=True)

    write_events(sys.argv[1], endless(), detector, default_params(detector),
                 mode=sys.argv[2], chunk_events=1_000)
    """
)


@pytest.mark.parametrize("mode", ["create", "append"])
def test_sigkill_mid_write_leaves_target_absent_or_unchanged(tmp_path, detector, params, mode):
    path = tmp_path / "k.h5"
    before = None
    if mode == "append":
        before = write_events(path, event_stream(make_flat(50)), detector, params).read_bytes()
    child = subprocess.Popen(
        [sys.executable, "-c", KILL_SCRIPT, str(path), mode],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        line = child.stdout.readline()
        assert line.strip() == "writing", child.stderr.read()
        partial = [p for p in os.listdir(tmp_path) if ".partial-" in p]
        assert partial, "the child should be writing to a temporary file"
        assert (tmp_path / partial[0]).stat().st_size > 0
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=30)
    assert child.returncode == -signal.SIGKILL
    if mode == "create":
        assert not path.exists()
    else:
        assert path.read_bytes() == before
        with read_events(path) as f:
            assert len(f) == 50
    # A stale temporary file does not block the next write.
    write_events(path, [], detector, params, mode="recreate")
    assert path.exists()


# ---- provenance ------------------------------------------------------------------------


def test_detector_and_params_provenance_round_trip(big_file, detector, params):
    path, _ = big_file
    with read_events(path) as f:
        back = f.detector
        assert f.format_version == FORMAT_VERSION
        assert f.attrs["photonflow_version"]
        assert f.attrs["created"][:2] == "20"
        back_params = f.params
    assert back.name == detector.name == "TOY_CYLINDER"
    assert back.shape == detector.shape
    assert back.sensor_models == detector.sensor_models
    for name in ("sensor_positions", "sensor_normals", "sensor_radius", "sensor_type"):
        np.testing.assert_array_equal(getattr(back, name), getattr(detector, name))
    for name, value in params.to_dict().items():
        stored = back_params.to_dict()[name]
        assert stored.shape == value.shape
        np.testing.assert_array_equal(stored, value)
    with h5py.File(path, "r") as h5:
        for spec in PARAM_SPECS:
            assert h5["params"][spec.name].attrs["unit"] == spec.unit
            assert h5["params"][spec.name].dtype == np.float64


def test_summary(big_file):
    path, flat = big_file
    summary = summarize_events(path)
    counts = flat["counts"]
    assert summary["format_version"] == FORMAT_VERSION
    assert summary["detector"] == "TOY_CYLINDER" and summary["n_sensors"] == 200
    assert summary["detector_shape"]["kind"] == "cylinder"
    assert summary["n_events"] == N_BIG and summary["total_hits"] == counts.sum()
    assert summary["hits_per_event"] == {
        "mean": pytest.approx(counts.mean()), "min": 0, "max": int(counts.max())
    }
    assert summary["charge_per_event_mean"] == pytest.approx(
        flat["charge"].sum(dtype=np.float64) / N_BIG
    )
    assert summary["time_range"] == (float(flat["time"].min()), float(flat["time"].max()))
    assert summary["source_kinds"] == ["isotropic", "laser", "track"]
    assert summary["particles"] == sorted({"mu-", "e-", "μ+"})
    assert summary["file_size"] == path.stat().st_size
    text = format_summary(summary)
    assert "TOY_CYLINDER" in text and str(N_BIG) in text and "isotropic, laser, track" in text


# ---- bad files -----------------------------------------------------------------------


def test_bad_files_give_one_line_event_file_errors(tmp_path, detector, params):
    missing = tmp_path / "nothing.h5"
    text = tmp_path / "notes.h5"
    text.write_text("not hdf5\n")
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as h5:
        h5.attrs["format"] = "something-else"
    future = write_events(tmp_path / "future.h5", [], detector, params)
    with h5py.File(future, "r+") as h5:
        h5.attrs["format_version"] = FORMAT_VERSION + 1
    truncated = write_events(tmp_path / "trunc.h5", event_stream(make_flat(10)), detector, params)
    with h5py.File(truncated, "r+") as h5:
        del h5["events/hits/time"]
    cases = {
        missing: "no such file",
        text: "not an HDF5 file",
        foreign: "not a photonflow event file",
        future: "newer",
        truncated: "malformed",
        tmp_path: "directory",
    }
    for path, reason in cases.items():
        for opener in (read_events, summarize_events, EventFile):
            with pytest.raises(EventFileError) as excinfo:
                opener(path)
            assert reason in one_line_error(excinfo, path)
            error = excinfo.value  # no h5py traceback chained to the message
            assert error.__cause__ is None
            assert error.__context__ is None or error.__suppress_context__


def test_corrupt_detector_group_is_an_event_file_error(tmp_path, detector, params):
    path = write_events(tmp_path / "det.h5", [], detector, params)
    with h5py.File(path, "r+") as h5:
        h5["detector"].attrs["shape"] = '{"kind": "pyramid"}'
    with read_events(path) as f, pytest.raises(EventFileError) as excinfo:
        _ = f.detector
    assert "/detector" in one_line_error(excinfo, path)


# ---- the records themselves --------------------------------------------------------------


def test_event_is_a_validated_pytree():
    event = make_event([1, 2, 3], [1.0, 2.0, 0.5], [10, 20, 30], Truth("laser", energy=3.0))
    assert event.sensor_ids.dtype == np.int32 and event.charge.dtype == np.float32
    assert event.n_hits == 3
    total = jax.jit(lambda e: e.charge.sum() + e.truth.energy)(event)
    assert float(total) == pytest.approx(6.5)
    leaves, treedef = jax.tree_util.tree_flatten(event)
    assert jax.tree_util.tree_unflatten(treedef, leaves).truth.source_kind == "laser"
    assert Truth().seed == -1 and np.isnan(Truth().position).all() and Truth().is_unknown
    with pytest.raises(ConfigError, match="charge"):
        make_event([1, 2], [1.0], [1.0, 2.0])
    with pytest.raises(ConfigError, match="whole"):
        make_event([1.5], [1.0], [1.0])
    with pytest.raises(AttributeError):
        event.charge = None


def test_event_writer_context_manager(tmp_path, detector, params):
    path = tmp_path / "w.h5"
    flat = make_flat(40)
    events = list(event_stream(flat))
    with EventWriter(path, detector, params, chunk_events=16) as writer:
        writer.append(events[0])
        writer.extend(events[1:])
        assert writer.n_events == 40
        assert not path.exists()
    with read_events(path) as f:
        assert_events_match(f, flat)
    with pytest.raises(EventFileError, match="not open"):
        writer.append(events[0])
