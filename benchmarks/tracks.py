"""Expected track light benchmark (issue 24): ``python benchmarks/tracks.py``.

A 1 GeV muon from the centre of SK along +x, the water defaults, float32: the expected
prediction (forward), the value and gradient of the event likelihood (``nll``, charge +
first-hit time, against one sampled event) with respect to the 7 track parameters
(position, time, two direction angles, energy), and the forward of a batch of 64 tracks
(``lax.map`` in vmapped chunks of 8), for direct light only (``n_bounces=0``) and for
direct + indirect light
(2 bounces, 1,024 rays), each with the default direct-light quadrature and with the
moment tables (``emission_model="tables"``), and, as the reconstruction's fit stages
evaluate it, with the tables and the indirect light held at the track
(``held_indirect_function``: its hold timed apart; the batch of 64 traces rays, as
the case before), the last also for the muon starting 10 m from the centre (its light
ends 2.4 m from the barrel, where the nearest discs' sub-discs are computed: the near
field, ``track_direct``). Medians of 5 calls after compilation;
each case runs in its own process (peak memory is per case). Prints a Markdown table
for BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

#: (bounces, emission model) per case: the default quadrature, and the direct light of
#: the sensors seen from afar read from moment tables (``emission_model="tables"``).
CASES = {"direct": (0, "spline"), "direct + indirect": (2, "spline"),
         "direct, tables": (0, "tables"), "direct + indirect, tables": (2, "tables"),
         "direct + held indirect, tables": (2, "tables", True),
         "direct + held indirect, tables, from (10, 0, 0) m": (2, "tables", True, 10.0)}


def _median_seconds(function, repeats: int = 5) -> float:
    import jax
    import numpy as np

    jax.block_until_ready(function())
    times = []
    for _ in range(repeats):
        began = time.perf_counter()
        jax.block_until_ready(function())
        times.append(time.perf_counter() - began)
    return float(np.median(times))


def measure(bounces: int, emission_model: str = "spline", held: bool = False,
            start_x: float = 0.0) -> dict:
    """One case in this process: seconds and peak resident memory (MB). ``held``: the
    indirect light held at the track (``held_indirect_function``, as the reconstruction's
    fit stages use it), its hold timed apart. ``start_x``: the muon's start on the x axis
    (m; it heads along +x)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import photonflow as pf
    from photonflow.generator import stack_tracks

    detector = pf.load_detector("SK")
    params = pf.default_params(detector)
    config = pf.TransportConfig(n_bounces=bounces, n_rays=1024, emission_model=emission_model)
    predict = pf.expected_function(detector, config=config)
    truth = pf.Track("mu-", [start_x, 0.0, 0.0], [1.0, 0.0, 0.0], 1000.0, 0.0)
    event = pf.sample(detector, params, truth, seed=1)

    def track_of(x):
        """Track from (x, y, z m, t ns, theta, phi rad, log E/MeV)."""
        direction = jnp.stack([jnp.sin(x[4]) * jnp.cos(x[5]), jnp.sin(x[4]) * jnp.sin(x[5]),
                               jnp.cos(x[4])])
        return pf.Track("mu-", x[:3], direction, jnp.exp(x[6]), x[3])

    start = jnp.array([start_x, 0.0, 0.0, 0.0, 0.5 * np.pi, 0.0, np.log(1000.0)])
    light = None
    hold_s = None
    if held:
        from photonflow.transport.expected import held_indirect_function

        hold = jax.jit(lambda x: held_indirect_function(detector, config=config)(
            params, track_of(x)))
        light = hold(start)
        hold_s = _median_seconds(lambda: hold(start))
    forward = jax.jit(lambda x, light: predict(params, track_of(x), held=light).charge)
    loss = jax.jit(jax.value_and_grad(
        lambda x, light: pf.nll(predict(params, track_of(x), held=light), event)))
    rng = np.random.default_rng(0)
    batch = stack_tracks([
        pf.Track("mu-", rng.uniform(-5, 5, 3), direction / np.linalg.norm(direction),
                 float(rng.uniform(500, 2000)), 0.0)
        for direction in rng.normal(size=(64, 3))
    ])
    # vmap over all 64 at once would hold every track's (sensors x nodes x patch) arrays
    # together (~36 GB): lax.map vmaps 8 tracks at a time
    batched = jax.jit(lambda tracks: jax.lax.map(lambda track: predict(params, track).charge,
                                                 tracks, batch_size=8))
    began = time.perf_counter()
    jax.block_until_ready(forward(start, light))
    compile_forward = time.perf_counter() - began
    began = time.perf_counter()
    jax.block_until_ready(loss(start, light))
    compile_gradient = time.perf_counter() - began
    result = {
        "forward_s": _median_seconds(lambda: forward(start, light)),
        "value_and_grad_s": _median_seconds(lambda: loss(start, light)),
        "hold_s": hold_s,
        # the held light belongs to one track: the batch predicts with the rays
        "batch64_s": _median_seconds(lambda: batched(batch), repeats=3),
        "compile_forward_s": compile_forward,
        "compile_gradient_s": compile_gradient,
    }
    result["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", choices=list(CASES), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case is not None:
        print(json.dumps(measure(*CASES[args.case])))
        return
    from photonflow.benchmarking import machine_description

    rows = {}
    for case in CASES:
        out = subprocess.run([sys.executable, __file__, "--case", case], check=True,
                             capture_output=True, text=True).stdout
        rows[case] = json.loads(out.strip().splitlines()[-1])
    print(f"Machine: {machine_description()}\n")
    print("| light | forward s | value+grad s (7 track parameters) | ratio | 64 tracks s"
          " | tracks/s | peak RSS MB | compile fwd / grad s | hold s |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for case, row in rows.items():
        print(f"| {case} | {row['forward_s']:.3f} | {row['value_and_grad_s']:.3f}"
              f" | {row['value_and_grad_s'] / row['forward_s']:.1f}"
              f" | {row['batch64_s']:.2f} | {64 / row['batch64_s']:.0f}"
              f" | {row['peak_rss_mb']:.0f}"
              f" | {row['compile_forward_s']:.0f} / {row['compile_gradient_s']:.0f}"
              f" | {'' if row.get('hold_s') is None else format(row['hold_s'], '.2f')} |")


if __name__ == "__main__":
    main()
