"""Direct light from tables of the emission's moments along the track (far sensors):
the Gauss rule and energy weights against exact results, the light against the
quadrature of ``track_direct``."""

import jax
import jax.numpy as jnp
import numpy as np

import photonflow as pf
from photonflow.emission import emission_model, moments
from photonflow.geometry.sensor_arrays import sensors_for
from photonflow.transport import track_direct, track_moments


def test_two_node_rule_integrates_cubics_exactly():
    """For measures on [0, 1] (Beta densities of several shapes and a point mass pair),
    the rule from the moments T_0 ... T_3 integrates 1, x, x^2, x^3 exactly."""
    with jax.enable_x64(True):
        x = np.linspace(0.0, 1.0, 200001)
        measures = [x**a * (1 - x) ** b for a, b in ((1, 1), (0.5, 3), (4, 0.3), (8, 8))]
        for density in measures:
            raw = np.array([np.trapezoid(density * x**k, x) for k in range(4)])
            nodes, weights = track_moments._gauss_nodes(jnp.asarray(raw[None]))
            nodes, weights = np.asarray(nodes[0]), np.asarray(weights[0])
            assert np.all((nodes >= 0) & (nodes <= 1)) and np.all(weights > 0)
            for k in range(4):
                np.testing.assert_allclose(raw[0] * np.sum(weights * nodes**k), raw[k],
                                           rtol=1e-6)


def test_energy_weights_are_local_and_exact_at_nodes_and_for_lines():
    """Cubic Hermite weights in log E: 1 at a node, sum 1, and exact for a function
    linear in log E between nodes of uneven spacing."""
    with jax.enable_x64(True):
        nodes = jnp.log(jnp.asarray([10.0, 20.0, 35.0, 70.0, 100.0, 200.0]))
        for energy in (10.0, 27.0, 35.0, 99.0, 150.0, 200.0):
            weights, index = moments._energy_terms(nodes, jnp.asarray(energy))
            assert abs(float(jnp.sum(weights)) - 1.0) < 1e-12
            line = 3.0 + 2.0 * nodes
            assert abs(float(weights @ line[index]) - (3.0 + 2.0 * np.log(energy))) < 1e-9
        weights, index = moments._energy_terms(nodes, jnp.asarray(35.0))
        np.testing.assert_allclose(np.asarray(weights)[np.asarray(index) == 2].sum(), 1.0,
                                   atol=1e-12)


def test_far_light_matches_the_quadrature_for_a_muon_in_sk():
    """A 1 GeV muon from the centre of SK (float32): the tabulated light agrees with the
    quadrature (``track_direct``'s discs, no near field) in total within 0.2 %
    (measured 0.04 %), per sensor within 1 % light-weighted rms (0.49 %), and in mean
    arrival time within 0.05 ns rms (0.004 ns)."""
    detector = pf.load_detector("SK")
    params = pf.default_params(detector)
    sensors = sensors_for(detector)
    model = emission_model("mu-", "water", kind="tables")
    energy = jnp.asarray(1000.0, jnp.float32)
    emission = model.at(energy)
    position = jnp.zeros(3, jnp.float32)
    direction = jnp.asarray([1.0, 0.0, 0.0], jnp.float32)
    quadrature = track_direct._disc_light(
        sensors.positions, sensors.normals, sensors.radius, params=params,
        position=position, direction=direction, time=0.0, emission=emission,
        extent=emission.extent, breaks=track_direct.PANEL_BREAKS)
    expected, expected_time, _ = (np.asarray(x) for x in
                                  track_direct.mixed_moments(*quadrature, axis=1))
    charge, mean, _ = (np.asarray(x[:, 0]) for x in track_moments.far_direct_light(
        sensors.positions, sensors.normals, sensors.radius, params=params,
        position=position, direction=direction, time=0.0, emission=emission,
        peak=track_direct.peak_cos(emission)))
    assert abs(charge.sum() / expected.sum() - 1.0) < 2e-3
    lit = expected > 1e-3 * expected.max()
    weight = expected[lit] / expected[lit].sum()
    relative = charge[lit] / expected[lit] - 1.0
    assert np.sqrt(np.sum(weight * relative**2)) < 0.01
    assert np.sqrt(np.sum(weight * (mean[lit] - expected_time[lit]) ** 2)) < 0.05
