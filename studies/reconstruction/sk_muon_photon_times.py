"""The muon's direct light before the sensor response: the sampled photons' arrival
times per sensor against the expected mode's direct components.

20 events of the 1 GeV muon of ``sk_muon_time_offset.py`` (SK, no scattering, no
reflection; the generator and the sampled mode, the tables), the expected mode with a
transit-time spread of 1 ps. Per bin of the sensors' expected p.e.: the detected
photons' count against the model's, their mean time less the model's mean (ns), the
mean of the model's CDF at each photon's time less 1/2, and the rms spread of the
times about the sensor's mean in the model and in the sampled photons (ns).

    python studies/reconstruction/sk_muon_photon_times.py [EVENTS]
"""

from __future__ import annotations

import sys

import numpy as np
from scipy.special import ndtr
from sk_muon_extent_scale import TRUTH  # the study beside this one

import photonflow as pf
from photonflow.transport.pseudo_data import event_keys, sample_track_tally
from photonflow.transport.tracks import track_light


def main() -> None:
    events = int(sys.argv[1]) if len(sys.argv) > 1 else 20
    detector = pf.load_detector("SK")
    params = pf.default_params(detector).replace(
        scattering_length=1e9, mie_length=1e9, wall_reflectivity=0.0, sensor_reflectivity=0.0)
    config = pf.TransportConfig(n_rays=1024, emission_model="tables")
    prediction = pf.expected(detector, params.replace(tts=1e-3), TRUTH, config=config)
    weight, mean, sigma = (np.asarray(x, np.float64) for x in (
        prediction.time_weight, prediction.time_mean, prediction.time_sigma))
    mu = np.asarray(prediction.charge)
    model_mean = np.sum(weight * mean, axis=1)
    model_variance = np.sum(weight * (sigma ** 2 + mean ** 2), axis=1) - model_mean ** 2
    light = track_light(detector)
    sensors, times = [], []
    for index in range(events):
        tally = sample_track_tally(detector, params, TRUTH, event_keys(99, index)[0], 99,
                                   index, light, config=config)
        sensors.append(np.asarray(tally.photon_sensor))
        times.append(np.asarray(tally.photon_time))
    sensors, times = np.concatenate(sensors), np.concatenate(times)
    n = detector.n_sensors
    count = np.bincount(sensors, minlength=n)
    sensor_mean = np.bincount(sensors, weights=times, minlength=n) / np.maximum(count, 1)
    residual = times - model_mean[sensors]
    u = np.sum(weight[sensors] * ndtr((times[:, None] - mean[sensors]) / sigma[sensors]),
               axis=1)
    print(f"{events} events, {times.size} detected photons (model {events * mu.sum():.0f})")
    print(f"{'p.e.':10s} {'sensors':>8s} {'count/model':>12s} {'mean t - model ns':>18s}"
          f" {'mean u - 1/2':>13s} {'rms model':>10s} {'rms sampled':>12s}")
    for low, high in [(0, 0.3), (0.3, 1), (1, 3), (3, 10), (10, 30), (30, 1e9)]:
        chosen = (mu >= low) & (mu < high)
        photons = chosen[sensors]
        if photons.sum() < 50:
            continue
        sampled_rms = np.sqrt(np.mean((times[photons] - sensor_mean[sensors[photons]]) ** 2))
        rms = np.sqrt(np.mean(model_variance[sensors[photons]]))
        error = residual[photons].std() / np.sqrt(photons.sum())
        print(f"{low:g}-{high:g}".ljust(10),
              f"{chosen.sum():8d} {count[chosen].sum() / (events * mu[chosen].sum()):12.4f}"
              f" {residual[photons].mean():+11.3f}+-{error:.3f}"
              f" {u[photons].mean() - 0.5:+13.4f} {rms:10.3f} {sampled_rms:12.3f}")


if __name__ == "__main__":
    main()
