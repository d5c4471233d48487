"""Particle tracks in sampled mode (issue 4, items 3-4): generated photons thinned by the
sensor's spectral response, transported photon by photon, read out, stored and driven
from the command line."""

import math

import numpy as np
import pytest
from typer.testing import CliRunner

import photonflow as pf
from photonflow.cli import app
from photonflow.errors import ConfigError
from photonflow.generator import GeneratorSettings
from photonflow.geometry.layouts import fibonacci_sphere_layout
from photonflow.geometry.shapes import Sphere
from photonflow.photosensors import peak_response, sensor_model, spectral_keep_probability
from photonflow.transport import SPEED_OF_LIGHT
from photonflow.transport.sampled import sample_photon_bundle, sample_photons
from photonflow.transport.tracks import (
    PhotonBundle,
    event_seeds,
    parse_spectrum,
    random_tracks,
    spectrum_energy,
    track_light,
    track_photons,
)

pytestmark = pytest.mark.compile_bound

#: QE (%) of the SK 20-inch PMT vs wavelength (nm): shared/reference/physics.md section 4
#: ("QE vs lambda", WCSim WCSimPMTObject.cc raw table).
SK_QE_TABLE = {300: 1.4, 340: 16.9, 380: 20.6, 400: 21.1, 420: 20.2, 460: 16.7, 500: 11.6,
               540: 4.3, 600: 0.76}
#: QE (%) of the 3-inch PMT, same source.
MPMT_QE_TABLE = {300: 7.9, 340: 24.0, 380: 27.0, 400: 26.8, 420: 25.9, 460: 22.8, 500: 17.8,
                 540: 10.3, 600: 4.7}
FAST = GeneratorSettings(yield_scale=0.05)


def table_response(table, wavelength):
    """QE(lambda) / QE(400 nm) by linear interpolation of a reference-sheet row."""
    return np.interp(wavelength, list(table), list(table.values())) / table[400]


def assert_same_truth(truth, expected):
    for field in ("source_kind", "particle", "energy", "time", "seed"):
        assert getattr(truth, field) == getattr(expected, field), field
    for field in ("position", "direction"):
        np.testing.assert_array_equal(getattr(truth, field), getattr(expected, field))


def test_spectral_keep_probability_follows_the_reference_tables():
    """Keep probability = QE(lambda) / QE_max; with the QE raised by QE_max / QE(400) the
    detection probability is QE(lambda) / QE(400) times the reference QE (physics.md §4)."""
    wavelengths = np.array([300.0, 320.0, 350.0, 400.0, 433.0, 500.0, 575.0, 600.0])
    sk = sensor_model("R3600")
    assert peak_response(sk) == 1.0  # the SK table peaks at 400 nm
    np.testing.assert_allclose(
        spectral_keep_probability(sk, wavelengths), table_response(SK_QE_TABLE, wavelengths)
    )
    mpmt = sensor_model("R14374")
    assert peak_response(mpmt) == pytest.approx(27.0 / 26.8)  # peak at 380 nm
    np.testing.assert_allclose(spectral_keep_probability(mpmt, 380.0), 1.0)
    np.testing.assert_allclose(
        spectral_keep_probability(mpmt, wavelengths) * peak_response(mpmt),
        table_response(MPMT_QE_TABLE, wavelengths),
    )
    np.testing.assert_array_equal(spectral_keep_probability(sk, [250.0, 650.0]), 0.0)


@pytest.fixture(scope="module")
def big_sphere():
    """A 15 m radius water sphere, 5000 SK PMTs on a Fibonacci lattice (~37 % coverage)."""
    positions, normals = fibonacci_sphere_layout(15.0, 5000)
    detector = pf.make_detector(Sphere(15.0), positions, normals, 0.254, name="BIG_SPHERE")
    return detector, pf.default_params(detector)


def test_muon_charge_matches_the_isotropic_estimate_in_a_large_sphere(big_sphere):
    """A 1 GeV muon centred in a 15 m sphere: every photon starts within 2.3 m of the centre,
    so it meets the wall within 9 degrees of normal incidence (acceptance 1.00 there) after
    13-17 m; its detection probability is then the same in every direction to ~1 %, the
    one of an isotropic point source at the centre. Hence detected photons = sum over the
    generated photons of QE(lambda) / QE(400) (the thinning, from the reference table) x
    (detected fraction of the isotropic source), within 5 % (statistics ~1.2 %)."""
    detector, params = big_sphere
    track = pf.Track("mu-", (0.0, 0.0, -2.2), (0.0, 0.0, 1.0), 1000.0)
    light = track_light(detector)
    seed = 3
    generated = pf.generate(track, event_seeds(seed, 0)[0], medium="water")
    expected_kept = table_response(SK_QE_TABLE, generated.wavelength).sum()
    bundle = track_photons(detector, track, seed, 0, light)
    assert abs(len(bundle.time) - expected_kept) < 5 * math.sqrt(expected_kept)
    assert np.isin(bundle.time, generated.time).all()

    tally = sample_photon_bundle(detector, params, bundle, 1)
    assert tally.emitted == len(bundle.time)
    assert tally.detected + tally.absorbed + tally.lost == tally.emitted
    isotropic = sample_photons(detector, params, pf.IsotropicSource((0.0, 0.0, 0.0), 2e6), 2)
    estimate = expected_kept * isotropic.detected / 2e6
    assert tally.detected == pytest.approx(estimate, rel=0.05)


def test_bundle_photons_start_at_their_own_position_direction_and_time():
    """A pencil beam on the axis of the 2 m radius toy cylinder, aimed horizontally at a
    barrel sensor, emitted at t = 10 ns: that sensor detects most, and the direct photons
    arrive 2 m x n_g / c after 10 ns."""
    detector = pf.load_detector("TOY_CYLINDER")
    params = pf.default_params(detector)
    target = 7
    aim = np.asarray(detector.sensor_positions[target], np.float64)
    start = np.array([0.0, 0.0, aim[2]])
    n = 20000
    bundle = PhotonBundle(
        np.tile(start, (n, 1)), np.tile((aim - start) / np.linalg.norm(aim - start), (n, 1)),
        np.full(n, 10.0),
    )
    tally = sample_photon_bundle(detector, params, bundle, 0, source_time=10.0)
    assert tally.emitted == n and tally.detected > 1000
    # the rest comes back after reflections off the sensor glass and the far wall
    assert np.argmax(tally.n_pe) == target and tally.n_pe[target] > 0.7 * tally.detected
    arrival = 10.0 + np.linalg.norm(aim - start) * float(params.group_index) / SPEED_OF_LIGHT
    assert np.median(tally.photon_time) == pytest.approx(arrival, abs=0.1)


def test_track_event_is_reproducible_and_carries_its_truth():
    """A 1 GeV muon in SK (5 % photon yield): same seed, same event; the truth is the
    track; another seed gives another event."""
    detector = pf.load_detector("SK")
    params = pf.default_params(detector)
    track = pf.Track("mu-", (1.0, -2.0, -5.0), (0.6, 0.0, 0.8), 1000.0, time=5.0)
    first = pf.sample(detector, params, track, 11, generator=FAST)
    again = pf.sample(detector, params, track, 11, generator=FAST)
    other = pf.sample(detector, params, track, 12, generator=FAST)
    for name in ("sensor_ids", "charge", "time"):
        np.testing.assert_array_equal(getattr(first, name), getattr(again, name))
    assert not np.array_equal(first.charge, other.charge)
    assert_same_truth(first.truth, pf.Truth("track", "mu-", np.array(track.position),
                                            np.array(track.direction), 1000.0, 5.0, 11))
    assert first.n_hits > 100 and float(np.sum(first.charge)) > 200


def test_random_tracks_lie_in_the_fiducial_volume_and_are_per_event():
    detector = pf.load_detector("SK")
    tracks = random_tracks(detector, "e-", (100.0, 500.0), 4, 400, fiducial_margin=2.0)
    vertices = np.array([t.position for t in tracks])
    directions = np.array([t.direction for t in tracks])
    energies = np.array([t.energy for t in tracks])
    assert np.asarray(detector.shape.distance_to_wall(vertices)).min() >= 2.0
    radius, half_height = 33.6815 / 2 - 2.0, 36.2 / 2 - 2.0
    inner = np.hypot(vertices[:, 0], vertices[:, 1]) < radius / math.sqrt(2)
    assert abs(inner.mean() - 0.5) < 0.1  # uniform in area: half inside R / sqrt(2)
    assert abs(np.mean(np.abs(vertices[:, 2]) < half_height / 2) - 0.5) < 0.1
    assert np.abs(directions.mean(axis=0)).max() < 0.15  # isotropic
    assert energies.min() >= 100.0 and energies.max() <= 500.0
    assert random_tracks(detector, "e-", (100.0, 500.0), 4, 5)[3] == tracks[3]
    fixed = random_tracks(detector, "mu-", 300.0, 4, 2, vertex=(1.0, 2.0, 3.0),
                          direction=(0.0, 0.0, -1.0))
    np.testing.assert_array_equal(fixed[0].position, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(fixed[1].direction, [0.0, 0.0, -1.0])
    with pytest.raises(ConfigError, match="fiducial margin"):
        random_tracks(detector, "e-", 100.0, 4, 1, fiducial_margin=17.0)


@pytest.mark.parametrize(("spectrum", "gamma"), [("uniform", 0.0), ("power:1", 1.0),
                                               ("power:2.7", 2.7), ("power:-1", -1.0)])
def test_range_energies_follow_the_spectrum_and_the_seed(spectrum, gamma):
    """dN/dE ~ E^-gamma on [20, 2000] MeV: the drawn energies pass a Kolmogorov-Smirnov
    test against the analytic cumulative distribution; event i's energy depends only on
    (seed, i)."""
    from scipy.stats import kstest

    low, high = 20.0, 2000.0
    detector = pf.load_detector("TOY_CYLINDER")
    tracks = random_tracks(detector, "mu-", (low, high), 8, 1500, vertex=(0.0, 0.0, 0.0),
                           spectrum=spectrum)
    energies = np.array([track.energy for track in tracks])
    assert parse_spectrum(spectrum) == gamma
    assert energies.min() >= low and energies.max() <= high

    def cdf(energy):
        if gamma == 1:
            return np.log(energy / low) / np.log(high / low)
        power = 1.0 - gamma
        return (energy**power - low**power) / (high**power - low**power)

    assert kstest(energies, cdf).pvalue > 1e-3
    assert kstest(energies, lambda e: (e - low) / (high - low)).pvalue < 1e-3 or gamma == 0
    again = random_tracks(detector, "mu-", (low, high), 8, 3, vertex=(0.0, 0.0, 0.0),
                          spectrum=spectrum)
    assert [t.energy for t in again] == list(energies[:3])


def test_spectrum_quantiles_and_bad_spectra():
    assert spectrum_energy(0.5, 10.0, 1000.0, 1.0) == pytest.approx(100.0)  # geometric mean
    assert spectrum_energy(0.5, 10.0, 1000.0, 2.0) == pytest.approx(1 / (0.5 / 10 + 0.5 / 1000))
    assert spectrum_energy(0.25, 10.0, 1000.0, 0.0) == pytest.approx(257.5)
    for bad in ("power", "power:", "power:x", "power:nan", "gauss:2", "Uniform"):
        with pytest.raises(ConfigError, match=f"spectrum = '{bad}'"):
            parse_spectrum(bad)


@pytest.mark.parametrize("gamma", [1e6, -1e6, 1e300, -1e300, 40.0, -40.0, 1.0 + 1e-12])
def test_steep_spectra_stay_in_range(gamma):
    """Any finite index gives energies in [low, high], rising with the quantile, piled at
    ``low`` for gamma >> 1 and at ``high`` for gamma << 0 (power:1e6 was a
    ZeroDivisionError, power:-1e6 an OverflowError)."""
    low, high = 100.0, 1000.0
    energies = [spectrum_energy(q, low, high, gamma) for q in (0.0, 1e-300, 0.1, 0.5, 0.999)]
    assert all(math.isfinite(e) and low <= e <= high for e in energies)
    assert energies == sorted(energies)
    if abs(gamma) >= 1e6:
        assert energies[3] == pytest.approx(low if gamma > 0 else high, rel=1e-3)


def test_steep_spectra_agree_with_the_closed_form():
    rng = np.random.default_rng(3)
    for q, low, span, gamma in zip(rng.random(200), rng.uniform(1, 100, 200),
                                   rng.uniform(1.1, 100, 200), rng.uniform(-4, 4, 200),
                                   strict=True):
        power = 1.0 - gamma
        high = low * span
        closed = (low**power + q * (high**power - low**power)) ** (1.0 / power)
        assert spectrum_energy(q, low, high, gamma) == pytest.approx(closed, rel=1e-9)


def test_default_fiducial_margin_scales_with_the_detector():
    """2 m in the large tanks, a quarter of the centre-to-wall distance in small ones,
    so that the default leaves a fiducial volume in every preset."""
    from photonflow.transport.tracks import default_fiducial_margin

    margins = {name: default_fiducial_margin(pf.load_detector(name)) for name in pf.presets()}
    assert margins["SK"] == margins["HK"] == 2.0
    assert margins["TOY_CYLINDER"] == pytest.approx(0.5)
    assert margins["WCTE"] == pytest.approx(0.34, abs=0.005)
    for name, margin in margins.items():
        detector = pf.load_detector(name)
        depth = float(detector.shape.distance_to_wall(np.zeros(3)))
        assert margin == pytest.approx(min(2.0, 0.25 * depth)) and margin < depth, name
        random_tracks(detector, "mu-", 100.0, 0, 2)  # the default leaves a fiducial volume


def test_track_events_round_trip_through_an_event_file(tmp_path):
    detector = pf.load_detector("TOY_CYLINDER")
    params = pf.default_params(detector)
    tracks = random_tracks(detector, "e-", (50.0, 150.0), 5, 3, fiducial_margin=0.5)
    events = list(pf.sample_events(detector, params, tracks, 5, 3, generator=FAST))
    pf.write_events(tmp_path / "e.h5", events, detector, params)
    with pf.read_events(tmp_path / "e.h5") as stored:
        for event, back, track in zip(events, stored, tracks, strict=True):
            assert_same_truth(back.truth, event.truth)
            assert back.truth.source_kind == "track" and back.truth.energy == track.energy
            np.testing.assert_array_equal(back.charge, event.charge)
            np.testing.assert_array_equal(back.sensor_ids, event.sensor_ids)


def test_track_events_from_threads_are_the_serial_events():
    """``threads=3`` gives the serial events, in order: each event's generator and
    transport depend on its index alone, not on the thread or the timing."""
    detector = pf.load_detector("TOY_CYLINDER")
    params = pf.default_params(detector)
    tracks = random_tracks(detector, "e-", (50.0, 150.0), 7, 5, fiducial_margin=0.5)
    serial = list(pf.sample_events(detector, params, tracks, 7, 5, generator=FAST))
    threaded = list(pf.sample_events(detector, params, tracks, 7, 5, generator=FAST,
                                     threads=3))
    assert len({len(event.charge) for event in serial}) > 1  # five different events
    for event, again in zip(serial, threaded, strict=True):
        np.testing.assert_array_equal(again.sensor_ids, event.sensor_ids)
        np.testing.assert_array_equal(again.charge, event.charge)
        np.testing.assert_array_equal(again.time, event.time)
    with pytest.raises(ConfigError, match="threads = 0"):
        list(pf.sample_events(detector, params, tracks, 7, 5, threads=0))


def invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_simulate_particle_writes_track_events(tmp_path):
    out = tmp_path / "e.h5"
    result = invoke("simulate", "--detector", "TOY_CYLINDER", "--particle", "e-",
                    "--energy-range", "50,100", "--spectrum", "power:1", "--events", 2,
                    "--fiducial-margin", 0.5, "--seed", 1, "--out", out)
    assert result.exit_code == 0, result.output
    with pf.read_events(out) as stored:
        truths = [event.truth for event in stored]
    assert [t.particle for t in truths] == ["e-", "e-"]
    assert all(50.0 <= t.energy <= 100.0 for t in truths)
    expected = random_tracks(pf.load_detector("TOY_CYLINDER"), "e-", (50.0, 100.0), 1, 2,
                             fiducial_margin=0.5, spectrum="power:1")
    np.testing.assert_array_equal(truths[1].position, expected[1].position)
    assert [t.energy for t in truths] == [track.energy for track in expected]


@pytest.mark.parametrize(
    ("options", "named"),
    [
        (["--particle", "pi0", "--energy", "100"], "--particle"),
        (["--particle", "mu-", "--energy", "-5"], "--energy"),
        (["--particle", "mu-", "--energy-range", "500,100"], "--energy-range"),
        (["--particle", "mu-"], "--energy"),
        (["--particle", "mu-", "--energy", "100", "--vertex", "40,0,0"], "--vertex"),
        (["--particle", "mu-", "--energy", "100", "--direction", "0,0,0"], "--direction"),
        (["--particle", "mu-", "--energy", "100", "--fiducial-margin", "17"], "fiducial"),
        (["--particle", "mu-", "--energy", "100", "--source", "laser"], "--source"),
        (["--particle", "mu-", "--energy", "100", "--seed", "-1"], "seed = -1"),
        (["--particle", "mu-", "--energy-range", "100,500", "--spectrum", "power:x"],
         "--spectrum = 'power:x'"),
        (["--particle", "mu-", "--energy", "100", "--spectrum", "power:2"],
         "--spectrum = 'power:2'"),
    ],
)
def test_simulate_particle_bad_input_is_one_line_exit_2_and_no_file(tmp_path, options, named):
    out = tmp_path / "x.h5"
    result = invoke("simulate", "--out", out, *options)
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and named in lines[0]
    assert not out.exists()


def test_bundle_input_is_checked_and_may_be_empty():
    detector = pf.load_detector("TOY_CYLINDER")
    params = pf.default_params(detector)
    empty = PhotonBundle(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    tally = sample_photon_bundle(detector, params, empty, 0, source_time=3.0)
    assert tally.emitted == tally.detected == 0 and tally.n_pe.shape == (detector.n_sensors,)
    outside = PhotonBundle(np.array([[0.0, 0.0, 2.5]]), np.array([[0.0, 0.0, 1.0]]), np.zeros(1))
    with pytest.raises(ConfigError, match="1 outside"):
        sample_photon_bundle(detector, params, outside, 0)
    bad = PhotonBundle(np.zeros((2, 3)), np.array([[0.0, 0.0, 2.0]] * 2), np.zeros(2))
    with pytest.raises(ConfigError, match="not unit"):
        sample_photon_bundle(detector, params, bad, 0)
