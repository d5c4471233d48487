"""Timing and memory benchmarks of the transport (used by ``photonflow benchmark``).

Each case runs in a fresh Python process so that its peak resident memory is its own.
Times are medians of repeated calls after compilation (compilation time is reported
separately). Benchmarks never run in the test suite: the machines are shared and noisy.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable

import numpy as np

from .errors import ConfigError

#: Case name -> where the isotropic source sits (fraction of the barrel radius or m).
TRANSPORT_CASES = ("centre", "2 m from barrel")


def median_time(function: Callable[[], object], repeats: int) -> float:
    """Median wall time (s) of ``repeats`` calls of ``function`` (no warm-up: call it
    once before where compilation or caches would count)."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def transport_case(detector_name: str, case: str, photons: float, repeats: int,
                   n_rays: int, n_bounces: int) -> dict[str, float]:
    """Measure one case in this process (s, photons/s, relative noise, MB). See
    ``benchmark_transport``."""
    import resource

    import jax
    import jax.numpy as jnp

    from .config import load_setup
    from .geometry.sensor_grid import build_sensor_grid
    from .likelihood import nll
    from .sources import IsotropicSource
    from .transport.expected import expected
    from .transport.optics import TransportConfig
    from .transport.pseudo_data import sample as sample_event
    from .transport.sampled import sample_photons

    setup = load_setup(detector_name)
    detector, params = setup.detector, setup.params
    radius = getattr(detector.shape, "radius", 0.0)
    position = [0.0, 0.0, 0.0] if case == "centre" else [radius - 2.0, 0.0, 0.0]
    source = IsotropicSource(position=position, n_photons=photons)
    config = TransportConfig(n_bounces=n_bounces, n_rays=n_rays)
    grid = build_sensor_grid(detector) if detector.shape.has_walls else None
    window = config.window

    # the public call as users jit it: the detector is prepared inside, once
    @jax.jit
    def forward(p, key):
        return expected(detector, p, source, config=config, key=key, grid=grid)

    start = time.perf_counter()
    jax.block_until_ready(forward(params, jax.random.key(0)).charge)
    compile_forward = time.perf_counter() - start
    t_forward = median_time(
        lambda: jax.block_until_ready(forward(params, jax.random.key(0)).charge), repeats)

    event = sample_event(detector, params, source, 1, config=config)

    def loss(p):
        return nll(forward(p, jax.random.key(0)), event, p, window=window)

    value_and_grad = jax.jit(jax.value_and_grad(loss))
    start = time.perf_counter()
    jax.block_until_ready(value_and_grad(params))
    compile_grad = time.perf_counter() - start
    t_grad = median_time(lambda: jax.block_until_ready(value_and_grad(params)), repeats)

    charges = np.stack([np.asarray(forward(params, jax.random.key(k)).charge)
                        for k in range(5)])
    mean = charges.mean(axis=0)
    lit = mean > 1e-3 * mean.max()
    noise = charges[:, lit].std(axis=0, ddof=1) / mean[lit]

    key = jax.random.key(7)
    sample_photons(detector, params, source, key, config=config, grid=grid)  # compile
    t_sample = median_time(
        lambda: sample_photons(detector, params, source, key, config=config, grid=grid), 3
    )
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return {
        "forward_s": t_forward,
        "value_and_grad_s": t_grad,
        "compile_forward_s": compile_forward,
        "compile_grad_s": compile_grad,
        "noise_median": float(np.median(noise)),
        "noise_p90": float(np.percentile(noise, 90)),
        "sampled_photons_per_s": photons / t_sample,
        "peak_rss_mb": peak_mb,
        "n_params_leaves": float(sum(int(jnp.size(x)) for x in jax.tree.leaves(params))),
    }


def benchmark_transport(detector_name: str = "SK", photons: float = 1e6, repeats: int = 5,
                        n_rays: int | None = None, n_bounces: int = 2,
                        report: Callable[[str], None] | None = None) -> list[dict]:
    """Run every transport case in its own process; one result row per case (times s,
    memory MB). ``report`` is called with a line before each case starts.

    Raises:
        ConfigError: a case's process failed (its last line of output, one line).
    """
    from .transport.optics import TransportConfig

    n_rays = TransportConfig().n_rays if n_rays is None else n_rays
    rows = []
    for number, case in enumerate(TRANSPORT_CASES, start=1):
        if report is not None:
            report(f"case {number} of {len(TRANSPORT_CASES)}: {detector_name}, {case}"
                   f" ({photons:g} photons, {n_rays} rays, {n_bounces} bounces, {repeats}"
                   " repeats, in a fresh process) ...")
        code = (
            "import json; from photonflow.benchmarking import transport_case;"
            f"print(json.dumps(transport_case({detector_name!r}, {case!r}, {photons!r},"
            f" {repeats!r}, {n_rays!r}, {n_bounces!r})))"
        )
        # compilation measured, not loaded from the persistent cache
        environment = {**os.environ, "PHOTONFLOW_COMPILATION_CACHE": "off"}
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              env=environment)
        if done.returncode != 0:
            lines = [line.strip() for line in done.stderr.splitlines() if line.strip()]
            raise ConfigError(
                f"benchmark case {case!r} of {detector_name!r} failed in its process (exit"
                f" {done.returncode}): {lines[-1] if lines else 'no message'}"
            )
        row = json.loads(done.stdout.strip().splitlines()[-1])
        rows.append({"detector": detector_name, "case": case, "photons": photons,
                     "n_rays": n_rays, "n_bounces": n_bounces, **row})
    return rows


def machine_description() -> str:
    """CPU model, core count, Python and JAX versions of this machine."""
    import os

    import jax

    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as handle:
            for line in handle:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return (f"{model}, {os.cpu_count()} cores, Python {platform.python_version()},"
            f" JAX {jax.__version__} ({jax.default_backend()})")
