"""Gradient-based calibration of detector parameters on calibration-source runs.

``calibrate(detector, runs, init_params, free=[...])`` fits any subset of ``Params``
(optical scalars and per-sensor arrays) jointly by Fisher scoring on the expected
mode's exact likelihood; ``CalibrationResult`` holds the fit with Cramer-Rao errors and
saves to JSON; ``load_params`` reads the fitted parameters back;
``sequential_calibration`` is the conventional one-block-at-a-time baseline. See
``docs/calibration.md``.
"""

from .conventional import SEQUENTIAL_FIELDS, sequential_calibration
from .fit import UNCONSTRAINED_SIGMA, calibrate, unconstrained_labels
from .information import charge_information
from .layout import RESPONSE_FIELDS, FreeLayout, free_layout
from .methods import LBFGS, METHODS, Adam, GaussNewton
from .result import CalibrationResult, load_params
from .runs import LIKELIHOODS, CalibrationRun, prepare_runs

__all__ = [
    "LBFGS",
    "LIKELIHOODS",
    "METHODS",
    "RESPONSE_FIELDS",
    "SEQUENTIAL_FIELDS",
    "UNCONSTRAINED_SIGMA",
    "Adam",
    "CalibrationResult",
    "CalibrationRun",
    "FreeLayout",
    "GaussNewton",
    "calibrate",
    "charge_information",
    "free_layout",
    "load_params",
    "prepare_runs",
    "sequential_calibration",
    "unconstrained_labels",
]
