"""Tests of ``photonflow.likelihood`` and ``photonflow.prediction``."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, stats

from photonflow.errors import ConfigError
from photonflow.io.events import Event
from photonflow.likelihood import (
    MU_BLEND,
    MU_SWITCH,
    OVERDISPERSED_BLEND,
    OVERDISPERSED_SWITCH,
    charge_logcdf,
    charge_logpdf,
    dark_expectation,
    first_hit_logpdf,
    nll,
    sensor_nll,
)
from photonflow.params import N_ACCEPTANCE_ANGLES, PARAM_SPECS, Params
from photonflow.prediction import Prediction
from photonflow.response import single_pe_charges

pytestmark = pytest.mark.compile_bound

SPE_WIDTH = 0.4
WINDOW = (0.0, 100.0)
WEIGHTS = (0.7, 0.3)
MEANS = (40.0, 55.0)
SIGMAS = (3.0, 8.0)


def make_params(n: int, dark_rate: float = 0.0, spe_width: float = SPE_WIDTH) -> Params:
    """Params with the given dark rate (Hz) and single-p.e. width; the rest nominal."""
    values = {spec.name: 1.0 for spec in PARAM_SPECS}
    values.update(
        mie_g=0.0,
        refractive_index=1.33,
        group_index=1.38,
        wall_reflectivity=0.1,
        wall_specular_fraction=0.5,
        sensor_reflectivity=0.3,
        quantum_efficiency=0.25,
        efficiency=np.ones(n),
        time_offset=np.zeros(n),
        angular_acceptance=np.ones(N_ACCEPTANCE_ANGLES),
        spe_width=spe_width,
        dark_rate=dark_rate,
    )
    return Params.from_dict(values)


def make_prediction(mu, n: int) -> Prediction:
    """n identical sensors expecting mu signal p.e. with the two-component time mixture."""
    dtype = jnp.zeros(()).dtype
    return Prediction.from_components(
        jnp.full(n, mu, dtype=dtype), jnp.asarray(WEIGHTS), jnp.asarray(MEANS),
        jnp.asarray(SIGMAS),
    )


def hits(ids, charge, time) -> Event:
    """Event with float arrays of the current default dtype (no float32 rounding)."""
    dtype = jnp.zeros(()).dtype
    return Event(
        np.asarray(ids, dtype=np.int32), np.asarray(charge, dtype=dtype),
        np.asarray(time, dtype=dtype),
    )


def simpson(y, x):
    return integrate.simpson(y, x=x)


# (a) P(unhit) + integral of p(hit, q, t) dq dt = 1 -----------------------------------------


def charge_grid(q_range, dq):
    """Charge nodes (p.e.) with a node just below and one at zero, where the density of
    one photoelectron (a normal truncated at 0) jumps, so each side integrates smoothly."""
    lo, hi = q_range
    if lo >= 0:
        return np.linspace(lo, hi, 2 * int(round((hi - lo) / dq / 2)) + 1)
    left = np.linspace(lo, -1e-12, 2 * int(round(-lo / dq / 2)) + 1)
    right = np.linspace(0.0, hi, 2 * int(round(hi / dq / 2)) + 1)
    return np.concatenate([left, right])


def integrate_charge(values, q):
    """Simpson integral over the charge axis (last), piecewise on either side of zero."""
    split = int(np.searchsorted(q, 0.0))
    if split in (0, q.size):
        return simpson(values, q)
    return simpson(values[..., :split], q[:split]) + simpson(values[..., split:], q[split:])



@pytest.mark.parametrize(
    ("mu", "dark_rate", "threshold", "q_range", "dq", "overdispersion"),
    [
        (0.0, 1e6, None, (-3.0, 12.0), 0.05, 0.0),
        (0.05, 0.0, None, (-3.0, 12.0), 0.05, 0.0),
        (1.0, 1e6, None, (-3.0, 15.0), 0.05, 0.0),
        (3.0, 2e6, 0.3, (0.3, 20.0), 0.05, 0.0),
        (40.0, 1e6, None, (-3.0, 90.0), 0.1, 0.0),
        (70.0, 0.0, None, (-3.0, 140.0), 0.1, 0.0),
        (150.0, 1e6, None, (40.0, 260.0), 0.25, 0.0),
        # overdispersed: exact sum, the blend into the Gamma model, Gamma only
        (1.0, 1e6, None, (-3.0, 40.0), 0.05, 0.3),
        (3.0, 2e6, 0.3, (0.3, 80.0), 0.05, 0.3),
        (10.0, 1e6, None, (-3.0, 160.0), 0.1, 0.3),
        (40.0, 0.0, None, (0.0, 400.0), 0.1, 0.05),
    ],
)
def test_likelihood_is_normalised(mu, dark_rate, threshold, q_range, dq, overdispersion):
    with jax.enable_x64(True):
        q = charge_grid(q_range, dq)
        t = np.linspace(WINDOW[0], WINDOW[1], 401)
        n = q.size
        prediction = make_prediction(mu, n)
        params = make_params(n, dark_rate)

        def density(t_value):
            event = Event(jnp.arange(n, dtype=jnp.int32), jnp.asarray(q), jnp.full(n, t_value))
            return jnp.exp(
                -sensor_nll(
                    prediction, event, params, window=WINDOW, charge_threshold=threshold,
                    overdispersion=overdispersion,
                )
            )

        grid_fn = jax.jit(lambda times: jax.lax.map(density, times, batch_size=16))
        grid = np.asarray(grid_fn(jnp.asarray(t)))  # (n_t, n_q)
        p_hit = simpson(integrate_charge(grid, q), t)
        empty = hits([], [], [])
        unhit_nll = jax.jit(
            lambda p, par: sensor_nll(p, empty, par, window=WINDOW, charge_threshold=threshold,
                                      overdispersion=overdispersion)
        )
        p_unhit = float(np.exp(-unhit_nll(make_prediction(mu, 1), make_params(1, dark_rate))[0]))
        assert p_hit > 1e-3
        assert p_unhit + p_hit == pytest.approx(1.0, abs=2e-6)


# (b) first-hit density against a Monte Carlo Poisson process --------------------------------


def _survival_numpy(t, mu_s, mu_d):
    """P(first hit after t | n >= 1), independently in numpy/scipy."""
    cdf = sum(
        w * stats.norm.cdf(t, loc=m, scale=s)
        for w, m, s in zip(WEIGHTS, MEANS, SIGMAS, strict=True)
    )
    big_lambda = mu_s * cdf + mu_d * np.clip((t - WINDOW[0]) / (WINDOW[1] - WINDOW[0]), 0, 1)
    mu = mu_s + mu_d
    return (np.exp(-big_lambda) - np.exp(-mu)) / (1 - np.exp(-mu))


def test_first_hit_density_matches_poisson_process():
    mu_s, dark_rate = 3.0, 5e6
    with jax.enable_x64(True):
        params = make_params(1, dark_rate)
        mu_d = float(dark_expectation(params, WINDOW))
        edges = np.linspace(WINDOW[0], WINDOW[1], 51)
        fine = np.linspace(WINDOW[0], WINDOW[1], 50 * 64 + 1)
        prediction = make_prediction(mu_s, fine.size)
        density = np.exp(
            np.asarray(first_hit_logpdf(prediction, jnp.asarray(fine), mu_d, WINDOW))
        )
        # p_first = -dS/dt: its integral over each bin equals the drop of the survival.
        bin_prob = np.array(
            [simpson(density[i * 64 : (i + 1) * 64 + 1], fine[i * 64 : (i + 1) * 64 + 1])
             for i in range(50)]
        )
        surv = _survival_numpy(edges, mu_s, mu_d)
        np.testing.assert_allclose(bin_prob, -np.diff(surv), rtol=1e-6, atol=1e-10)
        assert bin_prob.sum() == pytest.approx(1.0, abs=1e-8)

    rng = np.random.default_rng(1)
    n_events = 200_000
    n_sig = rng.poisson(mu_s, n_events)
    n_dark = rng.poisson(mu_d, n_events)
    first = np.full(n_events, np.inf)
    owner = np.repeat(np.arange(n_events), n_sig)
    comp = rng.choice(2, size=owner.size, p=WEIGHTS)
    times = rng.normal(np.take(MEANS, comp), np.take(SIGMAS, comp))
    np.minimum.at(first, owner, times)
    owner = np.repeat(np.arange(n_events), n_dark)
    np.minimum.at(first, owner, rng.uniform(WINDOW[0], WINDOW[1], owner.size))
    first = first[np.isfinite(first)]
    assert first.min() >= WINDOW[0] - 50  # signal tails barely leave the window

    counts, _ = np.histogram(first, bins=edges)
    expected = first.size * bin_prob
    keep = expected > 5
    chi2 = np.sum((counts[keep] - expected[keep]) ** 2 / expected[keep])
    assert stats.chi2.sf(chi2, keep.sum() - 1) > 1e-3
    cdf_fine = integrate.cumulative_trapezoid(density, fine, initial=0.0)
    ks = stats.kstest(first, lambda x: np.interp(x, fine, cdf_fine))
    assert ks.pvalue > 1e-3
    # Sanity: the test can fail — the plain arrival density f(t) is rejected.
    plain = sum(
        w * np.diff(stats.norm.cdf(edges, m, s)) for w, m, s in zip(WEIGHTS, MEANS, SIGMAS,
                                                                     strict=True)
    )
    plain_expected = first.size * plain / plain.sum()
    ok = plain_expected > 5
    chi2_plain = np.sum((counts[ok] - plain_expected[ok]) ** 2 / plain_expected[ok])
    assert stats.chi2.sf(chi2_plain, ok.sum() - 1) < 1e-6


# (c) charge term against a Monte Carlo of summed single-p.e. charges ------------------------


def bin_probability(mu, low, high, nodes=65):
    """Integral of the charge density over [low, high] (p.e.), split at zero."""
    pieces = [(low, high)] if not low < 0 < high else [(low, -1e-12), (0.0, high)]
    total = 0.0
    for a, b in pieces:
        x = np.linspace(a, b, nodes)
        with jax.enable_x64(True):
            dens = np.exp(np.asarray(jax.jit(charge_logpdf)(jnp.asarray(x), mu, SPE_WIDTH)))
        total += simpson(dens, x)
    return total


@pytest.mark.parametrize("mu", [0.3, 3.0, 30.0])
def test_charge_matches_monte_carlo(mu):
    rng = np.random.default_rng(int(mu * 10))
    n = rng.poisson(mu, 400_000)
    n = n[n >= 1]
    # The sampled mode's single-p.e. model: Normal(1, w) truncated at 0, summed over n.
    single = single_pe_charges(rng, int(n.sum()), SPE_WIDTH)
    q = np.add.reduceat(single, np.concatenate([[0], np.cumsum(n)[:-1]]))
    lo, hi = -2.0, mu + 8 * np.sqrt(mu) + 4
    edges = np.linspace(lo, hi, 61)
    with jax.enable_x64(True):
        logcdf = np.asarray(jax.jit(charge_logcdf)(jnp.asarray(edges), mu, SPE_WIDTH))
    prob = np.array([bin_probability(mu, edges[i], edges[i + 1]) for i in range(60)])

    np.testing.assert_allclose(np.diff(np.exp(logcdf)), prob, rtol=1e-6, atol=1e-12)
    counts, _ = np.histogram(q, bins=edges)
    expected = n.size * prob
    keep = expected > 5
    chi2 = np.sum((counts[keep] - expected[keep]) ** 2 / expected[keep])
    assert stats.chi2.sf(chi2, keep.sum() - 1) > 1e-3


# (d) finite values and gradients at the extremes --------------------------------------------


CONFIGS = ((True, None), (True, 0.25), (False, None), (False, 0.25))  # (use_time, threshold)


def test_finite_values_and_gradients_at_extremes():
    window = (0.0, 2.0e4)
    mu = jnp.asarray([0.0, 1e-8, 1.0, 1e4, 0.0, 1e-8, 1.0, 1e4, 0.0, 1e-8, 1e4, 3.0])
    n = mu.size
    prediction = Prediction.from_components(
        mu, jnp.asarray(WEIGHTS), jnp.asarray([100.0, 120.0]), jnp.asarray([1.0, 2.0])
    )
    # sensors 0-3 unhit; 4-7 hit on time; 8-10 hit 1e4 ns late; 11 hit 1e4 ns early
    # (outside the window).
    event = Event.make(
        [4, 5, 6, 7, 8, 9, 10, 11],
        [1.0, 1.0, 1.2, 1e4, 0.5, 3.0, 50.0, 1.0],
        [100.0, 101.0, 99.0, 100.0, 1.01e4, 1.01e4, 1.01e4, -1e4],
    )

    @jax.jit
    def all_values(pred, par):
        return jnp.stack([
            sensor_nll(pred, event, par, window=window, use_time=use_time,
                       charge_threshold=threshold)
            for use_time, threshold in CONFIGS
        ])

    grads = jax.jit(jax.grad(lambda pred, par: jnp.sum(all_values(pred, par)), argnums=(0, 1)))
    for dark_rate in (0.0, 1e3):
        params = make_params(n, dark_rate, spe_width=1.03)
        values = np.asarray(all_values(prediction, params))
        assert np.all(np.isfinite(values))
        assert np.all(values > -60)
        for leaf in jax.tree_util.tree_leaves(grads(prediction, params)):
            assert np.all(np.isfinite(np.asarray(leaf)))
        # unhit with mu = 1e4 costs exactly mu; a hit far from the prediction costs more
        # than one on time.
        mu_dark = float(dark_expectation(params, window))
        assert values[0, 3] == pytest.approx(1e4 + mu_dark, rel=1e-6)
        assert values[0, 8] > values[0, 4]


def test_gradient_matches_finite_difference():
    with jax.enable_x64(True):
        event = hits([0, 2], [1.3, 4.0], [42.0, 37.0])
        params = make_params(3, 2e6)

        @jax.jit
        def loss(mu):
            prediction = Prediction.from_components(
                mu, jnp.asarray(WEIGHTS), jnp.asarray(MEANS), jnp.asarray(SIGMAS)
            )
            return nll(prediction, event, params, window=WINDOW, charge_threshold=0.2)

        mu = jnp.asarray([0.7, 2.0, 3.5])
        grad = np.asarray(jax.grad(loss)(mu))
        eps = 1e-6
        for i in range(3):
            step = jnp.zeros(3).at[i].set(eps)
            fd = (float(loss(mu + step)) - float(loss(mu - step))) / (2 * eps)
            assert grad[i] == pytest.approx(fd, rel=1e-6, abs=1e-8)


# (e) continuity of the Poisson-sum / Gaussian switch ----------------------------------------


def test_charge_model_is_continuous_across_switch():
    mu = jnp.linspace(MU_SWITCH - 2 * MU_BLEND, MU_SWITCH + 2 * MU_BLEND, 8001)
    sd = jnp.sqrt(mu * (1 + SPE_WIDTH**2))
    logpdf = jax.jit(charge_logpdf)
    for k in (-2.0, -1.0, 0.0, 1.0, 2.0):
        values = np.asarray(logpdf(mu + k * sd, mu, SPE_WIDTH))
        assert np.all(np.isfinite(values))
        assert np.max(np.abs(np.diff(values))) < 1e-2
    # Both branches agree at the switch to well within the blend's jump budget.
    with jax.enable_x64(True):
        at = jnp.asarray([MU_SWITCH])
        exact = charge_logpdf(at + 5.0, at, SPE_WIDTH, mu_switch=1e9, blend=1.0)
        gauss = charge_logpdf(at + 5.0, at, SPE_WIDTH, mu_switch=1.0, blend=0.5)
        assert abs(float(exact[0] - gauss[0])) < 0.05


# (f) jit, sum and the time term ---------------------------------------------------------------


def test_jit_and_sum():
    n = 6
    prediction = make_prediction(2.0, n)
    prediction = Prediction(
        prediction.charge * jnp.arange(n, dtype=prediction.charge.dtype),
        prediction.time_weight, prediction.time_mean, prediction.time_sigma,
    )
    params = make_params(n, 1e6)
    event = Event.make([1, 3, 4], [0.8, 2.5, 6.0], [41.0, 38.5, 57.0])
    total_nll = jax.jit(lambda p, e, par: nll(p, e, par, window=WINDOW))
    total = total_nll(prediction, event, params)

    @jax.jit
    def terms(p, e, par):
        mu_dark = dark_expectation(par, WINDOW)
        times = jnp.zeros(n).at[e.sensor_ids].set(e.time)
        return (
            sensor_nll(p, e, par, window=WINDOW),
            sensor_nll(p, e, par, window=WINDOW, use_time=False),
            first_hit_logpdf(p, times, mu_dark, WINDOW),
            p.charge + mu_dark,
        )

    jit_sensor, no_time, log_first, mu_total = (np.asarray(x) for x in terms(
        prediction, event, params))
    assert float(total) == pytest.approx(float(np.sum(jit_sensor)), rel=1e-6)
    # unhit sensors cost mu_total; the time term is exactly the first-hit log density.
    np.testing.assert_allclose(jit_sensor[[0, 2, 5]], mu_total[[0, 2, 5]], rtol=1e-6)
    np.testing.assert_allclose((no_time - jit_sensor)[[1, 3, 4]], log_first[[1, 3, 4]],
                               rtol=1e-5, atol=1e-5)
    # Two hits on one sensor merge: charges add, the earliest time counts.
    merged = Event.make([3, 3], [1.0, 1.5], [45.0, 38.5])
    single = Event.make([3], [2.5], [38.5])
    assert float(total_nll(prediction, merged, params)) == pytest.approx(
        float(total_nll(prediction, single, params)), rel=1e-6
    )


def test_prediction_time_functions():
    prediction = Prediction.from_components(
        jnp.ones(3), jnp.asarray([[2.0, 2.0], [1.0, 0.0], [0.0, 1.0]]),
        jnp.asarray([0.0, 10.0]), jnp.asarray([1.0, 2.0]),
    )
    np.testing.assert_allclose(prediction.time_weight.sum(axis=1), 1.0, rtol=1e-6)
    t = jnp.asarray([10.0, 0.0, 1e4])
    pdf, logpdf, cdf = jax.jit(lambda p, t: (p.time_pdf(t), p.time_logpdf(t), p.time_cdf(t)))(
        prediction, t
    )
    pdf, logpdf = np.asarray(pdf), np.asarray(logpdf)
    expected = [0.5 * stats.norm.pdf(10.0) + 0.5 * stats.norm.pdf(10.0, 10.0, 2.0),
                stats.norm.pdf(0.0), 0.0]
    np.testing.assert_allclose(pdf, expected, rtol=1e-5, atol=1e-30)
    assert np.isfinite(logpdf[2]) and logpdf[2] < -1e6
    np.testing.assert_allclose(cdf, [0.5 + 0.25, 0.5, 1.0], rtol=1e-6)
    grad = jax.jit(jax.grad(lambda p: jnp.sum(p.time_logpdf(t))))(prediction)
    for leaf in jax.tree_util.tree_leaves(grad):
        assert np.all(np.isfinite(np.asarray(leaf)))


def test_second_derivatives_stay_finite_with_a_vanishing_component():
    """A time-mixture component with 2e-21 of a sensor's light (a quadrature panel far
    from the Cherenkov peak, as in SK) leaves the float32 Hessian of the first-hit time
    density finite (it was -inf through log w, and the SK likelihood's Hessian NaN), and
    the density unchanged to 1e-6."""
    weights = jnp.asarray([[2e-21, 0.23, 0.76, 0.01]], jnp.float32)
    weights = weights / jnp.sum(weights)

    def log_density(w):
        prediction = Prediction(jnp.asarray([1.1], jnp.float32), w,
                                jnp.asarray([[20.0, 25.0, 30.0, 60.0]], jnp.float32),
                                jnp.asarray([[1.0, 3.0, 8.0, 20.0]], jnp.float32))
        return prediction.time_logpdf(jnp.asarray([185.0], jnp.float32))[0]

    hessian = jax.hessian(log_density)(weights)
    assert np.all(np.isfinite(np.asarray(hessian)))
    without = weights.at[0, 0].set(0.0)
    assert float(log_density(weights)) == pytest.approx(float(log_density(without)),
                                                        abs=1e-6)


# (g) overdispersion: a gamma-mixed (negative-binomial) count -------------------------------


def _gamma_mixed_counts(rng, mu, r, size):
    """Counts of a Poisson process whose mean mu is scaled by g ~ Gamma(mean 1, var r)."""
    return rng.poisson(mu * rng.gamma(1.0 / r, r, size))


@pytest.mark.parametrize(("mu", "r"), [(0.3, 0.3), (3.0, 0.3), (30.0, 0.3), (8.0, 0.05)])
def test_overdispersed_charge_matches_monte_carlo(mu, r):
    rng = np.random.default_rng(int(mu * 10) + 7)
    n = _gamma_mixed_counts(rng, mu, r, 400_000)
    n = n[n >= 1]
    single = single_pe_charges(rng, int(n.sum()), SPE_WIDTH)
    q = np.add.reduceat(single, np.concatenate([[0], np.cumsum(n)[:-1]]))
    edges = np.quantile(q, np.linspace(0.0, 1.0, 41))[1:-1]
    with jax.enable_x64(True):
        cdf = np.exp(np.asarray(jax.jit(charge_logcdf, static_argnames="overdispersion")(
            jnp.asarray(edges), mu, SPE_WIDTH, overdispersion=r)))
    empirical = np.linspace(0.0, 1.0, 41)[1:-1]
    if mu + 3.0 * np.sqrt(mu + r * mu * mu) < OVERDISPERSED_SWITCH - OVERDISPERSED_BLEND:
        # exact negative-binomial sum: the model's cumulative at the sample's quantiles
        # agrees within the sampling error (~1e-3).
        assert np.max(np.abs(cdf - empirical)) < 4e-3
    else:
        # the Gamma approximation of the charge (mean and variance matched)
        assert np.max(np.abs(cdf - empirical)) < 0.02
    # The Poisson model misses the same sample by far more: the test can fail.
    with jax.enable_x64(True):
        poisson = np.exp(np.asarray(charge_logcdf(jnp.asarray(edges), mu, SPE_WIDTH)))
    assert np.max(np.abs(poisson - empirical)) > 3.0 * np.max(np.abs(cdf - empirical))


def test_overdispersed_first_hit_matches_polya_process():
    mu_s, dark_rate, r = 3.0, 5e6, 0.3
    with jax.enable_x64(True):
        params = make_params(1, dark_rate)
        mu_d = float(dark_expectation(params, WINDOW))
        fine = np.linspace(WINDOW[0], WINDOW[1], 50 * 64 + 1)
        density = np.exp(np.asarray(first_hit_logpdf(
            make_prediction(mu_s, fine.size), jnp.asarray(fine), mu_d, WINDOW, r)))
    cdf_fine = integrate.cumulative_trapezoid(density, fine, initial=0.0)
    assert cdf_fine[-1] == pytest.approx(1.0, abs=1e-6)
    rng = np.random.default_rng(3)
    n_events = 200_000
    gain = rng.gamma(1.0 / r, r, n_events)  # the sensor's whole intensity is scaled
    n_sig, n_dark = rng.poisson(mu_s * gain), rng.poisson(mu_d * gain)
    first = np.full(n_events, np.inf)
    owner = np.repeat(np.arange(n_events), n_sig)
    comp = rng.choice(2, size=owner.size, p=WEIGHTS)
    np.minimum.at(first, owner, rng.normal(np.take(MEANS, comp), np.take(SIGMAS, comp)))
    owner = np.repeat(np.arange(n_events), n_dark)
    np.minimum.at(first, owner, rng.uniform(WINDOW[0], WINDOW[1], owner.size))
    first = first[np.isfinite(first)]
    assert stats.kstest(first, lambda x: np.interp(x, fine, cdf_fine)).pvalue > 1e-3
    # the Poisson first-hit density is rejected by the same sample
    with jax.enable_x64(True):
        poisson = np.exp(np.asarray(first_hit_logpdf(
            make_prediction(mu_s, fine.size), jnp.asarray(fine), mu_d, WINDOW)))
    poisson_cdf = integrate.cumulative_trapezoid(poisson, fine, initial=0.0)
    assert stats.kstest(first, lambda x: np.interp(x, fine, poisson_cdf)).pvalue < 1e-6


def test_overdispersion_tends_to_poisson_and_stays_finite():
    with jax.enable_x64(True):
        mu = jnp.asarray([0.01, 0.3, 2.0, 9.0, 30.0])
        q = jnp.asarray([1.0, 0.7, 2.5, 11.0, 40.0])
        poisson = np.asarray(charge_logpdf(q, mu, 1.03))
        # a small r through the Stirling branch, with the Poisson model's switch (the
        # variance grows by r mu^2: 1e-3 at mu = 30)
        small = np.asarray(charge_logpdf(q, mu, 1.03, overdispersion=1e-6, mu_switch=MU_SWITCH,
                                         blend=MU_BLEND))
    np.testing.assert_allclose(small, poisson, atol=2e-5)
    # values and gradients finite at the extremes, with dark noise and a threshold
    window = (0.0, 2.0e4)
    mu = jnp.asarray([0.0, 1e-8, 1.0, 1e4, 0.0, 1e-8, 1.0, 1e4, 1e-3])
    prediction = Prediction.from_components(
        mu, jnp.asarray(WEIGHTS), jnp.asarray([100.0, 120.0]), jnp.asarray([1.0, 2.0]))
    event = Event.make([4, 5, 6, 7, 8], [1.0, 1.0, 1.2, 1e4, 3.0],
                       [100.0, 101.0, 99.0, 100.0, 1.01e4])
    for threshold in (None, 0.25):
        def total(pred, par, threshold=threshold):
            return nll(pred, event, par, window=window, charge_threshold=threshold,
                       overdispersion=0.3)
        params = make_params(mu.size, 1e3, spe_width=1.03)
        assert np.isfinite(float(jax.jit(total)(prediction, params)))
        for leaf in jax.tree_util.tree_leaves(jax.jit(jax.grad(total, argnums=(0, 1)))(
                prediction, params)):
            assert np.all(np.isfinite(np.asarray(leaf)))


@pytest.mark.parametrize("value", [-0.1, 0.7, "0.3"])
def test_bad_overdispersion_is_refused(value):
    prediction = make_prediction(1.0, 2)
    with pytest.raises(ConfigError, match="overdispersion"):
        nll(prediction, hits([0], [1.0], [40.0]), make_params(2), window=WINDOW,
            overdispersion=value)
