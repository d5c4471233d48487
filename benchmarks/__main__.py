"""``python -m benchmarks`` (from the repository root): run every benchmark and rewrite
its table in BENCHMARKS.md (``benchmarks/run_all.py``)."""

import runpy
from pathlib import Path

runpy.run_path(str(Path(__file__).with_name("run_all.py")), run_name="__main__")
