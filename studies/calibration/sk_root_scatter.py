"""The SK fit's optics refitted with the data or the rays redrawn, one part of the noise
at a time, against the two parts of the error the fit reports (~2-4 min per fit alone).

``python studies/calibration/sk_root_scatter.py data|rays [fits] [seed] [--jacobian-sets K]
[--ray-extrapolation] [--skip S] [--out F.json]``: the campaign experiment ``seed``
(default 1) of ``photonflow.calibration.campaign``, fitted ``fits`` times (default 8):

- ``data``: the fit's ray key stays the campaign's (``key(seed)``); the pseudo-data are
  the campaign's, then those of data seeds 101, 102, ... (the same truth and
  efficiencies, new photons). The scatter of the roots is the data's part of their
  variance given the rays; the fit's is ``error * sqrt(1 - ray_noise_share)``.
- ``rays``: the pseudo-data stay the campaign's; the ray key is the campaign's, then
  ``key(5000)``, ``key(5001)``, ... The scatter is the ray noise's part given the
  data; the fit's is ``error * sqrt(ray_noise_share)``.

Prints, per fit, the one-set root theta_1 (the last ``"independent rays"`` step), the
returned value and its error; at the end, per optical parameter, the scatter of both
over the fits against the fit's part. ``--skip S`` leaves out the first S draws (to extend
an earlier run with the same seeds; the summary is then over the new fits only).
``--out`` keeps the rows, rewritten after each fit.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import numpy as np

import photonflow as pf
from photonflow.calibration import calibrate
from photonflow.calibration.campaign import OPTICS, campaign_runs, campaign_start, campaign_truth
from photonflow.transport.optics import TransportConfig

#: The first data seed and ray key after the campaign's own.
FIRST_DATA_SEED, FIRST_RAY_KEY = 101, 5000


def draws(vary: str, fits: int, seed: int) -> list[tuple[int, int]]:
    """(data seed, ray key) of each fit: the campaign's, then the other part fixed."""
    if vary == "data":
        return [(seed, seed)] + [(FIRST_DATA_SEED + k, seed) for k in range(fits - 1)]
    return [(seed, seed)] + [(seed, FIRST_RAY_KEY + k) for k in range(fits - 1)]


def fit(detector, truth, data_seed: int, ray_key: int, config, jacobian_sets,
        extrapolate: bool) -> dict:
    """One fit of the campaign's sources with the pseudo-data of ``data_seed`` and the
    rays of ``key(ray_key)``: theta_1, the returned value, its error and ray-noise
    share per optical parameter."""
    runs = campaign_runs(detector, truth, data_seed, 1e6, config)
    result = calibrate(detector, runs, campaign_start(detector, truth),
                       [*OPTICS, "efficiency"], config=config, truth=truth,
                       key=jax.random.key(ray_key), jacobian_sets=jacobian_sets,
                       ray_extrapolation=extrapolate)
    one = [e for e in result.history if e.get("stage") == "independent rays"][-1]
    return {"data_seed": data_seed, "ray_key": ray_key, "fit_s": result.wall_time_s,
            "converged": result.converged,
            "theta1": {n: one["values"][n] for n in OPTICS},
            "fitted": {n: float(getattr(result.params, n)) for n in OPTICS},
            "error": {n: float(getattr(result.errors, n)) for n in OPTICS},
            "ray_noise_share": result.history[-1]["ray_noise_share"]}


def summary(rows: list[dict], vary: str) -> None:
    """Per optical parameter: the scatter of theta_1 and of the returned value over the
    fits, and the fit's own data (or ray) part of the error, averaged over the fits."""
    print(f"\n{len(rows)} fits, {vary} redrawn: scatter of theta_1 / of the returned value"
          f" against the fit's {vary} part of the error")
    for name in OPTICS:
        one = np.array([row["theta1"][name] for row in rows])
        value = np.array([row["fitted"][name] for row in rows])
        error = np.array([row["error"][name] for row in rows])
        share = np.array([row["ray_noise_share"][name] for row in rows])
        part = error * np.sqrt(share if vary == "rays" else 1.0 - share)
        print(f"  {name:20s} {one.std(ddof=1):.4g} / {value.std(ddof=1):.4g}"
              f"   fit's part {np.mean(part):.4g} (error {np.mean(error):.4g})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("vary", choices=["data", "rays"])
    parser.add_argument("fits", type=int, nargs="?", default=8)
    parser.add_argument("seed", type=int, nargs="?", default=1)
    parser.add_argument("--jacobian-sets", type=int, default=None)
    parser.add_argument("--ray-extrapolation", action="store_true")
    parser.add_argument("--skip", type=int, default=0,
                        help="leave out the first SKIP draws (already fitted)")
    parser.add_argument("--out", help="JSON file for the rows")
    args = parser.parse_args()
    if args.skip < 0:
        parser.error(f"skip = {args.skip}: must be >= 0")
    if args.fits - args.skip < 2:
        parser.error(f"fits = {args.fits}, skip = {args.skip}: need at least 2 fits for a"
                     " scatter")
    detector = pf.load_detector("SK")
    truth = campaign_truth(detector, args.seed)
    config = TransportConfig(n_bounces=2, n_rays=1024)
    rows = []
    for data_seed, ray_key in draws(args.vary, args.fits, args.seed)[args.skip:]:
        row = fit(detector, truth, data_seed, ray_key, config, args.jacobian_sets,
                  args.ray_extrapolation)
        rows.append(row)
        print(f"data {data_seed} rays {ray_key}: {row['fit_s']:.0f} s  " + "  ".join(
            f"{n} {row['theta1'][n]:.4g} -> {row['fitted'][n]:.4g} +- {row['error'][n]:.2g}"
            for n in OPTICS), flush=True)
        if args.out:
            Path(args.out).write_text(json.dumps({"settings": vars(args), "rows": rows},
                                                 indent=1))
    summary(rows, args.vary)


if __name__ == "__main__":
    main()
