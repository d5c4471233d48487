"""How well a reconstruction did, from a reconstruction file (``io.reco_file``) whose
events carry their truth: resolutions (68 % quantiles), the energy bias, the e/mu
misidentification rate, failures, time per event, and the pulls of the reported
uncertainties; per true particle type, and per energy bin where the sample has several
energies (``photonflow evaluate``).

Resolutions are the 68 % quantiles of the absolute errors of the events whose fit did
not fail: ``vertex_68_cm`` of the distance between the fitted and true vertex,
``longitudinal_68_cm`` / ``transverse_68_cm`` of its parts along and across the true
direction, ``direction_68_deg`` of the angle between the directions, ``energy_68_frac``
of (E_fit - E_true) / E_true, ``time_68_ns`` of t_fit - t_true. ``energy_bias_frac`` is
the median of (E_fit - E_true) / E_true, and ``energy_resolution_68_frac`` the 68 %
quantile of its distance from that median (the spread without the scale's bias).
``misid_rate`` (only for a ``--particle auto`` job) is the share of fitted events whose
particle family (mu or e) is not the true one.
A pull is an error divided by its reported 1-sigma uncertainty, in the coordinates of
the covariance (``coordinates.LOCAL``); its width is half the 16-84 % interval (1 for a
correct uncertainty, insensitive to a few outliers).

Where the file holds its detector, each particle's summary also has ``contained``: the
same numbers for the events whose true track's light ends inside the detector
(``contained_events``). A muon that leaves the detector shows only the part of its track
inside, and its light then bounds its energy from below only: the energy resolution of
a mixed sample measures how many muons leave.
"""

from __future__ import annotations

import math

import numpy as np

from .coordinates import LOCAL

#: Most distinct true energies that get one bin each; more are cut into ``ENERGY_BINS``
#: bins of equal counts.
DISTINCT_ENERGIES = 12
ENERGY_BINS = 5
#: Fewest events of a bin with a summary.
MIN_BIN_EVENTS = 5


def _family(particle: str) -> str:
    return particle.rstrip("+-")


def event_errors(table) -> dict[str, np.ndarray]:
    """Per-event errors (fit - truth) of a ``RecoTable``: ``vertex_cm``,
    ``longitudinal_cm``, ``transverse_cm``, ``direction_deg``, ``energy_frac``,
    ``time_ns``, the pulls ``pull_<name>`` for each of ``LOCAL`` and ``misidentified``
    (1 or 0; NaN unless the true particle is a muon or an electron); NaN for failed
    fits and events without truth."""
    reco, truth = table.reco, table.truth
    delta = reco["position"] - truth["position"]
    axis = truth["direction"]
    along = np.sum(delta * axis, axis=1)
    across = np.linalg.norm(delta - along[:, None] * axis, axis=1)
    cosine = np.clip(np.sum(reco["direction"] * axis, axis=1), -1.0, 1.0)
    errors = {
        "vertex_cm": 100.0 * np.linalg.norm(delta, axis=1),
        "longitudinal_cm": 100.0 * along, "transverse_cm": 100.0 * across,
        "direction_deg": np.degrees(np.arccos(cosine)),
        "energy_frac": reco["energy"] / truth["energy"] - 1.0,
        "time_ns": reco["time"] - truth["time"],
    }
    local = np.concatenate([delta, (reco["time"] - truth["time"])[:, None],
                            _angle_errors(reco["direction"], axis),
                            np.log(reco["energy"] / truth["energy"])[:, None]], axis=1)
    sigma = np.sqrt(np.clip(np.diagonal(reco["covariance"], axis1=1, axis2=2), 0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        pulls = local / sigma
    for k, name in enumerate(LOCAL):
        errors[f"pull_{name}"] = pulls[:, k]
    true_family = [_family(p) for p in truth["particle"]]
    errors["misidentified"] = np.array(
        [float(t != _family(f)) if t in ("mu", "e") else math.nan
         for t, f in zip(true_family, reco["particle"], strict=True)])
    bad = failures(table)
    return {name: np.where(bad, np.nan, value) for name, value in errors.items()}


def contained_events(table) -> np.ndarray:
    """(n,) 1.0 where the true track's light ends inside the detector (the distance from
    the true vertex along the true direction to the wall, m, exceeds the light's extent
    in the shipped spline emission model at the true energy), 0.0 where it leaves, NaN
    where that is unknown: no detector in the table, a particle without an emission
    model, a true energy outside the model's range (MeV), a true vertex outside the
    detector. In an open medium, 1.0 wherever it is known."""
    from ..emission import emission_model
    from ..errors import ConfigError
    from ..transport.tracks import detector_medium

    truth, detector = table.truth, table.detector
    n = len(table)
    contained = np.full(n, math.nan)
    if detector is None or "position" not in truth:
        return contained
    shape = detector.shape
    position = np.asarray(truth["position"], np.float64)
    direction = np.asarray(truth["direction"], np.float64)
    if shape.has_walls:
        inside = np.asarray(shape.distance_to_wall(position), np.float64) > 0.0
        exits = np.where(inside, np.asarray(shape.ray_exit(position, direction),
                                            np.float64), math.nan)
    else:
        exits = np.full(n, math.inf)
    energies = np.asarray(truth["energy"], np.float64)
    medium = detector_medium(detector)
    for particle in set(truth["particle"]):
        try:
            model = emission_model(str(particle), medium)
        except ConfigError:
            continue
        low, high = model.energy_range
        rows = np.flatnonzero((truth["particle"] == particle) & (energies >= low)
                              & (energies <= high) & ~np.isnan(exits))
        for energy in np.unique(energies[rows]):
            extent = float(model.at(float(energy)).extent)
            same = rows[energies[rows] == energy]
            contained[same] = (exits[same] > extent).astype(np.float64)
    return contained


def _angle_errors(fitted, true) -> np.ndarray:
    """(n, 2) the fitted direction's angles about itself (0) less the true direction's,
    as tangents towards the basis ``orthonormal_basis`` of the fitted direction (the
    covariance's angle coordinates)."""
    from ..transport.optics import orthonormal_basis

    first, second = (np.asarray(v, np.float64) for v in orthonormal_basis(
        np.asarray(fitted, np.float32)))
    along = np.sum(true * fitted, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return -np.stack([np.sum(true * first, axis=1) / along,
                          np.sum(true * second, axis=1) / along], axis=1)


def _quantile(values, q: float = 0.68) -> float | None:
    values = values[np.isfinite(values)]
    return float(np.quantile(values, q)) if values.size else None


def _pull_width(values) -> float | None:
    values = values[np.isfinite(values)]
    if values.size < 2:
        return None
    low, high = np.quantile(values, [0.16, 0.84])
    return float(0.5 * (high - low))


def failures(table) -> np.ndarray:
    """(n,) bool: the events whose fit failed."""
    return np.array([bool(f) for f in table.reco["failure"]], bool)


def _metrics(table, errors, failed, rows, auto: bool) -> dict:
    """The summary of the events ``rows`` (boolean mask); ``failed``: ``failures``."""
    fitted = rows & ~failed
    pick = {name: value[fitted] for name, value in errors.items()}
    median = np.median(pick["energy_frac"][np.isfinite(pick["energy_frac"])]) \
        if np.any(np.isfinite(pick["energy_frac"])) else math.nan
    identified = pick["misidentified"][np.isfinite(pick["misidentified"])]
    misid = float(np.mean(identified)) if auto and identified.size else None
    seconds = table.reco["seconds"][rows]
    return {
        "n_events": int(rows.sum()), "n_failed": int((rows & failed).sum()),
        "vertex_68_cm": _quantile(pick["vertex_cm"]),
        "longitudinal_68_cm": _quantile(np.abs(pick["longitudinal_cm"])),
        "transverse_68_cm": _quantile(pick["transverse_cm"]),
        "direction_68_deg": _quantile(pick["direction_deg"]),
        "energy_68_frac": _quantile(np.abs(pick["energy_frac"])),
        "energy_bias_frac": float(median) if math.isfinite(median) else None,
        "energy_resolution_68_frac": _quantile(np.abs(pick["energy_frac"] - median)),
        "time_68_ns": _quantile(np.abs(pick["time_ns"])),
        "misid_rate": misid,
        "seconds_per_event": float(np.median(seconds)) if seconds.size else None,
        "pull_width": {name: _pull_width(pick[f"pull_{name}"]) for name in LOCAL},
    }


def energy_bins(energies) -> list[tuple[float, float]]:
    """Bins (low, high) MeV of the true ``energies`` (one per distinct energy when there
    are at most ``DISTINCT_ENERGIES``, else ``ENERGY_BINS`` of equal counts); [] for
    one energy."""
    values = np.unique(energies[np.isfinite(energies)])
    if values.size < 2:
        return []
    if values.size <= DISTINCT_ENERGIES:
        return [(float(v), float(v)) for v in values]
    edges = np.unique(np.quantile(energies[np.isfinite(energies)],
                                  np.linspace(0, 1, ENERGY_BINS + 1)))
    return [(float(a), float(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def summarize(table) -> dict:
    """The summary of ``photonflow evaluate`` (module docstring) of a ``RecoTable``:
    ``{"events", "settings", "particles": {particle: {metrics..., "contained":
    {metrics...} or None, "energy_bins": [{"energy_low_mev", "energy_high_mev",
    metrics...}]}}}``; undefined numbers are None."""
    errors = event_errors(table)
    failed = failures(table)
    auto = table.run.get("particle") == "auto"
    true_particles = table.truth["particle"]
    contained = contained_events(table)
    summary = {"events": len(table), "settings": table.run, "particles": {}}
    for particle in sorted(set(true_particles)):
        rows = true_particles == particle
        entry = _metrics(table, errors, failed, rows, auto)
        inside = rows & (contained == 1.0)
        entry["contained"] = _metrics(table, errors, failed, inside, auto) \
            if inside.any() else None
        energies = table.truth["energy"]
        entry["energy_bins"] = []
        bins = energy_bins(energies[rows])
        for k, (low, high) in enumerate(bins):
            last = k == len(bins) - 1
            inside = rows & (energies >= low) & ((energies <= high) if last or low == high
                                                 else (energies < high))
            if inside.sum() >= MIN_BIN_EVENTS:
                entry["energy_bins"].append({"energy_low_mev": low, "energy_high_mev": high,
                                             **_metrics(table, errors, failed, inside,
                                                         auto)})
        summary["particles"][particle or "unknown"] = entry
    return summary


#: Columns of ``format_summary``: (key, heading, scale, format).
_COLUMNS = (("n_events", "events", 1, "{:.0f}"), ("n_failed", "failed", 1, "{:.0f}"),
            ("vertex_68_cm", "vertex cm", 1, "{:.1f}"),
            ("longitudinal_68_cm", "long. cm", 1, "{:.1f}"),
            ("transverse_68_cm", "trans. cm", 1, "{:.1f}"),
            ("direction_68_deg", "dir. deg", 1, "{:.2f}"),
            ("energy_68_frac", "energy %", 100, "{:.2f}"),
            ("energy_bias_frac", "bias %", 100, "{:+.2f}"),
            ("energy_resolution_68_frac", "E spread %", 100, "{:.2f}"),
            ("time_68_ns", "time ns", 1, "{:.2f}"), ("misid_rate", "misid %", 100, "{:.1f}"),
            ("seconds_per_event", "s/event", 1, "{:.2f}"))


def format_summary(summary: dict) -> str:
    """The summary as a plain-text table (68 % quantiles), one row per particle, its
    contained events and its energy bins."""
    headings = ["particle", "energy MeV", *(c[1] for c in _COLUMNS)]
    rows = []
    for particle, entry in summary["particles"].items():
        contained = [("contained", entry["contained"])] if entry.get("contained") else []
        for label, metrics in [("all", entry), *contained] + [
                (f"{b['energy_low_mev']:.0f}" if b["energy_low_mev"] == b["energy_high_mev"]
                 else f"{b['energy_low_mev']:.0f}-{b['energy_high_mev']:.0f}", b)
                for b in entry["energy_bins"]]:
            cells = [particle, label]
            for key, _, scale, pattern in _COLUMNS:
                value = metrics.get(key)
                cells.append("-" if value is None else pattern.format(scale * value))
            rows.append(cells)
    widths = [max(len(r[k]) for r in [headings, *rows]) for k in range(len(headings))]
    lines = [" ".join(c.rjust(w) for c, w in zip(r, widths, strict=True))
             for r in [headings, *rows]]
    return "\n".join(lines)
