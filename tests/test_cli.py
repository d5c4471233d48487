"""The real ``photonflow`` command, run as ``python -m photonflow`` in a subprocess."""

import math
import subprocess
import sys
from pathlib import Path

import pytest

import photonflow
from photonflow.geometry import PRESETS, preset_table

pytestmark = pytest.mark.compile_bound

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def run(*args, cwd):
    return subprocess.run(
        [sys.executable, "-m", "photonflow", *map(str, args)],
        cwd=cwd, capture_output=True, text=True, timeout=300,
    )


def assert_one_line_error(result, *fragments):
    assert result.returncode == 2, result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: ")
    assert "Traceback" not in result.stderr
    for fragment in fragments:
        assert fragment in lines[0]


def assert_png(path):
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE and len(data) > 1000


def test_version(tmp_path):
    result = run("--version", cwd=tmp_path)
    assert result.returncode == 0
    assert result.stdout.strip() == f"photonflow {photonflow.__version__}"


def test_presets_lists_every_preset(tmp_path):
    result = run("presets", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    for name in PRESETS:
        assert name in result.stdout
    sk_row = next(line for line in result.stdout.splitlines() if " SK " in line)
    assert "11146" in sk_row and "40.3" in sk_row
    assert "source" in result.stdout and "WCSim; SK site" in sk_row  # the README's column


def test_geometry_writes_a_png(tmp_path):
    result = run("geometry", "TOY_CYLINDER", "--out", "pictures/x.png", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert_png(tmp_path / "pictures" / "x.png")
    assert [p.name for p in (tmp_path / "pictures").iterdir()] == ["x.png"]  # no leftovers
    assert "pictures/x.png" in result.stdout


def test_geometry_unknown_preset_is_one_line_and_writes_nothing(tmp_path):
    result = run("geometry", "NOPE", "--out", "x.png", cwd=tmp_path)
    assert_one_line_error(result, "NOPE", *PRESETS)
    assert list(tmp_path.iterdir()) == []


def test_geometry_unknown_picture_format_writes_nothing(tmp_path):
    result = run("geometry", "TOY_CYLINDER", "--out", "x.txt", cwd=tmp_path)
    assert_one_line_error(result, "x.txt", ".png")
    assert list(tmp_path.iterdir()) == []


def test_info_summarises_an_event_file(tmp_path):
    from photonflow.geometry import preset_detector
    from photonflow.io import make_event, write_events

    detector = preset_detector("TOY_CYLINDER")
    events = [make_event([0, 5, 7], [1.0, 2.5, 1.2], [10.0, 12.5, 30.0]),
              make_event([199], [3.0], [55.0])]
    write_events(tmp_path / "run.h5", events, detector, photonflow.default_params(detector))
    result = run("info", "run.h5", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    lines = {line.split()[0]: line for line in result.stdout.splitlines() if line.strip()}
    assert "TOY_CYLINDER" in lines["detector"]
    assert lines["events"].split()[-1] == "2"
    assert "4 total" in lines["hits"]
    assert "10 .. 55 ns" in lines["time"]


def test_info_on_a_missing_file_exits_2(tmp_path):
    result = run("info", "missing.h5", cwd=tmp_path)
    assert_one_line_error(result, "missing.h5")


def test_demo_writes_the_geometry_pictures(tmp_path):
    result = run("demo", "--out-dir", "out", "--skip-fit", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    for name in ("SK", "JUNO"):
        assert_png(tmp_path / "out" / f"geometry_{name}.png")
        assert f"geometry_{name}.png" in result.stdout
    assert "11146" in result.stdout  # the preset table comes first
    # the calibration run: an event file with its truth, and its event display
    assert_png(tmp_path / "out" / "calibration_event0.png")
    with photonflow.read_events(tmp_path / "out" / "calibration_run.h5") as events:
        assert len(events) == 3 and events.detector.name == "SK"
        assert events[0].truth.source_kind == "isotropic" and events[0].n_hits > 1000
    assert "optics calibration" not in result.stdout  # --skip-fit leaves the fit out
    # the tracks: a muon and an electron, each drawn against its prediction
    for index in range(2):
        assert_png(tmp_path / "out" / f"track_event{index}.png")
    with photonflow.read_events(tmp_path / "out" / "track_events.h5") as events:
        assert [event.truth.particle for event in events] == ["mu-", "e-"]


def test_readme_starts_with_set_up_and_its_preset_table_matches_the_presets():
    """README: `make demo` and `make test` first; its preset table is what
    `photonflow presets` prints (no drift)."""
    readme = (Path(__file__).parents[1] / "README.md").read_text()
    first_code = readme.split("```")[1].splitlines()  # the set-up commands come first
    assert [line.split()[:2] for line in first_code[1:3]] == [["make", "demo"], ["make", "test"]]
    rows = {}
    for line in readme.splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if len(cells) == 8 and cells[0] in PRESETS:
            rows[cells[0]] = cells
    assert list(rows) == list(PRESETS)
    for row in preset_table():
        coverage = "-" if math.isnan(row["coverage"]) else f"{100 * row['coverage']:.1f}"
        expected = [row["name"], row["shape"], row["dimensions"], str(row["sensors"]), coverage,
                    row["sensor_model"], row["medium"], row["source"]]
        assert rows[row["name"]] == expected


def test_simulate_then_info_and_display(tmp_path):
    result = run("simulate", "--detector", "TOY_CYLINDER", "--source", "laser",
                 "--position", "0,0,1", "--direction", "0,0,-1", "--opening-angle", "0.3",
                 "--photons", "2e4", "--events", "4", "--seed", "5", "--out", "run.h5",
                 cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    with photonflow.read_events(tmp_path / "run.h5") as events:
        assert len(events) == 4
        truth = events[0].truth
        assert truth.source_kind == "laser" and truth.seed == 5
        assert list(truth.position) == [0.0, 0.0, 1.0]
        assert all(event.n_hits > 0 for event in events)
    info = run("info", "run.h5", cwd=tmp_path)
    assert info.returncode == 0 and "events       4" in info.stdout
    shown = run("display", "run.h5", "--event", "2", "--out", "ev.png", cwd=tmp_path)
    assert shown.returncode == 0, shown.stderr
    assert_png(tmp_path / "ev.png")
    # the same seed gives the same events; create mode refuses to overwrite
    again = run("simulate", "--detector", "TOY_CYLINDER", "--source", "laser",
                "--position", "0,0,1", "--direction", "0,0,-1", "--opening-angle", "0.3",
                "--photons", "2e4", "--events", "4", "--seed", "5", "--out", "run.h5",
                cwd=tmp_path)
    assert_one_line_error(again, "run.h5", "recreate")


def test_simulate_bad_input_is_one_line_and_writes_nothing(tmp_path):
    cases = [
        (["--position", "0,0,9"], "source.position"),
        (["--photons", "-5"], "source.n_photons"),
        (["--position", "1,2"], "--position"),
        (["--source", "torch"], "source = 'torch'"),
        (["--source", "laser"], "source.direction"),
        (["--detector", "NOPE"], "NOPE"),
    ]
    for extra, fragment in cases:
        result = run("simulate", "--detector", "TOY_CYLINDER", "--out", "bad.h5", *extra,
                     cwd=tmp_path)
        assert_one_line_error(result, fragment)
        assert not (tmp_path / "bad.h5").exists()


def test_display_out_of_range_event(tmp_path):
    result = run("simulate", "--detector", "TOY_SPHERE", "--photons", "1e3", "--out", "r.h5",
                 cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert_one_line_error(run("display", "r.h5", "--event", "3", cwd=tmp_path),
                          "--event = 3", "0..0")
