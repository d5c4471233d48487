"""Emission tables of the particle generator: content, file format and resume."""

import numpy as np
import pytest

from photonflow.errors import ConfigError
from photonflow.generator import GeneratorSettings
from photonflow.generator import emission_tables as tables
from photonflow.generator.materials import WATER, refractive_index

FAST = GeneratorSettings(yield_scale=0.05)


@pytest.fixture(scope="module")
def muon_table():
    return tables.build_table("mu-", [300.0, 1000.0], 3, seed=7, settings=FAST)


def test_muon_table_matches_range_and_cherenkov_angle(muon_table):
    """Mean path length against the CSDA range (PDG-format table, physics.md section 3:
    129.1 and 473.2 g/cm^2 at 300 and 1000 MeV, i.e. m at 1 g/cm^3) within 3 %; the
    angular peak at cos(theta_c) = 1 / (n beta) with n(400 nm) (the band's middle);
    every photon of a muon that stops within the 25 m range is in the table."""
    np.testing.assert_allclose(muon_table.track_length, [1.291, 4.732], rtol=0.03)
    np.testing.assert_allclose(muon_table.photons.sum(axis=(1, 2)), muon_table.total_yield)
    width = np.diff(muon_table.cos_edges)[0]
    cos_c = 1.0 / float(refractive_index(WATER, 400.0))
    peak = tables.cherenkov_peak_cos(muon_table)
    assert abs(peak[1] - cos_c) < 2 * width  # 1 GeV: beta = 0.995
    assert peak[0] > peak[1]  # slower muon, narrower cone
    # the light-speed front: a beta ~ 1 muon's photons are emitted within ~1 ns of it
    times = muon_table.time_offsets[1].sum(axis=0)
    centres = 0.5 * (muon_table.time_edges[1:] + muon_table.time_edges[:-1])
    assert abs(np.average(centres, weights=times)) < 1.0


def test_same_seed_same_table_and_resume_after_interruption(tmp_path, monkeypatch):
    """An interrupted build resumed from its file equals an uninterrupted one."""
    energies = [200.0, 400.0, 800.0]
    reference = tables.build_table("e-", energies, 2, seed=3, settings=FAST)
    path = tmp_path / "e.h5"
    real_row = tables._energy_row
    calls = []

    def failing_row(*args):
        calls.append(args[1])
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real_row(*args)

    monkeypatch.setattr(tables, "_energy_row", failing_row)
    with pytest.raises(KeyboardInterrupt):
        tables.build_table("e-", energies, 2, seed=3, settings=FAST, resume=path)
    with pytest.raises(ConfigError, match="1 of 3 energies built"):
        tables.load_table(path)
    monkeypatch.setattr(tables, "_energy_row", real_row)
    resumed = tables.build_table("e-", energies, 2, seed=3, settings=FAST, resume=path)
    loaded = tables.load_table(path)
    for name in ("photons", "time_offsets", "total_yield", "yield_spread", "track_length"):
        np.testing.assert_array_equal(getattr(resumed, name), getattr(reference, name))
        np.testing.assert_array_equal(getattr(loaded, name), getattr(reference, name))
    assert loaded.settings["seed"] == 3 and loaded.settings["generator"]["yield_scale"] == 0.05
    with pytest.raises(ConfigError, match="different build"):
        tables.build_table("e-", energies, 2, seed=4, settings=FAST, resume=path)


def test_bad_input_and_foreign_files(tmp_path):
    with pytest.raises(ConfigError, match="particle = 'proton'"):
        tables.build_table("proton", [100.0], 1)
    with pytest.raises(ConfigError, match="energies"):
        tables.build_table("mu-", [500.0, 100.0], 1)
    with pytest.raises(ConfigError, match="per_energy = 0"):
        tables.build_table("mu-", [100.0], 0)
    with pytest.raises(ConfigError, match="cannot be read"):
        tables.load_table(tmp_path / "missing.h5")
    import h5py

    with h5py.File(tmp_path / "old.h5", "w") as handle:
        handle.attrs["schema_version"] = 99
    with pytest.raises(ConfigError, match="schema_version = 99"):
        tables.load_table(tmp_path / "old.h5")


def test_shipped_tables_load_and_hold_the_reference_physics():
    """The tables inside the package: muon path length against the CSDA range of the
    PDG-format table (physics.md section 3: 31.23 g/cm^2 at 100 MeV ... 2235 at 5 GeV,
    interpolated in log-log) within 3 %; electron light per GeV within 5 % of the
    Radel-Wiebusch 1.65e5 photons/GeV in 300-600 nm (physics.md section 3) above 1 GeV."""
    muons = tables.shipped_table("mu-")
    electrons = tables.shipped_table("e-", "water")
    kinetic = np.array([100, 200, 300, 500, 1000, 2000, 5000, 10000], float)
    csda_cm = np.array([31.23, 78.90, 129.1, 229.6, 473.2, 935.6, 2235, 4282])
    covered = muons.energies >= kinetic[0]  # the CSDA table starts at 100 MeV
    expected_m = np.exp(np.interp(np.log(muons.energies[covered]), np.log(kinetic),
                                  np.log(csda_cm))) / 100
    np.testing.assert_allclose(muons.track_length[covered], expected_m, rtol=0.03)
    high = electrons.energies >= 1000.0
    per_gev = electrons.total_yield[high] / (electrons.energies[high] / 1000.0)
    np.testing.assert_allclose(per_gev, 1.65e5, rtol=0.05)
    # the full tables (scripts/build_emission_tables.py): full yield, the yield of every
    # energy to 0.2 %
    for table, energies in ((muons, 40), (electrons, 48)):
        assert table.settings["generator"]["yield_scale"] == 1.0
        assert table.energies.size == energies
        assert np.all(table.yield_error / table.total_yield <= 0.002 + 1e-9)
    with pytest.raises(ConfigError, match="no shipped emission table"):
        tables.shipped_table("gamma")


def test_shipped_scintillator_tables_hold_the_quenched_deposit():
    """The scintillator's tables (Cherenkov light and visible energy): the visible energy
    of muons from 1 GeV up is the Birks-quenched kinetic energy of a minimum-ionising
    particle, 1 / (1 + kB1 S + kB2 S^2) with S ~ 2.0 MeV cm^2/g and the medium's kB
    (0.987), within 0.5 %; the visible energy is known to 0.2 % at every energy, the
    Cherenkov yield to 0.2 % above the muon's Cherenkov threshold (~50 MeV; below it
    the few photons of knock-on electrons, capped at 4,096 muons)."""
    muons = tables.shipped_table("mu-", "scintillator")
    electrons = tables.shipped_table("e-", "scintillator")
    kb1, kb2 = 6.5e-3, 1.5e-6  # physics.md section 6
    minimum_ionising = 1.0 / (1.0 + kb1 * 2.0 + kb2 * 4.0)
    high = muons.energies >= 1000.0
    np.testing.assert_allclose(muons.visible_total[high] / muons.energies[high],
                               minimum_ionising, rtol=5e-3)
    for table in (muons, electrons):
        assert table.scintillating and table.medium == "scintillator"
        assert np.all(table.visible_error <= 0.002 * table.visible_total)
        above = table.energies > 60.0 if table is muons else table.energies > 1.0
        assert np.all(table.yield_error[above] <= 0.002 * table.total_yield[above] + 1e-9)


def test_tables_build_command(tmp_path):
    """``photonflow tables build`` writes a loadable table; bad input exits with code 2,
    one line, and no file."""
    from typer.testing import CliRunner

    from photonflow.cli import app

    out = tmp_path / "mu.h5"
    runner = CliRunner()
    done = runner.invoke(app, ["tables", "build", "--particle", "mu-", "--energies", "200,400",
                               "--per-energy", "1", "--yield-scale", "0.02", "--out", str(out)])
    assert done.exit_code == 0, done.output
    assert list(tables.load_table(out).energies) == [200.0, 400.0]
    bad = tmp_path / "bad.h5"
    for arguments in (["--particle", "proton"], ["--particle", "mu-", "--energies", "1,x"],
                      ["--particle", "mu-", "--yield-scale", "0"]):
        failed = runner.invoke(app, ["tables", "build", *arguments, "--out", str(bad)])
        assert failed.exit_code == 2
        assert failed.output.count("error:") == 1
        assert not bad.exists()


def test_kill_stops_a_build_within_an_energy_and_keeps_the_finished_ones(tmp_path):
    """``kill`` (SIGTERM) during a long energy ends ``photonflow tables build`` within
    seconds with exit code 130; the energies written before stay in the file, and the
    same command resumes from them."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "e.h5"
    command = [sys.executable, "-m", "photonflow", "tables", "build", "--particle", "e-",
               "--energies", "1,3000", "--per-energy", "1000", "--yield-scale", "0.05",
               "--out", str(out)]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                               env={**os.environ, "PYTHONUNBUFFERED": "1"})
    deadline = time.monotonic() + 240
    while not out.exists() and time.monotonic() < deadline and process.poll() is None:
        time.sleep(0.5)
    assert out.exists(), "the first energy was never written"
    time.sleep(2.0)  # well inside the second energy (1,000 electrons of 3 GeV, minutes)
    process.send_signal(signal.SIGTERM)
    began = time.monotonic()
    code = process.wait(timeout=60)
    assert code == 130 and time.monotonic() - began < 10
    table, completed = tables._read(out)
    assert completed == [0] and table.particles[0] == 1000
