"""``CalibrationResult``: fitted parameters, 1-sigma errors, correlations and history,
saved to and loaded from JSON (``docs/calibration.md``, "Result file")."""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from .._version import __version__
from ..errors import ConfigError
from ..params import Params

#: Value of the ``format`` key of a calibration result file, and its layout version.
FORMAT = "photonflow-calibration"
FORMAT_VERSION = 1


@dataclasses.dataclass(frozen=True)
class CalibrationResult:
    """The outcome of ``calibrate``.

    Attributes:
        params: fitted ``Params`` (fixed fields at their starting values).
        errors: ``Params``-shaped 1-sigma uncertainties in the fields' units (from the
            inverse curvature, the Cramer-Rao bound for the charge likelihood); zero for
            fixed fields.
        correlation: (P, P) correlation matrix of the dense (scalar) free entries.
        correlation_names: the P labels of its rows (e.g. "absorption_length").
        history: one dict per iteration: ``iteration``, ``loss`` (-log L), ``time_s``
            (since the start) and ``values`` (label -> physical value of every dense
            free entry). Steps of the independent-ray stage (charge likelihood with
            free optics, ``fit.calibrate``) carry ``"stage": "independent rays"`` (or
            ``"independent rays, K sets"`` for the root with K ray sets) and the -log L
            of the point the step started from; its last entry, ``"stage":
            "extrapolated"``, is the result, with the diagnostics
            ``"ray_noise_share"``, ``"ray_noise_bias"`` and
            ``"ray_count_extrapolation"`` (``independent_ray_stage.independent_ray_steps``).
        free: the free fields.
        method: step rule used ("gauss-newton", "lbfgs", "adam").
        likelihood: "charge" or "charge+time".
        converged: whether the convergence criteria were met and every dense free
            value has a finite error (one at the edge of its range or unconstrained,
            error inf, makes the fit not converged).
        message: why the fit stopped.
        loss: final -log L.
        settings: transport and fit settings (rays, bounces, window ns, tolerances).
        runs: provenance of each run: label, source kind, position m, photons, events.
        detector: the detector's name and sensor count.
        truth: the true ``Params`` when known (pseudo-data), else None.
        wall_time_s: wall time of the fit, s.
    """

    params: Params
    errors: Params
    correlation: np.ndarray
    correlation_names: tuple[str, ...]
    history: tuple[dict, ...]
    free: tuple[str, ...]
    method: str
    likelihood: str
    converged: bool
    message: str
    loss: float
    settings: dict
    runs: tuple[dict, ...]
    detector: dict
    truth: Params | None = None
    wall_time_s: float = math.nan

    def pulls(self) -> dict[str, np.ndarray]:
        """(fitted - true) / error per free field (needs ``truth``)."""
        if self.truth is None:
            raise ConfigError("pulls: this result has no true parameters")
        return {
            name: (np.asarray(getattr(self.params, name), np.float64)
                   - np.asarray(getattr(self.truth, name), np.float64))
            / np.asarray(getattr(self.errors, name), np.float64)
            for name in self.free
        }

    def to_json(self) -> dict[str, Any]:
        """The result as a JSON-able dict (arrays as lists)."""
        return {
            "format": FORMAT,
            "version": FORMAT_VERSION,
            "photonflow_version": __version__,
            "detector": self.detector,
            "free": list(self.free),
            "method": self.method,
            "likelihood": self.likelihood,
            "converged": self.converged,
            "message": self.message,
            "loss": self.loss,
            "wall_time_s": self.wall_time_s,
            "settings": self.settings,
            "runs": list(self.runs),
            "params": _params_json(self.params),
            "errors": _params_json(self.errors),
            "truth": None if self.truth is None else _params_json(self.truth),
            "correlation": {
                "names": list(self.correlation_names),
                "matrix": np.asarray(self.correlation).tolist(),
            },
            "history": list(self.history),
        }

    def save(self, path: str | os.PathLike) -> Path:
        """Write the JSON file (under a temporary name, then renamed; missing parent
        folders are created; infinite and undefined numbers as the strings "inf",
        "-inf" and "nan", which ``load`` reads back); returns the path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        temporary = path.with_name(f".{path.name}.partial")
        text = json.dumps(_encode_numbers(self.to_json()), indent=1, allow_nan=False)
        temporary.write_text(text + "\n")
        os.replace(temporary, path)
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> CalibrationResult:
        """Read a file written by ``save`` (one-line ``ConfigError`` if it is not one, or
        lacks a key)."""
        data = _read(path)
        try:
            correlation = data.get("correlation") or {"names": [], "matrix": []}
            truth = data.get("truth")
            return cls(
                params=_params_from_json(data["params"], path, "params"),
                errors=_params_from_json(data["errors"], path, "errors"),
                correlation=np.asarray(correlation["matrix"], dtype=np.float64),
                correlation_names=tuple(correlation["names"]),
                history=tuple(data.get("history", ())),
                free=tuple(data["free"]),
                method=data["method"],
                likelihood=data["likelihood"],
                converged=bool(data["converged"]),
                message=data.get("message", ""),
                loss=float(data["loss"]),
                settings=data.get("settings", {}),
                runs=tuple(data.get("runs", ())),
                detector=data.get("detector", {}),
                truth=None if truth is None else _params_from_json(truth, path, "truth"),
                wall_time_s=float(data.get("wall_time_s", math.nan)),
            )
        except ConfigError:
            raise
        except (KeyError, TypeError, ValueError) as error:
            raise _incomplete(path, error) from None


#: How ``save`` writes the numbers JSON has no literal for (an infinite error, an
#: undefined correlation), and ``load`` reads them back.
NON_FINITE = {"inf": math.inf, "-inf": -math.inf, "nan": math.nan}


def _encode_numbers(value):
    """``value`` (nested dicts and lists) with every non-finite float written as the
    string "inf", "-inf" or "nan", so that the file is valid JSON."""
    if isinstance(value, dict):
        return {key: _encode_numbers(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_encode_numbers(item) for item in value]
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    return value


def _decode_numbers(value):
    """The inverse of ``_encode_numbers``: the strings "inf", "-inf" and "nan" as floats
    (``json.loads`` reads the bare ``Infinity`` and ``NaN`` of older files itself)."""
    if isinstance(value, dict):
        return {key: _decode_numbers(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_decode_numbers(item) for item in value]
    if isinstance(value, str) and value in NON_FINITE:
        return NON_FINITE[value]
    return value


def _incomplete(path, error: Exception) -> ConfigError:
    """The one-line error for a calibration result that lacks a key or holds a value of
    the wrong kind."""
    if isinstance(error, KeyError):
        problem = f"the key {error.args[0]!r} is missing"
    else:
        problem = " ".join(str(error).split())
    return ConfigError(f"{path}: not a complete calibration result ({problem}); use a file"
                       " written by photonflow calibrate")


def _params_json(params: Params) -> dict[str, Any]:
    out = {}
    for name, value in params.to_dict().items():
        value = np.asarray(value, dtype=np.float64)
        out[name] = value.tolist() if value.ndim else float(value)
    return out


def _params_from_json(values: dict, path, key: str) -> Params:
    if not isinstance(values, dict):
        raise ConfigError(f"{path}: {key}: expected an object of Params fields, not"
                          f" {type(values).__name__}")
    try:
        return Params.from_dict(values)
    except ConfigError as error:
        raise ConfigError(f"{path}: {key}: {error}") from None


def _read(path) -> dict:
    try:
        data = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ConfigError(f"{path}: not a calibration result ({error})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ConfigError(f"{path}: not a calibration result (format is not {FORMAT!r})")
    data = _decode_numbers(data)
    if not isinstance(data.get("version", 0), int):
        raise _incomplete(path, TypeError(f"version = {data['version']!r}, not an integer"))
    if int(data.get("version", 0)) > FORMAT_VERSION:
        raise ConfigError(
            f"{path}: calibration format version {data['version']} is newer than this"
            f" photonflow reads ({FORMAT_VERSION}); upgrade photonflow"
        )
    return data


def load_params(path: str | os.PathLike) -> Params:
    """The fitted ``Params`` of a calibration result file (``CalibrationResult.save``),
    ready for ``expected``, ``sample`` and reconstruction."""
    data = _read(path)
    if "params" not in data:
        raise _incomplete(path, KeyError("params"))
    return _params_from_json(data["params"], path, "params")



