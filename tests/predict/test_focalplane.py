"""The focal plane's prediction: the shared-h_n formula on the axis, the TOD of every pair on its
own samples band by band, and its expectation over the pairs' draws against their mean."""

import dataclasses

import numpy as np
import pytest
from helpers import EXAMPLES, toast_schedule

from boresight import engine, harmonics, predict, spectra
from boresight import moments as scanstats
from boresight.cosmology import load_spectra
from boresight.instrument import focalplane
from boresight.instrument.hwp import HWP
from boresight.instrument.pairs import Instrument, Spread, Systematics
from boresight.predict import focalplane as predict_fp
from boresight.predict.expectation import smoothed_spectra
from boresight.schedule import load_schedule
from boresight.sky import Sky, SkyConfig, make_sky

NSIDE, LMAX = 32, 64
EDGES = np.array([40, 48, 56, LMAX + 1])  #: bands of 40 <= ell <= 2 Nside
#: an elliptical beam on every detector A and a wider one on every B
BEAMS = dict(ellipticity_a=0.05, ellipticity_angle_a_deg=30.0, dfwhm_b_arcmin=10.0)


def _bb(footprint, dp):
    d = dp[footprint.pixels]
    b = footprint.alm(np.array([d.real, d.imag]), LMAX, 2)[1]
    return spectra.bin_spectrum(harmonics.alm2cl(b), EDGES)[1]


@pytest.fixture(scope="module")
def deep():
    """The deep example at 1 Hz, TOAST's 7-pixel hexagon 20 deg wide, with and without the 0/90
    repeat, and a sky smooth over a pixel (4 pixels' FWHM)."""
    fp = focalplane.hexagon(7, 20.0)
    base = load_schedule(str(EXAMPLES / "schedule_deep_sat.toml"))
    schedules = {
        r: dataclasses.replace(base, sample_rate_hz=1.0, repeat_boresight_deg=r)
        for r in ((0.0,), (0.0, 90.0))
    }
    stats = {
        r: scanstats.characterise_focalplane(s, fp, NSIDE, per_pair=True)
        for r, s in schedules.items()
    }
    sky = make_sky(SkyConfig(nside=NSIDE, lmax=LMAX, fwhm_arcmin=450.0, seed=10))
    return fp, schedules, stats, sky


def test_on_the_axis_it_is_the_shared_moments_prediction():
    """Pairs on the axis: the focal plane's dP (fields at pixel centres) is predict.delta_p's
    with the boresight's h_n, to rounding, on every observed pixel; the beams' terms too (each
    pair's own filters against the pairs' mean filters)."""
    schedule = toast_schedule()
    sky = make_sky(SkyConfig(nside=NSIDE, lmax=LMAX, fwhm_arcmin=120.0, seed=1))
    stats = scanstats.characterise_focalplane(
        schedule, focalplane.on_axis((0.0, 45.0)), NSIDE, per_pair=True
    )
    alone = scanstats.characterise_schedule(schedule, NSIDE)
    seen = alone.hits > 0
    for sy in (
        Systematics(dg=(0.01, -0.02), leak=(0.0, 0.01)),
        Systematics(rho_arcmin=(0.5, 1.0), chi_deg=(10.0, -30.0)),
        Systematics(pol_angle_deg=(0.5, -0.2), nonortho_deg=0.3),
        Systematics(ellipticity_a=0.05, ellipticity_angle_a_deg=20.0, dfwhm_b_arcmin=3.0),
        Systematics(dg=0.01, ellipticity_b=(0.02, 0.04), ellipticity_angle_b_deg=(10.0, 70.0)),
    ):
        ours = predict_fp.delta_p(sky, stats, sy, spread=False)
        shared = predict.delta_p(sky, alone.h, sy, Instrument())
        assert np.max(np.abs(ours - shared)[seen]) < 1e-12 * np.max(np.abs(shared))


@pytest.mark.parametrize("repeats", [(0.0,), (0.0, 90.0)])
def test_it_follows_the_tod_of_every_pair_in_every_band(deep, repeats):
    """Each pair on its own samples (engine.simulate_focalplane, the sky read exactly there),
    binned into one map, against the prediction from each pair's own h_n: the leaked pseudo-C_BB
    within 10 % in every band 40 <= ell <= 2 Nside (measured 0-6 %; the beams 1-3 %) for a gain
    and a pointing offset drawn per pair, and for an elliptical and a wider beam (the sky read
    exactly through each detector's beam, predicted through each pair's h_-2..h_4), with and
    without the 0/90 repeat, on the pixels whose 2x2 system is
    well conditioned (rcond > 0.05: below it, the map-maker amplifies the hits' in-pixel scatter,
    which the pixel average does not hold)."""
    fp, schedules, stats, sky = deep
    schedule = schedules[repeats]
    ref = engine.simulate_focalplane(sky, schedule, fp, Systematics(), evaluation="exact")
    mask = (ref.rcond > 0.05).astype(float)
    footprint = spectra.as_footprint(mask)
    assert mask.sum() > 0.75 * np.count_nonzero(stats[repeats].combined.hits)  # 82-89 %
    for sy in (
        Systematics(dg=Spread(0.0, 0.01), seed=1),
        Systematics(rho_arcmin=Spread(1.0, 0.5), seed=2),
        Systematics(**BEAMS),
    ):
        tod = engine.simulate_focalplane(sky, schedule, fp, sy, evaluation="exact")
        d_qu = np.array([tod.q - ref.q, tod.u - ref.u])
        measured = _bb(footprint, d_qu[0] + 1j * d_qu[1])
        predicted = _bb(footprint, predict_fp.delta_p(sky, stats[repeats], sy))
        assert np.all(np.abs(predicted / measured - 1) < 0.10), (sy, predicted / measured)


def _pointing_leak(sky, schedule, fp, sy):
    """A pointing offset's leaked pseudo-C_BB in the TOD (the sky read exactly at every sample),
    and its prediction to first and to second order in rho."""
    ref, tod = (
        engine.simulate_focalplane(sky, schedule, fp, s, evaluation="exact")
        for s in (Systematics(), sy)
    )
    footprint = spectra.as_footprint((ref.rcond > 0.05).astype(float))
    stats = scanstats.characterise_focalplane(schedule, fp, NSIDE, per_pair=True)
    offsets = scanstats.centroid_moments(schedule, NSIDE, focalplane=fp)
    first, both = (
        _bb(footprint, predict_fp.delta_p(sky, stats, sy, offsets=offsets, second_order=second))
        for second in (False, True)
    )
    return _bb(footprint, (tod.q - ref.q) + 1j * (tod.u - ref.u)), first, both


@pytest.mark.parametrize("pairs", ["on the axis", "hexagon"])
def test_a_pointing_offsets_second_order_is_what_0_180_leaves(deep, pairs):
    """On the axis 0/180 cancels a pointing offset's first order (h_1, h_3) to rounding; what the
    TOD leaks is its second order in rho (d^2 T turned by the offset's angle through h_0, dbar d T
    and conj(d^2 T) through h_2 and h_4, each with the coordinate step's cot(theta) terms and its
    change across the pixel), which delta_p(..., second_order=True) predicts within 3 % in every
    band 40 <= ell <= 2 Nside (measured 1.003-1.013 for 10 arcmin). On the hexagon, whose pairs
    see other pixels after the turn, 0/180 leaves the first order, and the second takes its
    prediction from 1.00-1.02 to 1.000-1.006 for 10 +- 5 arcmin."""
    hexagon, schedules, _, sky = deep
    fp = focalplane.on_axis((0.0, 45.0)) if pairs == "on the axis" else hexagon
    sy = (
        Systematics(rho_arcmin=10.0, chi_deg=30.0)
        if pairs == "on the axis"
        else Systematics(rho_arcmin=Spread(10.0, 5.0), chi_deg=Spread(0.0, 90.0), seed=3)
    )
    schedule = dataclasses.replace(schedules[(0.0,)], repeat_boresight_deg=(0.0, 180.0))
    measured, first, both = _pointing_leak(sky, schedule, fp, sy)
    assert np.all(np.abs(both / measured - 1) < 0.03), both / measured
    if pairs == "on the axis":
        assert np.all(first < 1e-20 * measured), first / measured
    else:
        assert np.all(np.abs(both / measured - 1) < 0.01), both / measured


def test_a_pointing_offsets_second_order_has_the_sign_that_brings_the_tod(deep):
    """The sign of the second order, which 0/180's test cannot see (it leaks in power alone):
    a 40 arcmin offset at chi = 100 deg without rotation, where the second order's cross term
    with the first is large, goes from 1.02-1.12 of the TOD to 1.02 with it (the other sign
    would give 1.03-1.26)."""
    _, schedules, _, sky = deep
    fp, sy, schedule = (
        focalplane.on_axis((0.0, 45.0)),
        Systematics(rho_arcmin=40.0, chi_deg=100.0),
        schedules[(0.0,)],
    )
    measured, first, both = _pointing_leak(sky, schedule, fp, sy)
    assert np.all(np.abs(both / measured - 1) < 0.03), both / measured
    assert np.max(np.abs(first / measured - 1)) > 0.08, first / measured


@pytest.mark.slow
def test_the_expectation_is_the_mean_over_the_pairs_draws(deep):
    """expected_leak_bb (coherent + scattered) against the mean of the predictions of 600 drawn
    focal planes, within 3 standard errors of that mean (about 2 % here) in every band; the
    scattered part is most of it for a gain of mean 0.002 and rms 0.01."""
    fp, _, stats, sky = deep
    one = stats[(0.0, 90.0)]
    mask = (one.combined.hits > 0).astype(float)
    footprint = spectra.as_footprint(mask)
    for make in (
        lambda seed: Systematics(dg=Spread(0.002, 0.01), seed=seed),
        lambda seed: Systematics(rho_arcmin=Spread(1.0, 0.5), leak=Spread(0.0, 0.01), seed=seed),
    ):
        coherent, scattered = predict_fp.expected_leak_bb(sky, one, make(0), mask, LMAX)
        expected = spectra.bin_spectrum(coherent + scattered, EDGES)[1]
        draws = np.array(
            [_bb(footprint, predict_fp.delta_p(sky, one, make(s))) for s in range(600)]
        )
        error = draws.std(axis=0) / np.sqrt(len(draws))
        assert np.all(np.abs(draws.mean(axis=0) - expected) < 3 * error), (
            draws.mean(axis=0) / expected
        )
        assert np.all(error < 0.04 * expected)  # the test can see a 12 % error
    assert np.all(spectra.bin_spectrum(scattered, EDGES)[1] > 0)


def test_what_it_does_not_cover_is_refused(deep):
    fp, _, stats, sky = deep
    one = stats[(0.0,)]
    mask = (one.combined.hits > 0).astype(float)
    with pytest.raises(ValueError, match="pol_angle_deg drawn per pair"):
        predict_fp.expected_leak_bb(
            sky, one, Systematics(pol_angle_deg=Spread(0.0, 1.0)), mask, LMAX
        )
    with pytest.raises(ValueError, match="ellipticity_a drawn per pair"):
        predict_fp.expected_leak_bb(
            sky, one, Systematics(ellipticity_a=Spread(0.05, 0.01)), mask, LMAX
        )
    bare = dataclasses.replace(one, observed_pair_h=None, observed_pair_hits=None)
    with pytest.raises(ValueError, match="per-pair maps"):
        predict_fp.delta_p(sky, bare, Systematics(dg=0.01))
    behind = dataclasses.replace(one, hwp=HWP("continuous", frequency_hz=0.37))
    with pytest.raises(ValueError, match="moments behind it: characterise with per_pair and hwp"):
        predict_fp.delta_p(sky, behind, Systematics(dg=0.01))


def test_its_sky_expectation_on_the_axis_is_the_shared_moments_one():
    """Pairs on the axis: the focal plane's exact expected leaked and total residual (coherent +
    scattered, fields read as the engine interpolates them, with the h_0 scatter) equal
    predict.expected_residual of the boresight's h_n with the coefficients' moments, to rounding;
    with beams too, their h_0 term's scatter included (a gain given as numbers: with a drawn one
    the on-axis beams take the draw's gain and the focal plane the mean, a term of second order)."""
    schedule = toast_schedule()
    theory = load_spectra()
    stats = scanstats.characterise_focalplane(
        schedule, focalplane.on_axis((0.0, 45.0)), NSIDE, per_pair=True
    )
    alone = scanstats.characterise_schedule(schedule, NSIDE)
    mask = (alone.hits > 0).astype(float)
    for sy in (
        Systematics(dg=0.01, ellipticity_b=0.03, ellipticity_angle_b_deg=40.0, dfwhm_a_arcmin=5.0),
        Systematics(dg=Spread(0.002, 0.01), leak=0.003, seed=1),
        Systematics(rho_arcmin=Spread(1.0, 0.5), chi_deg=20.0, pol_angle_deg=0.3, seed=2),
    ):
        ours = predict_fp.expected_residual(stats, mask, sy, theory, 120.0, lmax=LMAX)
        shared = predict.expected_residual(
            alone.h, mask, sy, theory, 120.0, lmax=LMAX, instrument=Instrument(), hits=alone.hits
        )
        for mine, theirs in ((ours.leaked, shared.leaked), (ours.residual, shared.residual)):
            assert np.max(np.abs(mine - theirs)[2:]) < 1e-9 * np.max(np.abs(theirs))
        if not sy.has_beams:  # the drawn cases' scattered parts count: both parts are tested
            assert np.all(ours.scattered[40:] > 0.01 * ours.leaked[40:])


@pytest.mark.slow
def test_read_exactly_its_offsets_on_the_axis_are_the_shared_moments_ones():
    """Pairs on the axis, the sky read exactly at every sample: the focal plane's expectation with
    each pair's samples' offsets from their pixel centres equals predict.expected_residual with
    the boresight's, to rounding, for a drawn pointing with a gain and for beams; the offsets
    move it by more than 1 % in some band, so they are tested."""
    schedule = toast_schedule()
    theory = load_spectra()
    pairs = focalplane.on_axis((0.0, 45.0))
    stats = scanstats.characterise_focalplane(schedule, pairs, NSIDE, per_pair=True)
    alone = scanstats.characterise_schedule(schedule, NSIDE)
    mask = (alone.hits > 0).astype(float)
    offsets = scanstats.centroid_moments(schedule, NSIDE, focalplane=pairs)
    shared_offsets = scanstats.centroid_moments(schedule, NSIDE)
    for sy in (
        Systematics(dg=0.01, rho_arcmin=Spread(1.0, 0.5), chi_deg=20.0, seed=2),
        Systematics(ellipticity_b=0.03, ellipticity_angle_b_deg=40.0, dfwhm_a_arcmin=5.0),
    ):
        ours, without = (
            predict_fp.expected_residual(
                stats, mask, sy, theory, 60.0, lmax=LMAX, evaluation="exact", offsets=o
            )
            for o in (offsets, None)
        )
        shared = predict.expected_residual(
            alone.h, mask, sy, theory, 60.0, lmax=LMAX, instrument=Instrument(),
            hits=alone.hits, evaluation="exact", offsets=shared_offsets,
        )  # fmt: skip
        for mine, theirs in ((ours.leaked, shared.leaked), (ours.residual, shared.residual)):
            assert np.max(np.abs(mine - theirs)[2:]) < 1e-9 * np.max(np.abs(theirs))
        moved = (
            spectra.bin_spectrum(ours.leaked, EDGES)[1]
            / spectra.bin_spectrum(without.leaked, EDGES)[1]
        )
        assert np.max(np.abs(moved - 1)) > 0.01, moved


@pytest.mark.slow
@pytest.mark.parametrize(
    "sy",
    [
        Systematics(dg=Spread(0.002, 0.01), rho_arcmin=Spread(1.0, 0.5), seed=0),
        Systematics(dg=Spread(0.002, 0.01), **BEAMS, seed=0),
    ],
    ids=["gain and pointing", "gain and beams"],
)
def test_its_sky_expectation_is_the_mean_over_skies_of_the_per_sky_one(deep, sy):
    """Off the axis (7-pixel, 20 deg hexagon, H_4 != 0): the exact expectation over skies and
    draws, fields at the pixel centres, against the mean over 64 skies of expected_leak_bb (the
    real-space expectation over the draws of one sky, itself checked against 600 drawn focal
    planes above): the coherent and scattered parts each within 3 standard errors of that mean
    in every band 40 <= ell <= 2 Nside, and that mean good to 6 % (so a 20 % error shows). With
    the beams, 99 % of the coherent part is theirs."""
    fp, _, stats, _ = deep
    theory = load_spectra()
    one = stats[(0.0, 90.0)]
    rcond = predict_fp.rcond(one)
    mask = (rcond > predict_fp.RCOND_EXPECTATION).astype(float)
    assert np.median(rcond[mask > 0]) < 0.9  # H_4 > 0.05 mostly: its conjugate terms count
    expected = predict_fp.expected_residual(
        one, mask, sy, theory, 450.0, lmax=LMAX, evaluation=None
    )
    whole = predict_fp.expected_residual(
        one, (rcond > 0).astype(float), sy, theory, 450.0, lmax=LMAX, evaluation=None
    )  # near-singular pixels are invalid: the same as masking them
    assert np.allclose(whole.leaked, expected.leaked, rtol=1e-12, atol=0)
    skies = [
        make_sky(SkyConfig(nside=NSIDE, lmax=LMAX, fwhm_arcmin=450.0, seed=s)) for s in range(64)
    ]
    per_sky = np.array(
        [predict_fp.expected_leak_bb(sky, one, sy, mask, LMAX, spread=False) for sky in skies]
    )  # (skies, 2, lmax + 1)
    binned = spectra.bin_spectrum(per_sky.reshape(-1, LMAX + 1), EDGES)[1].reshape(
        len(skies), 2, -1
    )
    mean, error = binned.mean(axis=0), binned.std(axis=0) / np.sqrt(len(skies))
    for k, part in enumerate((expected.coherent.leaked, expected.scattered)):
        want = spectra.bin_spectrum(part, EDGES)[1]
        assert np.all(np.abs(mean[k] - want) < 3 * error[k]), (k, mean[k] / want)
        assert np.all(error[k] < 0.06 * want)


def _check_tod_mean(schedule, fp, sy, footprint, expected, *, skies, fwhm_arcmin):
    """The mean over ``skies`` TOD skies of every pair on its own samples, read exactly, against
    ``expected``: the leaked power and the total residual within 5 % or 2.5 standard errors in
    every band, the mean good to 5 %. Returns the skies' leaked pseudo-C_BB."""
    leaked, residual = [], []
    for seed in range(skies):
        sky = make_sky(SkyConfig(nside=NSIDE, lmax=LMAX, fwhm_arcmin=fwhm_arcmin, seed=100 + seed))
        maps = [
            engine.simulate_focalplane(
                sky, schedule, fp, s, evaluation="exact", rcond_min=predict_fp.RCOND_EXPECTATION
            )
            for s in (Systematics(), sy)
        ]
        ref, tod = (np.array([m.q, m.u])[:, footprint.pixels] for m in maps)
        b = [footprint.alm(d, LMAX, 2)[1] for d in (tod - ref, tod, ref)]
        leaked.append(harmonics.alm2cl(b[0]))
        residual.append(harmonics.alm2cl(b[1]) - harmonics.alm2cl(b[2]))
    for measured, predicted in ((leaked, expected.leaked), (residual, expected.residual)):
        binned = spectra.bin_spectrum(np.array(measured), EDGES)[1]
        mean, error = binned.mean(axis=0), binned.std(axis=0) / np.sqrt(len(binned))
        want = spectra.bin_spectrum(predicted, EDGES)[1]
        assert np.all(np.abs(mean - want) < np.maximum(0.05 * want, 2.5 * error)), mean / want
        assert np.all(error < 0.05 * want)
    return np.array(leaked)


@pytest.mark.slow
@pytest.mark.parametrize("repeats", [(0.0,), (0.0, 90.0)])
def test_the_beams_expectation_is_the_mean_of_16_tod_skies(deep, repeats):
    """Off the axis, an elliptical beam on every detector A and a wider one on every B: the exact
    expectation over skies (the beams' fields read exactly at the hits spread over their pixels,
    with their h_0 term's in-pixel scatter) against the mean over 16 TOD skies of every pair on
    its own samples, the leaked power and the total residual, within 5 % or 2.5 standard errors
    in every band 40 <= ell <= 2 Nside (measured 0.95-1.03, within 1.8 standard errors), with
    and without 0/90; the mean of 16 is good to 5 %, so a 15 % error shows."""
    fp, schedules, stats, _ = deep
    schedule, one = schedules[repeats], stats[repeats]
    mask = predict_fp.valid(one).astype(float)
    footprint = spectra.as_footprint(mask)
    sy = Systematics(**BEAMS)
    expected = predict_fp.expected_residual(
        one, mask, sy, load_spectra(), 450.0, lmax=LMAX, evaluation="exact"
    )
    _check_tod_mean(schedule, fp, sy, footprint, expected, skies=16, fwhm_arcmin=450.0)


@pytest.mark.slow
def test_read_exactly_the_offsets_expectation_is_the_mean_of_32_tod_skies(deep):
    """Off the axis, a pointing offset on every pair, a sky with structure at the pixel scale (30
    arcmin) read exactly at every sample: the expectation with each pair's samples' offsets from
    their pixel centres against the mean over 32 TOD skies of every pair on its own samples, the
    leaked power and the total residual within 5 % or 2.5 standard errors in every band 40 <=
    ell <= 2 Nside (measured 1.02-1.04 and 0.99-1.03), and the leaked power nearer the TOD than
    without the offsets (1.02-1.10)."""
    fp, schedules, stats, _ = deep
    schedule, one = schedules[(0.0,)], stats[(0.0,)]
    mask = predict_fp.valid(one).astype(float)
    footprint = spectra.as_footprint(mask)
    sy = Systematics(rho_arcmin=1.0, chi_deg=30.0)
    offsets = scanstats.centroid_moments(schedule, NSIDE, focalplane=fp)
    expected, without = (
        predict_fp.expected_residual(
            one, mask, sy, load_spectra(), 30.0, lmax=LMAX, evaluation="exact", offsets=o
        )
        for o in (offsets, None)
    )
    leaked = _check_tod_mean(schedule, fp, sy, footprint, expected, skies=32, fwhm_arcmin=30.0)
    mean = spectra.bin_spectrum(leaked, EDGES)[1].mean(axis=0)
    gaps = [
        np.sum(np.abs(mean / spectra.bin_spectrum(p.leaked, EDGES)[1] - 1))
        for p in (expected, without)
    ]
    assert gaps[0] < 0.6 * gaps[1], gaps


def test_a_gain_jitter_adds_the_white_power_of_each_pairs_hits():
    """A jitter of its own rms on each pair (no other systematic), on a sky of constant T so
    that E[T^2] is exact: the mean over 8 jitter draws of the TOD's leaked pseudo-C_BB at
    20 <= ell <= 64, and of its per-pixel ``|dP|^2``, against jitter_bb's white power (measured
    1.02 and 1.03), with the 2x2 solve's H_4 terms (without them the pixels' power is 1.4x
    off). expected_residual carries it as its leaked power."""
    schedule = load_schedule(str(EXAMPLES / "schedule_deep_sat.toml"))
    schedule = dataclasses.replace(schedule, sample_rate_hz=0.5, ces=schedule.ces[:12])
    fp = focalplane.hexagon(7, 20.0)
    stats = scanstats.characterise_focalplane(schedule, fp, NSIDE, per_pair=True)
    mask = predict_fp.valid(stats).astype(float)
    footprint = spectra.as_footprint(mask)
    npix, t0 = 12 * NSIDE**2, 100.0
    sky = Sky.from_maps(np.array([np.full(npix, t0), np.zeros(npix), np.zeros(npix)]), lmax=LMAX)
    jitter = Systematics(dg_jitter=(0.02, 0.01, 0.03, 0.02, 0.015, 0.025, 0.02), seed=3)
    sky_cl = np.zeros((4, LMAX + 1))
    sky_cl[0, 0] = 4 * np.pi * t0**2  # E[T^2] = t0^2
    params, _ = predict_fp.at_means(jitter, fp.n_pairs)
    shares = predict_fp.pair_shares(params, fp)
    h4 = np.einsum(
        "i,ip,ip->p",
        shares["m4"],
        stats.pair_hits / np.maximum(stats.combined.hits, 1),
        stats.pair_h[:, 4],
    )
    predicted = predict_fp.jitter_bb(stats, jitter, mask, sky_cl, shares=shares, h4=h4)
    run = dict(evaluation="exact", rcond_min=predict_fp.RCOND_EXPECTATION)
    ref = engine.simulate_focalplane(sky, schedule, fp, Systematics(), **run)
    bands, power = [], np.zeros(npix)
    for seed in range(8):
        tod = engine.simulate_focalplane(
            sky, schedule, fp, dataclasses.replace(jitter, seed=seed), **run
        )
        dp = (tod.q - ref.q) + 1j * (tod.u - ref.u)
        power += np.abs(dp) ** 2 / 8
        d = dp[footprint.pixels]
        bands.append(
            harmonics.alm2cl(footprint.alm(np.array([d.real, d.imag]), LMAX, 2)[1])[20:].mean()
        )
    bands = np.array(bands)
    se = bands.std(ddof=1) / np.sqrt(bands.size)
    assert abs(bands.mean() - predicted) < max(3 * se, 0.05 * predicted), (
        bands.mean(),
        predicted,
        se,
    )
    # the same white power from the pixels' own |dP|^2: 0.5 Omega_pix <w^2 |dP|^2>
    from_pixels = 0.5 * (4 * np.pi / npix) * np.sum(mask**2 * power) / npix
    assert from_pixels == pytest.approx(predicted, rel=0.06)
    expected = predict_fp.expected_residual(
        stats, mask, jitter, load_spectra(), 0.0, lmax=LMAX, evaluation=None
    )
    white = predict_fp.jitter_bb(
        stats, jitter, mask, smoothed_spectra(load_spectra(), 0.0, LMAX), shares=shares, h4=h4
    )
    np.testing.assert_allclose(expected.leaked, white, rtol=1e-12)  # the jitter's alone
    assert np.all(expected.scattered == 0)
