"""Light of mu+ against mu- and e+ against e- (docs/tracks.md, "The emission model"):

    python studies/tracks/charge_conjugates.py

64 particles per energy at yield_scale 0.2 (about a minute): yields with their errors,
the angular profiles' chi2 per bin, and the mean path lengths.
"""

import numpy as np

from photonflow.generator import GeneratorSettings
from photonflow.generator import emission_tables as T


def main() -> None:
    s = GeneratorSettings(yield_scale=0.2)
    for neg, pos, energies in (("mu-", "mu+", [300.0, 1000.0]), ("e-", "e+", [20.0, 500.0])):
        a = T.build_table(neg, energies, 64, seed=21, settings=s)
        b = T.build_table(pos, energies, 64, seed=22, settings=s)
        for k, e in enumerate(energies):
            ya, yb = a.total_yield[k], b.total_yield[k]
            dy = (yb - ya) / np.hypot(a.yield_error[k], b.yield_error[k])
            pa, pb = a.photons[k].sum(0), b.photons[k].sum(0)
            ea, eb = a.angular_error[k], b.angular_error[k]
            lit = (pa > 0) & (pb > 0)
            chi2 = np.sum((pa - pb)[lit] ** 2 / (ea[lit] ** 2 + eb[lit] ** 2)) / lit.sum()
            print(f"{pos} vs {neg} at {e:g} MeV: yield {yb:.0f} vs {ya:.0f}"
                  f" ({(yb / ya - 1) * 100:+.2f} %, {dy:+.1f} sigma);"
                  f" angular profile chi2/bin {chi2:.2f} over {lit.sum()} bins;"
                  f" track length {b.track_length[k]:.3f} vs {a.track_length[k]:.3f} m")


if __name__ == "__main__":
    main()
