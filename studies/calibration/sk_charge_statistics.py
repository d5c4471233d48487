"""Is the sampled mode's summed charge per sensor compound Poisson, sensor by sensor and
between sensors, as the calibration's likelihood and its sandwich error assume?

``python studies/calibration/sk_charge_statistics.py [SOURCE] [DRAWS]`` draws DRAWS (default 200)
sampled events of source SOURCE (default 1, the flash at the centre) of the SK campaign
(``photonflow.calibration.campaign``, 10^6 photons) at the truth of its seed 1, and
compares, over the draws:

- per sensor, in bands of mean p.e., the summed sample variance of the charge with the
  compound-Poisson value mean x E[q^2] / m1 (q: one photoelectron's charge, m1 its mean);
- the variance of the total charge of all sensors, of the top cap and of the bottom cap
  with the same sum (a correlation between sensors shows here; the fixed photon number
  per flash takes a fraction P = detected / emitted, ~7 %, off the total);
- the variance of three projections with random Gaussian weights;
- the mean correlation of each sensor with its 1st to 6th nearest neighbour, and with a
  random partner.

Takes about a minute for 200 draws on the 2-core machine (57 s alone, 2026-11-25).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.spatial import cKDTree

import photonflow as pf
from photonflow.calibration.campaign import campaign_sources, campaign_truth
from photonflow.response.spe import single_pe_moments
from photonflow.transport.optics import TransportConfig
from photonflow.transport.pseudo_data import sample_events

#: Pseudo-data seed of the draws (apart from every campaign seed's, 1000 seed + k).
DRAW_SEED = 123457
#: Bands of mean p.e. per sensor and draw.
BANDS = ((0.0, 0.3), (0.3, 1.0), (1.0, 3.0), (3.0, 10.0), (10.0, 30.0), (30.0, np.inf))


def summed_charges(detector, truth, source, draws: int) -> np.ndarray:
    """(draws, N) summed charge per sensor (p.e.) of ``draws`` sampled events."""
    config = TransportConfig(n_bounces=2, n_rays=1024)
    charges = np.zeros((draws, detector.n_sensors))
    for k, event in enumerate(sample_events(detector, truth, source, DRAW_SEED, draws,
                                            config=config)):
        np.add.at(charges[k], np.asarray(event.sensor_ids), np.asarray(event.charge))
    return charges


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", type=int, nargs="?", default=1,
                        help="index into the campaign's 16 sources (0: the laser)")
    parser.add_argument("draws", type=int, nargs="?", default=200)
    args = parser.parse_args()
    if args.draws < 3:
        parser.error(f"draws = {args.draws}: need at least 3")
    detector = pf.load_detector("SK")
    truth = campaign_truth(detector, 1)
    sources = campaign_sources(1e6)
    if not 0 <= args.source < len(sources):
        parser.error(f"source = {args.source}: must be in 0..{len(sources) - 1}")
    started = time.perf_counter()
    charges = summed_charges(detector, truth, sources[args.source], args.draws)
    n = args.draws
    print(f"{n} draws in {time.perf_counter() - started:.0f} s")

    m1, v1 = (float(x) for x in single_pe_moments(float(truth.spe_width)))
    second_moment = m1**2 + v1
    mean, variance = charges.mean(axis=0), charges.var(axis=0, ddof=1)
    pe = mean / m1
    print(f"mean p.e. per draw: {pe.sum():.0f} ({pe.sum() / 1e6:.3f} of the photons)")
    print("variance / compound-Poisson value (error of a variance from n draws: "
          f"{np.sqrt(2 / (n - 1)):.2f}; per band it is averaged over the sensors)")
    for low, high in BANDS:
        band = (pe >= low) & (pe < high)
        if band.any():
            print(f"  sensors with mean p.e. in [{low:g}, {high:g}): {band.sum():6d}"
                  f"   {variance[band].sum() / (pe[band].sum() * second_moment):.3f}")

    z = detector.sensor_positions[:, 2]
    groups = {"all sensors": np.ones(z.size, bool), "the top cap": z > z.max() - 0.5,
              "the bottom cap": z < z.min() + 0.5}
    for name, group in groups.items():
        total = charges[:, group].sum(axis=1)
        print(f"  sum over {name}: {total.var(ddof=1) / (pe[group].sum() * second_moment):.3f}")
    rng = np.random.default_rng(0)
    for trial in range(3):
        weights = rng.normal(size=z.size)
        ratio = (charges @ weights).var(ddof=1) / ((weights**2 * pe).sum() * second_moment)
        print(f"  random projection {trial}: {ratio:.3f}")

    standardised = (charges - mean) / np.sqrt(variance)
    distances, neighbours = cKDTree(detector.sensor_positions).query(
        detector.sensor_positions, k=7)
    print("correlation between sensors, mean over all sensors +- its error")
    partners = [(f"neighbour {k} (median {np.median(distances[:, k]):.2f} m)", neighbours[:, k])
                for k in range(1, 7)] + [("a random partner", rng.permutation(z.size))]
    for label, partner in partners:
        correlation = (standardised * standardised[:, partner]).sum(axis=0) / (n - 1)
        print(f"  {label}: {correlation.mean():+.4f} +- "
              f"{correlation.std() / np.sqrt(correlation.size):.4f}")


if __name__ == "__main__":
    main()
