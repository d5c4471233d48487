"""The e/mu reconstruction study of docs/reconstruction.md ("Muons and electrons"):
``python examples/reconstruction/sk_mu_e.py --events N --out-dir DIR``.

SK with its preset response (or ``--detector``, e.g. IWCD; ``--energies MU,E`` MeV):
N 1 GeV muons and N 500 MeV electrons from the generator and the sampled mode
(vertices uniform in ``photonflow simulate``'s fiducial volume, at least 2 m inside the
walls in SK, isotropic directions), each reconstructed from its hits alone with
``--particle auto`` (both hypotheses fitted, the likelier kept), then summarised by
``photonflow evaluate`` (resolutions per particle, misidentification, pulls, plots).
Every stage is a ``photonflow`` command and is resumable: run the same command again after an
interruption and it goes on where it stopped (the event file is made once; the
reconstruction resumes at its first missing event).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

#: (particle, seed offset) of the two samples ...
SAMPLES = (("mu-", 0), ("e-", 1))
#: ... and their kinetic energies (MeV) unless ``--energies`` says otherwise.
ENERGIES = "1000,500"


def _photonflow(*arguments: str) -> None:
    """Run one ``photonflow`` command; stop with its exit code if it fails."""
    command = [sys.executable, "-m", "photonflow", *arguments]
    print("$", " ".join(command[2:]), flush=True)
    done = subprocess.run(command, check=False)
    if done.returncode != 0:
        sys.exit(done.returncode)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=300, help="events per particle")
    parser.add_argument("--out-dir", type=Path, default=Path("sk_mu_e"))
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--rays", type=int, default=1024,
                        help="rays of the predicted indirect light")
    parser.add_argument("--emission-model", default="tables")
    parser.add_argument("--method", default="gradient", help="gradient or minuit")
    parser.add_argument("--fits", type=int, default=None,
                        help="starts fitted per hypothesis (default: the command's)")
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--detector", default="SK", help="preset or configuration file")
    parser.add_argument("--energies", default=ENERGIES,
                        help="kinetic energies of the muons and the electrons, MeV")
    args = parser.parse_args()
    energies = [float(x) for x in args.energies.split(",")]
    folder = args.out_dir
    folder.mkdir(parents=True, exist_ok=True)
    events = folder / "events.h5"
    if not events.exists():
        Path(str(events) + ".part").unlink(missing_ok=True)  # an interrupted start
        for k, ((particle, offset), energy) in enumerate(zip(SAMPLES, energies,
                                                              strict=True)):
            _photonflow("simulate", "--detector", args.detector, "--particle", particle,
                        "--energy", str(energy), "--events", str(args.events),
                        "--seed", str(args.seed + offset), "--out", str(events) + ".part",
                        "--mode", "create" if k == 0 else "append")
        Path(str(events) + ".part").rename(events)
    reco = folder / f"reco_{args.method}.h5"
    if not reco.exists():
        partial = reco.with_name(f".{reco.name}.partial")
        extra = ["--resume"] if partial.exists() else []
        if args.workers:
            extra += ["--workers", str(args.workers)]
        if args.fits:
            extra += ["--fits", str(args.fits)]
        _photonflow("reconstruct", str(events), "--out", str(reco), "--particle", "auto",
                    "--method", args.method, "--rays", str(args.rays),
                    "--emission-model", args.emission_model, *extra)
    _photonflow("evaluate", str(reco), "--out", str(folder / f"summary_{args.method}.json"),
                "--plots", str(folder / f"plots_{args.method}"))


if __name__ == "__main__":
    main()
