"""The batch command ``photonflow reconstruct`` (issue 25): a job killed outright
(SIGKILL) and resumed on two Dask workers writes the same file as an uninterrupted
serial one, events that cannot be fitted are recorded and the job goes on, and
file-level problems are one line with exit code 2. ``photonflow evaluate`` summarises a
reconstruction file against the truth.

The toy detector, direct light only and short fits (the file's content, not the fits'
quality, is under test); the subprocesses share a persistent compilation cache in the
test's folder, so that only the first compiles."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

import photonflow as pf
from photonflow.io import make_event, write_events
from photonflow.io.reco_file import RecoTable, read_reco
from photonflow.provenance import code_identity
from photonflow.reconstruction.batch import reconstruct_events
from photonflow.reconstruction.evaluation import contained_events, summarize

#: Short fits (the file's content and the job's bookkeeping are under test, not the fits).
#: Short fits reported with H^-1 (no simulated events: their cost, ~5 s per job, is
#: tested in-process by test_reconstruction.py; their seeds come from the hits alone).
FAST = ["--bounces", "0", "--fits", "1", "--restarts", "0", "--scan-directions", "0",
        "--max-iterations", "3", "--variability-events", "0"]
CONFIG = pf.TransportConfig(n_bounces=0)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A folder with ``events.h5``: three sampled muons in the toy and one event without
    hits (recorded as a failure), and ``reference.h5``, their uninterrupted serial job."""
    path = tmp_path_factory.mktemp("batch")
    detector = pf.load_detector("TOY_CYLINDER")
    params = pf.default_params(detector)
    events = []
    for k, (position, direction) in enumerate([([0.3, -0.2, 0.1], [0.6, 0.8, 0.1]),
                                               ([-0.4, 0.3, -0.5], [0.0, -0.6, 0.8]),
                                               ([0.2, 0.5, 0.4], [-0.9, 0.1, -0.3])]):
        track = pf.Track("mu-", position, np.asarray(direction) / np.linalg.norm(direction),
                         300.0, 0.0)
        events.append(pf.sample(detector, params, track, seed=10 + k, config=CONFIG))
    events.insert(2, make_event([], [], []))
    write_events(path / "events.h5", events, detector, params)
    run(path, "reconstruct", "events.h5", "--out", "reference.h5", *FAST)
    return path


def environment(folder):
    return {**os.environ, "PHOTONFLOW_COMPILATION_CACHE": str(folder / "jax-cache")}


def run(folder, *args, check=True):
    done = subprocess.run([sys.executable, "-m", "photonflow", *args], cwd=folder,
                          capture_output=True, text=True, timeout=900,
                          env=environment(folder))
    if check:
        assert done.returncode == 0, done.stderr
    return done


def same_file(a, b) -> None:
    """Two reconstruction files hold the same rows (every dataset but the wall times)."""
    with h5py.File(a, "r") as first, h5py.File(b, "r") as second:
        assert first.attrs["run"] == second.attrs["run"]
        for group in ("reco", "truth"):
            assert set(first[group]) == set(second[group])
            for name in first[group]:
                if name == "seconds":
                    continue
                x, y = first[group][name][()], second[group][name][()]
                assert x.shape == y.shape, name
                if x.dtype.kind == "f":
                    np.testing.assert_array_equal(x, y, err_msg=name)
                else:
                    assert np.all(x == y), name


def rows_written(partial) -> int:
    """Rows counted in a partial file another process is writing (0 if unreadable)."""
    try:
        with h5py.File(partial, "r", locking=False) as h5:
            return int(h5["reco"].attrs["n_events"])
    except (OSError, KeyError):
        return 0


def test_the_reference_job_records_every_event(folder):
    table = read_reco(folder / "reference.h5")
    assert len(table) == 4
    assert table.run["code"] == code_identity()  # a resume must run the same code
    assert list(table.reco["event"]) == [0, 1, 2, 3]
    assert table.reco["failure"][2] == "no hits"
    assert all(f == "" for k, f in enumerate(table.reco["failure"]) if k != 2)
    with pf.read_events(folder / "events.h5") as events:
        for k in (0, 1, 3):
            np.testing.assert_array_equal(table.truth["position"][k],
                                          events[k].truth.position)
    fitted = [0, 1, 3]
    assert np.all(np.isfinite(table.reco["position"][fitted]))
    assert np.all(np.isfinite(table.reco["nll"][fitted]))
    assert set(table.reco["particle"]) == {"mu-"}
    assert np.isnan(table.reco["energy"][2]) and table.truth["particle"][2] == ""
    # without simulated events: H^-1 reported and kept, no bias or correction
    np.testing.assert_array_equal(table.reco["fisher_covariance"][fitted],
                                  table.reco["covariance"][fitted])
    assert np.all(np.isnan(table.reco["bias"])) and np.all(np.isnan(table.reco["correction"]))
    # a file written before those fields existed reads them as NaN
    old = folder / "without_later_fields.h5"
    shutil.copyfile(folder / "reference.h5", old)
    with h5py.File(old, "r+") as h5:
        del h5["reco/fisher_covariance"], h5["reco/bias"], h5["reco/correction"]
    earlier = read_reco(old)
    assert np.all(np.isnan(earlier.reco["bias"])) and earlier.reco["bias"].shape == (4, 7)
    np.testing.assert_array_equal(earlier.reco["covariance"], table.reco["covariance"])


def test_a_job_killed_midway_and_resumed_on_two_workers_writes_the_serial_file(folder):
    """Killed outright (SIGKILL) once its first row is written, the serial job resumed with
    ``--workers 2`` (the rest of the events shared by two Dask workers) writes the file
    of the uninterrupted serial job: the resume loses and duplicates nothing, and the
    workers give the serial results (one job tests both: each costs a job's start-up)."""
    partial = folder / ".killed.h5.partial"
    process = subprocess.Popen([sys.executable, "-m", "photonflow", "reconstruct",
                                "events.h5", "--out", "killed.h5", *FAST], cwd=folder,
                               env=environment(folder), stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 600
    while rows_written(partial) < 1:
        assert process.poll() is None and time.monotonic() < deadline
        time.sleep(0.05)
    process.send_signal(signal.SIGKILL)
    process.wait()
    kept = rows_written(partial)
    assert 1 <= kept < 4 and not (folder / "killed.h5").exists()
    resumed = run(folder, "reconstruct", "events.h5", "--out", "killed.h5", *FAST,
                  "--resume", "--workers", "2")
    assert f"resumed at event {kept}" in resumed.stdout
    assert not partial.exists()
    same_file(folder / "reference.h5", folder / "killed.h5")


def test_file_level_problems_are_one_line_and_exit_2(folder):
    """A calibration of another detector, a resume with other settings or with nothing
    to resume, an existing output, a file that is not an event file."""
    other = pf.load_detector("TOY_SPHERE")
    params = {name: np.asarray(v).tolist() for name, v in
              pf.default_params(other).to_dict().items()}
    from photonflow.calibration.result import FORMAT

    (folder / "other.json").write_text(json.dumps({"format": FORMAT, "version": 1,
                                                   "params": params}))
    (folder / "junk.h5").write_bytes(b"not hdf5")
    cases = [
        (["--params", "other.json", "--out", "x.h5"], "--params"),
        (["--out", "x.h5", "--resume"], "no interrupted job"),
        (["--out", "reference.h5"], "file exists"),
        (["--out", "x.h5", "--particle", "tau"], "particle"),
        (["--out", "x.h5", "--overdispersion", "0.7"], "--overdispersion"),
        (["--out", "x.h5", "--rays", "0"], "--rays"),
        (["--out", "x.h5", "--threads", "0"], "--threads"),
        (["--out", "x.h5", "--variability-events", "3"], "--variability-events"),
        (["--out", "x.h5", "--emission-model", "table"], "--emission-model"),
        (["--out", "plots_folder"], "is a folder"),
        (["--out", "events.h5", "--mode", "recreate"], "the event file itself"),
    ]
    (folder / "plots_folder").mkdir(exist_ok=True)
    for extra, words in cases:
        done = run(folder, "reconstruct", "events.h5", *FAST, *extra, check=False)
        assert done.returncode == 2 and words in done.stderr, (extra, done.stderr)
        assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    done = run(folder, "reconstruct", "junk.h5", "--out", "x.h5", check=False)
    assert done.returncode == 2 and "junk.h5" in done.stderr
    assert not (folder / "x.h5").exists()


def test_bad_events_are_recorded_and_the_batch_goes_on(folder):
    """Non-finite hits, sensor ids out of range, all hits in one sensor: recorded
    failures with their reasons, in order, without a fit; a serial job resumed at an
    event (``first_event``) gives the results from that event on."""
    detector = pf.load_detector("TOY_CYLINDER")
    params = pf.default_params(detector)
    bad = [make_event([1, 2], [1.0, math.nan], [3.0, 4.0]),
           make_event([1, 2], [1.0, 1.0], [3.0, math.inf]),
           make_event([1, 900], [1.0, 1.0], [3.0, 4.0]),
           make_event([5, 5], [1.0, 1.0], [3.0, 4.0])]
    results = list(reconstruct_events(detector, params, bad, "auto", config=CONFIG))
    reasons = [r.failure for r in results]
    assert reasons == ["non-finite hit charge", "non-finite hit time",
                       "sensor id 900 out of range (the detector has 200 sensors)",
                       "all hits in one sensor"]
    assert all(not r.converged and math.isnan(r.energy) for r in results)
    resumed = reconstruct_events(detector, params, bad, "auto", config=CONFIG, first_event=2)
    assert [r.failure for r in resumed] == reasons[2:]


def test_evaluate_summarises_against_the_truth(folder):
    done = run(folder, "evaluate", "reference.h5", "--out", "summary.json", "--plots",
               "plots")
    summary = json.loads((folder / "summary.json").read_text())
    muons = summary["particles"]["mu-"]
    table = read_reco(folder / "reference.h5")
    distance = 100 * np.linalg.norm(table.reco["position"] - table.truth["position"], axis=1)
    fitted = [k for k in range(4) if table.reco["failure"][k] == ""]
    assert muons["n_events"] == 3 and muons["n_failed"] == 0
    assert summary["particles"][""]["n_failed"] == 1 if "" in summary["particles"] else \
        summary["particles"]["unknown"]["n_failed"] == 1
    assert math.isclose(muons["vertex_68_cm"], np.quantile(distance[fitted], 0.68))
    assert muons["misid_rate"] is None  # a mu- job identifies nothing
    assert "vertex cm" in done.stdout
    assert sorted(p.name for p in (folder / "plots").iterdir()) == ["errors.png",
                                                                   "pulls.png"]


def test_summary_quantities_on_a_known_table():
    """The summary's definitions on a hand-made table: errors along and across the true
    direction, the angle, the energy bias, misidentification and pull widths."""
    n = 200
    rng = np.random.default_rng(0)
    along = rng.normal(0, 0.1, n)
    direction = np.tile([0.0, 0.0, 1.0], (n, 1))
    covariance = np.tile(np.diag([0.1**2, 0.1**2, 0.2**2, 1.0, 1e-4, 1e-4, 0.01]),
                         (n, 1, 1))
    energy = 1000.0 * np.exp(rng.normal(0.02, 0.1, n))
    reco = {"event": np.arange(n), "particle": np.array(["mu-"] * (n - 10) + ["e-"] * 10,
                                                         dtype=object),
            "position": np.stack([np.zeros(n), np.zeros(n), 2 * along], 1),
            "time": rng.normal(0, 1, n), "direction": direction, "energy": energy,
            "covariance": covariance, "errors": np.zeros((n, 6)), "nll": np.zeros(n),
            "log_likelihood_ratio": np.full(n, -5.0), "converged": np.ones(n, bool),
            "iterations": np.ones(n, int), "evaluations": np.ones(n, int),
            "seconds": np.full(n, 2.0), "failure": np.array([""] * n, dtype=object)}
    truth = {"particle": np.array(["mu-"] * n, dtype=object), "position": np.zeros((n, 3)),
             "direction": direction, "energy": np.full(n, 1000.0), "time": np.zeros(n)}
    summary = summarize(RecoTable(reco=reco, truth=truth, run={"particle": "auto"},
                                  attrs={}))
    muons = summary["particles"]["mu-"]
    assert muons["misid_rate"] == pytest.approx(10 / n)
    assert muons["transverse_68_cm"] == pytest.approx(0.0, abs=1e-9)
    assert muons["longitudinal_68_cm"] == pytest.approx(
        np.quantile(np.abs(200 * along), 0.68))
    assert muons["direction_68_deg"] == pytest.approx(0.0, abs=1e-6)
    assert muons["energy_bias_frac"] == pytest.approx(np.median(energy / 1000 - 1))
    assert muons["energy_resolution_68_frac"] == pytest.approx(np.quantile(
        np.abs(energy / 1000 - 1 - np.median(energy / 1000 - 1)), 0.68))
    assert muons["seconds_per_event"] == 2.0
    widths = muons["pull_width"]
    assert widths["z"] == pytest.approx(1.0, abs=0.15)  # 2 x N(0, 0.1) / 0.2
    assert widths["time"] == pytest.approx(1.0, abs=0.15)
    assert widths["log_energy"] == pytest.approx(1.0, abs=0.15)
    assert widths["x"] == 0.0


def test_contained_events_are_those_whose_light_ends_inside():
    """In the toy cylinder (radius 2 m), a 300 MeV muon's light (extent 1.38 m) from
    1.5 m off the axis ends inside when it heads inwards (3.5 m to the wall) and leaves
    when it heads outwards (0.5 m); a 300 MeV electron's (2.07 m) leaves from the centre
    towards the barrel (2 m); a particle without an emission model, a vertex outside
    the detector and an energy above the model's range are unknown; the summary has the
    contained events' numbers beside all events'."""
    detector = pf.load_detector("TOY_CYLINDER")
    n = 6
    truth = {"particle": np.array(["mu-", "mu-", "e-", "gamma", "mu-", "mu-"], dtype=object),
             "position": np.array([[1.5, 0, 0], [1.5, 0, 0], [0, 0, 0], [0, 0, 0],
                                   [3.0, 0, 0], [0, 0, 0]], float),
             "direction": np.array([[-1.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0],
                                    [-1.0, 0, 0], [0, 0, 1.0]]),
             "energy": np.array([300.0, 300, 300, 300, 300, 1e6]), "time": np.zeros(n)}
    reco = {"event": np.arange(n), "particle": truth["particle"],
            "position": truth["position"] + 0.01, "time": np.zeros(n),
            "direction": truth["direction"],
            "energy": np.array([330.0, 600.0, 300, 300, 300, 1e6]),
            "covariance": np.tile(np.eye(7), (n, 1, 1)), "errors": np.zeros((n, 6)),
            "nll": np.zeros(n), "log_likelihood_ratio": np.full(n, np.nan),
            "converged": np.ones(n, bool), "iterations": np.ones(n, int),
            "evaluations": np.ones(n, int), "seconds": np.ones(n),
            "failure": np.array([""] * n, dtype=object)}
    table = RecoTable(reco=reco, truth=truth, run={"particle": "mu-"}, attrs={},
                      detector=detector)
    contained = contained_events(table)
    np.testing.assert_array_equal(contained[:3], [1.0, 0.0, 0.0])
    assert np.all(np.isnan(contained[3:]))
    muons = summarize(table)["particles"]["mu-"]
    assert muons["n_events"] == 4 and muons["contained"]["n_events"] == 1
    assert muons["contained"]["energy_68_frac"] == pytest.approx(0.1)
    assert summarize(dataclasses.replace(table, detector=None))["particles"]["mu-"][
        "contained"] is None
