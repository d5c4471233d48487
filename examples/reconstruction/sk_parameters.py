"""What calibration buys a reconstruction, and how far the fits are from the Cramér-Rao
bound (docs/reconstruction.md, "Detector parameters and the Cramér-Rao bound"):
``python examples/reconstruction/sk_parameters.py --events N --out-dir DIR``.

SK with the true parameters of calibration pseudo-experiment ``--seed``
(``photonflow.calibration.campaign``: per-sensor efficiencies drawn with a 10 % spread,
optics away from the preset's). N 1 GeV muons and N 500 MeV electrons are sampled at
those parameters (generator + sampled mode; vertices uniform at least 2 m inside the
walls, isotropic), and each is reconstructed with its true particle as the hypothesis
four times, with:

- ``true``: the true parameters;
- ``calibrated``: those fitted by ``calibrate`` to the campaign's calibration
  pseudo-data (16 flashes of 10^6 photons, sampled at the truth; 4 optics and every
  efficiency free, from 25 % away);
- ``nominal``: the preset's parameters (every efficiency 1): no calibration;
- ``absorption -10%``: the true parameters with the absorption length 10 % short.

Beside them, the Cramér-Rao covariance at the true track
(``cramer_rao_covariance``, true parameters) of every event, and from it the 68 %
quantiles the bound allows (``BOUND_DRAWS`` Gaussian draws per event from its
covariance, pooled). One JSON line per fit in ``DIR/fits.jsonl``, written as each ends:
run the command again after an interruption and it goes on where it stopped. Prints
the table of docs/reconstruction.md and writes it to ``DIR/summary.json``. Lengths m,
times ns, energies MeV.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

#: (particle, kinetic energy MeV, seed offset) of the two samples.
SAMPLES = (("mu-", 1000.0, 0), ("e-", 500.0, 1))
#: Parameter sets the events are reconstructed with, in order.
PARAMETER_SETS = ("true", "calibrated", "nominal", "absorption -10%")
#: Gaussian draws per event from its Cramér-Rao covariance.
BOUND_DRAWS = 200


def _tracks(detector, particle: str, energy: float, count: int, seed: int) -> list:
    """``count`` tracks: vertices uniform at least 2 m inside SK's walls, isotropic."""
    import photonflow as pf

    rng = np.random.default_rng(seed)
    radius, half = detector.shape.radius - 2.0, 0.5 * detector.shape.height - 2.0
    tracks = []
    while len(tracks) < count:
        x, y = rng.uniform(-radius, radius, 2)
        if x * x + y * y > radius * radius:
            continue
        direction = rng.normal(size=3)
        tracks.append(pf.Track(particle, [x, y, rng.uniform(-half, half)],
                               direction / np.linalg.norm(direction), energy, 0.0))
    return tracks


def _calibrated(detector, truth, seed: int, path: Path):
    """The calibrated parameters (``calibrate`` on the campaign's pseudo-data), saved to
    and read back from ``path``."""
    import jax

    from photonflow import TransportConfig
    from photonflow.calibration import calibrate, load_params
    from photonflow.calibration.campaign import (
        OPTICS,
        PHOTONS_PER_FLASH,
        campaign_runs,
        campaign_start,
    )

    if not path.exists():
        config = TransportConfig(n_bounces=2, n_rays=1024)
        runs = campaign_runs(detector, truth, seed, PHOTONS_PER_FLASH, config)
        result = calibrate(detector, runs, campaign_start(detector, truth),
                           [*OPTICS, "efficiency"], config=config, key=jax.random.key(seed))
        print(f"calibration: {result.message}, {result.wall_time_s:.0f} s", flush=True)
        result.save(path)
    return load_params(path)


def _errors(fit_position, fit_direction, fit_energy, truth) -> dict:
    """Vertex (cm), direction (degrees) and energy (fraction) errors against ``truth``."""
    cosine = float(np.clip(np.dot(fit_direction, truth.direction), -1.0, 1.0))
    return {"vertex_cm": 100 * float(np.linalg.norm(fit_position - truth.position)),
            "direction_deg": math.degrees(math.acos(cosine)),
            "energy_frac": float(fit_energy) / float(truth.energy) - 1.0}


def _bound_draws(covariance, truth, rng) -> list[dict]:
    """``BOUND_DRAWS`` draws of the errors the Cramér-Rao ``covariance`` (``LOCAL``)
    allows about ``truth``: vertex, direction and energy errors as ``_errors``'."""
    from photonflow.transport.optics import orthonormal_basis

    draws = rng.multivariate_normal(np.zeros(7), covariance, size=BOUND_DRAWS)
    # any basis across the direction gives the same angles' size (the LOCAL one here)
    first, second = (np.asarray(v, np.float64) for v in orthonormal_basis(
        np.asarray(truth.direction, np.float32)))
    rows = []
    for d in draws:
        direction = truth.direction + d[4] * first + d[5] * second
        rows.append(_errors(truth.position + d[:3], direction / np.linalg.norm(direction),
                            float(truth.energy) * math.exp(d[6]), truth))
    return rows


def _quantiles(rows: list[dict]) -> dict:
    """68 % quantiles of the errors, the median energy bias and the 68 % quantile of the
    energy error's distance from it."""
    if not rows:
        return {}
    return {"n": len(rows),
            "vertex_68_cm": float(np.quantile([r["vertex_cm"] for r in rows], 0.68)),
            "direction_68_deg": float(np.quantile([r["direction_deg"] for r in rows], 0.68)),
            "energy_68_frac": float(np.quantile([abs(r["energy_frac"]) for r in rows], 0.68)),
            "energy_bias_frac": float(np.median([r["energy_frac"] for r in rows])),
            "energy_resolution_68_frac": float(np.quantile(np.abs(
                np.subtract([r["energy_frac"] for r in rows],
                            np.median([r["energy_frac"] for r in rows]))), 0.68))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=10, help="events per particle")
    parser.add_argument("--out-dir", type=Path, default=Path("sk_parameters"))
    parser.add_argument("--seed", type=int, default=1,
                        help="calibration pseudo-experiment (truth) and event seed")
    parser.add_argument("--rays", type=int, default=1024)
    args = parser.parse_args()
    import photonflow as pf
    from photonflow.calibration.campaign import campaign_truth
    from photonflow.reconstruction import cramer_rao_covariance

    folder = args.out_dir
    folder.mkdir(parents=True, exist_ok=True)
    detector = pf.load_detector("SK")
    truth_params = campaign_truth(detector, args.seed)
    parameter_sets = {
        "true": truth_params,
        "calibrated": _calibrated(detector, truth_params, args.seed,
                                  folder / "calibrated.json"),
        "nominal": pf.default_params(detector),
        "absorption -10%": truth_params.replace(
            absorption_length=0.9 * float(truth_params.absorption_length)),
    }
    config = pf.TransportConfig(n_rays=args.rays, emission_model="tables")
    settings = pf.RecoSettings()
    log = folder / "fits.jsonl"
    done = {(r["particle"], r["event"], r["parameters"]): r
            for r in map(json.loads, log.read_text().splitlines())} if log.exists() else {}
    rng = np.random.default_rng(args.seed)
    with log.open("a") as out:
        for particle, energy, offset in SAMPLES:
            tracks = _tracks(detector, particle, energy, args.events,
                             1000 + 10 * args.seed + offset)
            for k, truth in enumerate(tracks):
                event = pf.sample(detector, truth_params, truth, seed=100 * args.seed + k
                                  + 50 * offset)
                for name in ("bound", *PARAMETER_SETS):
                    if (particle, k, name) in done:
                        continue
                    row = {"particle": particle, "event": k, "parameters": name}
                    if name == "bound":
                        covariance = cramer_rao_covariance(detector, truth_params, event,
                                                           truth, config=config)
                        row["covariance"] = covariance.tolist()
                    else:
                        fit = pf.reconstruct(detector, parameter_sets[name], event, particle,
                                             config=config, settings=settings)
                        row.update(converged=fit.converged, failure=fit.failure,
                                   seconds=fit.seconds,
                                   **_errors(fit.position, fit.direction, fit.energy, truth))
                    done[(particle, k, name)] = row
                    out.write(json.dumps(row) + "\n")
                    out.flush()
                    print(json.dumps({k: v for k, v in row.items() if k != "covariance"}),
                          flush=True)
    summary = {}
    for particle, energy, offset in SAMPLES:
        tracks = _tracks(detector, particle, energy, args.events,
                         1000 + 10 * args.seed + offset)
        block = {}
        for name in PARAMETER_SETS:
            rows = [done[(particle, k, name)] for k in range(args.events)
                    if (particle, k, name) in done and done[(particle, k, name)]["failure"]
                    is None]
            block[name] = _quantiles(rows) | {
                "converged": sum(bool(r["converged"]) for r in rows)}
        draws = []
        for k, truth in enumerate(tracks):
            covariance = np.asarray(done[(particle, k, "bound")]["covariance"])
            if np.all(np.isfinite(covariance)):
                draws += _bound_draws(covariance, truth, rng)
        block["Cramér-Rao bound"] = _quantiles(draws)
        summary[particle] = block
    (folder / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    for particle, block in summary.items():
        print(f"{particle}: {'':18} vertex 68%  direction 68%  energy 68%  bias  spread"
              "  converged")
        for name, q in block.items():
            if q.get("n"):
                print(f"  {name:24} {q['vertex_68_cm']:6.1f} cm {q['direction_68_deg']:8.2f}°"
                      f" {100 * q['energy_68_frac']:8.1f} % {100 * q['energy_bias_frac']:+6.1f} %"
                      f" {100 * q['energy_resolution_68_frac']:5.1f} %"
                      f"  {q.get('converged', '')}")


if __name__ == "__main__":
    main()
