"""The real schedule beside its synthetic twin as a library job: the paper's per-pair values go to
a focal plane's pairs by their angles, and the job returns what ``compare-scans`` writes."""

import csv
import logging

import numpy as np
import pytest
from helpers import EXAMPLES

from boresight import cli
from boresight._util.provenance import Timer
from boresight.instrument.focalplane import hexagon, on_axis
from boresight.instrument.pairs import PAPER_GAIN
from boresight.jobs.compare_scans import compare_scans, on_focalplane
from boresight.schedule import Schedule, load_schedule, write_schedule
from boresight.sky import SkyConfig, make_sky


def test_the_papers_per_pair_values_go_to_the_pairs_by_their_angle():
    """The Q pair's value where cos(4 gamma) > 0, the U pair's elsewhere; scalars stay."""
    dg = on_focalplane(PAPER_GAIN, on_axis((0.0, 45.0))).dg
    assert dg == PAPER_GAIN.dg
    pairs = hexagon(7, 10.0)
    q_like = np.cos(4 * np.radians(pairs.gamma_deg)) > 0
    assert 0 < q_like.sum() < pairs.n_pairs
    spread = on_focalplane(PAPER_GAIN, pairs)
    want = [PAPER_GAIN.dg[0] if q else PAPER_GAIN.dg[1] for q in q_like]
    assert spread.dg == pytest.approx(want, abs=0)
    assert spread.rho_arcmin == PAPER_GAIN.rho_arcmin


def test_the_job_returns_what_the_command_writes(tmp_path):
    base = load_schedule(EXAMPLES / "schedule_deep_sat.toml")
    schedule = Schedule(base.ces[:2], base.site, 2.0, repeat_boresight_deg=(0.0, 90.0))
    path = tmp_path / "s.toml"
    write_schedule(schedule, str(path), "toml")
    out = tmp_path / "o"
    assert cli.main(["-q", "compare-scans", str(path), "--out", str(out), "--nside", "16"]) == 0
    sky = make_sky(SkyConfig(nside=16, lmax=32, fwhm_arcmin=30.0, seed=1))
    result = compare_scans(
        load_schedule(str(path)), sky, "gain", timer=Timer(logging.getLogger("test"))
    )
    written = list(csv.DictReader(open(out / "compare.csv")))
    assert len(written) == len(result.rows) > 0
    for row, mine in zip(written, result.rows):
        for key, value in mine.items():
            assert float(row[key]) == pytest.approx(float(value), rel=1e-15, nan_ok=True), key
    assert result.observed.sum() == result.table[1]["pixels"]


def test_the_job_refuses_what_it_cannot_compare():
    schedule = load_schedule(EXAMPLES / "schedule_deep_sat.toml")
    timer = Timer(logging.getLogger("test"))
    sky = make_sky(SkyConfig(nside=16, lmax=32, fwhm_arcmin=30.0, seed=1))
    with pytest.raises(ValueError, match="'beam'; allowed"):
        compare_scans(schedule, sky, "beam", timer=timer)
    low = make_sky(SkyConfig(nside=16, lmax=24, fwhm_arcmin=30.0, seed=1))
    with pytest.raises(ValueError, match="lmax 24 is under"):
        compare_scans(schedule, low, "gain", timer=timer)
