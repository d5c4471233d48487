"""The history of a calibration fit: one entry per iteration (loss, wall time, the
physical values of the dense free entries), as ``CalibrationResult.history`` keeps it."""

from __future__ import annotations

import time

import numpy as np

from ..params import Params


def record_iteration(problem, theta, history, started, callback, loss, stage=None) -> None:
    """Append an iteration at ``theta`` to ``history`` (with ``"stage"`` when given) and
    tell ``callback``."""
    values = dense_values(problem, problem.params_of(theta))
    entry = {"iteration": len(history), "loss": loss,
             "time_s": time.perf_counter() - started, "values": values}
    history.append(entry if stage is None else {**entry, "stage": stage})
    if callback is not None:
        callback(len(history) - 1, loss, values)


def dense_values(problem, params: Params) -> dict[str, float]:
    """Label -> physical value of every dense free entry."""
    values = {}
    for name in problem.layout.dense_fields:
        value = np.asarray(getattr(params, name), np.float64)
        if value.ndim:
            values.update({f"{name}[{k}]": float(v) for k, v in enumerate(value)})
        else:
            values[name] = float(value)
    return values
