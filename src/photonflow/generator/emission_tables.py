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
from .materials import resolve_material
from .particles import PARTICLES
from .settings import GeneratorSettings
from .track import Track

#: Version of the table file layout; readers refuse other versions.
SCHEMA_VERSION = 3
#: Default energy grid, MeV (kinetic): 100 MeV to 5 GeV, log-spaced.
DEFAULT_ENERGIES = tuple(float(e) for e in np.geomspace(100.0, 5000.0, 8).round(1))
#: Default bins per axis: distance, time offset.
DISTANCE_BINS, TIME_BINS = 100, 40
#: Bin edges of cos(angle to the initial direction): 0.005 wide over 0.55-0.95, where the
#: Cherenkov peaks of water and scintillator lie (a muon's ring is ~0.02-0.03 wide in
#: cos), 0.05 wide below and 0.01 wide above.
COS_EDGES = np.concatenate([np.linspace(-1.0, 0.55, 32), np.linspace(0.55, 0.95, 81)[1:],
                            np.linspace(0.95, 1.0, 6)[1:]])
#: Time offsets histogrammed, ns (w.r.t. the light-speed front).
TIME_RANGE = (-2.0, 18.0)


@dataclasses.dataclass(frozen=True)
class EmissionTable:
    """Mean photon emission of one particle type on an energy grid.

    Attributes:
        particle: the species ("mu-", "e-", ...).
        medium: the medium's name.
        energies: (E,) kinetic energies, MeV.
        distance_edges: (E, D + 1) bin edges of the distance along the initial direction,
            m, per energy (0 to the energy's light extent, ``light_extent``).
        cos_edges: (A + 1,) bin edges of cos(angle to the initial direction).
        time_edges: (T + 1,) bin edges of the emission time minus z / c, ns.
        photons: (E, D, A) mean photons per particle per (distance, cos) bin.
        time_offsets: (E, D, T) mean photons per particle per (distance, time) bin.
        offset_sums: (E, D, 2) per particle and distance bin, the sums over photons of
            the time offset and of its square (ns, ns^2): exact moments, free of the
            time bins' width (a muon's photons lie within ~0.1 ns of the front).
        total_yield: (E,) mean photons per particle (all of them, in or out of range).
        yield_spread: (E,) standard deviation of the photons per particle.
        track_length: (E,) mean path length of the primary, m.
        particles: (E,) particles generated at each energy.
        yield_error: (E,) standard error of ``total_yield``.
        angular_error: (E, A) standard error of ``photons`` summed over distance (the
            angular profile), photons per particle per bin.
        per_energy: particles per batch (the whole count without an error target).
        settings: generator settings, seed and error target, as a JSON-able dict.
        visible_energy: (E, D) mean Birks-quenched energy deposit per particle per
            distance bin, MeV (each deposit spread uniformly along its segment, as its
            scintillation light is); None for a medium that does not scintillate. In a
            scintillating medium ``photons`` and the other photon fields hold the
            Cherenkov light alone (the scintillation light is ``light_yield`` x this).
        visible_offset_sums: (E, D, 2) per particle and distance bin, the sums over
            deposits of visible energy x the deposit's time offset (mid-point time minus
            mid-point z / c) and x its square (MeV ns, MeV ns^2); None likewise.
        visible_total: (E,) mean visible energy per particle, MeV (all of it, in or out
            of the distance range); None likewise.
        visible_error: (E,) standard error of ``visible_total``, MeV; None likewise.
    """

    particle: str
    medium: str
    energies: np.ndarray
    distance_edges: np.ndarray
    cos_edges: np.ndarray
    time_edges: np.ndarray
    photons: np.ndarray
    time_offsets: np.ndarray
    offset_sums: np.ndarray
    total_yield: np.ndarray
    yield_spread: np.ndarray
    track_length: np.ndarray
    particles: np.ndarray
    yield_error: np.ndarray
    angular_error: np.ndarray
    per_energy: int
    settings: dict
    visible_energy: np.ndarray | None = None
    visible_offset_sums: np.ndarray | None = None
    visible_total: np.ndarray | None = None
    visible_error: np.ndarray | None = None

    @property
    def scintillating(self) -> bool:
        """Whether the table holds the medium's visible energy deposit (a scintillator)."""
        return self.visible_energy is not None

    def profile_error(self) -> np.ndarray:
        """(E,) statistical error of the angular profile: the summed standard errors of
        its bins over its photons (the photon-weighted mean relative error)."""
        profile = self.photons.sum(axis=1)
        return self.angular_error.sum(axis=1) / np.maximum(profile.sum(axis=1), 1e-300)


#: Particles of the pilot run that sets an energy's distance range (``light_extent``).
PILOT_PARTICLES = 8
#: ... in a scintillator, where the range follows the visible energy's tail (an
#: electron's bremsstrahlung photons, a few per particle).
SCINTILLATOR_PILOT_PARTICLES = 64
#: The distance range is this multiple of the pilot's 99.9 % light quantile along z.
EXTENT_MARGIN = 1.15
#: In a scintillator, the distance range covers this quantile of the visible energy's
#: deposits along z (weighted by their energy; not 0.999: an electron's few
#: bremsstrahlung photons deposit ~1 % of its energy up to ten times further than its
#: track, light the model spreads over the range instead).
VISIBLE_QUANTILE = 0.98
#: Smallest distance range, m.
MINIMUM_EXTENT = 0.01


def light_extent(particle, energy, seed, medium, settings) -> float:
    """Distance range (m) of one energy's table: ``EXTENT_MARGIN`` x the 99.9 % quantile
    of the emission points' z over ``PILOT_PARTICLES`` particles (seeds: children of the
    ``SeedSequence`` ``seed`` spawned before the table's own particles), at least
    ``MINIMUM_EXTENT``. In a scintillator, the ``VISIBLE_QUANTILE`` of the deposits' far
    ends weighted by their visible energy instead (the scintillation light, ~98 % of
    the light; a quantile of the few Cherenkov photons let one hard bremsstrahlung
    photon converting metres away stretch a muon's range twofold), over
    ``SCINTILLATOR_PILOT_PARTICLES`` particles. Bins then follow the light's extent at
    every energy (a 60 MeV muon's ~0.1 m as well as a 5 GeV muon's ~20 m), so the model
    can interpolate in energy at a fixed fraction of the extent."""
    material, scintillating = cherenkov_material(medium)
    z, ends, visible = [], [], []
    pilots = SCINTILLATOR_PILOT_PARTICLES if scintillating else PILOT_PARTICLES
    for child in seed.spawn(pilots):
        event = generate(Track(particle, (0, 0, 0), (0, 0, 1), energy), child, material,
                         settings)
        z.append(event.position[:, 2].astype(np.float64))
        if scintillating:
            ends.append(np.maximum(event.deposits.start[:, 2], event.deposits.end[:, 2]))
            visible.append(event.deposits.visible_energy)
    if scintillating:
        quantile = _weighted_quantile(np.concatenate(ends), np.concatenate(visible),
                                      VISIBLE_QUANTILE)
    else:
        z = np.concatenate(z)
        quantile = float(np.quantile(z, 0.999)) if z.size else 0.0
    return max(MINIMUM_EXTENT, EXTENT_MARGIN * quantile)


def _weighted_quantile(values, weights, q: float) -> float:
    """The ``q`` quantile of ``values`` weighted by ``weights`` (0 without weight)."""
    order = np.argsort(values)
    cumulative = np.cumsum(np.asarray(weights, np.float64)[order])
    if cumulative.size == 0 or cumulative[-1] <= 0:
        return 0.0
    return float(np.asarray(values, np.float64)[order][np.searchsorted(cumulative,
                                                                       q * cumulative[-1])])


#: The per-energy results of a build, in the order ``_energy_row`` returns them.
ROW_FIELDS = ("distance_edges", "photons", "time_offsets", "offset_sums", "total_yield",
              "yield_spread", "track_length", "particles", "yield_error", "angular_error")
#: ... followed, in a scintillating medium, by these.
SCINTILLATION_FIELDS = ("visible_energy", "visible_offset_sums", "visible_total",
                        "visible_error")


def cherenkov_material(medium):
    """(the ``Material`` of ``medium`` without scintillation, whether ``medium``
    scintillates): tables follow the Cherenkov photons and tabulate the scintillator's
    visible energy deposit instead of its millions of scintillation photons."""
    material = resolve_material(medium)
    if material.light_yield > 0:
        return dataclasses.replace(material, light_yield=0.0), True
    return material, False


def _row_fields(scintillating: bool) -> tuple[str, ...]:
    return ROW_FIELDS + (SCINTILLATION_FIELDS if scintillating else ())


def segment_histogram(low, high, weights, edges) -> np.ndarray:
    """Histogram in ``edges`` of segments [low, high] (z of their ends, m) each carrying
    ``weights`` spread uniformly along it (a point segment, low == high, falls in its
    bin): sum_i w_i x (the share of segment i inside each bin)."""
    low, high = np.minimum(low, high), np.maximum(low, high)
    length = high - low
    point = length <= 0
    share = np.clip((edges[None, :] - low[:, None]) / np.where(point, 1.0, length)[:, None],
                    0.0, 1.0)
    share = np.where(point[:, None], (edges[None, :] >= low[:, None]).astype(float), share)
    return weights @ np.diff(share, axis=1)


def _energy_row(particle, energy, per_energy, seed, medium, settings, edges,
                target_error=None, max_per_energy=None, check=None):
    """Histograms, moments and errors of the particles at one energy (``ROW_FIELDS``).

    Particles come in batches of ``per_energy`` (their seeds the successive children of
    the ``SeedSequence`` ``seed``); without ``target_error`` one batch, else batches until
    the relative error of the yield is below it, or ``max_per_energy`` particles.
    ``check`` (if given) is called after every particle (e.g. to honour an interrupt).
    """
    distance_edges, cos_edges, time_edges = edges
    if distance_edges is None:
        extent = light_extent(particle, energy, seed, medium, settings)
        distance_edges = np.linspace(0.0, extent, DISTANCE_BINS + 1)
    photons = np.zeros((len(distance_edges) - 1, len(cos_edges) - 1))
    times = np.zeros((len(distance_edges) - 1, len(time_edges) - 1))
    offset_sums = np.zeros((len(distance_edges) - 1, 2))
    angular_squares = np.zeros(len(cos_edges) - 1)
    yields, lengths = [], []
    material, scintillating = cherenkov_material(medium)
    visible = np.zeros(len(distance_edges) - 1)
    visible_sums = np.zeros((len(distance_edges) - 1, 2))
    visible_totals = []
    scale = settings.yield_scale
    while True:
        for child in seed.spawn(per_energy):
            event = generate(Track(particle, (0, 0, 0), (0, 0, 1), energy), child, material,
                             settings)
            if scintillating:
                deposits = event.deposits
                low, high = deposits.start[:, 2], deposits.end[:, 2]
                middle = 0.5 * (deposits.start_time + deposits.end_time) \
                    - 0.5 * (low + high) / SPEED_OF_LIGHT
                energy_in = deposits.visible_energy.astype(np.float64)
                visible += segment_histogram(low, high, energy_in, distance_edges)
                for k, power in enumerate((middle, middle * middle)):
                    visible_sums[:, k] += segment_histogram(low, high, energy_in * power,
                                                            distance_edges)
                visible_totals.append(float(np.sum(energy_in)))
            z = event.position[:, 2].astype(np.float64)
            cos = event.direction[:, 2].astype(np.float64)
            offset = event.time.astype(np.float64) - z / SPEED_OF_LIGHT
            histogram = np.histogram2d(z, cos, bins=(distance_edges, cos_edges))[0] / scale
            photons += histogram
            angular_squares += histogram.sum(axis=0) ** 2
            times += np.histogram2d(z, offset, bins=(distance_edges, time_edges))[0] / scale
            for k, power in enumerate((offset, offset * offset)):
                offset_sums[:, k] += np.histogram(z, bins=distance_edges,
                                                  weights=power)[0] / scale
            yields.append(len(event) / scale)
            lengths.append(float(event.tracks.length[0]))
            if check is not None:
                check()
        n = len(yields)
        mean_yield = float(np.mean(yields))
        yield_error = float(np.std(yields, ddof=1) / np.sqrt(n)) if n > 1 else np.inf
        profile = photons.sum(axis=0) / n
        variance = np.maximum(angular_squares / n - profile**2, 0.0) * n / max(n - 1, 1)
        angular_error = np.sqrt(variance / n) if n > 1 else np.full_like(profile, np.inf)
        precise = target_error is None or yield_error <= target_error * mean_yield
        if precise or max_per_energy is None or n + per_energy > max_per_energy:
            break
    row = (distance_edges, photons / n, times / n, offset_sums / n, mean_yield,
           float(np.std(yields)), float(np.mean(lengths)), n, yield_error, angular_error)
    if not scintillating:
        return row
    visible_error = float(np.std(visible_totals, ddof=1) / np.sqrt(n)) if n > 1 else np.inf
    return row + (visible / n, visible_sums / n, float(np.mean(visible_totals)), visible_error)


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
    target_error: float | None = None,
    max_per_energy: int | None = None,
    check=None,
) -> EmissionTable:
    """Generate particles at every energy and tabulate their light.

    Args:
        particle: "mu-", "mu+", "e-", "e+" or "gamma".
        energies: kinetic energies, MeV (increasing).
        per_energy: particles per energy (>= 1); with ``target_error``, per batch.
        seed: energy i uses ``SeedSequence(seed).spawn(len(energies))[i]``, one child per
            particle: the same seed gives the same table, whatever is resumed.
        medium: generator medium ("water", "scintillator").
        settings: generator settings; ``yield_scale`` < 1 makes the build faster (counts
            are divided by it, so the table means photons at full yield).
        max_distance: one distance range for every energy, m (default: each energy's
            ``light_extent``).
        resume: a table file to write after every energy; energies already in it (same
            particle, grid, settings and seed) are read back instead of generated.
        progress: show a rich progress bar.
        target_error: if given, batches of ``per_energy`` particles are generated until the
            relative statistical error of the yield is below it (e.g. 0.002), or
            ``max_per_energy`` particles (default 100 x ``per_energy``); the angular
            profile's error is recorded (``EmissionTable.profile_error``).
        check: called after every particle (e.g. ``Interrupts.check``, so that Ctrl-C or
            ``kill`` stops a long energy; the energies already written are kept).

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
    edges = (
        None if max_distance is None else np.linspace(0.0, float(max_distance),
                                                      DISTANCE_BINS + 1),
        COS_EDGES.copy(),
        np.linspace(*TIME_RANGE, TIME_BINS + 1),
    )
    if target_error is not None and not 0.0 < float(target_error) < 1.0:
        raise ConfigError(f"target_error = {format_value(target_error)}: must be in (0, 1)")
    if target_error is not None and max_per_energy is None:
        max_per_energy = 100 * per_energy
    meta = {"generator": dataclasses.asdict(settings), "seed": int(seed)}
    if max_distance is not None:
        meta["max_distance"] = float(max_distance)
    if target_error is not None:
        meta["target_error"] = float(target_error)
        meta["max_per_energy"] = int(max_per_energy)
    table = _empty_table(particle, medium, energies, edges, per_energy, meta,
                         scintillating=cherenkov_material(medium)[1])
    done = _resumed_rows(resume, table) if resume is not None else set()
    children = np.random.SeedSequence(seed).spawn(len(energies))
    rows = [i for i in range(len(energies)) if i not in done]
    for i in with_progress(rows, f"{particle} table", show=progress):
        row = _energy_row(particle, energies[i], per_energy, children[i], medium, settings,
                          edges, target_error, max_per_energy, check)
        for field, value in zip(_row_fields(table.scintillating), row, strict=True):
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


def _empty_table(particle, medium, energies, edges, per_energy, settings,
                 scintillating=False) -> EmissionTable:
    n, d, a, t = len(energies), DISTANCE_BINS, len(edges[1]) - 1, len(edges[2]) - 1
    extra = {}
    if scintillating:
        extra = {"visible_energy": np.zeros((n, d)), "visible_offset_sums": np.zeros((n, d, 2)),
                 "visible_total": np.zeros(n), "visible_error": np.zeros(n)}
    return EmissionTable(
        particle=particle,
        medium=medium,
        energies=energies,
        distance_edges=np.zeros((n, d + 1)) if edges[0] is None
        else np.broadcast_to(edges[0], (n, d + 1)).copy(),
        cos_edges=edges[1],
        time_edges=edges[2],
        photons=np.zeros((n, d, a)),
        time_offsets=np.zeros((n, d, t)),
        offset_sums=np.zeros((n, d, 2)),
        total_yield=np.zeros(n),
        yield_spread=np.zeros(n),
        track_length=np.zeros(n),
        particles=np.zeros(n, dtype=np.int64),
        yield_error=np.zeros(n),
        angular_error=np.zeros((n, a)),
        per_energy=per_energy,
        settings=settings,
        **extra,
    )


_ARRAYS = (
    "energies",
    "distance_edges",
    "cos_edges",
    "time_edges",
    "photons",
    "time_offsets",
    "offset_sums",
    "total_yield",
    "yield_spread",
    "track_length",
    "particles",
    "yield_error",
    "angular_error",
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
        for name in _ARRAYS + (SCINTILLATION_FIELDS if table.scintillating else ()):
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
        arrays.update({name: np.asarray(handle[name]) for name in SCINTILLATION_FIELDS
                       if name in handle})
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
        and all(np.array_equal(getattr(old, n), getattr(table, n))
                for n in ("energies", "cos_edges", "time_edges"))
    )
    if not same:
        raise ConfigError(f"{path}: holds a different build; remove it or choose another file")
    for i in completed:
        for name in _row_fields(table.scintillating):
            getattr(table, name)[i] = getattr(old, name)[i]
    return set(completed)


#: Tables shipped inside the package (built by ``scripts/build_emission_tables.py``), by
#: (particle, medium).
SHIPPED = {(particle, medium): f"emission_{particle}_{medium}.h5"
           for particle in ("mu-", "e-") for medium in ("water", "scintillator")}


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
