"""``Event`` and ``Truth``: one detector readout and the true source that caused it.

Both are immutable dataclasses registered as JAX pytrees: hit arrays and truth
numbers are leaves, the truth's string labels are static. Constructors never
validate (JAX calls them with tracers when unflattening); use ``make_event`` /
``Event.make`` to build a checked event from user data.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..errors import ConfigError
from ..pytree import pytree_dataclass, static_field


def unknown_vector() -> np.ndarray:
    """A read-only (3,) float64 vector of NaN: an unknown position or direction."""
    vector = np.full(3, np.nan)
    vector.setflags(write=False)
    return vector


@pytree_dataclass
class Truth:
    """What really happened in one event (Monte Carlo truth); every field optional.

    Attributes:
        source_kind: kind of light source, e.g. "isotropic", "laser", "track"
            ("" = unknown). Static.
        particle: particle name, e.g. "mu-", "e-" ("" = none or unknown). Static.
        position: (3,) source vertex, m (NaN = unknown).
        direction: (3,) unit direction of the source or particle (NaN = unknown).
        energy: kinetic energy, MeV (NaN = unknown).
        time: source time, ns (NaN = unknown).
        seed: seed of the run that produced the event, the same for all its events
            (-1 = unknown); event i of the run is ``sample_events(..., seed, 1,
            first_event=i)`` (docs/file-format.md).
    """

    source_kind: str = static_field(default="")
    particle: str = static_field(default="")
    position: np.ndarray = dataclasses.field(default_factory=unknown_vector)
    direction: np.ndarray = dataclasses.field(default_factory=unknown_vector)
    energy: float = math.nan
    time: float = math.nan
    seed: int = -1

    @property
    def is_unknown(self) -> bool:
        """True when every field holds its "unknown" default (outside ``jit`` only)."""
        return (
            self.source_kind == ""
            and self.particle == ""
            and bool(np.all(np.isnan(np.asarray(self.position, dtype=np.float64))))
            and bool(np.all(np.isnan(np.asarray(self.direction, dtype=np.float64))))
            and math.isnan(float(self.energy))
            and math.isnan(float(self.time))
            and int(self.seed) == -1
        )


@pytree_dataclass
class Event:
    """The hits recorded in one event.

    Attributes:
        sensor_ids: (K,) int32 index of the sensor of each hit (into the detector's
            sensor arrays).
        charge: (K,) float32 charge of each hit, photoelectrons (p.e.).
        time: (K,) float32 time of each hit, ns.
        truth: the true source (a ``Truth``), or None when unknown.
    """

    sensor_ids: np.ndarray
    charge: np.ndarray
    time: np.ndarray
    truth: Truth | None = None

    @property
    def n_hits(self) -> int:
        """Number of hits K."""
        return int(np.shape(self.sensor_ids)[0])

    @classmethod
    def make(cls, sensor_ids, charge, time, truth: Truth | None = None) -> Event:
        """Build a validated event; same as ``make_event``."""
        return make_event(sensor_ids, charge, time, truth)

    def __repr__(self) -> str:
        kind = "" if self.truth is None else f", truth={self.truth.source_kind or '?'}"
        return f"Event({self.n_hits} hits{kind})"


def hit_arrays_problem(sensor_ids, charge, time) -> str | None:
    """Why three hit arrays do not form a valid event, or None if they do.

    Checks that each is one-dimensional and that all have the same length K.
    Works on numpy arrays and concrete JAX arrays (not inside ``jit``).
    """
    shapes = {
        "sensor_ids": np.shape(sensor_ids), "charge": np.shape(charge), "time": np.shape(time)
    }
    for name, shape in shapes.items():
        if len(shape) != 1:
            return f"{name} has shape {shape}, expected (K,) (one value per hit)"
    k = shapes["sensor_ids"][0]
    for name in ("charge", "time"):
        if shapes[name][0] != k:
            return f"{name} has {shapes[name][0]} values but sensor_ids has {k} (one per hit)"
    return None


def make_event(sensor_ids, charge, time, truth: Truth | None = None) -> Event:
    """Build a validated, read-only ``Event`` from array-likes.

    Args:
        sensor_ids: (K,) sensor index of each hit (cast to int32).
        charge: (K,) charge of each hit, p.e. (cast to float32).
        time: (K,) time of each hit, ns (cast to float32).
        truth: optional ``Truth``.

    Raises:
        ConfigError: arrays of different lengths, not one-dimensional, or sensor ids
            that are not whole numbers; ``truth`` not a ``Truth``.
    """
    ids = np.asarray(sensor_ids)
    problem = hit_arrays_problem(ids, charge, time)
    if problem is not None:
        raise ConfigError(f"event: {problem}")
    if ids.size and not np.issubdtype(ids.dtype, np.integer):
        if not np.all(np.isfinite(ids)) or np.any(ids != np.round(ids)):
            raise ConfigError("event.sensor_ids: must be whole numbers (sensor indices)")
    if truth is not None and not isinstance(truth, Truth):
        raise ConfigError(f"event.truth: a {type(truth).__name__}, expected a Truth or None")
    arrays = []
    for values, dtype in ((ids, np.int32), (charge, np.float32), (time, np.float32)):
        array = np.array(values, dtype=dtype)
        array.setflags(write=False)
        arrays.append(array)
    return Event(*arrays, truth=truth)
