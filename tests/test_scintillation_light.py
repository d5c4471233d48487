"""Scintillation light in the expected mode: exponentially modified time components
against scipy, the tables' deposit histogram against an exact integral, the scintillation
model against its table, and its direct light against isotropic point sources along the
track (the calibration-source transport, an independent path)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import exponnorm, norm

import photonflow as pf
from photonflow.emission import scintillation_emission
from photonflow.emission.spline import distance_groups
from photonflow.generator import emission_tables as tables
from photonflow.geometry.sensor_arrays import sensors_for
from photonflow.prediction import Prediction
from photonflow.transport.direct import direct_light_jit
from photonflow.transport.track_direct import track_direct_light


def test_exponentially_modified_components_match_scipy():
    """A mixture of an exponentially modified Gaussian (tau 4.93 ns, sigma 1.5 ns) and a
    Gaussian: density and CDF equal scipy's from -50 to 300 ns (1e-9 relative where the
    density exceeds 1e-30), the CDF reaches 1, and gradients are finite in the far
    tails (t - mu = -60 ns and +290 ns)."""
    with jax.enable_x64(True):
        mean, sigma, tau = 10.0, 1.5, 4.93

        def prediction(tau_value):
            return Prediction(charge=jnp.ones(1), time_weight=jnp.array([[0.3, 0.7]]),
                              time_mean=jnp.array([[mean, mean]]),
                              time_sigma=jnp.array([[sigma, sigma]]),
                              time_tau=jnp.stack([tau_value, 0.0])[None])

        p = prediction(jnp.asarray(tau))
        for t in (-50.0, 0.0, 8.0, 10.0, 15.0, 40.0, 120.0, 300.0):
            pdf = 0.3 * exponnorm.pdf(t, tau / sigma, loc=mean, scale=sigma) \
                + 0.7 * norm.pdf(t, mean, sigma)
            cdf = 0.3 * exponnorm.cdf(t, tau / sigma, loc=mean, scale=sigma) \
                + 0.7 * norm.cdf(t, mean, sigma)
            got = float(p.time_pdf(jnp.array([t]))[0])
            if pdf > 1e-30:
                assert got == pytest.approx(pdf, rel=1e-9)
            assert float(p.time_cdf(jnp.array([t]))[0]) == pytest.approx(cdf, rel=1e-9,
                                                                          abs=1e-15)
        for t in (-50.0, 300.0):
            gradient = jax.grad(lambda x, t=t: prediction(x).time_logpdf(jnp.array([t]))[0])(
                jnp.asarray(tau))
            assert np.isfinite(float(gradient))


def test_deposit_histogram_spreads_each_segment_over_its_bins():
    """A segment from 0.05 to 0.25 m carrying 2 MeV over bins 0.1 m wide puts 0.5, 1,
    0.5 MeV in the first three; a point deposit at 0.15 m falls in the second; a segment
    given end first counts the same."""
    edges = np.array([0.0, 0.1, 0.2, 0.3, 0.4])
    got = tables.segment_histogram(np.array([0.05, 0.15, 0.25]), np.array([0.25, 0.15, 0.05]),
                                   np.array([2.0, 3.0, 1.0]), edges)
    np.testing.assert_allclose(got, [0.5 + 0.25, 1.0 + 3.0 + 0.5, 0.5 + 0.25, 0.0])


@pytest.mark.parametrize("particle", ["mu-", "e-"])
def test_the_scintillation_model_reproduces_its_table(particle):
    """At the table's energies the model's light integrates to light yield x the
    tabulated visible energy (0.5 %; that beyond the distance range, < 5 %: an
    electron's far bremsstrahlung deposits, spread over the range), the light up to
    each knot along the track follows the table's deposit within 2 % of the total (a
    knot interval smooths an electron's sharp end), and the shipped table holds the
    visible energy to 0.2 % (statistical)."""
    table = tables.shipped_table(particle, "scintillator")
    model = scintillation_emission(particle, "scintillator", np.float64)
    assert table.scintillating
    visible = table.visible_total
    assert np.all(table.visible_error <= 0.002 * visible)
    assert np.all(table.visible_energy.sum(axis=1) >= 0.95 * visible)
    for row in (len(table.energies) // 2, len(table.energies) - 3):
        energy = float(table.energies[row])
        piece = model.at(energy)
        edges = table.distance_edges[row]
        s = np.linspace(0.0, edges[-1], 4001)
        per_m = 2.0 * np.asarray(piece.density(jnp.asarray(s), jnp.zeros_like(s)))
        total = np.trapezoid(per_m, s)
        assert total == pytest.approx(model.light_yield * visible[row], rel=5e-3)
        # the light up to each edge of the model's knot intervals against the table's
        # (whose deposit per bin is scaled to the total)
        cumulative = np.concatenate([[0.0], np.cumsum(0.5 * (per_m[1:] + per_m[:-1])
                                                      * np.diff(s))])
        groups = distance_groups(edges.size - 1)
        table_cumulative = model.light_yield * np.concatenate(
            [[0.0], np.cumsum(table.visible_energy[row])])[groups] \
            * visible[row] / table.visible_energy[row].sum()
        np.testing.assert_allclose(np.interp(edges[groups], s, cumulative), table_cumulative,
                                   atol=0.02 * total)


def test_scintillation_direct_light_equals_isotropic_point_sources_along_the_track():
    """In TAO, the direct scintillation light of a 1 GeV muon's slice (quadrature in the
    angle to the track) equals the direct light of isotropic point sources at 400
    Gauss-Legendre nodes along it (the calibration-source transport): 0.3 % in total, and
    per sensor within 1 % for the sensors that hold 90 % of the light of those more than
    5 disc radii from the track."""
    with jax.enable_x64(True):
        detector = pf.load_detector("TAO")
        params = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), pf.default_params(detector))
        sensors = sensors_for(detector, jnp.float64)
        piece = scintillation_emission("mu-", "scintillator", np.float64).at(1000.0)
        start = np.array([0.1, -0.2, 0.3])
        direction = np.array([0.6, 0.0, 0.8])
        length = float(detector.shape.ray_exit(start[None], direction[None])[0])
        charge, _, _ = track_direct_light(sensors, params, jnp.asarray(start),
                                          jnp.asarray(direction), jnp.asarray(0.0), piece,
                                          jnp.asarray(length))
        got = np.asarray(charge).sum(axis=1)
        nodes, weights = np.polynomial.legendre.leggauss(400)
        s = 0.5 * length * (nodes + 1.0)
        per_m = 2.0 * np.asarray(piece.density(jnp.asarray(s), jnp.zeros_like(s)))
        reference = np.zeros(detector.n_sensors)
        for point, photons in zip(start + s[:, None] * direction,
                                  0.5 * length * weights * per_m, strict=True):
            source = pf.IsotropicSource(jnp.asarray(point), jnp.asarray(photons))
            reference += np.asarray(direct_light_jit(sensors, params, source)[0])
        assert got.sum() == pytest.approx(reference.sum(), rel=3e-3)
        # away from the exit (a disc a few radii from the track is not a point for the
        # sources, nor is it for the quadrature: the sampled mode judges those)
        centres = np.asarray(detector.sensor_positions)
        along = np.clip((centres - start) @ direction, 0.0, length)
        gap = np.linalg.norm(centres - start - along[:, None] * direction, axis=1)
        far = gap > 5.0 * float(sensors.radius[0])
        order = np.argsort(np.where(far, reference, 0.0))[::-1]
        held = order[: np.searchsorted(np.cumsum(reference[order]), 0.9 * reference[far].sum())]
        np.testing.assert_allclose(got[held], reference[held], rtol=0.01)
        print(far.size - far.sum(), np.abs(got[held] / reference[held] - 1).max())
