"""Python's garbage collector in the photonflow command (photonflow.garbage_collection):
the command runs with the relaxed thresholds, a library import keeps the interpreter's."""

import gc
import subprocess
import sys

import pytest

from photonflow import cli_errors, garbage_collection
from photonflow.cli import root

#: Python's own default thresholds.
DEFAULTS = (700, 10, 10)


@pytest.fixture
def default_thresholds():
    """Python's default thresholds for the test; this process's own afterwards."""
    before = gc.get_threshold()
    gc.set_threshold(*DEFAULTS)
    yield
    gc.set_threshold(*before)


def test_the_thresholds_are_set_and_the_previous_ones_returned(default_thresholds):
    assert garbage_collection.collect_less_often() == DEFAULTS
    assert gc.get_threshold() == garbage_collection.THRESHOLDS


def test_the_command_runs_with_the_relaxed_thresholds(default_thresholds, monkeypatch):
    seen = []
    monkeypatch.setattr(cli_errors, "run_console", lambda app, prog_name: seen.append(
        gc.get_threshold()))
    root.main()
    assert seen == [garbage_collection.THRESHOLDS]


def test_importing_photonflow_keeps_the_interpreters_thresholds():
    code = "import gc; t = gc.get_threshold(); import photonflow; print(t == gc.get_threshold())"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True)
    assert done.stdout.strip() == "True"
