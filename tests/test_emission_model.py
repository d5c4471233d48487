"""The spline emission model against the emission tables it is fitted to: yields and
angular profiles at the nodes, smooth interpolation between them, the threshold, and
jit/grad without NaN."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from photonflow.emission import spline_emission
from photonflow.generator import emission_tables as tables
from photonflow.generator.cherenkov import cherenkov_threshold
from photonflow.generator.constants import MUON_MASS
from photonflow.generator.materials import WATER, refractive_index

pytestmark = pytest.mark.compile_bound


@pytest.fixture(scope="module")
def muon():
    table = tables.shipped_table("mu-")
    threshold = cherenkov_threshold(MUON_MASS, float(refractive_index(WATER, 300.0)))
    return table, spline_emission(table, threshold)


def _integrate(piece, energy_extent, cos_edges, s_points=1201, cos_per_bin=9):
    """Photons per cos bin of the model at one energy: the density integrated over s in
    [0, extent] and over each cos bin (trapezoids on a fine grid)."""
    s = np.linspace(0.0, energy_extent, s_points)
    rows = []
    for low, high in zip(cos_edges[:-1], cos_edges[1:], strict=True):
        c = np.linspace(low, high, cos_per_bin)
        grid_s, grid_c = np.meshgrid(s, c, indexing="ij")
        d = np.asarray(piece.density(jnp.asarray(grid_s.ravel()),
                                     jnp.asarray(grid_c.ravel()))).reshape(grid_s.shape)
        rows.append(np.trapezoid(np.trapezoid(d, c, axis=1), s))
    return np.array(rows)


def test_the_model_reproduces_yield_and_angular_profile_at_the_nodes(muon):
    """At two energy nodes (~200 MeV and ~1.4 GeV): the yield exactly, the density's
    integral within 1 %, and the angular profile over the bins holding 99 % of the
    light with chi2/bin < 2 against the table's standard errors (measured 0.1-0.2:
    studies/tracks/emission_model_report.py)."""
    table, model = muon
    for k in (12, 28):
        energy = float(table.energies[k])
        piece = jax.jit(model.at)(energy)
        profile = _integrate(piece, float(table.distance_edges[k, -1]), table.cos_edges)
        reference = table.photons[k].sum(axis=0)
        assert float(piece.total_yield) == pytest.approx(table.total_yield[k], rel=1e-9)
        assert profile.sum() == pytest.approx(table.total_yield[k], rel=0.01)
        order = np.argsort(reference)[::-1]
        main = order[: np.searchsorted(np.cumsum(reference[order]), 0.99 * reference.sum()) + 1]
        pulls = (profile - reference)[main] / table.angular_error[k][main]
        assert np.mean(pulls**2) < 2.0


def test_between_nodes_the_light_moves_smoothly(muon):
    """Yield and extent between two nodes lie between theirs; the density's energy
    derivative is finite and matches a central difference."""
    table, model = muon
    low, high = float(table.energies[3]), float(table.energies[4])
    middle = float(np.sqrt(low * high))
    piece = model.at(middle)
    assert table.total_yield[3] < float(piece.total_yield) < table.total_yield[4]
    assert table.distance_edges[3, -1] < float(piece.extent) < table.distance_edges[4, -1]
    s, cos = 0.3 * float(piece.extent), 0.745
    gradient = jax.grad(lambda e: model.density(e, s, cos))(middle)
    step = 1e-3 * middle
    central = (model.density(middle + step, s, cos) - model.density(middle - step, s, cos)) \
        / (2 * step)
    assert np.isfinite(float(gradient))
    assert float(gradient) == pytest.approx(float(central), rel=1e-3, abs=1e-6)


def test_threshold_and_clamping(muon):
    """No light below the Cherenkov threshold (smoothly: zero value and gradient), the
    energy clamped above the last node; no NaN in values or gradients anywhere."""
    _, model = muon
    threshold, top = model.energy_range
    assert float(model.yield_at(0.5 * threshold)) == 0.0
    assert float(model.yield_at(top * 2.0)) == pytest.approx(float(model.yield_at(top)))
    energies = jnp.array([0.5 * threshold, threshold, 1.01 * threshold, 1000.0, top, 2 * top])
    for s, cos in ((0.0, 1.0), (1.0, -1.0), (2.0, 0.745), (1e3, 0.0)):
        values = jax.vmap(lambda e, s=s, cos=cos: model.density(e, s, cos))(energies)
        grads = jax.vmap(jax.grad(lambda e, s=s, cos=cos: model.density(e, s, cos)))(energies)
        assert np.all(np.isfinite(values)) and np.all(np.asarray(values) >= 0)
        assert np.all(np.isfinite(grads))
