"""The independent-ray estimator of the calibration (charge likelihood, free fields that
change the light transport): the expected charges M_a of every run from its own rays,
their derivatives J_b from an independent ray set, the score J_b^T [dL/dM_a - bias]
with the second-order (Jensen) bias of the ray noise removed, its Newton matrix and
covariance, and the ray-noise samples that estimate that bias and the noise's share of
the covariance (docs/calibration.md, "Ray noise and the independent-ray score").
Charges in p.e.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError
from .information import charge_information, expected_score_curvature
from .run_terms import (
    RunStatic,
    charge_jacobian_jit,
    charge_score,
    information_blocks,
    mean_jit,
)
from .structured import SandwichCovariance, StructuredMatrix

#: ``fold_in`` tag of a run's independent ray set (its derivatives J of the expected
#: charges, ``CalibrationProblem.independent_ray_curvature``).
JACOBIAN_RAY_STREAM = 0x4A4143


#: ``fold_in`` tag of a run's further ray sets: their expected charges estimate the ray
#: noise of the run's own (``CalibrationProblem.ray_noise_covariance``).
NOISE_RAY_STREAM = 0x4E4F49


#: ``fold_in`` tag of the further ray sets over which the expected charges M_a, their
#: derivatives J_a (``independent_ray_curvature(charge_sets=K)``) and the independent
#: derivatives J_b (``independent_jacobians``) are averaged: the root with K sets of
#: each has 1/K of the ray-noise bias of the root with one
#: (``independent_ray_stage.independent_ray_steps`` extrapolates the two).
EXTRA_RAY_STREAM = 0x434852


#: Ray sets besides the run's own from which ``CalibrationProblem.ray_noise_covariance``
#: estimates the ray noise of the expected charges: the estimate has this many degrees
#: of freedom per run.
RAY_NOISE_SETS = 8


@dataclasses.dataclass(frozen=True)
class IndependentRayParts:
    """The independent-ray estimating equation at one point
    (``CalibrationProblem.independent_ray_curvature``).

    Attributes:
        loss: -log L at the point (with the run's own rays).
        grad_dense: (P,) the score J_b^T [dL/dM_a - bias] of the dense free entries.
        grad_sensor: (N, F) the score of the per-sensor free entries.
        bias_dense: (P,) the part J_b^T bias that was subtracted: the second-order
            (Jensen) bias of dL/dM at ray-sampled charges, 1/2 E[d^3(-log L)/dM^3]
            Var(M_a) (zero without ``RayNoiseSets``).
        bias_sensor: (N, F) the same for the per-sensor free entries.
        newton: the score's expected derivative I J_b J_a^T (not symmetric).
        information: the score's data covariance I J_b J_b^T (symmetric).
        projectors: per run, I J_b (N, T) in float64: a change dM of the run's expected
            charges changes the score by projector^T dM.
        jacobians: per run, J_b (N, T): the derivatives from the independent ray set
            (``CalibrationProblem.independent_ray_score`` reuses them).
    """

    loss: float
    grad_dense: np.ndarray
    grad_sensor: np.ndarray
    bias_dense: np.ndarray
    bias_sensor: np.ndarray
    newton: StructuredMatrix
    information: StructuredMatrix
    projectors: tuple
    jacobians: tuple

    def covariance(self) -> SandwichCovariance:
        """The root's covariance from the data's noise alone (no ray noise)."""
        return SandwichCovariance(self.newton, self.information)


@dataclasses.dataclass(frozen=True)
class RayNoiseSets:
    """The ray noise of every run's expected charges M_a, sampled
    (``CalibrationProblem.ray_noise_sets``).

    Attributes:
        charges: per run, (N,) p.e.: the mean expected charges over the K ray sets.
        deviations: per run, (K, N) p.e.: the expected charges of K independent ray sets
            (the run's own and K - 1 further ones) minus that mean.
    """

    charges: tuple
    deviations: tuple

    def relative_variances(self) -> list[np.ndarray]:
        """Per run, (N,) dimensionless: the sample variance (K - 1 degrees of freedom)
        of a sensor's expected charges over the ray sets over their mean squared. The
        relative variance of M_a is what carries over to other parameters: a sensor's
        efficiency scales its charge and its ray noise alike."""
        return [
            np.sum(d**2, axis=0) / (d.shape[0] - 1) / np.maximum(m, 1e-30) ** 2
            for m, d in zip(self.charges, self.deviations, strict=True)
        ]


def ray_noise_score_bias(mean, variance, spe_width: float) -> jax.Array:
    """(N,) the second-order bias of a run's summed-charge score dL/dM (1/p.e.) when the
    expected charges are ray-sampled, M_a = M + e with zero-mean ray noise e of variance
    ``variance`` (p.e.^2): E[dL/dM(M + e)] - E[dL/dM(M)] = 1/2 E[d^3(-log L)/dM^3] Var(e)
    to second order (Jensen), the expectation over the data at ``mean`` (p.e.;
    ``expected_score_curvature``). ``spe_width`` in p.e., a Python float."""
    return 0.5 * expected_score_curvature(mean, spe_width) * variance


def independent_ray_score_run(theta, base, data, mean, jac_b, relative_variance,
                           static: RunStatic):
    """The independent-ray score of one run (charge likelihood) at expected charges M_a
    (N,) p.e., with derivatives J_b (N, T) from an independent ray set and
    ``relative_variance`` (N,) the variance of M_a's ray noise over M_a^2 (zeros: no
    bias correction). Returns (terms (N,); the score J_b^T [dL/dM_a - bias] as (P,) and
    (N, F), bias from ``ray_noise_score_bias``; the subtracted J_b^T bias as (P,) and
    (N, F))."""
    n_dense = static.layout.n_dense
    terms, score = charge_score(theta, base, data, mean)
    variance = relative_variance * mean * mean
    bias = jac_b * ray_noise_score_bias(mean, variance, static.spe_width)[:, None]
    grad = jac_b * score[:, None] - bias
    return (terms, jnp.sum(grad[:, :n_dense], axis=0), grad[:, n_dense:],
            jnp.sum(bias[:, :n_dense], axis=0), bias[:, n_dense:])


def independent_ray_run(theta, base, data, mean, jac_a, jac_b, relative_variance,
                         static: RunStatic):
    """The independent-ray parts of one run (charge likelihood) from its expected charges
    M_a (N,) p.e. and their derivatives J_a (N, T) (``charge_jacobian`` with the run's
    own rays, or averaged over several ray sets) and the derivatives J_b (N, T) from an
    independent ray set. Returns (``independent_ray_score_run``'s five parts; the score's
    expected derivative I J_b J_a^T as blocks A, C, B, C_upper (not symmetric: rows are
    the score's components, columns the free values); I J_b J_b^T as blocks A, C, B
    (the score's data covariance); and the projector I J_b (N, T): a change dM of the
    expected charges changes the score by projector^T dM)."""
    layout = static.layout
    n_dense = layout.n_dense
    score = independent_ray_score_run(theta, base, data, mean, jac_b, relative_variance, static)
    fisher = charge_information(mean, static.spe_width)
    weight = fisher[:, None, None]
    derivative = weight * jac_b[:, :, None] * jac_a[:, None, :]
    c_upper = jnp.swapaxes(derivative[:, :n_dense, n_dense:], 1, 2)
    information = information_blocks(layout, weight * jac_b[:, :, None] * jac_b[:, None, :])
    return (*score, *information_blocks(layout, derivative), c_upper, *information,
            jac_b * fisher[:, None])


independent_ray_jit = jax.jit(independent_ray_run, static_argnames=("static",))


independent_ray_score_jit = jax.jit(independent_ray_score_run, static_argnames=("static",))


def ray_set_keys(key, n_sets: int) -> list:
    """``key`` and ``n_sets`` - 1 further independent keys derived from it
    (``fold_in(fold_in(key, EXTRA_RAY_STREAM), k)``): the ray sets whose expected charges
    or derivatives are averaged."""
    stream = jax.random.fold_in(key, EXTRA_RAY_STREAM)
    return [key] + [jax.random.fold_in(stream, k) for k in range(int(n_sets) - 1)]


class IndependentRays:
    """The independent-ray estimator as methods of ``CalibrationProblem`` (which inherits
    them): they read its ``arrays``, ``statics``, ``cached``, ``base``, ``sensors``,
    ``layout``, ``likelihood``, ``config``, ``jacobian_keys`` and ``noise_keys``
    (per run) and its ``_summed``."""

    @property
    def has_independent_rays(self) -> bool:
        """True when ``independent_ray_curvature`` applies: the charge
        likelihood with a free field that changes the light transport, and indirect
        light (rays) in the expected mode."""
        return (self.likelihood == "charge" and self.layout.needs_transport
                and self.config.n_bounces > 0)

    def independent_ray_curvature(
        self, theta: dict, ray_noise: RayNoiseSets | None = None, charge_sets: int = 1,
        jacobians: tuple | None = None,
    ) -> IndependentRayParts:
        """The independent-ray estimating equation at ``theta`` (``has_independent_rays``
        only): every run's expected charges M_a come from its own rays and the
        derivatives J_b from a second, independent ray set; the score is
        J_b^T [dL/dM_a - bias], the Newton matrix its expected derivative I J_b J_a^T
        (not symmetric), the score's data covariance I J_b^T J_b. With ``ray_noise``
        (``ray_noise_sets``, taken at or near ``theta``) the bias is the second-order
        (Jensen) bias that the ray noise of M_a puts into dL/dM; without it, none. With
        ``charge_sets`` = K > 1, M_a and J_a are the averages over the run's own rays and
        K - 1 further sets (``ray_set_keys``), so their ray noise (and the bias
        correction) has 1/K of the variance. With ``jacobians`` (per run, J_b (N, T), e.g.
        ``independent_jacobians`` of a nearby point) those are the score's weights
        instead of a fresh set: any weights independent of the noise of M_a and of the
        data keep the score unbiased at the truth, and weights with less ray noise make
        the root more efficient. Float64 numpy. The root is free of the bias that the
        correlated ray noise of M and J puts into the minimum of -log L
        (docs/calibration.md, "Ray noise and the independent-ray score")."""
        per_run, used = [], []
        inputs = self._independent_ray_inputs(ray_noise, charge_sets)
        given = [None] * len(inputs) if jacobians is None else jacobians
        for (data, static, jacobian_key, variance, keys), jac_b in zip(
            inputs, given, strict=True
        ):
            sets = [self._jacobian(theta, data, static, key) for key in keys]
            mean = sum(m for m, _ in sets) / len(sets)
            jac_a = sum(j for _, j in sets) / len(sets)
            if jac_b is None:
                _, jac_b = self._jacobian(theta, data, static, jacobian_key)
            used.append(jac_b)
            per_run.append(independent_ray_jit(theta, self.base, data, mean, jac_a, jac_b,
                                                variance, static=static))
        value, (grad_dense, grad_sensor, bias_dense, bias_sensor, *blocks) = self._summed(
            run[:-1] for run in per_run
        )
        return IndependentRayParts(
            value, grad_dense, grad_sensor, bias_dense, bias_sensor,
            StructuredMatrix(*blocks[:4]), StructuredMatrix(*blocks[4:]),
            tuple(np.asarray(run[-1], np.float64) for run in per_run), tuple(used),
        )

    def independent_ray_score(
        self, theta: dict, jacobians: tuple, ray_noise: RayNoiseSets | None = None,
        charge_sets: int = 1,
    ) -> tuple[float, np.ndarray, np.ndarray]:
        """(-log L, score dense (P,), per sensor (N, F)) of
        ``independent_ray_curvature`` at ``theta`` with the derivatives J_b given (per
        run, ``IndependentRayParts.jacobians`` of a nearby point): only the expected
        charges are computed, a third of the cost of their derivatives. For steps that
        reuse a nearby point's Newton matrix. Float64 numpy."""
        per_run = []
        for (data, static, _, variance, keys), jac_b in zip(
            self._independent_ray_inputs(ray_noise, charge_sets), jacobians, strict=True
        ):
            mean = sum(mean_jit(theta, self.base, self.sensors,
                                 dataclasses.replace(data, key=key), None, static=static)
                       for key in keys) / len(keys)
            per_run.append(independent_ray_score_jit(theta, self.base, data, mean, jac_b,
                                                      variance, static=static)[:3])
        value, (grad_dense, grad_sensor) = self._summed(per_run)
        return value, grad_dense, grad_sensor

    def _independent_ray_inputs(self, ray_noise: RayNoiseSets | None, charge_sets: int):
        """Per run (data, static, J_b's key, relative variance of M_a's ray noise over
        ``charge_sets`` sets, the keys of those sets)."""
        if not self.has_independent_rays:
            raise ConfigError(
                "independent rays: need the charge likelihood, a free field that changes"
                " the light transport and n_bounces > 0"
            )
        if int(charge_sets) < 1:
            raise ConfigError(f"charge_sets = {charge_sets}: must be >= 1")
        if ray_noise is None:
            variances = [jnp.zeros_like(data.charge_sum) for data in self.arrays]
        else:
            variances = [jnp.asarray(v / charge_sets, data.charge_sum.dtype) for v, data in zip(
                ray_noise.relative_variances(), self.arrays, strict=True)]
        return [
            (data, static, jacobian_key, variance, ray_set_keys(data.key, charge_sets))
            for data, static, jacobian_key, variance in zip(
                self.arrays, self.statics, self.jacobian_keys, variances, strict=True)
        ]

    def _jacobian(self, theta: dict, data, static: RunStatic, key):
        """(M (N,), J (N, T)) of a run with the rays of ``key`` (``charge_jacobian``)."""
        return charge_jacobian_jit(theta, self.base, self.sensors,
                                    dataclasses.replace(data, key=key), None, static=static)

    def independent_jacobians(self, theta: dict, n_sets: int) -> tuple:
        """Per run, the derivatives J_b (N, T) of the expected charges at ``theta``
        averaged over ``n_sets`` independent ray sets: the run's J_b set and
        ``n_sets`` - 1 further ones (``ray_set_keys``), for ``independent_ray_score``."""
        return tuple(
            sum(self._jacobian(theta, data, static, key)[1]
                for key in ray_set_keys(jacobian_key, n_sets)) / n_sets
            for data, static, jacobian_key in zip(
                self.arrays, self.statics, self.jacobian_keys, strict=True)
        )

    def ray_noise_sets(self, theta: dict, n_sets: int = RAY_NOISE_SETS) -> RayNoiseSets:
        """Every run's expected charges at ``theta`` from its own rays and ``n_sets``
        further independent ray sets (keys ``fold_in(fold_in(run key,
        NOISE_RAY_STREAM), k)``), as deviations from their mean: a sample of the ray
        noise of M_a with ``n_sets`` degrees of freedom per run."""
        means, deviations = [], []
        for data, cached, static, key in zip(
            self.arrays, self.cached, self.statics, self.noise_keys, strict=True
        ):
            keys = [data.key] + [jax.random.fold_in(key, k) for k in range(n_sets)]
            charges = np.stack([
                np.asarray(mean_jit(theta, self.base, self.sensors,
                                     dataclasses.replace(data, key=k), cached, static=static),
                           np.float64)
                for k in keys
            ])
            means.append(charges.mean(axis=0))
            deviations.append(charges - means[-1])
        return RayNoiseSets(tuple(means), tuple(deviations))

    def ray_noise_covariance(
        self, parts: IndependentRayParts, ray_noise: RayNoiseSets
    ) -> SandwichCovariance:
        """The covariance of the independent-ray root: the sandwich of the score's data
        covariance (``parts.information``) and of its ray-noise covariance, which the
        rays of M_a add: per run the sample covariance of projector^T M over the ray sets
        of ``ray_noise`` (independent of J_b, so their spread is pure ray noise). Both
        at (or within a small step of) the root."""
        n_dense = self.layout.n_dense
        noise_dense, noise_sensor = [], []
        for projector, deviations in zip(parts.projectors, ray_noise.deviations, strict=True):
            # sum of u u^T over the K sets = sample covariance (K - 1 degrees of freedom)
            scaled = deviations / np.sqrt(deviations.shape[0] - 1)
            noise_dense.append(scaled @ projector[:, :n_dense])
            noise_sensor.append(scaled[:, :, None] * projector[None, :, n_dense:])
        return SandwichCovariance(parts.newton, parts.information,
                                  np.concatenate(noise_dense), np.concatenate(noise_sensor))
