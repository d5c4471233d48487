"""Guards of a calibration fit: free values the runs cannot constrain, values that run
off, non-finite likelihoods, and the boundary that turns a numerical failure inside a
stage of the fit into one line. Free values in unconstrained units (``params.py``)."""

from __future__ import annotations

import numpy as np

from ..errors import CalibrationError, ConfigError, PhotonflowError
from .history import dense_values
from .layout import FreeLayout
from .structured import StructuredMatrix

#: A free value whose 1-sigma uncertainty exceeds this, in unconstrained units (log for
#: lengths and rates: a factor e^3 = 20; logit for probabilities; ns for time offsets),
#: is reported as not constrained by the data.
UNCONSTRAINED_SIGMA = 3.0


def unconstrained_labels(
    layout: FreeLayout, curvature: StructuredMatrix, expected_information: bool = True
) -> list[str]:
    """Free entries that the curvature leaves (nearly) flat: no information at all, or
    (for an expected Fisher information, which both likelihoods use) a 1-sigma
    uncertainty above ``UNCONSTRAINED_SIGMA`` (a flat direction, e.g. a global
    efficiency degenerate with the per-sensor ones). An observed information away from
    the optimum does not measure identifiability, so for it
    (``expected_information=False``) only the first test applies. Empty when all are
    constrained."""
    labels = layout.dense_names()
    flat = [labels[i] for i in np.flatnonzero(~(np.diag(curvature.a) > 0))]
    for column, name in enumerate(layout.sensor_fields):
        dead = np.flatnonzero(~(curvature.b[:, column, column] > 0))
        if dead.size:
            flat.append(f"{name} of {dead.size} sensors (first: {int(dead[0])})")
    if flat or not expected_information:
        return flat
    try:
        dense_var, sensor_var = curvature.covariance()
    except np.linalg.LinAlgError:
        return labels + list(layout.sensor_fields)
    dense_var = np.diag(dense_var)
    wide = ~(dense_var > 0) | (np.sqrt(np.abs(dense_var)) > UNCONSTRAINED_SIGMA)
    flat = [labels[i] for i in np.flatnonzero(wide)]
    for column, name in enumerate(layout.sensor_fields):
        var = sensor_var[:, column]
        bad = np.flatnonzero(~(var > 0) | (np.sqrt(np.abs(var)) > UNCONSTRAINED_SIGMA))
        if bad.size:
            flat.append(f"{name} of {bad.size} sensors (first: {int(bad[0])})")
    return flat


class Stage:
    """What a fit is doing (``name``), and, as a context manager, the boundary that turns
    a numerical failure inside it (a linear-algebra error, a floating-point or XLA
    runtime error, memory exhausted) into a one-line ``CalibrationError`` naming the
    stage. ``PhotonflowError`` passes unchanged."""

    def __init__(self, name: str):
        self.name = name

    def __enter__(self):
        return self

    def __exit__(self, kind, error, traceback):
        if error is None or isinstance(error, PhotonflowError):
            return False
        if isinstance(error, (np.linalg.LinAlgError, ArithmeticError, RuntimeError,
                              MemoryError)):
            text = str(error).strip().splitlines()
            detail = f"{type(error).__name__}: {text[0][:160]}" if text else type(error).__name__
            raise CalibrationError(
                f"calibrate: {self.name} failed ({detail}); check the runs and the starting"
                " parameters, or fewer free fields / more rays (--rays)"
            ) from error
        return False


def refuse_runaway(theta: dict, iteration: int) -> None:
    """Raise a one-line ``ConfigError`` naming the free fields whose unconstrained value
    left the finite range during the fit (a length run off to infinity, a probability
    saturated past float precision): the runs do not constrain them."""
    runaway = [name for name, value in theta.items() if not np.all(np.isfinite(np.asarray(value)))]
    if runaway:
        raise ConfigError(
            f"free: {', '.join(runaway)}: ran off to the edge of the parameter range at"
            f" iteration {iteration} (not constrained by these runs); fix them or add runs"
            " sensitive to them"
        )


def refuse_non_finite(problem, theta: dict, stage: str, iteration: int, loss: float,
                      grad_dense: np.ndarray, grad_sensor: np.ndarray,
                      newton: StructuredMatrix) -> None:
    """Raise a one-line ``ConfigError`` when -log L, the score or the Newton matrix at
    ``theta`` is not finite: a step took the free values where the expected charges
    vanish or overflow (e.g. an absorption length of 1e-36 m after a Newton step from a
    minimum that the expected mode's ray noise had run off), and solving on would fail
    inside the linear algebra. Names the dense free values there."""
    if (np.isfinite(loss) and np.all(np.isfinite(grad_dense))
            and np.all(np.isfinite(grad_sensor)) and newton.finite):
        return
    values = ", ".join(f"{name} {value:.3g}" for name, value in
                       dense_values(problem, problem.params_of(theta)).items())
    raise ConfigError(
        f"{stage}, iteration {iteration}: -log L or its derivatives are not finite at"
        f" {values} (the fit ran off); use more rays (TransportConfig.n_rays, --rays) or runs"
        " that constrain the free values better"
    )
