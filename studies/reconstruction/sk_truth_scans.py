"""The likelihood of sampled SK muons near their true tracks: where it is lowest in
energy at the true vertex, and along the track's start (vertex moved by s along the
direction, time by s / (beta c), energy by -dE/dx s), charge and first-hit-time terms
apart; its value at the truth for several overdispersions; and the first-hit term at
the true track with the predicted times of one band of sensors (by expected charge)
moved by a common offset (studies/reconstruction-validation.md).

    python studies/reconstruction/sk_truth_scans.py sk20.h5 [--events 20]
        [--overdispersion 0.3] [--rays 1024] [--offsets-only]

The rays of the indirect light are fixed by the true track throughout, so the scans see
no change of ray sample. Prints the scans summed over the events and the mean and
spread of the per-event minima (a quartic through each event's scan).
"""

from __future__ import annotations

import argparse
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

import photonflow as pf
from photonflow.likelihood import dense_sensor_nll
from photonflow.reconstruction import fit as fitting

DTYPE = jnp.float32
BETA_C = 0.9954 * 0.299792458  # m/ns, a 1 GeV muon
DEDX = 225.0  # MeV/m, a 1 GeV muon in water
SHIFTS = np.round(np.arange(-0.1, 0.31, 0.05), 2)  # m
ENERGY_STEPS = np.round(np.arange(-0.06, 0.041, 0.01), 2)  # relative
OVERDISPERSIONS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)
TIME_OFFSETS = np.round(np.arange(-0.6, 0.91, 0.3), 1)  # ns
BANDS = ((0.0, 1.0), (1.0, 10.0), (10.0, np.inf))  # expected p.e.


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("events")
    parser.add_argument("--events", dest="count", type=int, default=20)
    parser.add_argument("--overdispersion", type=float, default=0.0)
    parser.add_argument("--rays", type=int, default=1024)
    parser.add_argument("--offsets-only", action="store_true",
                        help="only the time-offset scan by band")
    args = parser.parse_args()
    config = pf.TransportConfig(n_rays=args.rays)
    window = tuple(float(x) for x in config.window)
    with pf.read_events(args.events) as events:
        detector, params = events.detector, events.params
        functions = fitting.likelihood_functions(detector, DTYPE, config)
        predict = pf.expected_function(detector, DTYPE, config=config)

        @jax.jit
        def prediction(track, reference, data):
            return predict(data.params, track, None, reference, emission=data.emission,
                           arrays=data.sensors)

        def parts(pred, data, overdispersion):
            terms = [jnp.sum(dense_sensor_nll(
                pred, data.hit, data.charge, data.time, data.dark_rate, data.spe_width,
                window, time_weight=jnp.asarray(weight, DTYPE),
                overdispersion=overdispersion)) for weight in (0.0, 1.0)]
            return np.array([float(terms[0]), float(terms[1] - terms[0])])

        shift_scan = np.zeros((args.count, SHIFTS.size, 2))
        energy_scan = np.zeros((args.count, ENERGY_STEPS.size, 2))
        at_truth = np.zeros((len(OVERDISPERSIONS), 2))
        offset_scan = np.zeros((len(BANDS), args.count, TIME_OFFSETS.size, 2))
        for k in range(min(args.count, len(events))):
            event = events[k]
            truth = event.truth
            data = dataclasses.replace(
                fitting.event_data(detector, params, event, DTYPE, functions),
                emission=functions.emission("mu-"))
            direction = np.asarray(truth.direction)
            reference = fitting.cast_track(pf.Track("mu-", truth.position, direction,
                                                     truth.energy, truth.time), DTYPE)
            true_prediction = prediction(reference, reference, data)
            expected_charge = np.asarray(true_prediction.charge)
            for b, (low, high) in enumerate(BANDS):
                band = jnp.asarray((expected_charge >= low) & (expected_charge < high))
                for i, offset in enumerate(TIME_OFFSETS):
                    moved = dataclasses.replace(
                        true_prediction, time_mean=true_prediction.time_mean
                        + jnp.where(band, DTYPE(offset), DTYPE(0))[:, None])
                    offset_scan[b, k, i] = parts(moved, data, args.overdispersion)
            if args.offsets_only:
                print(f"event {k} done", flush=True)
                continue
            for i, s in enumerate(SHIFTS):
                moved = pf.Track("mu-", np.asarray(truth.position) + s * direction, direction,
                                 truth.energy - DEDX * s, truth.time + s / BETA_C)
                shift_scan[k, i] = parts(prediction(fitting.cast_track(moved, DTYPE),
                                                    reference, data), data,
                                         args.overdispersion)
            for i, step in enumerate(ENERGY_STEPS):
                scaled = pf.Track("mu-", truth.position, direction,
                                  truth.energy * (1 + step), truth.time)
                energy_scan[k, i] = parts(prediction(fitting.cast_track(scaled, DTYPE),
                                                     reference, data), data,
                                          args.overdispersion)
            for i, r in enumerate(OVERDISPERSIONS):
                at_truth[i] += parts(true_prediction, data, r)
            print(f"event {k} done", flush=True)
    for (low, high), scan in zip(BANDS, offset_scan, strict=True):
        _report(f"time offset (ns) of sensors expecting {low:g}-{high:g} p.e.", TIME_OFFSETS,
                scan)
    if args.offsets_only:
        return
    _report("shift s (m)", SHIFTS, shift_scan)
    _report("energy step", ENERGY_STEPS, energy_scan)
    print("-log L at the truth, summed, relative to Poisson: overdispersion, charge, time")
    for r, (charge, time) in zip(OVERDISPERSIONS, at_truth - at_truth[0], strict=True):
        print(f"  {r:.1f}  {charge:9.1f}  {time:9.1f}")


def _report(name, grid, scan) -> None:
    """The scans summed over events (relative to the grid's zero) and the per-event minima."""
    zero = int(np.argmin(np.abs(grid)))
    scan = scan - scan[:, zero:zero + 1]
    print(f"{name}: summed -log L (charge, time, both)")
    for i, x in enumerate(grid):
        total = scan[:, i].sum(axis=0)
        print(f"  {x:+.2f}  {total[0]:9.1f}  {total[1]:9.1f}  {total.sum():9.1f}")
    fine = np.linspace(grid[0], grid[-1], 401)
    for label, values in (("charge", scan[..., 0]), ("time", scan[..., 1]),
                          ("both", scan.sum(axis=-1))):
        minima = np.array([fine[np.argmin(np.polyval(np.polyfit(grid, v, 4), fine))]
                           for v in values])
        print(f"  per-event minimum ({label}): mean {minima.mean():+.3f} "
              f"+- {minima.std(ddof=1) / np.sqrt(minima.size):.3f}, sd {minima.std(ddof=1):.3f}")


if __name__ == "__main__":
    main()
