"""The validation studies' scripts and the SK campaign example stay importable: they import
their shared code from ``photonflow.calibration.campaign`` (never by editing sys.path),
so a module moved inside photonflow shows here rather than the next time a study is
rerun. Imports only; nothing is simulated."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

import photonflow as pf
from photonflow.calibration import campaign

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted((ROOT / "studies").rglob("*.py")) + [
    ROOT / "examples" / "calibration" / "sk_joint.py"]


@pytest.mark.parametrize("path", SCRIPTS, ids=lambda p: str(p.relative_to(ROOT)))
def test_script_imports(path, monkeypatch):
    """Each script imports as it would when run (its folder first on sys.path)."""
    assert "sys.path.insert" not in path.read_text(), f"{path.name}: edits sys.path"
    monkeypatch.syspath_prepend(str(path.parent))
    for name in [n for n in sys.modules if n.startswith("sk_")]:
        monkeypatch.delitem(sys.modules, name)
    spec = importlib.util.spec_from_file_location(f"_study_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)
    spec.loader.exec_module(module)
    assert callable(module.main)


def test_benchmarks_hold_only_benchmarks():
    names = {p.name for p in (ROOT / "benchmarks").glob("*.py")}
    assert not {n for n in names if n.startswith("sk_")}, names


def test_campaign_setup():
    """The campaign's truth, sources and start as the studies used them."""
    detector = pf.load_detector("SK")
    truth = campaign.campaign_truth(detector, 1)
    again = campaign.campaign_truth(detector, 1)
    np.testing.assert_array_equal(np.asarray(truth.efficiency), np.asarray(again.efficiency))
    assert np.asarray(truth.efficiency).shape == (detector.n_sensors,)
    for name, value in campaign.TRUE_OPTICS.items():
        assert float(getattr(truth, name)) == pytest.approx(value)
    sources = campaign.campaign_sources()
    assert len(sources) == 16 and isinstance(sources[0], pf.LaserSource)
    assert all(float(s.n_photons) == campaign.PHOTONS_PER_FLASH for s in sources)
    radius, half_height = detector.shape.radius, detector.shape.height / 2  # m
    for point in campaign.grid_positions():
        assert np.hypot(point[0], point[1]) < radius and abs(point[2]) < half_height
    start = campaign.campaign_start(detector, truth)
    assert float(start.absorption_length) == pytest.approx(1.25 * 90.0)
    assert float(start.wall_reflectivity) == pytest.approx(0.75 * 0.15)
    np.testing.assert_array_equal(np.asarray(start.efficiency), 1.0)
