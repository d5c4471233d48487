"""Interrupting the real ``photonflow simulate`` (Ctrl-C and ``kill``) at any moment.

Each case starts the console command in a subprocess, waits until the command runs
(it has taken over SIGTERM: Python has imported photonflow and JAX), then sends SIGINT
or SIGTERM after a delay: at once, during JAX's compilation of the first event, and
after a chunk of events is in the partial file. Every case must end with exit code 130
and one line (no segmentation fault, which 6 of 10 such interrupts during compilation
gave before), write no event file, and leave either nothing or a partial file that
holds the events it reports and that ``--resume`` finishes.
"""

import json
import re
import signal
import subprocess
import sys
import time

import h5py
import pytest

from photonflow.provenance import code_identity

#: Enough events that the run outlasts the longest delay (4.5 s): 1,000 finished within
#: it on a fast 2-core AMD EPYC (2026-11-27), which exited 0 before the SIGTERM.
EVENTS = 3000
#: The line of an interrupt while photonflow (and JAX) is still being imported.
STARTING = "interrupted while photonflow was starting (nothing was done)"
RUN = ["simulate", "--detector", "TOY_CYLINDER", "--photons", "2000", "--bounces", "1",
       "--events", str(EVENTS), "--seed", "3", "--out", "run.h5"]

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="reads the signal mask from /proc")


def start(cwd, *extra):
    return subprocess.Popen([sys.executable, "-m", "photonflow", *RUN, *extra], cwd=cwd,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_until_running(process, timeout=120.0):
    """Until the command catches SIGTERM (bit 15 of SigCgt in /proc/PID/status)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert process.poll() is None, process.communicate()
        with open(f"/proc/{process.pid}/status") as status:
            caught = next(int(line.split()[1], 16) for line in status
                          if line.startswith("SigCgt:"))
        if caught & (1 << (signal.SIGTERM - 1)):
            return
        time.sleep(0.02)
    raise AssertionError("the command never took over SIGTERM")


def wait_for_events(process, partial, timeout=180.0):
    """Until the partial file grows after its empty layout: the writer creates it at
    once, the first event then compiles for seconds, and each chunk of 100 events
    makes it grow."""
    deadline = time.monotonic() + timeout
    layout, last, changed = None, -1, time.monotonic()
    while True:
        assert process.poll() is None and time.monotonic() < deadline
        size, now = (partial.stat().st_size if partial.exists() else -1), time.monotonic()
        if layout is None:
            if size != last:
                last, changed = size, now
            elif size > 0 and now - changed >= 0.5:  # laid out: steady for 0.5 s
                layout = size
        elif size > layout:
            return
        time.sleep(0.02)


def interrupt(tmp_path, signum, delay):
    """Run, interrupt after ``delay`` s (or "events": after the first chunk), and check
    the exit; returns (events reported kept, the partial file)."""
    partial = tmp_path / ".run.h5.partial"
    process = start(tmp_path)
    wait_until_running(process)
    if delay == "events":
        wait_for_events(process, partial)
    else:
        time.sleep(delay)
    process.send_signal(signum)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, stderr
    assert "Fatal Python error" not in stderr and "Traceback" not in stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert not (tmp_path / "run.h5").exists()
    if lines[0] in ("interrupted", STARTING):  # before the event file was opened
        assert list(tmp_path.iterdir()) == []
        return 0, partial
    match = re.fullmatch(rf"interrupted after (\d+) of {EVENTS} events; (.*)", lines[0])
    assert match, lines[0]
    kept = int(match.group(1))
    if partial.exists():
        assert kept > 0 and "--resume" in match.group(2)
        with h5py.File(partial, "r") as h5:  # readable, holding what it reports
            assert int(h5["events"].attrs["n_events"]) == kept
    else:
        assert kept == 0 and match.group(2) == "nothing kept"
        assert list(tmp_path.iterdir()) == []
    return kept, partial


@pytest.mark.parametrize(("signum", "delay"), [
    (signal.SIGINT, 0.0),  # parsing and loading the detector
    (signal.SIGTERM, 0.5),
    (signal.SIGINT, 3.0),  # tracing and compiling the first event
    (signal.SIGTERM, 4.5),
    (signal.SIGINT, "events"),
], ids=["int-0s", "term-0.5s", "int-3s", "term-4.5s", "int-after-events"])
def test_interrupt_exits_130_and_keeps_what_was_done(tmp_path, signum, delay):
    interrupt(tmp_path, signum, delay)


def test_kill_after_events_keeps_a_partial_file_that_resume_finishes(tmp_path):
    kept, partial = interrupt(tmp_path, signal.SIGTERM, "events")
    assert partial.exists() and 0 < kept < EVENTS
    resumed = subprocess.run([sys.executable, "-m", "photonflow", *RUN, "--resume"],
                             cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert f"resumed at event {kept}" in resumed.stdout
    assert not partial.exists()
    with h5py.File(tmp_path / "run.h5", "r") as h5:
        assert int(h5["events"].attrs["n_events"]) == EVENTS
        # the run was made by this code, which a resume must match
        assert json.loads(h5.attrs["run"])["code"] == code_identity()


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["int", "term"])
def test_an_interrupt_while_photonflow_is_imported_is_one_line(tmp_path, signum):
    """The command takes over both signals as soon as photonflow's import starts (the
    SIGTERM bit appears), a second before JAX is loaded and the command runs: an
    interrupt then is one line and exit code 130, not Python's traceback."""
    process = start(tmp_path)
    wait_until_running(process)  # the guard of photonflow._startup: JAX still loading
    process.send_signal(signum)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, stderr
    assert stderr.strip().splitlines() == [STARTING]
    assert list(tmp_path.iterdir()) == []
