"""Emission tables: the mean light of a particle type, binned along its initial direction.

For each kinetic energy of a grid, ``per_energy`` particles start at the origin along +z
and their photons are histogrammed in

- the distance z (m) of the emission point along the initial direction,
- the cosine of the angle between the photon's direction and the initial direction,
- and, per distance bin, the time offset (ns) of the emission with respect to a front
  moving along the initial direction at the speed of light (t - z / c),

as mean photons per particle per bin (float64 sums / particles). With the total yield and
its spread and the mean path length of the primary, these are what a differentiable
track model is fitted to. Tables are written to HDF5 (``save_table``; schema version
``SCHEMA_VERSION``, the generator settings and the seeds as attributes) one energy at a
time, so an interrupted build resumes where it stopped (``build_table(..., resume=path)``).
Units: MeV, m, ns.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Sequence
from pathlib import Path

import h5py
import numpy as np

from ..constants import SPEED_OF_LIGHT
from ..errors import ConfigError, format_value
from ..progress import with_progress
from .generate import generate
from .particles import PARTICLES
from .settings import GeneratorSettings
from .track import Track

#: Version of the table file layout; readers refuse other versions.
SCHEMA_VERSION = 1
#: Default energy grid, MeV (kinetic): 100 MeV to 5 GeV, log-spaced.
DEFAULT_ENERGIES = tuple(float(e) for e in np.geomspace(100.0, 5000.0, 8).round(1))
#: Default bins per axis: distance, cos(angle), time offset.
DISTANCE_BINS, COS_BINS, TIME_BINS = 100, 80, 40
#: Time offsets histogrammed, ns (w.r.t. the light-speed front).
TIME_RANGE = (-2.0, 18.0)


@dataclasses.dataclass(frozen=True)
class EmissionTable:
    """Mean photon emission of one particle type on an energy grid.

    Attributes:
        particle: the species ("mu-", "e-", ...).
        medium: the medium's name.
        energies: (E,) kinetic energies, MeV.
        distance_edges: (D + 1,) bin edges of the distance along the initial direction, m.
        cos_edges: (A + 1,) bin edges of cos(angle to the initial direction).
        time_edges: (T + 1,) bin edges of the emission time minus z / c, ns.
        photons: (E, D, A) mean photons per particle per (distance, cos) bin.
        time_offsets: (E, D, T) mean photons per particle per (distance, time) bin.
        total_yield: (E,) mean photons per particle (all of them, in or out of range).
        yield_spread: (E,) standard deviation of the photons per particle.
        track_length: (E,) mean path length of the primary, m.
        per_energy: particles generated per energy.
        settings: generator settings and seed, as a JSON-able dict.
    """

    particle: str
    medium: str
    energies: np.ndarray
    distance_edges: np.ndarray
    cos_edges: np.ndarray
    time_edges: np.ndarray
    photons: np.ndarray
    time_offsets: np.ndarray
    total_yield: np.ndarray
    yield_spread: np.ndarray
    track_length: np.ndarray
    per_energy: int
    settings: dict


def default_max_distance(particle: str) -> float:
    """Distance range of the table, m: 25 m for muons (5 GeV range ~22 m in water), 10 m
    for electrons, positrons and photons (showers end within ~8 m at 5 GeV)."""
    return 25.0 if particle.startswith("mu") else 10.0


def _energy_row(particle, energy, per_energy, seed, medium, settings, edges):
    """Histograms and moments of ``per_energy`` particles at one energy (their seeds are
    the children of the ``SeedSequence`` ``seed``)."""
    distance_edges, cos_edges, time_edges = edges
    photons = np.zeros((len(distance_edges) - 1, len(cos_edges) - 1))
    times = np.zeros((len(distance_edges) - 1, len(time_edges) - 1))
    yields, lengths = [], []
    scale = settings.yield_scale
    for child in seed.spawn(per_energy):
        event = generate(Track(particle, (0, 0, 0), (0, 0, 1), energy), child, medium, settings)
        z = event.position[:, 2].astype(np.float64)
        cos = event.direction[:, 2].astype(np.float64)
        offset = event.time.astype(np.float64) - z / SPEED_OF_LIGHT
        photons += np.histogram2d(z, cos, bins=(distance_edges, cos_edges))[0]
        times += np.histogram2d(z, offset, bins=(distance_edges, time_edges))[0]
        yields.append(len(event) / scale)
        lengths.append(float(event.tracks.length[0]))
    norm = 1.0 / (per_energy * scale)
    return photons * norm, times * norm, np.mean(yields), np.std(yields), np.mean(lengths)


def build_table(
    particle: str,
    energies: Sequence[float] = DEFAULT_ENERGIES,
    per_energy: int = 20,
    *,
    seed: int = 0,
    medium: str = "water",
    settings: GeneratorSettings | None = None,
    max_distance: float | None = None,
    resume: str | Path | None = None,
    progress: bool = False,
) -> EmissionTable:
    """Generate ``per_energy`` particles at every energy and tabulate their light.

    Args:
        particle: "mu-", "mu+", "e-", "e+" or "gamma".
        energies: kinetic energies, MeV (increasing).
        per_energy: particles per energy (>= 1).
        seed: energy i uses ``SeedSequence(seed).spawn(len(energies))[i]``, one child per
            particle: the same seed gives the same table, whatever is resumed.
        medium: generator medium ("water", "scintillator").
        settings: generator settings; ``yield_scale`` < 1 makes the build faster (counts
            are divided by it, so the table means photons at full yield).
        max_distance: distance range, m (default ``default_max_distance``).
        resume: a table file to write after every energy; energies already in it (same
            particle, grid, settings and seed) are read back instead of generated.
        progress: show a rich progress bar.

    Returns:
        The ``EmissionTable``.
    """
    energies = _check_energies(energies)
    if particle not in PARTICLES:
        raise ConfigError(f"particle = {format_value(particle)}: one of {sorted(PARTICLES)}")
    if not isinstance(per_energy, int) or isinstance(per_energy, bool) or per_energy < 1:
        raise ConfigError(f"per_energy = {format_value(per_energy)}: must be an integer >= 1")
    settings = settings if settings is not None else GeneratorSettings()
    if not settings.yield_scale > 0:
        raise ConfigError(f"yield_scale = {format_value(settings.yield_scale)}: must be > 0")
    reach = default_max_distance(particle) if max_distance is None else float(max_distance)
    edges = (
        np.linspace(0.0, reach, DISTANCE_BINS + 1),
        np.linspace(-1.0, 1.0, COS_BINS + 1),
        np.linspace(*TIME_RANGE, TIME_BINS + 1),
    )
    meta = {"generator": dataclasses.asdict(settings), "seed": int(seed)}
    table = _empty_table(particle, medium, energies, edges, per_energy, meta)
    done = _resumed_rows(resume, table) if resume is not None else set()
    children = np.random.SeedSequence(seed).spawn(len(energies))
    rows = [i for i in range(len(energies)) if i not in done]
    for i in with_progress(rows, f"{particle} table", show=progress):
        row = _energy_row(particle, energies[i], per_energy, children[i], medium, settings, edges)
        for field, value in zip(
            ("photons", "time_offsets", "total_yield", "yield_spread", "track_length"),
            row,
            strict=True,
        ):
            getattr(table, field)[i] = value
        done.add(i)
        if resume is not None:
            save_table(resume, table, completed=sorted(done))
    return table


def _check_energies(energies) -> np.ndarray:
    values = np.asarray(energies, dtype=np.float64).ravel()
    if values.size == 0 or not np.all(np.isfinite(values)) or np.any(values <= 0):
        raise ConfigError(f"energies = {format_value(energies)}: must be finite MeV > 0")
    if np.any(np.diff(values) <= 0):
        raise ConfigError(f"energies = {format_value(energies)}: must increase")
    return values


def _empty_table(particle, medium, energies, edges, per_energy, settings) -> EmissionTable:
    n, (d, a, t) = len(energies), (len(e) - 1 for e in edges)
    return EmissionTable(
        particle=particle,
        medium=medium,
        energies=energies,
        distance_edges=edges[0],
        cos_edges=edges[1],
        time_edges=edges[2],
        photons=np.zeros((n, d, a)),
        time_offsets=np.zeros((n, d, t)),
        total_yield=np.zeros(n),
        yield_spread=np.zeros(n),
        track_length=np.zeros(n),
        per_energy=per_energy,
        settings=settings,
    )


_ARRAYS = (
    "energies",
    "distance_edges",
    "cos_edges",
    "time_edges",
    "photons",
    "time_offsets",
    "total_yield",
    "yield_spread",
    "track_length",
)


def save_table(path: str | Path, table: EmissionTable, completed: Sequence[int] | None = None):
    """Write ``table`` to an HDF5 file (atomically: a temporary file renamed over ``path``).

    ``completed`` lists the energy rows that hold results (default: all)."""
    path = Path(path)
    completed = list(range(len(table.energies))) if completed is None else list(completed)
    temporary = path.with_name(path.name + ".partial")
    with h5py.File(temporary, "w") as handle:
        handle.attrs["schema_version"] = SCHEMA_VERSION
        handle.attrs["particle"] = table.particle
        handle.attrs["medium"] = table.medium
        handle.attrs["per_energy"] = table.per_energy
        handle.attrs["settings"] = json.dumps(table.settings)
        handle.attrs["completed"] = np.asarray(completed, dtype=np.int64)
        for name in _ARRAYS:
            handle.create_dataset(name, data=np.asarray(getattr(table, name)), compression="gzip")
    os.replace(temporary, path)


def load_table(path: str | Path) -> EmissionTable:
    """Read a table written by ``save_table``; ``ConfigError`` for a missing file, another
    schema version or an incomplete build."""
    table, completed = _read(path)
    if len(completed) != len(table.energies):
        raise ConfigError(
            f"{path}: {len(completed)} of {len(table.energies)} energies built; resume the build"
        )
    return table


def _read(path) -> tuple[EmissionTable, list[int]]:
    try:
        handle = h5py.File(path, "r")
    except OSError as error:
        raise ConfigError(f"emission table {path}: cannot be read ({error})") from None
    with handle:
        version = int(handle.attrs.get("schema_version", -1))
        if version != SCHEMA_VERSION:
            raise ConfigError(f"{path}: schema_version = {version}, expected {SCHEMA_VERSION}")
        arrays = {name: np.asarray(handle[name]) for name in _ARRAYS}
        table = EmissionTable(
            particle=str(handle.attrs["particle"]),
            medium=str(handle.attrs["medium"]),
            per_energy=int(handle.attrs["per_energy"]),
            settings=json.loads(handle.attrs["settings"]),
            **arrays,
        )
        return table, [int(i) for i in handle.attrs["completed"]]


def _resumed_rows(path, table: EmissionTable) -> set[int]:
    """Fill ``table`` with the rows an earlier, identical build wrote to ``path``."""
    if not Path(path).exists():
        return set()
    old, completed = _read(path)
    same = (
        old.particle == table.particle
        and old.medium == table.medium
        and old.per_energy == table.per_energy
        and old.settings == json.loads(json.dumps(table.settings))
        and all(np.array_equal(getattr(old, n), getattr(table, n)) for n in _ARRAYS[:4])
    )
    if not same:
        raise ConfigError(f"{path}: holds a different build; remove it or choose another file")
    for i in completed:
        for name in ("photons", "time_offsets", "total_yield", "yield_spread", "track_length"):
            getattr(table, name)[i] = getattr(old, name)[i]
    return set(completed)


#: Tables shipped inside the package (built by ``photonflow tables build`` with the
#: defaults, ``--per-energy 20 --yield-scale 0.2``), by (particle, medium).
SHIPPED = {("mu-", "water"): "emission_mu-_water.h5", ("e-", "water"): "emission_e-_water.h5"}


def shipped_table(particle: str, medium: str = "water") -> EmissionTable:
    """A table that ships with photonflow (see ``SHIPPED``); ``ConfigError`` otherwise."""
    from importlib.resources import files

    name = SHIPPED.get((particle, medium))
    if name is None:
        raise ConfigError(
            f"no shipped emission table for particle = {particle!r} in {medium!r};"
            f" shipped: {sorted(SHIPPED)}"
        )
    return load_table(files("photonflow") / "data" / name)


def angular_density(table: EmissionTable) -> np.ndarray:
    """(E, A) photons per particle per unit cos(angle), summed over distance."""
    return table.photons.sum(axis=1) / np.diff(table.cos_edges)


def cherenkov_peak_cos(table: EmissionTable) -> np.ndarray:
    """(E,) centre of the cos(angle) bin holding the most photons."""
    centres = 0.5 * (table.cos_edges[1:] + table.cos_edges[:-1])
    return centres[np.argmax(angular_density(table), axis=1)]


__all__ = [
    "DEFAULT_ENERGIES",
    "EmissionTable",
    "SCHEMA_VERSION",
    "build_table",
    "cherenkov_peak_cos",
    "load_table",
    "save_table",
    "shipped_table",
]
