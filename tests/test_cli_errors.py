"""Bad command-line input, class by class, through the real console entry.

Every case runs ``python -m photonflow`` in a subprocess (the console script's
``main``, where usage errors, warnings and interrupts are handled) and checks the rule
of the command line: one line ``error: ...`` on stderr naming the option (or file) and
its value, exit code 2, no traceback, no usage box, no warning ahead of it, and nothing
written. The cases are those of the newcomer audit of issue 22 that gave tracebacks,
multi-line usage boxes, warnings before the error, runs that never end, or options
silently ignored.
"""

import json
import subprocess
import sys

import numpy as np
import pytest

import photonflow as pf
from photonflow.errors import ConfigError
from photonflow.io import make_event, write_events

pytestmark = pytest.mark.compile_bound

TOY = ["--detector", "TOY_CYLINDER"]


def run(*args, cwd):
    return subprocess.run([sys.executable, "-m", "photonflow", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def assert_one_line_error(result, *fragments):
    """Exit 2 and exactly one stderr line, ``error: ...``, holding every fragment."""
    assert result.returncode == 2, (result.returncode, result.stderr)
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: "), lines[0]
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])


def assert_nothing_written(folder, before=()):
    """Nothing in ``folder`` but the files in ``before`` (no output, no partial file)."""
    assert sorted(p.name for p in folder.iterdir()) == sorted(before)


@pytest.fixture(scope="module")
def event_file(tmp_path_factory):
    """A small valid event file (no transport: three hand-made events), 1 MB of hits so
    that its data blocks lie well inside the file."""
    detector = pf.load_detector("TOY_CYLINDER")
    rng = np.random.default_rng(0)
    events = [make_event(rng.integers(0, 200, 40000), rng.random(40000) + 0.5,
                         rng.random(40000) * 100) for _ in range(3)]
    path = tmp_path_factory.mktemp("events") / "run.h5"
    write_events(path, events, detector, pf.default_params(detector))
    return path


# ---- values that are not numbers, unknown and missing options: one line, not a box ------
@pytest.mark.parametrize(("args", "named"), [
    (["simulate", *TOY, "--photons", "abc", "--out", "x.h5"], "'--photons'"),
    (["simulate", *TOY, "--events", "1.5", "--out", "x.h5"], "'--events'"),
    (["simulate", *TOY, "--out", "x.h5", "--colour", "red"], "--colour"),
    (["simulate", *TOY], "'--out'"),
    (["benchmark", "transport", "--repeats", "two"], "'--repeats'"),
    (["display", "run.h5", "--event", "first"], "'--event'"),
])
def test_usage_errors_are_one_line(tmp_path, args, named):
    result = run(*args, cwd=tmp_path)
    assert_one_line_error(result, named, "--help")
    assert "Usage" not in result.stderr and "╭" not in result.stderr
    assert_nothing_written(tmp_path)


def test_help_is_still_shown(tmp_path):
    result = run("simulate", "--help", cwd=tmp_path)
    assert result.returncode == 0 and "--fiducial-margin" in result.stdout


# ---- runs that could never end or never fit in memory: refused, naming the limit --------
@pytest.mark.parametrize(("args", "named"), [
    (["simulate", *TOY, "--events", "1000000000000", "--out", "x.h5"],
     "--events = 1000000000000: must be <= 1,000,000"),
    (["simulate", *TOY, "--events", "99999999999999999999999", "--out", "x.h5"],
     "--events = 99999999999999999999999"),
    (["simulate", *TOY, "--photons", "1e12", "--out", "x.h5"], "--photons = 1e+12"),
    (["simulate", *TOY, "--workers", "100000", "--out", "x.h5"], "--workers = 100000"),
    (["simulate", *TOY, "--bounces", "1000", "--out", "x.h5"], "--bounces = 1000"),
    (["calibrate", "run.h5", "--free", "absorption_length", "--rays", "100000000000",
      "--out", "x.json"], "--rays = 100000000000"),
    (["calibrate", "run.h5", "--free", "absorption_length", "--rays", "1", "--out",
      "x.json"], "--rays = 1: must be >= 32"),
    (["benchmark", "transport", "--repeats", "0"], "--repeats = 0"),
    (["benchmark", "transport", "--photons", "-1"], "--photons = -1"),
    (["benchmark", "transport", "--rays", "-1"], "--rays = -1"),
    (["benchmark", "transport", "--detector", "SKK"], "SKK"),
])
def test_counts_beyond_their_limits_are_refused(tmp_path, args, named):
    assert_one_line_error(run(*args, cwd=tmp_path), named)
    assert_nothing_written(tmp_path)


# ---- options the chosen mode does not use: refused, not silently ignored ----------------
@pytest.mark.parametrize(("args", "named"), [
    (["--opening-angle", "0.3"], "--opening-angle = 0.3: only for a laser source"),
    (["--anisotropy", "0.5"], "--anisotropy = 0.5: only for a diffuser source"),
    (["--direction", "0,0,1"], "--direction = '0,0,1'"),
    (["--source", "diffuser", "--direction", "0,0,1", "--opening-angle", "0.2"],
     "--opening-angle"),
    (["--energy", "100"], "--energy = 100: only with --particle"),
    (["--fiducial-margin", "0.5"], "--fiducial-margin = 0.5: only with --particle"),
    (["--particle", "mu-", "--energy", "100", "--photons", "10"],
     "--photons = 10: only for a calibration source"),
    (["--particle", "mu-", "--energy", "100", "--vertex", "0,0,0", "--fiducial-margin",
      "0.5"], "--fiducial-margin = 0.5: only with --vertex uniform-fiducial"),
])
def test_options_that_do_not_apply_are_refused(tmp_path, args, named):
    result = run("simulate", *TOY, "--out", "x.h5", *args, cwd=tmp_path)
    assert_one_line_error(result, named, "leave it out")
    assert_nothing_written(tmp_path)


def test_report_refuses_the_options_of_a_fit(tmp_path):
    result = run("calibrate", "--report", "calib.json", "--free", "absorption_length",
                 "--out", "r.png", cwd=tmp_path)
    assert_one_line_error(result, "--free = 'absorption_length'", "not with --report")


# ---- outputs that cannot be written: refused before any work ----------------------------
@pytest.mark.parametrize(("args", "named"), [
    (["tables", "build", "--particle", "mu-", "--energies", "100", "--per-energy", "1",
      "--out", "blocker/table.h5"], "--out = 'blocker/table.h5'"),
    (["tables", "build", "--particle", "mu-", "--energies", "100", "--per-energy", "1",
      "--out", "/proc/table.h5"], "--out = '/proc/table.h5'"),
    (["demo", "--out-dir", "blocker"], "--out-dir = 'blocker'"),
    (["geometry", "TOY_CYLINDER", "--out", "blocker/x.png"], "--out = 'blocker/x.png'"),
    (["calibrate", "missing.h5", "--free", "absorption_length", "--out", "blocker/c.json"],
     "--out = 'blocker/c.json'"),
    (["simulate", *TOY, "--out", "blocker/x.h5"], "blocker"),
])
def test_unwritable_outputs_are_refused_before_any_work(tmp_path, args, named):
    (tmp_path / "blocker").write_text("a file where a folder is expected")
    assert_one_line_error(run(*args, cwd=tmp_path), named)
    assert_nothing_written(tmp_path, ["blocker"])


def test_calibrate_refuses_to_overwrite_a_result_before_reading_the_runs(tmp_path):
    (tmp_path / "calib.json").write_text("{}")
    result = run("calibrate", "missing.h5", "--free", "absorption_length", "--out",
                 "calib.json", cwd=tmp_path)
    assert_one_line_error(result, "--out = 'calib.json'", "--mode recreate")
    assert (tmp_path / "calib.json").read_text() == "{}"


# ---- files that are damaged or incomplete: one line, never a traceback ------------------
def test_damaged_event_files_are_one_line(event_file, tmp_path):
    """Bytes overwritten at points through the file: ``info`` and ``display`` either
    still work or give one line naming the file; most of the points break it."""
    data = event_file.read_bytes()
    errors = 0
    for fraction in (0.02, 0.04, 0.3, 0.6):
        start = int(fraction * len(data))
        damaged = tmp_path / f"damaged_{fraction}.h5"
        damaged.write_bytes(data[:start] + b"\xff" * 1500 + data[start + 1500:])
        for args in (["info", damaged.name], ["display", damaged.name, "--out", "d.png"]):
            result = run(*args, cwd=tmp_path)
            assert "Traceback" not in result.stderr, (fraction, args, result.stderr)
            if result.returncode:
                assert_one_line_error(result, damaged.name)
                errors += 1
            (tmp_path / "d.png").unlink(missing_ok=True)
    assert errors >= 6


@pytest.mark.parametrize("option", ["--report", "--init"])
def test_a_calibration_result_without_params_is_one_line(event_file, tmp_path, option):
    (tmp_path / "bare.json").write_text(json.dumps({"format": "photonflow-calibration"}))
    fit = [event_file, "--free", "absorption_length"] if option == "--init" else []
    out = "r.png" if option == "--report" else "calib.json"
    result = run("calibrate", *fit, option, "bare.json", "--out", out, cwd=tmp_path)
    assert_one_line_error(result, "bare.json", "'params' is missing")
    assert_nothing_written(tmp_path, ["bare.json"])


# ---- warnings never come ahead of the error ---------------------------------------------
@pytest.mark.parametrize("args", [
    ["--position", "1e200,0,0"],
    ["--source", "laser", "--direction", "0,0,1", "--opening-angle", "1e308"],
    ["--source", "laser", "--direction", "1e308,1e308,0", "--opening-angle", "0.1"],
])
def test_no_warning_before_an_error(tmp_path, args):
    result = run("simulate", *TOY, "--out", "x.h5", *args, cwd=tmp_path)
    assert_one_line_error(result)
    assert "Warning" not in result.stderr
    assert_nothing_written(tmp_path)


# ---- values that were tracebacks and are valid: they run ------------------------------
@pytest.mark.parametrize(("spectrum", "end"), [("power:1e6", 50.0), ("power:-1e6", 60.0)])
def test_extreme_spectra_run(tmp_path, spectrum, end):
    """power:1e6 was a ZeroDivisionError and power:-1e6 an OverflowError; the energies
    now pile up at the low or high end of the range (and the default fiducial margin
    fits the 4 m toy)."""
    result = run("simulate", *TOY, "--particle", "e-", "--energy-range", "50,60",
                 "--spectrum", spectrum, "--events", "2", "--bounces", "0", "--out", "e.h5",
                 cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    with pf.read_events(tmp_path / "e.h5") as events:
        assert [event.truth.energy for event in events] == pytest.approx([end, end], rel=1e-3)


# ---- the library's side ------------------------------------------------------------------
def test_a_failing_benchmark_process_is_one_config_error():
    """``benchmark_transport`` called with a detector its child process cannot load:
    a ``ConfigError`` with the child's last line, not a CalledProcessError."""
    from photonflow.benchmarking import benchmark_transport

    with pytest.raises(ConfigError, match=r"benchmark case 'centre' of 'SKK' failed.*SKK"):
        benchmark_transport("SKK", 1e3, 1, 64, 0)
