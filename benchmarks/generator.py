"""Generator benchmark: ``python benchmarks/generator.py [--repeats 3]``.

The stochastic generator (``photonflow.generate``, pure numpy) one event at a time
against ``generate_together`` (every event's particles in one stack): 16 muons of 1 GeV
in water (what the reconstruction simulates at each fit) and 2,000 electrons of 10 MeV
in LAB (a calibration or solar-neutrino sample in a scintillator), and the pseudo-data
of 64 SK muons of 1 GeV from ``sample_events`` against ``sample_together`` (generation,
photon transport and readout). Medians of ``--repeats`` runs after a warm-up, one
process on one core for the generator (numpy); the SK rows include the compiled
transport. Prints a Markdown table for BENCHMARKS.md.
"""

from __future__ import annotations

import argparse


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()

    import photonflow as pf
    from photonflow.benchmarking import machine_description, median_time
    from photonflow.generator import Track, generate, generate_together

    cases = [("16 mu- of 1 GeV, water", Track("mu-", [0, 0, 0], [0, 0, 1], 1000.0), 16,
              "water"),
             ("2,000 e- of 10 MeV, LAB", Track("e-", [0, 0, 0], [0, 0, 1], 10.0), 2000,
              "scintillator")]
    print(f"Machine: {machine_description()}\n")
    print("| events | one at a time, s | together, s | ratio |")
    print("|---|---:|---:|---:|")
    for name, track, count, medium in cases:
        list(generate_together([track] * 2, 0, medium))  # tables built, code warm
        alone = median_time(
            lambda track=track, count=count, medium=medium:
            [generate(track, k, medium) for k in range(count)], args.repeats)
        together = median_time(
            lambda track=track, count=count, medium=medium:
            list(generate_together([track] * count, 1, medium)), args.repeats)
        print(f"| {name}: generation | {alone:.2f} | {together:.2f} | {alone / together:.1f} |",
              flush=True)

    detector = pf.load_detector("SK")
    params = pf.default_params(detector)
    muon = pf.Track("mu-", [1.0, -2.0, 3.0], [0.6, 0.0, 0.8], 1000.0)
    pf.sample_together(detector, params, [muon] * 2, 0)  # compiled, grid built
    list(pf.sample_events(detector, params, muon, 0, 2))
    alone = median_time(lambda: list(pf.sample_events(detector, params, muon, 1, 64)),
                        args.repeats)
    together = median_time(lambda: pf.sample_together(detector, params, [muon] * 64, 1),
                           args.repeats)
    print(f"| 64 mu- of 1 GeV in SK: pseudo-data | {alone:.2f} | {together:.2f} |"
          f" {alone / together:.1f} |")


if __name__ == "__main__":
    main()
