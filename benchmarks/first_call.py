"""Time to first result: the README's "Simulating light" snippet, and the first call of
``expected`` and of its gradient, cold (an empty compilation cache) and warm (a second
process with the cache the first one filled), each in a fresh Python process.

    python benchmarks/first_call.py [--detectors TOY_CYLINDER,SK] [--repeats 3]

Prints a markdown table for BENCHMARKS.md (medians over the repeats, seconds of wall
time inside the process, imports included; peak RSS in MB).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import textwrap
from datetime import date
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def readme_snippet() -> str:
    """The code block of the README's "Simulating light" section."""
    text = README.read_text()
    return text.split("## Simulating light", 1)[1].split("```python\n", 1)[1].split("```")[0]


FIRST_CALLS = """
import time
import jax
import photonflow as pf

detector = pf.load_detector({name!r})
params = pf.default_params(detector)
source = pf.IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=1e6)
event = pf.sample(detector, params, source, seed=1)
start = time.perf_counter()
jax.block_until_ready(pf.expected(detector, params, source).charge)
forward = time.perf_counter() - start
start = time.perf_counter()
jax.block_until_ready(jax.grad(lambda p: pf.nll(pf.expected(detector, p, source), event))(params))
gradient = time.perf_counter() - start
print("RESULT", forward, gradient)
"""

def _run(code: str, cache: str) -> dict:
    """Run ``code`` in a fresh interpreter with the compilation cache in ``cache``:
    {"wall": s (the whole process body, imports included), "rss": MB, "result": [...]}."""
    wrapper = textwrap.dedent(f"""
        import resource, time
        _start = time.perf_counter()
        exec(compile({code!r}, "snippet", "exec"))
        print("WALL", time.perf_counter() - _start)
        print("RSS", resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)
    """)
    env = {**os.environ, "PHOTONFLOW_COMPILATION_CACHE": cache}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    out = subprocess.run([sys.executable, "-c", wrapper], env=env, check=True,
                         capture_output=True, text=True).stdout
    values = {}
    for line in out.splitlines():
        key, _, rest = line.partition(" ")
        if key in ("WALL", "RSS"):
            values[key.lower()] = float(rest)
        elif key == "RESULT":
            values["result"] = [float(x) for x in rest.split()]
    return values


def cold_and_warm(code: str, repeats: int) -> tuple[list[dict], list[dict]]:
    """Per repeat: one process on an empty cache (cold), then one on the cache it filled
    (warm)."""
    cold, warm = [], []
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as cache:
            cold.append(_run(code, cache))
            warm.append(_run(code, cache))
    return cold, warm


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--detectors", default="TOY_CYLINDER,SK")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    rows = []
    cold, warm = cold_and_warm(readme_snippet(), args.repeats)
    rows.append(("README snippet (TOY_CYLINDER)", "process",
                 statistics.median(r["wall"] for r in cold),
                 statistics.median(r["wall"] for r in warm),
                 max(r["rss"] for r in cold)))
    for name in args.detectors.split(","):
        cold, warm = cold_and_warm(FIRST_CALLS.format(name=name), args.repeats)
        for index, label in enumerate(("expected", "grad of nll(expected)")):
            rows.append((f"{label} ({name})", "first call",
                         statistics.median(r["result"][index] for r in cold),
                         statistics.median(r["result"][index] for r in warm),
                         max(r["rss"] for r in cold)))
    print(f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}, {date.today().isoformat()}; medians of "
          f"{args.repeats} cold/warm process pairs.\n")
    print("| what | timed | cold s | warm s | peak RSS MB |\n|---|---|---:|---:|---:|")
    for label, timed, cold_s, warm_s, rss in rows:
        print(f"| {label} | {timed} | {cold_s:.1f} | {warm_s:.1f} | {rss:.0f} |")
    print(json.dumps({"rows": rows}), file=sys.stderr)


if __name__ == "__main__":
    main()
