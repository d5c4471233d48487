"""Expected mode for particle tracks: the direct-light quadrature against a brute-force
integral of the same emission model, smoothness in the track, jit/grad/vmap without NaN,
and the checks on bad tracks."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import photonflow as pf
from photonflow.emission import emission_model
from photonflow.errors import ConfigError
from photonflow.generator import stack_tracks
from photonflow.geometry.sensor_arrays import sensors_for
from photonflow.response.detection import acceptance_at_cos
from photonflow.transport.optics import interaction_rates
from photonflow.transport.track_direct import (
    DIRECT_COMPONENTS,
    NEAR_FROM,
    nearness,
    track_direct_light,
)
from photonflow.transport.track_expected import _skewed_indirect

pytestmark = pytest.mark.compile_bound


@pytest.fixture(scope="module")
def toy():
    detector = pf.load_detector("TOY_CYLINDER")
    return detector, pf.default_params(detector)


def _brute_force(sensors, params, emission, start, direction, index, points=200001):
    """mu_j by trapezoids over 200,001 points of the track: rho(s, cos) averaged over the
    disc's footprint / 2 pi x the disc solid angle x QE x acceptance x attenuation,
    integrated in s (the footprint's half-width from the unit vector e_theta)."""
    s = np.linspace(0.0, float(emission.extent), points)
    centre = np.asarray(sensors.positions[index], np.float64)
    normal = np.asarray(sensors.normals[index], np.float64)
    radius = float(sensors.radius[index])
    to_sensor = centre[None] - (start[None] + s[:, None] * direction[None])
    length = np.linalg.norm(to_sensor, axis=1)
    cos_track = to_sensor @ direction / length
    cos_in = -(to_sensor @ normal) / length
    reach = np.sqrt(length**2 + radius**2)
    omega = np.maximum(cos_in, 0.0) * 2 * np.pi * radius**2 / (reach * (reach + length))
    sight = to_sensor / length[:, None]
    e_theta = (cos_track[:, None] * sight - direction[None]) \
        / np.sqrt(1.0 - cos_track**2)[:, None]
    width = np.sqrt(1.0 - cos_track**2) * radius / reach \
        * np.sqrt(np.maximum(1.0 - (e_theta @ normal) ** 2, 0.0))
    density = np.asarray(emission.density(jnp.asarray(s), jnp.asarray(cos_track),
                                          jnp.asarray(width)))
    acceptance = np.asarray(acceptance_at_cos(params.angular_acceptance, jnp.asarray(cos_in)))
    rate = float(interaction_rates(params)[3])
    integrand = density / (2 * np.pi) * omega * float(params.quantum_efficiency) * acceptance \
        * np.exp(-rate * length)
    return np.trapezoid(integrand, s)


def test_direct_light_quadrature_matches_a_brute_force_integral():
    """On SK (a 1 GeV muon): the sensors that hold 80 % of the light agree with the
    brute-force integral within 1 %, and their sum within 0.3 %."""
    with jax.enable_x64(True):
        detector = pf.load_detector("SK")
        params = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), pf.default_params(detector))
        emission = emission_model("mu-", "water", np.float64).at(1000.0)
        sensors = sensors_for(detector, np.float64, near=False)
        start, direction = np.array([1.0, -2.0, 0.5]), np.array([0.6, 0.8, 0.0])
        charge, _, _ = track_direct_light(sensors, params, jnp.asarray(start),
                                          jnp.asarray(direction), 0.0, emission)
        charge = np.asarray(charge).sum(axis=1)  # the direct components together

        order = np.argsort(charge)[::-1]
        main = order[: np.searchsorted(np.cumsum(charge[order]), 0.8 * charge.sum())]
        picked = main[:: max(1, len(main) // 12)]
        brute = np.array([_brute_force(sensors, params, emission, start, direction, j)
                          for j in picked])
        np.testing.assert_allclose(charge[picked], brute, rtol=0.01)
        assert charge[picked].sum() == pytest.approx(brute.sum(), rel=0.003)


def test_direct_light_next_to_the_sensors_matches_traced_photons_of_the_model(toy):
    """A 600 MeV muon 0.6 m from the barrel, heading out (its ring lands on sensors a few
    of their radii away): the direct light against an independent Monte Carlo of the
    same emission model, 400,000 photons drawn from its density and traced to the sensor
    discs (attenuation, acceptance, QE x the spectral factor): the total within 1.5 %,
    the two brightest sensors (97 % of the light) within 3 % each."""
    from photonflow.emission.models import cherenkov_spectral_factor
    from photonflow.geometry.intersect import detector_ray_hits
    from photonflow.transport.tracks import principal_sensor_model

    detector, params = toy
    start, direction = np.array([1.4, 0.0, 0.5]), np.array([1.0, 0.0, 0.0])
    track = pf.Track("mu-", start, direction, 600.0, 0.0)
    charge = np.asarray(pf.expected(detector, params, track,
                                    config=pf.TransportConfig(n_bounces=0)).charge, float)
    emission = emission_model("mu-", "water").at(600.0)
    s_edges, cos_edges = np.linspace(0.0, 0.6, 241), np.linspace(-1.0, 1.0, 4001)
    grid_s, grid_c = np.meshgrid(s_edges, cos_edges, indexing="ij")
    density = np.asarray(emission.density(jnp.asarray(grid_s), jnp.asarray(grid_c)), float)
    cells = density[:-1, :-1] * np.diff(s_edges)[:, None] * np.diff(cos_edges)[None, :]
    rng = np.random.default_rng(1)
    count = 400_000
    i, j = np.unravel_index(rng.choice(cells.size, count, p=(cells / cells.sum()).ravel()),
                            cells.shape)
    s = s_edges[i] + rng.random(count) * np.diff(s_edges)[i]
    cos = cos_edges[j] + rng.random(count) * np.diff(cos_edges)[j]
    azimuth = 2 * np.pi * rng.random(count)
    sine = np.sqrt(1 - cos**2)
    rays = np.stack([cos, sine * np.cos(azimuth), sine * np.sin(azimuth)], axis=1)
    hit, distance = (np.asarray(x) for x in detector_ray_hits(
        detector, jnp.asarray(start + s[:, None] * direction, jnp.float32),
        jnp.asarray(rays, jnp.float32)))
    seen = hit >= 0
    cos_in = -np.sum(rays[seen] * np.asarray(detector.sensor_normals)[hit[seen]], axis=1)
    weight = np.exp(-float(interaction_rates(params)[3]) * distance[seen]) * np.asarray(
        acceptance_at_cos(params.angular_acceptance, jnp.asarray(cos_in, jnp.float32)))
    traced = np.bincount(hit[seen], weights=weight, minlength=detector.n_sensors)
    traced *= cells.sum() / count * float(params.quantum_efficiency) \
        * cherenkov_spectral_factor(principal_sensor_model(detector), "water")
    assert charge.sum() == pytest.approx(traced.sum(), rel=0.015)
    brightest = np.argsort(traced)[::-1][:2]
    assert traced[brightest].sum() > 0.95 * traced.sum()
    np.testing.assert_allclose(charge[brightest], traced[brightest], rtol=0.03)


def test_a_short_track_keeps_its_total_light():
    """A 20 MeV electron in SK (light over ~10 cm, shorter than the rays' 0.25 m
    smearing): the expected total p.e. (all optics) within 3 % of generator + sampled
    transport (100 events, statistical error 0.9 %; soft track ends as wide as the
    smearing had put 12 % too much light)."""
    from photonflow.transport.sampled import sample_photon_bundle
    from photonflow.transport.tracks import spectral_params, track_light, track_photons

    detector = pf.load_detector("SK")
    base = pf.default_params(detector)
    params = base.replace(dark_rate=base.dark_rate * 0)
    track = pf.Track("e-", [2.0, -1.0, 3.0], [0.0, 0.6, 0.8], 20.0, 0.0)
    expected = float(jnp.sum(pf.expected(detector, params, track).charge))
    light = track_light(detector)
    totals = [float(jnp.sum(sample_photon_bundle(
        detector, spectral_params(params, light), track_photons(detector, track, 3, k, light),
        jax.random.key(k), source_time=0.0).n_pe)) for k in range(100)]
    assert expected == pytest.approx(np.mean(totals), rel=0.03)


def test_the_prediction_moves_smoothly_with_the_track(toy):
    """Moving the start by 1 mm changes every sensor's direct light as the gradient says
    (no stripes from the quadrature), in float64. (The rays of the indirect light move
    with the track and can hit or miss a disc: piecewise smooth, not tested here.)"""
    detector, params = toy
    with jax.enable_x64(True):
        params = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), params)
        predict = pf.expected_function(detector, jnp.float64,
                                       config=pf.TransportConfig(n_bounces=0))

        def charges(position):
            return predict(params, pf.Track("mu-", position, jnp.array([0.0, 0.6, 0.8]),
                                            400.0, 0.0)).charge

        start = jnp.array([0.1, -0.2, -0.3])
        step = jnp.array([1e-3, 0.0, 0.0])
        change = charges(start + step) - charges(start)
        linear = jax.jacfwd(charges)(start) @ step
        scale = float(jnp.max(jnp.abs(change)))
        assert scale > 0
        np.testing.assert_allclose(change, linear, atol=0.02 * scale)


def test_the_near_field_switches_on_without_a_step():
    """The near field's sub-discs are computed only where some disc, seen from the
    track's light, has an angular radius above ``NEAR_FROM``. A 10 MeV electron in WCTE
    (3-inch PMTs, light over 4.6 cm) moved along x across the point where its nearest
    disc reaches that angular radius, float64: the light on either side of the switch
    joins (the total charge and the charge-weighted time change as the trapezoid rule
    on their derivatives says, within 1e-9), and its derivative, forward and reverse
    mode, is the central difference on both sides (1e-6)."""
    detector = pf.load_detector("WCTE")
    with jax.enable_x64(True):
        params = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), pf.default_params(detector))
        sensors = sensors_for(detector, jnp.float64)
        emission = emission_model("e-", "water", jnp.float64).at(10.0)
        direction = jnp.array([1.0, 0.0, 0.0])

        def nearest(x):
            return float(jnp.max(nearness(sensors, jnp.array([x, 0.0, 0.0]), direction,
                                          emission.extent)))

        low, high = 0.0, 0.5  # far at the centre, near 0.5 m towards the barrel
        assert nearest(low) < NEAR_FROM < nearest(high)
        for _ in range(60):  # bisection for the switch
            middle = 0.5 * (low + high)
            if nearest(middle) > NEAR_FROM:
                high = middle
            else:
                low = middle

        @jax.jit
        def light(x):
            charge, mean, _ = track_direct_light(sensors, params, jnp.stack([x, 0.0, 0.0]),
                                                 direction, 0.0, emission)
            return jnp.stack([jnp.sum(charge), jnp.sum(charge * mean)])

        forward, reverse = jax.jit(jax.jacfwd(light)), jax.jit(jax.jacrev(light))
        switch, gap, h = 0.5 * (low + high), 1e-5, 1e-6
        before, after = np.asarray(light(switch - gap)), np.asarray(light(switch + gap))
        slopes = np.asarray(forward(switch - gap)) + np.asarray(forward(switch + gap))
        np.testing.assert_allclose(after - before, gap * slopes,  # the trapezoid rule
                                   atol=1e-9 * np.abs(before).max())
        for x in (switch - gap, switch + gap, switch - 1e-3, switch + 1e-3):
            central = (np.asarray(light(x + h)) - np.asarray(light(x - h))) / (2 * h)
            np.testing.assert_allclose(forward(x), central, rtol=1e-6)
            np.testing.assert_allclose(reverse(x), central, rtol=1e-6)


#: The optical and sensor fields of ``Params`` the track light depends on (scalars).
OPTICS_FIELDS = ("absorption_length", "scattering_length", "mie_length", "mie_g",
                 "group_index", "wall_reflectivity", "wall_specular_fraction",
                 "sensor_reflectivity", "quantum_efficiency", "tts")


def test_autodiff_matches_finite_differences_for_the_optics(toy):
    """The full likelihood of a sampled muon event (direct + 2 bounces, charge + first-hit
    time) against relative changes of each optical field (``OPTICS_FIELDS``; Mie
    scattering over 60 m; the track 0.5 m from the barrel): autodiff agrees with
    central differences (float64) within 1 % of each derivative (or 1e-3 of the
    largest)."""
    detector, params = toy
    params = params.replace(mie_length=np.float32(60.0))  # default: none (infinite)
    track = pf.Track("mu-", (1.5, 0.0, -0.5), (0.0, 1.0, 0.0), 600.0, 0.0)
    event = pf.sample(detector, params, track, seed=6)
    with jax.enable_x64(True):
        params = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), params)
        track = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), track)
        predict = pf.expected_function(detector, jnp.float64,
                                       config=pf.TransportConfig(n_rays=128, n_bounces=2))

        def loss(change):
            scaled = params.replace(**{name: getattr(params, name) * (1.0 + change[k])
                                       for k, name in enumerate(OPTICS_FIELDS)})
            return pf.nll(predict(scaled, track), event)

        value_and_grad = jax.jit(jax.value_and_grad(loss))
        zero = jnp.zeros(len(OPTICS_FIELDS))
        gradient = np.asarray(value_and_grad(zero)[1])
        h = 1e-5
        central = np.array([(value_and_grad(h * e)[0] - value_and_grad(-h * e)[0]) / (2 * h)
                            for e in np.eye(len(OPTICS_FIELDS))])
        assert np.all(np.isfinite(gradient))
        assert np.count_nonzero(np.abs(gradient) > 1e-3 * np.max(np.abs(gradient))) >= 7
        np.testing.assert_allclose(gradient, central, rtol=0.01,
                                   atol=1e-3 * np.max(np.abs(gradient)))


def test_grad_jit_and_vmap_through_expected(toy):
    """Gradients of the total charge and of the direct time with respect to all track
    parameters are finite (a track aimed at a sensor and one grazing a wall included);
    below the Cherenkov threshold the light and its energy derivative are zero; vmap over
    a batch equals one call per track."""
    detector, params = toy
    # direct light only: the indirect light's gradients are checked against finite
    # differences above
    predict = pf.expected_function(detector, config=pf.TransportConfig(n_bounces=0))
    sensor = np.asarray(detector.sensor_positions[5])
    aimed = sensor / np.linalg.norm(sensor)
    starts = jnp.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.3, 0.2]])
    directions = jnp.array([aimed, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])

    def summary(position, direction, energy, time):
        prediction = predict(params, pf.Track("e-", position, direction, energy, time))
        return jnp.sum(prediction.charge) + 1e-3 * jnp.sum(prediction.time_mean[:, 0])

    value_and_grad = jax.jit(jax.value_and_grad(summary, argnums=(0, 1, 2, 3)))
    for position, direction in zip(starts, directions, strict=True):
        _, grads = value_and_grad(position, direction, 300.0, 2.0)
        assert all(bool(jnp.all(jnp.isfinite(g))) for g in grads)
    threshold = emission_model("e-", "water").energy_range[0]
    _, grads = value_and_grad(starts[1], directions[1], 0.9 * threshold, 0.0)
    below = predict(params, pf.Track("e-", starts[1], directions[1], 0.9 * threshold, 0.0))
    assert float(jnp.sum(below.charge)) == 0.0 and float(grads[2]) == 0.0
    batch = stack_tracks([pf.Track("e-", p, d, 300.0, 0.0) for p, d in
                          zip(np.asarray(starts), np.asarray(directions), strict=True)])
    batched = jax.vmap(lambda track: predict(params, track).charge)(batch)
    for k in range(3):
        np.testing.assert_allclose(batched[k], predict(params, batch[k]).charge, rtol=1e-3,
                                   atol=1e-6)


def test_bad_tracks_are_refused(toy):
    """A track outside the detector, or beyond the emission tables, is refused in one
    line before anything is computed."""
    detector, params = toy
    with pytest.raises(ConfigError, match=r"track.position = .*outside"):
        pf.expected(detector, params, pf.Track("mu-", [0.0, 0.0, 50.0], [0, 0, 1], 500.0))
    top = emission_model("mu-", "water").energy_range[1]
    with pytest.raises(ConfigError, match="track.energy = .*beyond the emission tables"):
        pf.expected(detector, params, pf.Track("mu-", [0.0, 0.0, 0.0], [0, 0, 1], top * 1.5))
    # the tables' top energy itself (5 GeV) is accepted
    direct = pf.TransportConfig(n_bounces=0)
    at_top = pf.expected(detector, params, pf.Track("mu-", [0.0, 0.0, 0.0], [0, 0, 1], 5000.0),
                         config=direct)
    assert float(jnp.sum(at_top.charge)) > 0
    # a concrete track closed over by a traced function (here the params are traced) is
    # checked the same way, and a good one traces
    with pytest.raises(ConfigError, match="track.energy = .*beyond the emission tables"):
        jax.eval_shape(lambda p: pf.expected(detector, p, pf.Track(
            "mu-", [0.0, 0.0, 0.0], [0, 0, 1], top * 1.5), config=direct).charge, params)
    traced = jax.eval_shape(lambda p: pf.expected(detector, p, pf.Track(
        "mu-", [0.0, 0.0, 0.0], [0, 0, 1], 500.0), config=direct).charge, params)
    assert traced.shape == (detector.n_sensors,)


def test_indirect_components_keep_their_moments_and_start_at_the_onset():
    """Each bounce order's component keeps its mean and variance (exponential delay tau
    plus Gaussian: mean m, variance s^2), takes the skewness 2 s / d of the gamma
    distribution of those moments that starts at the onset (d = m - onset), and a
    component wider than d is an exponential from the onset (no Gaussian width)."""
    onset = np.array([10.0, 10.0, 10.0, 10.0])
    mean_indirect = np.array([40.0, 40.0, 25.0, 10.05])  # d = 30, 30, 15, 0.05 ns
    spread = np.array([6.0, 24.0, 30.0, 5.0])  # s < d, s < d, s > d, s > d (tiny d)
    zeros = np.zeros((4, DIRECT_COMPONENTS))
    charge = np.ones((4, DIRECT_COMPONENTS + 1))
    mean = np.concatenate([zeros + 12.0, mean_indirect[:, None]], axis=1)
    variance = np.concatenate([zeros + 4.0, spread[:, None] ** 2], axis=1)
    _, shifted, gaussian, tau = (np.asarray(x, np.float64) for x in _skewed_indirect(
        jnp.asarray(charge), jnp.asarray(mean), jnp.asarray(variance), jnp.asarray(onset)))
    np.testing.assert_array_equal(tau[:, :DIRECT_COMPONENTS], 0.0)  # direct: untouched
    np.testing.assert_allclose(shifted[:, :DIRECT_COMPONENTS], 12.0)
    tau, shifted, gaussian = tau[:, -1], shifted[:, -1], gaussian[:, -1]
    narrow = slice(0, 2)
    np.testing.assert_allclose((shifted + tau)[narrow], mean_indirect[narrow], rtol=1e-6)
    np.testing.assert_allclose((gaussian + tau ** 2)[narrow], spread[narrow] ** 2, rtol=1e-5)
    skewness = 2.0 * tau ** 3 / spread ** 3  # that of an exponentially modified Gaussian
    np.testing.assert_allclose(skewness[narrow], 2.0 * spread[narrow] / 30.0, rtol=1e-5)
    np.testing.assert_allclose(tau[2], 15.0, rtol=1e-6)  # wide: exponential from the onset
    np.testing.assert_allclose(shifted[2], 10.0, rtol=1e-6)
    assert gaussian[2] == 0.0
    # a component at the onset is Gaussian (a delay below SHORTEST_TAIL), as it was
    assert tau[3] == 0.0 and gaussian[3] == pytest.approx(25.0)
    gradient = jax.grad(lambda v: jnp.sum(jnp.stack(_skewed_indirect(
        jnp.asarray(charge), jnp.asarray(mean), v, jnp.asarray(onset))[1:])))(
        jnp.asarray(variance))
    assert np.all(np.isfinite(np.asarray(gradient)))


def test_direct_arrival_times_match_the_sampled_photons():
    """SK, a 1 GeV muon, no scattering or reflection, no transit-time spread: for the 20
    brightest sensors the predicted mean arrival time of the direct light agrees with the
    median arrival time of the generator + sampled-transport photoelectrons (8 events)
    within 0.1 ns (a muon's light lies within ~0.1 ns of the light-speed front; time
    offsets taken from 0.5 ns histogram bins were 0.25 ns late)."""
    from photonflow.transport.sampled import sample_photon_bundle
    from photonflow.transport.tracks import spectral_params, track_light, track_photons

    detector = pf.load_detector("SK")
    base = pf.default_params(detector)
    params = base.replace(scattering_length=np.float32(1e6), mie_length=np.float32(1e6),
                          wall_reflectivity=np.float32(0.0),
                          sensor_reflectivity=np.float32(0.0))
    track = pf.Track("mu-", [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], 1000.0, 0.0)
    prediction = pf.expected(detector, params, track, config=pf.TransportConfig(n_bounces=0))
    charge = np.asarray(prediction.charge)
    weights = np.asarray(prediction.time_weight)
    main = np.argmax(weights, axis=1)
    mean = np.asarray(prediction.time_mean)[np.arange(len(main)), main]
    brightest = np.argsort(charge)[::-1][:20]
    light = track_light(detector)
    times = {int(j): [] for j in brightest}
    for index in range(8):
        photons = track_photons(detector, track, 11, index, light)
        tally = sample_photon_bundle(detector, spectral_params(params, light), photons,
                                     jax.random.key(index), source_time=0.0)
        sensors, arrival = np.asarray(tally.photon_sensor), np.asarray(tally.photon_time)
        for j in times:
            times[j].extend(arrival[sensors == j])
    sampled = np.array([np.median(times[int(j)]) for j in brightest])
    np.testing.assert_allclose(mean[brightest], sampled, atol=0.2)
    assert abs(np.median(mean[brightest] - sampled)) < 0.1


def test_moments_of_a_nearly_dark_run_have_finite_gradients():
    """A run of the quadrature's panels far from the Cherenkov peak can hold ~1e-20 p.e.;
    the derivatives of its light-weighted moments (~1 / light^2) overflowed float32 and
    made the SK event likelihood's gradient NaN during a fit. Below
    ``LIGHT_FLOOR`` a run has fixed moments: finite gradients, whatever the light."""
    from photonflow.transport.track_direct import LIGHT_FLOOR, mixed_moments

    def moments(x, scale):
        charge = scale * jnp.exp(jnp.stack([x, 2.0 * x]))
        mean = 36.0 + jnp.stack([x, 3.0 * x])
        variance = jnp.stack([4.0 + x, 4.0])
        total, first, second = mixed_moments(charge, mean, variance, axis=0)
        return total + first + second

    for scale in (5e-21, 1e-13, 1e-3, 1.0):
        gradient = jax.grad(moments)(jnp.float32(0.1), jnp.float32(scale))
        assert np.isfinite(float(gradient)), scale
    # above the floor the moments move with the light's times
    assert float(jax.grad(moments)(jnp.float32(0.1), jnp.float32(1.0))) > 1.0
    assert LIGHT_FLOOR < 1e-9


def test_the_scintillation_indirect_gaussian_starts_after_the_onset():
    """The scintillation light's merged indirect component (the last of each decay
    time's group) keeps its charge and mean, and its Gaussian is narrowed to lie
    ``ONSET_SPREADS`` spreads after the onset (scattered and reflected light cannot
    arrive before it; a symmetric Gaussian of the whole spread put ~10 % of TAO's
    indirect light there); the direct pairs and the decay weights are untouched, and
    the gradients are finite, at the onset too."""
    from photonflow.transport.track_expected import ONSET_SPREADS, _decayed

    onset = np.array([10.0, 10.0, 10.0])
    width = DIRECT_COMPONENTS + 2  # direct components, then two indirect ones
    charge = np.ones((3, width))
    mean = np.concatenate([np.full((3, DIRECT_COMPONENTS), 12.0),
                           np.array([[14.0, 16.0], [30.0, 30.0], [10.0, 10.0]])], axis=1)
    variance = np.concatenate([np.full((3, DIRECT_COMPONENTS), 0.04),
                               np.array([[9.0, 9.0], [1.0, 1.0], [4.0, 4.0]])], axis=1)
    times, weights = (2.0, 20.0), (0.7, 0.3)
    out = [np.asarray(x, np.float64) for x in _decayed(
        *(jnp.asarray(x) for x in (charge, mean, variance, onset)), times, weights)]
    groups = DIRECT_COMPONENTS // 2 + 1
    indirect = [groups * k + groups - 1 for k in range(len(times))]
    np.testing.assert_allclose(out[0][:, indirect], [2.0 * np.array(weights)] * 3)  # charges
    np.testing.assert_allclose(out[1][:, indirect[0]], [15.0, 30.0, 10.0])  # means kept
    np.testing.assert_array_equal(out[3][:, indirect], [times] * 3)
    # row 0's whole spread (variance 9 + 1 between the two) puts its onset 1.6 sigma
    # below its mean: narrowed to (15 - 10) / ONSET_SPREADS. Row 1 is far from it
    # (kept); row 2 sits at the onset (no Gaussian width left)
    expected = [(5.0 / ONSET_SPREADS) ** 2, 1.0, 0.0]
    np.testing.assert_allclose(out[2][:, indirect[0]], expected, rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(out[2][:, 0], 0.04, rtol=1e-3)  # a direct pair: untouched
    gradient = jax.grad(lambda m, v: sum(jnp.sum(x) for x in _decayed(
        jnp.asarray(charge), m, v, jnp.asarray(onset), times, weights)), argnums=(0, 1))(
        jnp.asarray(mean), jnp.asarray(variance))
    assert all(np.all(np.isfinite(np.asarray(g))) for g in gradient)


def test_a_track_cut_by_the_wall_gets_every_direct_component(toy):
    """A 1 GeV muon crossing the toy cylinder (its light ends at the wall after 2 m of
    the model's 5.4 m): its direct light is split into ``DIRECT_COMPONENTS`` stretches
    of the part that lights the detector, every one lit (the last, whose light meets
    the wall close by, least: 5 %). With stretches of the model's whole extent the last
    two stayed dark (56 and 44 % in the first two), each of those spread over a metre
    of track, putting light before the earliest arrival (TAO's first hits:
    docs/tracks.md)."""
    from photonflow.transport.track_expected import _inside_length

    detector, params = toy
    emission = emission_model("mu-", "water", np.float32).at(1000.0)
    sensors = sensors_for(detector, np.float32, near=False)
    start, direction = jnp.zeros(3), jnp.array([0.6, 0.8, 0.0])
    length = _inside_length(detector.shape, start, direction)
    assert float(length) < 0.6 * float(emission.extent)  # the wall ends the light
    charge = np.asarray(track_direct_light(sensors, params, start, direction, 0.0, emission,
                                           length)[0], np.float64)
    shares = charge.sum(axis=0) / charge.sum()
    assert shares.shape == (DIRECT_COMPONENTS,) and np.all(shares > 0.02), shares
