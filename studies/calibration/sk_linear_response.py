"""The SK fit's optics linearised at the truth: the response of the independent-ray root
to sampled pseudo-data, seed by seed, against its sandwich error (~1-2 min a seed).

``python studies/calibration/sk_linear_response.py FIRST LAST [--data 0 700 ...] [--draws N]
[--out F.json]``: for each campaign experiment ``seed`` of
``photonflow.calibration.campaign`` from FIRST to LAST (its truth, its fit's ray key
``key(seed)``), the independent-ray estimating equation at the true parameters with the
weights J_b averaged over 4 ray sets (as ``calibrate(jacobian_sets=4)``): its Newton
matrix D, the sandwich's data part D^-1 V D^-T and ray part D^-1 R D^-T, and the linear
response -D^-1 s of each optical parameter (unconstrained coordinates) to the score s of
pseudo-data at that truth:

- ``--data`` offsets (default ``0 700``): the pseudo-data of data seed ``seed + offset``
  (offset 0: the campaign's own). The campaign's one-set root theta_1 follows the
  response to its own data (correlation 0.99 over 40 seeds, studies/calibration-validation.md), so
  this is the campaign without the fits. Two draws at one seed share the rays and the
  truth: half the variance of their difference over the seeds is the data part alone.
- ``--draws N``: instead, N draws per seed (data seeds ``800 + 50 seed + k``): the
  response's scatter over them at fixed rays against the sandwich's data part (a check
  of V).
- ``--joint N``: instead, at the truth of each seed, N pairs of new pseudo-data and new
  rays (data seed ``JOINT_DATA + j``, ray key ``key(JOINT_RAYS + j)``), each with its
  own weights, ray-noise sets and sandwich: the response's scatter over the pairs
  against the mean sandwich, data and ray parts together (~50 s a pair alone).

``responses`` have no Jensen correction (its shift is a constant per seed). With
``--estimator`` also, per data seed, the linearised estimator of
``calibrate(jacobian_sets=4, ray_extrapolation=True)``: ``theta1``, the response with
the Jensen correction (``CalibrationProblem.ray_noise_sets`` at the truth), and
``extrapolated``, 2 r_2 - r_1 with r_2 the response with the expected charges averaged
over 2 ray sets (``fit.EXTRAPOLATION_SETS``); their pull means over the seeds are the
estimator's bias without the fits (~20 s more a seed).
Prints per seed the responses in units of the sandwich's total sigma, and a summary at
the end; ``--out`` keeps the numbers, rewritten after each seed.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import numpy as np

import photonflow as pf
from photonflow.calibration.campaign import OPTICS, campaign_runs, campaign_truth
from photonflow.calibration.fit import EXTRAPOLATION_SETS, ray_count_shift
from photonflow.calibration.layout import free_layout
from photonflow.calibration.objective import CalibrationProblem
from photonflow.calibration.runs import prepare_runs
from photonflow.transport.optics import TransportConfig

#: Ray sets over which the score's weights are averaged (``calibrate(jacobian_sets=)``).
WEIGHT_SETS = 4
#: ``--joint``: pair j has the pseudo-data of data seed JOINT_DATA + j and the rays of
#: key(JOINT_RAYS + j), apart from every campaign seed's data and rays.
JOINT_DATA, JOINT_RAYS = 3000, 7000


def problem_for(detector, truth, data_seed: int, ray_seed: int, config) -> CalibrationProblem:
    """The campaign's calibration problem (optics and efficiencies free, charge
    likelihood) on the pseudo-data of ``data_seed`` with the rays of ``key(ray_seed)``."""
    runs = prepare_runs(campaign_runs(detector, truth, data_seed, 1e6, config), detector,
                        "charge")
    return CalibrationProblem(detector, runs, truth,
                              free_layout([*OPTICS, "efficiency"], detector.n_sensors),
                              "charge", config, jax.random.key(ray_seed))


def linear_response(detector, seed: int, data_seeds: list[int], config,
                    estimator: bool = False, ray_seed: int | None = None) -> dict:
    """The sandwich's data and ray parts (variances, unconstrained) and the response
    -D^-1 s to the pseudo-data of each of ``data_seeds``, at the truth of ``seed`` with
    the rays of ``key(ray_seed)`` (default ``seed``, the campaign fit's); with
    ``estimator`` also the linearised ``theta1`` and ``extrapolated`` roots. The
    sandwich does not depend on the data."""
    truth = campaign_truth(detector, seed)
    ray_seed = seed if ray_seed is None else ray_seed
    problem = problem_for(detector, truth, data_seeds[0], ray_seed, config)
    theta = problem.initial_theta()
    weights = problem.independent_jacobians(theta, WEIGHT_SETS)
    parts = problem.independent_ray_curvature(theta, None, 1, weights)
    noise = problem.ray_noise_sets(theta)
    covariance = problem.ray_noise_covariance(parts, noise)
    variance = np.diag(covariance.covariance()[0])
    share = covariance.noise_share()
    rows = covariance.dense_rows

    def response(draw, ray_noise=None, charge_sets=1) -> np.ndarray:
        _, score_dense, score_sensor = draw.independent_ray_score(theta, weights, ray_noise,
                                                                  charge_sets)
        return np.array([-float(row_dense @ score_dense + np.sum(row_sensor * score_sensor))
                         for row_dense, row_sensor in rows])

    out = {"seed": seed, "ray_seed": ray_seed, "data_part": (variance * (1 - share)).tolist(),
           "ray_part": (variance * share).tolist(), "responses": {}}
    if estimator:
        out.update(theta1={}, extrapolated={})
    for data_seed in data_seeds:
        draw = problem if data_seed == data_seeds[0] else problem_for(
            detector, truth, data_seed, ray_seed, config)
        out["responses"][str(data_seed)] = response(draw).tolist()
        if estimator:
            one = response(draw, noise)
            many = response(draw, noise, EXTRAPOLATION_SETS)
            out["theta1"][str(data_seed)] = one.tolist()
            out["extrapolated"][str(data_seed)] = (one + ray_count_shift(one, many)).tolist()
    return out


def in_sigma(row: dict, kind: str = "responses") -> dict[str, np.ndarray]:
    """Data seed -> the responses (or ``kind``: "theta1", "extrapolated") in units of the
    sandwich's total sigma."""
    sigma = np.sqrt(np.add(row["data_part"], row["ray_part"]))
    return {k: np.asarray(v) / sigma for k, v in row[kind].items()}


def joint_summary(rows: list[dict]) -> None:
    """Per optical parameter, the responses' scatter over the (data, rays) pairs of one
    seed against the square root of the mean sandwich variance, and the width of the
    responses in units of each pair's own sigma."""
    if len(rows) < 3:
        print("\nfewer than 3 pairs: no scatter to summarise")
        return
    responses = np.array([next(iter(r["responses"].values())) for r in rows])
    variances = np.array([np.add(r["data_part"], r["ray_part"]) for r in rows])
    scatter = responses.std(axis=0, ddof=1) / np.sqrt(variances.mean(axis=0))
    pulls = responses / np.sqrt(variances)
    print(f"\n{len(rows)} pairs of new data and new rays at the truth of seed"
          f" {rows[0]['seed']} (error of a width: {1 / np.sqrt(2 * (len(rows) - 1)):.2f})")
    for j, name in enumerate(OPTICS):
        print(f"  {name:20s} scatter / sandwich sigma {scatter[j]:.2f}   pulls: mean"
              f" {pulls[:, j].mean():+.2f}, width {pulls[:, j].std(ddof=1):.2f}")


def summary(rows: list[dict], draws: bool) -> None:
    """Per optical parameter, the sandwich's data sigma against the measured one: over
    the draws of each seed (``draws``), or from pairs of draws at the same seed."""
    if len(rows) < 2 and not draws:
        print("\none seed: no scatter over the seeds to summarise")
        return
    share = np.mean([np.divide(r["data_part"], np.add(r["data_part"], r["ray_part"]))
                     for r in rows], axis=0)
    print(f"\n{len(rows)} seeds: data part of the sandwich (sigma, in units of the"
          " total) against the measured one")
    for j, name in enumerate(OPTICS):
        if draws:
            measured = [np.std([v[j] for v in in_sigma(r).values()], ddof=1) for r in rows]
            text = "scatter over the draws " + " ".join(f"{m:.2f}" for m in measured)
        else:
            values = [list(in_sigma(r).values()) for r in rows]
            pairs = [v[0][j] - other[j] for v in values for other in v[1:]]
            spread = np.std(pairs, ddof=1)
            text = (f"(first draw - each other) / sqrt 2: {spread / np.sqrt(2):.2f}"
                    f" (mean {np.mean(pairs):+.2f} +- {spread / np.sqrt(len(pairs)):.2f})")
        print(f"  {name:20s} sandwich {np.sqrt(share[j]):.2f}   {text}")
    if "theta1" in rows[0]:
        print("linearised estimator, pull mean +- its error (width), first data seed of each"
              " seed")
        for j, name in enumerate(OPTICS):
            text = []
            for kind in ("theta1", "extrapolated"):
                pulls = np.array([next(iter(in_sigma(r, kind).values()))[j] for r in rows])
                text.append(f"{kind} {pulls.mean():+.2f} +- "
                            f"{pulls.std(ddof=1) / np.sqrt(len(pulls)):.2f}"
                            f" ({pulls.std(ddof=1):.2f})")
            print(f"  {name:20s} " + "   ".join(text))


def joint_redraws(detector, config, args) -> None:
    """``--joint``: per seed, ``args.joint`` pairs of new data and new rays, printed as
    they come, kept in ``args.out`` and summarised by ``joint_summary``."""
    rows = []
    for seed in range(args.first, args.last + 1):
        pairs = []
        for j in range(args.joint):
            pairs.append(linear_response(detector, seed, [JOINT_DATA + j], config,
                                         args.estimator, ray_seed=JOINT_RAYS + j))
            print(f"seed {seed}, pair {j}: " + " ".join(
                f"{x:+.2f}" for x in next(iter(in_sigma(pairs[-1]).values()))), flush=True)
            if args.out:
                Path(args.out).write_text(json.dumps(
                    {"settings": vars(args), "rows": rows + pairs}, indent=1))
        rows += pairs
        joint_summary(pairs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("first", type=int)
    parser.add_argument("last", type=int)
    parser.add_argument("--data", type=int, nargs="+", default=[0, 700],
                        help="data-seed offsets (0: the campaign's own pseudo-data)")
    parser.add_argument("--draws", type=int, default=None,
                        help="instead: this many draws per seed (data seeds 800 + 50 seed + k)")
    parser.add_argument("--joint", type=int, default=None,
                        help="instead: this many pairs of new data and new rays per seed")
    parser.add_argument("--estimator", action="store_true",
                        help="also the linearised roots theta_1 and extrapolated")
    parser.add_argument("--out", help="JSON file for the numbers")
    args = parser.parse_args()
    if args.last < args.first or args.first < 1:
        parser.error(f"seeds {args.first}..{args.last}: need 1 <= FIRST <= LAST")
    if args.draws is not None and args.draws < 2:
        parser.error(f"draws = {args.draws}: need at least 2 for a scatter")
    if args.joint is not None and (args.joint < 1 or args.draws is not None):
        parser.error(f"joint = {args.joint}: need >= 1 pairs, and not with --draws")
    if args.draws is None and args.joint is None and len(set(args.data)) < 2:
        parser.error(f"data = {args.data}: need at least 2 different offsets for pairs")
    detector = pf.load_detector("SK")
    config = TransportConfig(n_bounces=2, n_rays=1024)
    if args.joint is not None:
        joint_redraws(detector, config, args)
        return
    rows = []
    for seed in range(args.first, args.last + 1):
        data_seeds = ([800 + 50 * seed + k for k in range(args.draws)] if args.draws
                      else [seed + offset for offset in args.data])
        rows.append(linear_response(detector, seed, data_seeds, config, args.estimator))
        print(f"seed {seed}: " + "  ".join(
            f"data {k}: " + " ".join(f"{x:+.2f}" for x in v)
            for k, v in in_sigma(rows[-1]).items()), flush=True)
        if args.out:
            Path(args.out).write_text(json.dumps({"settings": vars(args), "rows": rows},
                                                 indent=1))
    summary(rows, args.draws is not None)


if __name__ == "__main__":
    main()
