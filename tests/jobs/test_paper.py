"""The reproduction's pipeline: transforms on a background thread give the direct calls' spectra."""

import dataclasses

import numpy as np
import pytest

from boresight import engine, masks, predict, spectra
from boresight.jobs import paper
from boresight.scan import paper_scan
from boresight.sky import SkyConfig, make_sky

STUDY = paper.preset(nside=64, lmax=191, seed=3)


@pytest.fixture(scope="module")
def study():
    results, stages = paper.run_study(STUDY)
    return results, stages


@pytest.mark.parametrize("exp", paper.EXPERIMENTS, ids=lambda e: e.name)
def test_background_transforms_match_direct_calls(study, exp):
    res = study[0][exp.name]
    sky_cfg = SkyConfig(nside=64, lmax=191, fwhm_arcmin=7.0, seed=3)
    sky = make_sky(sky_cfg)
    unpolarised = make_sky(dataclasses.replace(sky_cfg, polarised=False))
    mask = masks.survey_mask(exp.survey, 64)
    obs, lmax = mask > 0, 128  # bands end at 2 Nside
    ref = engine.simulate(sky, paper_scan(exp.survey, seed=3), pixels=obs)
    assert set(res.cross) == set(res.auto) == {None, *exp.angles_deg}
    assert set(res.predicted_map) == set(res.zero_qu) == {None, exp.ideal_deg}
    for angle in (None, exp.ideal_deg, exp.angles_deg[-1]):
        scan = paper_scan(exp.survey, angle, seed=3)
        sim = engine.simulate(sky, scan, systematics=exp.systematics, pixels=obs)
        cross, auto = spectra.residual_bb_parts(sim.qu, ref.qu, mask, lmax)
        np.testing.assert_array_equal(res.cross[angle], cross)
        np.testing.assert_array_equal(res.auto[angle], auto)
        if angle in res.predicted_map:
            h, _ = engine.scan_moments(scan, 64, pixels=obs, dtype=np.complex64)  # the job's
            dp = predict.delta_p(sky, h, exp.systematics) * obs
            expected = spectra.residual_bb(ref.qu + [dp.real, dp.imag], ref.qu, mask, lmax)
            # the direct route adds dP to the reference and subtracts it again: rounding of ref
            scale = np.max(np.abs(res.predicted_map[None]))
            np.testing.assert_allclose(
                res.predicted_map[angle], expected, rtol=0, atol=1e-9 * scale
            )
            sim0 = engine.simulate(unpolarised, scan, systematics=exp.systematics, pixels=obs)
            zero = np.zeros_like(sim0.qu)
            np.testing.assert_array_equal(
                res.zero_qu[angle], spectra.residual_bb(sim0.qu, zero, mask, lmax)
            )


def test_the_queue_holds_one_waiting_transform_where_a_jobs_maps_are_large():
    """Two transforms wait at a time while a job's Q, U on the wide survey's pixels take at most
    QUEUE_BYTES, 0.27 GB (Nside 1024: 0.08 GB), one at the paper's Nside 2048 (0.33 GB); the deep
    survey alone (0.1 of the sky) keeps two at 2048 (0.08 GB)."""
    assert paper.queue_depth(paper.preset(quick=True)) == 2
    assert paper.queue_depth(paper.preset(nside=1024, lmax=2047)) == 2
    assert paper.queue_depth(paper.preset()) == 1
    deep = [exp for exp in paper.EXPERIMENTS if exp.survey == "deep"]
    assert paper.queue_depth(paper.preset(), deep) == 2


def test_stages_cover_the_waiting_for_transforms(study):
    stages = study[1]
    assert {"sky", "transforms still running"} <= set(stages)
    assert all(t >= 0 for t in stages.values())


GAIN_CASE = """
[sky]
nside = 64
lmax = 191
fwhm_arcmin = 7.0
seed = 3
[scan]
n_phi = 4
range_rad = 0.719
seed = 3
[systematics]
dg = [0.01, -0.01]
[mask]
survey = "deep"
"""


def test_a_study_file_of_the_gain_case_gives_the_reproduction_rows(study, tmp_path):
    """One pipeline: `simulate` on the paper's gain case (no rotation) writes the bands that
    `reproduce` writes for it, to the bit (same sky, scan, mask, prediction and binning)."""
    import csv

    from boresight.commands import simulate
    from boresight.config import load_study

    (tmp_path / "gain.toml").write_text(GAIN_CASE)
    simulate.run(load_study(tmp_path / "gain.toml"), tmp_path / "out")
    with open(tmp_path / "out" / "bands.csv") as f:
        mine = list(csv.DictReader(f))
    theirs = [
        r
        for r in paper.tidy_rows(study[0], STUDY)
        if r["experiment"] == "gain_deep" and r["pbr_angle_deg"] == ""
    ]
    assert len(mine) == len(theirs) > 5
    for a, b in zip(mine, theirs):
        assert (int(a["ell_lo"]), int(a["ell_hi"])) == (b["ell_lo"], b["ell_hi"])
        for column in ("residual_bb", "residual_auto_bb", "residual_cross_bb", "predicted_bb"):
            assert float(a[column]) == b[column], column  # CSV repr round-trips a float exactly


def test_reproduce_config_sets_sky_run_and_output_only(tmp_path):
    from boresight.config import ConfigError

    raw = {"sky": {"nside": 64, "lmax": 191, "seed": 3}, "output": {"n_bands": 5}}
    study_ = paper.from_raw(raw)
    assert study_.sky == STUDY.sky and study_.scan.seed == 3 and study_.output.n_bands == 5
    assert study_.output.lmax == 128
    with pytest.raises(ConfigError, match="systematics"):
        paper.from_raw({"systematics": {"dg": 0.1}})


def test_a_failing_transform_is_raised_not_lost(monkeypatch):
    def broken(*args, **kwargs):
        raise RuntimeError("transform failed")

    monkeypatch.setattr(spectra, "difference_bb_parts", broken)
    with pytest.raises(RuntimeError, match="transform failed"):
        paper.run_study(STUDY, experiments=paper.EXPERIMENTS[:1])
