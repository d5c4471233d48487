"""Transport benchmark (issue 3): run it as ``python benchmarks/transport.py [--rays N]``.

SK with an isotropic source of 10^6 photons at the centre and 2 m from the barrel wall,
water defaults (scattering, diffuse + specular wall reflection, sensor-glass
reflection), 2 bounces. Prints a Markdown table for BENCHMARKS.md with the machine it
ran on. Each case runs in its own process (peak memory is per case).
"""

import argparse

from photonflow.benchmarking import benchmark_transport, machine_description


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--detector", default="SK")
    parser.add_argument("--photons", type=float, default=1e6)
    parser.add_argument("--rays", type=int, default=1024)
    parser.add_argument("--bounces", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    rows = benchmark_transport(args.detector, args.photons, args.repeats, args.rays,
                               args.bounces)
    print(f"Machine: {machine_description()}\n")
    print("| case | forward s | value+grad s | noise median | noise p90 | sampled photons/s"
          " | peak RSS MB | compile fwd / grad s |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for row in rows:
        print(
            f"| {row['case']} | {row['forward_s']:.3f} | {row['value_and_grad_s']:.3f}"
            f" | {row['noise_median']:.2%} | {row['noise_p90']:.2%}"
            f" | {row['sampled_photons_per_s']:.3g} | {row['peak_rss_mb']:.0f}"
            f" | {row['compile_forward_s']:.1f} / {row['compile_grad_s']:.1f} |"
        )


if __name__ == "__main__":
    main()
