"""The maximum-likelihood bias of the SK calibration from the data's noise alone
(Cox & Snell 1968), with 11,146 efficiencies profiled (~2 min).

``python studies/calibration/sk_cox_snell.py [seed] [ray_sets]``: at the true parameters of the SK
campaign (``photonflow.calibration.campaign``, seed ``seed``: 16 sources, optics
90 m / 70 m / 0.15 / 0.25, efficiencies with a 10 % spread), the O(1/n) bias of the
estimator of the four optics and every efficiency,

    b = K^-1 sum_i J_i c_i,   c_i = (-I'(M_i) + E[L'''](M_i) / 2) q_i - I(M_i) s_i / 2,

per sensor and run i: M_i the expected charge (p.e.), J_i its derivatives in the free
values (log lengths, logit probabilities, log efficiency), K = sum_i I_i J_i J_i^T the
Fisher information, q_i = J_i^T K^-1 J_i the variance of the fitted M_i,
s_i = tr(K^-1 d^2 M_i / dtheta^2) (the efficiency terms: d^2 M / d(log e)^2 = dM / d(log e),
d^2 M / d(log e) d(optics) = J; the optics-optics curvature is left out), I(M) the
information and E[L'''] the expected third derivative of -log L of the summed charge
(``information.py``). For Poisson counting -I' + E[L''']/2 = 0 and the bias of the
optics vanishes (a multiplicative nuisance per sensor is harmless); the charge
likelihood's Gaussian regime makes it non-zero. M and J are averaged over ``ray_sets``
ray sets (default 4) of the campaign's 1,024 rays. Prints b in units of the optics'
Cramer-Rao sigma; the fit's own sigma is 1.8-2.7x larger (studies/calibration-validation.md).
"""

from __future__ import annotations

import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import photonflow as pf
from photonflow.calibration.campaign import OPTICS, campaign_sources, campaign_truth, sampled_events
from photonflow.calibration.information import charge_information, expected_score_curvature
from photonflow.calibration.layout import free_layout
from photonflow.calibration.objective import CalibrationProblem, ray_set_keys
from photonflow.calibration.runs import prepare_runs
from photonflow.calibration.structured import StructuredMatrix
from photonflow.transport.optics import TransportConfig


def information_slope(mean: np.ndarray, spe_width: float) -> np.ndarray:
    """dI/dM (1/p.e.^3) by a central difference of ``charge_information`` in log M."""
    step = 1e-3
    up = np.asarray(charge_information(jnp.asarray(mean * (1 + step)), spe_width), np.float64)
    down = np.asarray(charge_information(jnp.asarray(mean * (1 - step)), spe_width),
                      np.float64)
    return (up - down) / (2 * step * mean)


def main() -> None:
    seed = int(sys.argv[1]) if len(sys.argv) > 1 else 1
    ray_sets = int(sys.argv[2]) if len(sys.argv) > 2 else 4
    began = time.perf_counter()
    detector = pf.load_detector("SK")
    truth = campaign_truth(detector, seed)
    config = TransportConfig(n_bounces=2, n_rays=1024)
    sources = campaign_sources(1e6)
    # the bias is an expectation; the data only make the problem (its score is not used)
    runs = prepare_runs([(s, sampled_events(detector, truth, s, 1000 * seed + k, config))
                         for k, s in enumerate(sources)], detector, "charge")
    layout = free_layout([*OPTICS, "efficiency"], detector.n_sensors)
    problem = CalibrationProblem(detector, runs, truth, layout, "charge", config,
                                 jax.random.key(seed))
    theta = problem.initial_theta()
    width = float(truth.spe_width)
    rows = []
    for data, static in zip(problem.arrays, problem.statics, strict=True):
        sets = [problem._jacobian(theta, data, static, key)
                for key in ray_set_keys(data.key, ray_sets)]
        mean = np.mean([np.asarray(m, np.float64) for m, _ in sets], axis=0)
        jac = np.mean([np.asarray(j, np.float64) for _, j in sets], axis=0)
        rows.append((mean, jac))
    print(f"expected charges and derivatives: {time.perf_counter() - began:.0f} s", flush=True)

    n_dense = layout.n_dense
    a, c, b = 0.0, 0.0, 0.0
    for mean, jac in rows:
        info = np.asarray(charge_information(jnp.asarray(mean), width), np.float64)
        a = a + jac[:, :n_dense].T @ (info[:, None] * jac[:, :n_dense])
        c = c + (info * jac[:, n_dense])[:, None] * jac[:, :n_dense]
        b = b + info * jac[:, n_dense] ** 2
    fisher = StructuredMatrix(a, c[:, None, :], b[:, None, None])
    cov_dense, _ = fisher.covariance()
    b_inverse = 1.0 / b
    cov_cross = -b_inverse[:, None] * (c @ cov_dense)           # (N, P): Cov(log e_n, optics)
    cov_eff = b_inverse + np.einsum("np,pq,nq->n", b_inverse[:, None] * c, cov_dense,
                                    b_inverse[:, None] * c)     # (N,): Var(log e_n)

    rhs_dense, rhs_sensor = np.zeros(n_dense), np.zeros(detector.n_sensors)
    for mean, jac in rows:
        j_dense, j_eff = jac[:, :n_dense], jac[:, n_dense]
        info = np.asarray(charge_information(jnp.asarray(mean), width), np.float64)
        third = np.asarray(expected_score_curvature(jnp.asarray(mean), width), np.float64)
        slope = information_slope(mean, width)
        q = (np.einsum("np,pq,nq->n", j_dense, cov_dense, j_dense)
             + 2 * j_eff * np.sum(cov_cross * j_dense, axis=1) + j_eff**2 * cov_eff)
        s = cov_eff * j_eff + 2 * np.sum(cov_cross * j_dense, axis=1)
        weight = (-slope + 0.5 * third) * q - 0.5 * info * s
        rhs_dense += j_dense.T @ weight
        rhs_sensor += j_eff * weight
    bias_dense, bias_sensor = fisher.solve(rhs_dense, rhs_sensor[:, None])
    sigma = np.sqrt(np.diag(cov_dense))
    print(f"Cox-Snell bias of the optics (seed {seed}, M and J over {ray_sets} ray sets),"
          " in Cramer-Rao sigma:")
    for name, value, error in zip(OPTICS, bias_dense, sigma, strict=True):
        print(f"  {name:22s} {value / error:+.3f}   (bias {value:+.3g}, sigma {error:.3g},"
              " unconstrained units)")
    print(f"  efficiencies: mean bias of log e {np.mean(bias_sensor):+.4f},"
          f" of e (with +Var/2) {np.mean(bias_sensor[:, 0] + 0.5 * cov_eff):+.4f}")
    print(f"{time.perf_counter() - began:.0f} s")


if __name__ == "__main__":
    main()
