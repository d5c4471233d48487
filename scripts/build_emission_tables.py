"""Rebuild the emission tables shipped in ``src/photonflow/data`` exactly (same seeds, same
grids, same settings): ``python scripts/build_emission_tables.py [particle ...]``.

Each table is built by ``photonflow tables build`` into ``<out>/emission_<particle>_<medium>.h5``
(default ``src/photonflow/data``) and resumes where an interrupted run stopped. One core,
one table at a time; the build times on the 2-core machine are in docs/generator.md.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import numpy as np

#: particle, medium -> (kinetic energies MeV, particles per batch, yield error target,
#: most particles per energy, seed)
SPECS = {
    ("mu-", "water"): (np.geomspace(60.0, 5000.0, 40), 256, 0.002, 65536, 11),
    ("e-", "water"): (np.geomspace(0.5, 5000.0, 48), 256, 0.002, 65536, 12),
    # in the scintillator the tables hold the Cherenkov light (a few % of the light) and
    # the visible energy deposit (its statistical error is far below 0.2 %)
    ("mu-", "scintillator"): (np.geomspace(20.0, 5000.0, 24), 32, 0.002, 4096, 13),
    ("e-", "scintillator"): (np.geomspace(0.5, 5000.0, 36), 64, 0.002, 16384, 14),
}


def command(particle: str, medium: str, out: Path) -> list[str]:
    """The ``photonflow tables build`` command line of one shipped table."""
    energies, batch, target, most, seed = SPECS[(particle, medium)]
    grid = ",".join(f"{energy:.4g}" for energy in energies)
    return [
        sys.executable, "-m", "photonflow", "tables", "build",
        "--particle", particle, "--medium", medium,
        "--out", str(out / f"emission_{particle}_{medium}.h5"),
        "--energies", grid, "--per-energy", str(batch), "--seed", str(seed),
        "--yield-scale", "1.0", "--target-error", str(target),
        "--max-per-energy", str(most),
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("particles", nargs="*", default=["mu-", "e-"])
    parser.add_argument("--medium", default="water", choices=sorted({m for _, m in SPECS}))
    parser.add_argument("--out", type=Path,
                        default=Path(__file__).resolve().parents[1] / "src/photonflow/data")
    args = parser.parse_args()
    for particle in args.particles:
        subprocess.run(command(particle, args.medium, args.out), check=True)


if __name__ == "__main__":
    main()
