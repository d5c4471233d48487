"""Summaries of event files (for ``photonflow info FILE``), computed in bounded memory."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from ..errors import EventFileError
from ..geometry.shapes import shape_to_dict
from .hdf5 import READ_ERRORS, damaged
from .reader import EventFile

#: Elements read per block while scanning a file.
SCAN_BLOCK = 1 << 20


def summarize_events(path: str | os.PathLike) -> dict:
    """Statistics of an event file, reading it block by block.

    Args:
        path: an event file.

    Returns:
        A dict with keys ``path``, ``file_size`` (bytes), ``format_version``,
        ``photonflow_version``, ``created``, ``detector`` (name), ``detector_shape``
        (``shape_to_dict``), ``detector_description``, ``n_sensors``, ``n_events``,
        ``total_hits``, ``hits_per_event`` (dict mean/min/max; None values when there are
        no events), ``charge_per_event_mean`` (p.e., None without events),
        ``time_range`` ((min, max) ns of all hits, None without hits),
        ``source_kinds`` and ``particles`` (sorted non-empty truth labels present).

    Raises:
        EventFileError: the file cannot be read (see ``read_events``).
    """
    with EventFile(path) as events:
        detector = events.detector
        n_events = len(events)
        try:
            n_hits, attrs = events.n_hits, events.attrs
            hit_min, hit_max, charge_sum, (t_min, t_max), labels = _scan(
                events.h5, n_events, n_hits)
        except EventFileError:
            raise
        except READ_ERRORS as error:
            raise damaged(events.path, "its events", error) from None

    has_events = n_events > 0
    return {
        "path": str(Path(path)),
        "file_size": Path(path).expanduser().stat().st_size,
        "format_version": int(attrs.get("format_version", "0")),
        "photonflow_version": attrs.get("photonflow_version", ""),
        "created": attrs.get("created", ""),
        "detector": detector.name,
        "detector_shape": shape_to_dict(detector.shape),
        "detector_description": detector.describe(),
        "n_sensors": detector.n_sensors,
        "n_events": n_events,
        "total_hits": n_hits,
        "hits_per_event": {
            "mean": n_hits / n_events if has_events else None,
            "min": hit_min if has_events else None,
            "max": hit_max if has_events else None,
        },
        "charge_per_event_mean": charge_sum / n_events if has_events else None,
        "time_range": (t_min, t_max) if t_min <= t_max else None,
        "source_kinds": labels["source_kind"],
        "particles": labels["particle"],
    }


def _scan(h5, n_events: int, n_hits: int):
    """Read the whole file block by block: (fewest, most hits per event, total charge
    p.e., (earliest, latest) hit time ns, truth labels by field)."""
    hit_min, hit_max = math.inf, -math.inf
    offsets = h5["events/offsets"]
    for start in range(0, n_events, SCAN_BLOCK):
        counts = np.diff(offsets[start : min(start + SCAN_BLOCK, n_events) + 1])
        hit_min, hit_max = min(hit_min, int(counts.min())), max(hit_max, int(counts.max()))

    charge_sum = 0.0
    t_min, t_max = math.inf, -math.inf
    charge, time = h5["events/hits/charge"], h5["events/hits/time"]
    for start in range(0, n_hits, SCAN_BLOCK):
        block = slice(start, min(start + SCAN_BLOCK, n_hits))
        charge_sum += float(np.sum(charge[block], dtype=np.float64))
        times = time[block]
        times = times[np.isfinite(times)]
        if times.size:
            t_min, t_max = min(t_min, float(times.min())), max(t_max, float(times.max()))

    labels = {}
    for name in ("source_kind", "particle"):
        dataset = h5["events/truth"][name].asstr()
        found: set[str] = set()
        for start in range(0, n_events, SCAN_BLOCK):
            found.update(dataset[start : min(start + SCAN_BLOCK, n_events)])
        labels[name] = sorted(found - {""})
    return hit_min, hit_max, charge_sum, (t_min, t_max), labels


def _size(n_bytes: int) -> str:
    value = float(n_bytes)
    for unit in ("B", "KiB", "MiB", "GiB"):
        if value < 1024 or unit == "GiB":
            return f"{value:.0f} {unit}" if unit == "B" else f"{value:.1f} {unit}"
        value /= 1024
    return f"{value:.1f} TiB"


def format_summary(summary: dict) -> str:
    """Render a ``summarize_events`` dict as aligned, human-readable lines."""
    per_event = summary["hits_per_event"]
    if summary["n_events"]:
        hits = (
            f"{summary['total_hits']} total; per event mean {per_event['mean']:.2f},"
            f" min {per_event['min']}, max {per_event['max']}"
        )
        charge = f"{summary['charge_per_event_mean']:.4g} p.e. per event (mean)"
    else:
        hits, charge = f"{summary['total_hits']} total", "-"
    time_range = summary["time_range"]
    times = "-" if time_range is None else f"{time_range[0]:.4g} .. {time_range[1]:.4g} ns"
    version = f"photonflow-events v{summary['format_version']}"
    if summary["photonflow_version"]:
        version += f" (photonflow {summary['photonflow_version']}"
        version += f", {summary['created']})" if summary["created"] else ")"
    rows = [
        ("file", f"{summary['path']} ({_size(summary['file_size'])})"),
        ("format", version),
        ("detector", summary["detector_description"]),
        ("events", str(summary["n_events"])),
        ("hits", hits),
        ("charge", charge),
        ("time range", times),
        ("truth kinds", ", ".join(summary["source_kinds"]) or "-"),
        ("particles", ", ".join(summary["particles"]) or "-"),
    ]
    width = max(len(label) for label, _ in rows)
    return "\n".join(f"{label:<{width}}  {value}" for label, value in rows)
