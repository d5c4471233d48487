"""``benchmarks/run_all.py`` rewrites exactly the blocks of BENCHMARKS.md it owns (checked
with a stand-in script; the real benchmarks take minutes and never run in the tests)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture()
def run_all():
    spec = importlib.util.spec_from_file_location("_run_all", ROOT / "benchmarks" / "run_all.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_benchmark_has_its_block(run_all):
    text = (ROOT / "BENCHMARKS.md").read_text()
    for name, (script, *_) in run_all.BENCHMARKS.items():
        assert (ROOT / "benchmarks" / script).is_file(), script
        start, end = run_all.markers(name)
        assert text.count(start) == 1 and text.count(end) == 1, name
        assert text.index(start) < text.index(end)


def test_rewrites_only_its_block(run_all, tmp_path, monkeypatch):
    (tmp_path / "fake.py").write_text(
        'print("Machine: test CPU, 2 cores")\nprint()\n'
        'print("| case | s |")\nprint("|---|---:|")\nprint("| one | 0.5 |")\n')
    (tmp_path / "broken.py").write_text("raise SystemExit(3)\n")
    page = tmp_path / "BENCHMARKS.md"
    page.write_text("# B\n\nkeep this\n\n<!-- benchmark:fake -->\nold\n<!-- /benchmark:fake -->\n"
                    "\nand this\n<!-- benchmark:broken -->\nold too\n"
                    "<!-- /benchmark:broken -->\n")
    monkeypatch.setattr(run_all, "HERE", tmp_path)
    monkeypatch.setattr(run_all, "BENCHMARKS", {"fake": ["fake.py"], "broken": ["broken.py"]})
    monkeypatch.setattr(sys, "argv", ["run_all.py", "--file", str(page)])
    assert run_all.main() == 1  # the broken one fails, the other is written
    text = page.read_text()
    assert "keep this" in text and "and this" in text and "old\n" not in text
    assert "| one | 0.5 |" in text and "Machine: test CPU" in text and "Measured " in text
    assert "<!-- benchmark:broken -->\nold too\n<!-- /benchmark:broken -->" in text
    monkeypatch.setattr(sys, "argv", ["run_all.py", "--file", str(page), "--only", "missing"])
    with pytest.raises(SystemExit):
        run_all.main()
