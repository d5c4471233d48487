"""``FreeLayout``: which ``Params`` fields a calibration fits, and how they are packed.

A calibration works in unconstrained coordinates (``Params.to_unconstrained``). Its free
parameters are held as a dict ``theta`` of field name -> unconstrained array. The
curvature matrices use a fixed split of ``theta``:

- dense entries: every element of the free scalar and fixed-size vector fields
  (absorption length, ..., ``angular_acceptance[k]``), P of them in ``Params`` order;
- per-sensor fields (``efficiency``, ``time_offset``): an (N, F) matrix, one column per
  free per-sensor field. A sensor's light depends only on its own per-sensor values,
  so their curvature is block-diagonal per sensor (``structured.py``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError, format_value
from ..params import PARAM_SPECS, SPECS

#: Fields that enter the prediction after the light transport: a sensor's efficiency
#: scales its charge, its time offset shifts its times, the transit-time spread widens
#: them, and the dark rate and single-p.e. width enter only the likelihood. When every
#: free field is one of these, the transport is computed once per run, not per step.
RESPONSE_FIELDS = frozenset({"efficiency", "time_offset", "tts", "dark_rate", "spe_width"})


@dataclasses.dataclass(frozen=True)
class FreeLayout:
    """The free fields of a calibration (static; hashable).

    Attributes:
        names: free ``Params`` field names, in ``Params`` order.
        n_sensors: number of sensors N.
    """

    names: tuple[str, ...]
    n_sensors: int

    @property
    def dense_fields(self) -> tuple[str, ...]:
        """Free fields that are scalars or fixed-size vectors."""
        return tuple(name for name in self.names if not SPECS[name].per_sensor)

    @property
    def sensor_fields(self) -> tuple[str, ...]:
        """Free per-sensor fields (length N each)."""
        return tuple(name for name in self.names if SPECS[name].per_sensor)

    def dense_size(self, name: str) -> int:
        """Number of dense entries of field ``name`` (1 for a scalar)."""
        return SPECS[name].size or 1

    @property
    def n_dense(self) -> int:
        """P: number of dense entries."""
        return sum(self.dense_size(name) for name in self.dense_fields)

    @property
    def needs_transport(self) -> bool:
        """True when some free field changes the light transport (not only the response)."""
        return any(name not in RESPONSE_FIELDS for name in self.names)

    def dense_names(self) -> list[str]:
        """A label per dense entry: the field name, with ``[k]`` for vector fields."""
        labels = []
        for name in self.dense_fields:
            size = SPECS[name].size
            labels += [f"{name}[{k}]" for k in range(size)] if size else [name]
        return labels

    def split(self, theta: dict) -> tuple[jnp.ndarray, jnp.ndarray]:
        """``theta`` -> (dense (P,), per-sensor (N, F)) arrays."""
        dense = [jnp.ravel(theta[name]) for name in self.dense_fields]
        columns = [theta[name] for name in self.sensor_fields]
        dense_vector = jnp.concatenate(dense) if dense else jnp.zeros(0)
        sensor_matrix = (
            jnp.stack(columns, axis=1) if columns else jnp.zeros((self.n_sensors, 0))
        )
        return dense_vector, sensor_matrix

    def join(self, dense, sensor) -> dict:
        """Inverse of ``split``: (dense (P,), per-sensor (N, F)) -> ``theta``."""
        theta = {}
        start = 0
        for name in self.dense_fields:
            size = SPECS[name].size
            stop = start + (size or 1)
            theta[name] = dense[start:stop] if size else dense[start]
            start = stop
        for column, name in enumerate(self.sensor_fields):
            theta[name] = sensor[:, column]
        return theta

    def select(self, unconstrained) -> dict:
        """The free fields of an unconstrained ``Params`` as ``theta``."""
        return {name: getattr(unconstrained, name) for name in self.names}


def free_layout(free: Iterable[str] | str, n_sensors: int) -> FreeLayout:
    """Validate the names of the free fields (a list or a comma-separated string).

    Raises:
        ConfigError: no names, or a name that is not a ``Params`` field (one line).
    """
    if isinstance(free, str):
        free = [part.strip() for part in free.split(",") if part.strip()]
    requested = list(free)
    if not requested:
        raise ConfigError("free: empty; name at least one Params field to fit")
    for name in requested:
        if name not in SPECS:
            raise ConfigError(
                f"free: unknown parameter {format_value(name)}; known: {', '.join(SPECS)}"
            )
    names = tuple(spec.name for spec in PARAM_SPECS if spec.name in set(requested))
    return FreeLayout(names=names, n_sensors=int(n_sensors))


def entry_count(layout: FreeLayout) -> int:
    """Total number of fitted numbers: P dense entries + N per free per-sensor field."""
    return layout.n_dense + layout.n_sensors * len(layout.sensor_fields)


def as_numpy_theta(theta: dict) -> dict[str, np.ndarray]:
    """``theta`` with numpy float64 values (for files and printing)."""
    return {name: np.asarray(value, dtype=np.float64) for name, value in theta.items()}
