"""The residual job: shared moments and references give each job's own numbers, a study's job
follows its simulation, and the map-level prediction makes the sky's gradient once."""

import numpy as np
import pytest
from helpers import CENTRED, night_schedule

from boresight import coupling, engine, harmonics, masks, predict, spectra
from boresight.instrument.pairs import PAPER_GAIN, Instrument, Systematics
from boresight.moments import compute_moments
from boresight.scan import SyntheticScan, paper_scan
from boresight.schedule import CES, Schedule


def test_a_prediction_makes_the_gradient_once_per_sky_and_pixels(small_sky, monkeypatch):
    """The map-level prediction of several jobs on one mask synthesises the sky's gradient once;
    another sky or other pixels make their own, and delta_p gives the same map with it."""

    calls, original = [], harmonics.alm2map_gradient
    monkeypatch.setattr(
        harmonics, "alm2map_gradient", lambda *a, **k: calls.append(1) or original(*a, **k)
    )
    pred = predict.Prediction(None, None, 60.0)
    pixels = np.flatnonzero(masks.survey_mask("deep", small_sky.nside))
    first = pred.gradient(small_sky, pixels)
    assert pred.gradient(small_sky, pixels) is first and len(calls) == 1
    pred.gradient(small_sky, pixels[:10])
    pred.gradient(small_sky.without_polarisation(), pixels[:10])
    assert len(calls) == 3
    pred.gradient(small_sky, pixels), pred.gradient(small_sky, pixels)
    assert len(calls) == 4
    pred.release()
    pred.gradient(small_sky, pixels)
    assert len(calls) == 5
    h, _ = engine.scan_moments(SyntheticScan(**CENTRED), small_sky.nside)
    sysm = Systematics(rho_arcmin=(0.5, 0.3))
    want = predict.delta_p(small_sky, h, sysm, pixels=pixels)
    got = predict.delta_p(small_sky, h, sysm, pixels=pixels, gradient=first)
    np.testing.assert_array_equal(got, want)
    with pytest.raises(ValueError, match="gradient of shape"):
        predict.delta_p(small_sky, h, sysm, pixels=pixels[:10], gradient=first)


def test_a_prediction_lets_its_gradient_go_after_its_last_map_check(small_sky, monkeypatch):
    """With map_checks=2 the gradient is made once, kept for the second read, and let go after
    it: a third read makes it anew; without map_checks it is kept until release()."""
    calls, original = [], harmonics.alm2map_gradient
    monkeypatch.setattr(
        harmonics, "alm2map_gradient", lambda *a, **k: calls.append(1) or original(*a, **k)
    )
    pixels = np.flatnonzero(masks.survey_mask("deep", small_sky.nside))
    pred = predict.Prediction(None, None, 60.0, map_checks=2)
    first = pred.gradient(small_sky, pixels)
    assert pred._held and pred.gradient(small_sky, pixels) is first and len(calls) == 1
    assert not pred._held  # the caller's copy is the only one left
    assert pred.gradient(small_sky, pixels) is not first and len(calls) == 2
    kept = predict.Prediction(None, None, 60.0)
    for _ in range(3):
        kept.gradient(small_sky, pixels)
    assert kept._held and len(calls) == 3


def test_the_last_map_check_predicts_before_it_simulates(small_sky, monkeypatch):
    """The last job to read a prediction's gradient predicts its map before it simulates (the
    paper job's gradient is then gone before the simulated maps exist), and lets the gradient go;
    a job that keeps it predicts after simulating; the numbers are a lone job's either way."""
    from boresight.jobs import residual

    order, sim, dp = [], residual._simulate, predict.delta_p
    monkeypatch.setattr(
        residual, "_simulate", lambda *a, **k: order.append("simulate") or sim(*a, **k)
    )
    monkeypatch.setattr(
        residual.predict, "delta_p", lambda *a, **k: order.append("delta_p") or dp(*a, **k)
    )
    nside, lmax = small_sky.nside, 2 * small_sky.nside
    mask = masks.survey_mask("deep", nside)
    couplings = coupling.mask_coupling(mask, lmax)
    theory = residual.load_spectra()
    scan = SyntheticScan(n_phi=3, range_rad=0.5, seed=3, rotations_deg=(0.0, 90.0))
    sysm = Systematics(rho_arcmin=(0.5, 0.3))
    pred = predict.Prediction(theory, couplings, 60.0, map_checks=2)
    moments = compute_moments(scan, nside, mask > 0)
    jobs = []
    for _ in range(2):
        jobs.append(
            residual.residual(
                small_sky,
                scan,
                sysm,
                mask,
                lmax,
                prediction=pred,
                predict_map=True,
                moments=moments,
            )
        )
        assert bool(pred._held) == (len(jobs) == 1)  # kept for the second, then let go
    # each job simulates its reference first; the second predicts before its own simulation
    assert order == ["simulate", "simulate", "delta_p", "simulate", "delta_p", "simulate"]
    alone = residual.residual(
        small_sky,
        scan,
        sysm,
        mask,
        lmax,
        prediction=predict.Prediction(theory, couplings, 60.0),
        predict_map=True,
    )
    for job in jobs:
        for name in ("total", "predicted_cl", "predicted_map"):
            np.testing.assert_array_equal(getattr(job, name), getattr(alone, name))


def test_zero_qu_needs_a_synthetic_scan_and_the_detectors_map_maker_a_real_one(small_sky):
    from boresight.jobs import residual

    ces = CES(
        start_unix=1.79e9, duration_s=60, elevation_deg=50, az_centre_deg=134, az_throw_deg=40
    )
    schedule = Schedule((ces,), sample_rate_hz=1.0)
    with pytest.raises(ValueError, match="synthetic scan"):
        residual.residual(small_sky, schedule, Systematics(), np.ones(12 * 16**2), 32, zero_qu=True)
    with pytest.raises(ValueError, match="takes a real schedule's samples"):
        residual.simulate_maps(
            small_sky, SyntheticScan(), Instrument(), Systematics(), mapmaker="detectors"
        )
    maps = residual.simulate_maps(
        small_sky, schedule, Instrument(), Systematics(), mapmaker="detectors"
    )
    assert maps.i_obs is not None  # a real schedule's samples take the detectors' map-maker


def test_the_tod_reads_the_sky_as_asked(small_sky):
    """``evaluation="pixel"`` (the engine's alone) reads each map's value in the sample's pixel:
    the detectors' I map is then the sky's own pixels to rounding, where the interpolated TOD's
    is not; a method the engine does not know is refused."""
    from boresight.jobs import residual

    ces = CES(
        start_unix=1.79e9, duration_s=120, elevation_deg=50, az_centre_deg=134, az_throw_deg=40
    )
    schedule = Schedule((ces,), sample_rate_hz=5.0)
    args = (small_sky, schedule, Instrument(), Systematics())
    seen, gaps = None, {}
    for evaluation in ("pixel", None):
        maps = residual.simulate_maps(*args, mapmaker="detectors", evaluation=evaluation)
        seen = np.flatnonzero(maps.rcond > 0.1) if seen is None else seen
        gaps[evaluation] = np.max(np.abs(maps.i_at(seen) - small_sky.maps[0][seen]))
    scale = np.std(small_sky.maps[0])
    assert seen.size > 10 and gaps["pixel"] < 1e-10 * scale and gaps[None] > 1e-3 * scale
    with pytest.raises(ValueError, match="evaluation = 'nearest'"):
        residual.simulate_maps(*args, evaluation="nearest")


def test_shared_moments_give_the_same_prediction(small_sky, theory):
    """One repeat's moments, shared across rotations (as the reproduction does), predict what
    each job's own moments predict; moments too short for the systematic are refused."""
    from boresight.jobs import residual

    mask = masks.survey_mask("deep", 64)
    prediction = predict.Prediction(theory, coupling.mask_coupling(mask, 128), 60.0)
    shared = compute_moments(paper_scan("deep"), 64, mask > 0)
    for angle in (None, 90.0):
        scan = paper_scan("deep", angle)
        own, reused = (
            residual.residual(
                small_sky, scan, PAPER_GAIN, mask, 128, prediction=prediction, moments=m
            )
            for m in (None, shared)
        )
        assert np.array_equal(own.predicted_cl, reused.predicted_cl)
    with pytest.raises(ValueError, match="h_n to 4"):
        residual.residual(
            small_sky,
            scan,
            Systematics(ellipticity_b=0.01),
            mask,
            128,
            prediction=prediction,
            moments=shared,
        )


def test_beam_terms_with_pixel_centre_hits_and_a_lower_output_lmax(tmp_path):
    """A beam systematic with in_pixel = "centre" and [output] lmax below [sky] lmax crashed with
    "operands could not be broadcast together with shapes (192,) (129,)": the beams' h_0 field's
    filter now reaches the sky's band limit. Its leaked power follows the simulation within 10 %
    in every band of the deep mask."""
    from dataclasses import replace

    from boresight.config import parse_study
    from boresight.jobs import residual

    study = parse_study(
        {
            "sky": {"nside": 64, "lmax": 191, "fwhm_arcmin": 60.0, "seed": 1},
            "scan": {"n_phi": 4, "range_rad": 0.719, "in_pixel": "centre"},
            "systematics": {"dfwhm_b_arcmin": 0.5},
            "mask": {"survey": "deep"},
            "output": {"lmax": 128},
        }
    )
    assert np.isfinite(residual.from_study(study)[0].predicted_cl).all()  # the whole residual
    sky, mask = study.load_sky(), masks.from_config(study.mask, 64)
    leaked = replace(residual.study_prediction(study, sky, mask), leaked=True)
    job = residual.residual(sky, study.scan, study.systematics, mask, 128, prediction=leaked)
    edges = spectra.linear_bins(40, 128, 22)
    sim, pred = (spectra.bin_spectrum(x, edges)[1] for x in (job.auto, job.predicted_cl))
    assert np.all(np.abs(pred / sim - 1) < 0.10), pred / sim


def test_the_one_job_puts_a_plate_in_front_of_a_focal_planes_pairs(small_sky):
    """residual(..., focalplane=, hwp=) is the difference of the engine's maps behind the same
    plate, with and without the systematic, its B on the footprint (the HWP table's rows); a
    plate without a focal plane is refused."""
    from boresight.instrument.focalplane import on_axis
    from boresight.instrument.hwp import HWP
    from boresight.jobs import residual

    schedule = night_schedule(rate=2.0, n=2)
    pairs, plate = on_axis((0.0, 45.0)), HWP(mode="continuous", frequency_hz=0.37)
    gain = Systematics(dg=(0.01, -0.01))
    maps = [
        engine.simulate_focalplane(small_sky, schedule, pairs, s, hwp=plate)
        for s in (Systematics(), gain)
    ]
    footprint = spectra.as_footprint((maps[0].rcond > 0.05).astype(float))
    lmax = 2 * small_sky.nside
    d = (maps[1].qu_at(footprint.pixels) - maps[0].qu_at(footprint.pixels)).copy()
    want = harmonics.alm2cl(footprint.alm(d, lmax, 2)[1])
    job = residual.residual(small_sky, schedule, gain, footprint, lmax, focalplane=pairs, hwp=plate)
    np.testing.assert_array_equal(job.auto, want)
    bare = residual.residual(small_sky, schedule, gain, footprint, lmax, focalplane=pairs)
    assert not np.allclose(bare.auto[2:], want[2:])  # the plate took part
    with pytest.raises(ValueError, match="in front of a focal plane"):
        residual.residual(small_sky, schedule, gain, footprint, lmax, hwp=plate)
