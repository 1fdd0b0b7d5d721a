"""Kills at random moments: a run killed with SIGKILL and run again gives the output of
an uninterrupted run, and leaves nothing behind (no staging or replaced directories)."""

import random
import subprocess
import sys
import time

import healpy as hp
import numpy as np
import pytest

from boresight.cli import main

STUDY = """
[sky]
nside = 16
lmax = 47
fwhm_arcmin = 240.0
seed = 3
[scan]
n_phi = 3
rotations_deg = [0.0, 90.0]
[systematics]
dg = [0.01, -0.01]
[mask]
survey = "deep"
[output]
lmax = 40
"""


RUN_SECONDS = 4.0  #: a whole run in a fresh process on the 2-core CI machine (measured 3.7 s)


def _outputs(out):
    """What a run produces, without its timings: spectra and the maps."""
    maps = [
        hp.read_map(str(out / f), field=None)
        for f in ("maps_systematics.fits", "maps_reference.fits")
    ]
    return (out / "spectra.csv").read_text(), np.array(maps)


@pytest.mark.slow
def test_sigkill_at_random_moments_then_rerun_equals_an_uninterrupted_run(tmp_path):
    config = tmp_path / "study.toml"
    config.write_text(STUDY)
    cmd = [sys.executable, "-m", "boresight.cli", "-q", "simulate", str(config), "--force"]
    assert main(["-q", "simulate", str(config), "--out", str(tmp_path / "whole")]) == 0
    spectra, maps = _outputs(tmp_path / "whole")
    rng = random.Random(17)
    out = tmp_path / "killed"
    # one random moment in each third of the run: the imports, the simulation, the writing
    thirds = np.linspace(0.3, RUN_SECONDS, 4)
    for trial, (early, late) in enumerate(zip(thirds[:-1], thirds[1:])):
        proc = subprocess.Popen([*cmd, "--out", str(out)])
        time.sleep(rng.uniform(early, late))
        proc.kill()
        proc.wait()
        assert main(["-q", "simulate", str(config), "--out", str(out), "--force"]) == 0
        again_spectra, again_maps = _outputs(out)
        assert again_spectra == spectra and np.array_equal(again_maps, maps), trial
        left = sorted(p.name for p in tmp_path.iterdir())
        assert left == ["killed", "study.toml", "whole"], left
