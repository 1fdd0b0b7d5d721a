"""Analytic prediction against simulation, at Nside 512 with the paper's 7' beam."""

import numpy as np
import pytest

from boresight import coupling, engine, masks, predict, spectra
from boresight.instrument.pairs import PAPER_GAIN, PAPER_POINTING, Systematics
from boresight.scan import SyntheticScan, paper_scan
from boresight.sky import SkyConfig, make_sky

NSIDE, LMAX = 512, 300
#: Bands where the residual is far above the numerical floor and the interpolation window of the
#: simulated maps (a few per cent at ell ~ nside / 2) stays below the tolerance.
EDGES = spectra.linear_bins(40, 256, 32)
CASES = {"wide": PAPER_POINTING, "deep": PAPER_GAIN}


@pytest.fixture(scope="module")
def paper_sky(theory):
    return make_sky(SkyConfig(nside=NSIDE, lmax=3 * NSIDE - 1, fwhm_arcmin=7.0, seed=1), theory)


@pytest.fixture(scope="module")
def study(paper_sky):
    out = {}
    for survey, sysm in CASES.items():
        mask = masks.survey_mask(survey, NSIDE)
        obs = mask > 0
        scan = paper_scan(survey)
        ref = engine.simulate(paper_sky, scan, pixels=obs)
        sim = engine.simulate(paper_sky, scan, systematics=sysm, pixels=obs)
        h, _ = engine.scan_moments(scan, NSIDE, pixels=obs)
        out[survey] = dict(
            mask=mask,
            obs=obs,
            ref=ref,
            sim=sim,
            h=h,
            couplings=coupling.mask_coupling(mask, LMAX, band=3 * NSIDE - 1),
        )
    return out


@pytest.mark.parametrize("survey", ["wide", "deep"])
@pytest.mark.slow
def test_map_level_prediction_within_10_percent(survey, study, paper_sky):
    s = study[survey]
    dp = predict.delta_p(paper_sky, s["h"], CASES[survey]) * s["obs"]
    qu_pred = s["ref"].qu + np.array([dp.real, dp.imag])
    want = spectra.residual_bb(s["sim"].qu, s["ref"].qu, s["mask"], LMAX)
    got = spectra.residual_bb(qu_pred, s["ref"].qu, s["mask"], LMAX)
    _, w = spectra.bin_spectrum(want, EDGES)
    _, g = spectra.bin_spectrum(got, EDGES)
    assert np.all(np.abs(g / w - 1) < 0.10), g / w


@pytest.mark.parametrize("survey", ["wide", "deep"])
@pytest.mark.slow
def test_cl_level_prediction_within_10_percent(survey, study, paper_sky, theory):
    """Eq. 10 prediction against the leaked-power (auto) part of the simulated residual.

    The cross part 2 Re<B, dB> has zero mean and is one realisation's scatter, which an expectation
    cannot follow; the prediction uses the patch's own temperature spectrum (predict.local_cl).
    """
    s = study[survey]
    local = predict.local_cl(paper_sky, s["mask"], LMAX)
    prediction = predict.Prediction(theory, s["couplings"], 7.0, field_cl=local)
    pred = predict.residual_pseudo_bb(s["h"], s["mask"], prediction, CASES[survey])
    auto = spectra.residual_bb_parts(s["sim"].qu, s["ref"].qu, s["mask"], LMAX)[1]
    _, w = spectra.bin_spectrum(auto, EDGES)
    _, g = spectra.bin_spectrum(pred, EDGES)
    assert np.all(np.abs(g / w - 1) < 0.10), g / w


def test_ideal_rotation_with_zero_polarisation_is_at_the_floor(theory):
    """Q = U = 0: gain + 90 deg cancels to rounding; pointing + 180 deg leaves only O(rho^2)."""
    nside, lmax = 128, 200
    s0 = make_sky(
        SkyConfig(nside=nside, lmax=383, fwhm_arcmin=30.0, seed=2, polarised=False),
        theory,
    )
    mask = masks.survey_mask("deep", nside)
    # to lmax only: above it the prediction would take the theory's EE, which this sky has not
    couplings = coupling.mask_coupling(mask, lmax)
    zero = np.zeros((2, 12 * nside**2))
    for survey, sysm, angle, floor in (
        ("deep", PAPER_GAIN, 90, 1e-25),
        ("wide", PAPER_POINTING, 180, 1e-4),
    ):
        # Exact evaluation: bilinear interpolation has kinks that turn T(x+d) + T(x-d) - 2 T(x)
        # into a first-order-in-rho floor; the band-limited sky leaves the true O(rho^2).
        base = engine.simulate(s0, paper_scan(survey), systematics=sysm, evaluation="exact")
        pbr_scan = paper_scan(survey, angle)
        pbr = engine.simulate(s0, pbr_scan, systematics=sysm, evaluation="exact")
        no_pbr = spectra.residual_bb(base.qu, zero, mask, lmax)[2:].max()
        sim = np.abs(spectra.residual_bb(pbr.qu, zero, mask, lmax)[2:]).max()
        h, _ = engine.scan_moments(pbr_scan.one_repeat(), nside)
        # The sky's own (zero) polarisation spectrum: theory EE would feed the h_4 P* term.
        local = predict.local_cl(s0, mask, lmax)
        pred = predict.residual_pseudo_bb(
            h,
            mask,
            predict.Prediction(theory, couplings, 30.0, field_cl=local),
            sysm,
            rotations_deg=pbr_scan.rotations_deg,
        )
        pred = np.abs(pred[2:]).max()
        # Gain: exact cancellation, rounding of ~1e-16 squared. Pointing: the second-order term
        # relative to the first is ~ rho l_beam / 2 ~ 0.004, i.e. ~2e-5 in power.
        assert sim < floor * no_pbr, survey
        assert pred < 1e-25 * no_pbr, survey


@pytest.mark.parametrize("alpha", [45.0, 70.0, 89.0])
def test_spectrum_suppression_follows_cos2(alpha, theory):
    """Two-angle schedule (0, alpha): predicted gain C_ell scales by cos^2(alpha) exactly."""
    nside = 32
    mask = masks.survey_mask("wide", nside)
    sysm = Systematics(dg=(0.01, 0.01))
    ratios = []
    h, _ = engine.scan_moments(SyntheticScan(n_phi=3, range_rad=0.8), nside)
    for rot in ((0.0,), (0.0, alpha)):
        cl = predict.systematic_cl(h, mask, sysm, theory, 60, fwhm_arcmin=7.0, rotations_deg=rot)
        np.testing.assert_array_equal(cl[0], cl[1])  # no beam pairs: E and B share equally
        ratios.append(cl[1, 2:])
    assert np.allclose(ratios[1] / ratios[0], np.cos(np.radians(alpha)) ** 2, rtol=1e-10)


def test_coherent_power_is_numpys_bincount_of_the_weighted_h_for_any_thread_count():
    """The one-pass kernel against the plain numpy route (|h|^2 w summed, w h summed per block by
    bincount), with apodized weights and Nside below the block size (no blocks)."""
    from boresight._util.threads import numba_threads

    rng = np.random.default_rng(8)
    for nside, apodize in ((128, True), (4, False)):
        mask = masks.survey_mask("deep", nside)
        mask = masks.apodize(mask, 5.0) if apodize else mask
        h = rng.standard_normal(mask.size) + 1j * rng.standard_normal(mask.size)
        blocks = predict.PixelBlocks(mask)
        obs = np.flatnonzero(mask)
        w, ho = mask[obs], h[obs]
        total = np.sum(w * np.abs(ho) ** 2) / w.sum()
        coherent = total
        if blocks.parent is not None:
            sums = np.bincount(blocks.parent, w * ho.real) + 1j * np.bincount(
                blocks.parent, w * ho.imag
            )
            weight = np.bincount(blocks.parent, w)
            used = weight > 0
            coherent = np.sum(np.abs(sums[used]) ** 2 / weight[used]) / w.sum()
        got = []
        for threads in (1, 2):
            with numba_threads(threads):
                got.append(blocks.coherent_power(h))
        assert got[0] == got[1]  # to the bit
        assert got[0] == pytest.approx((total, coherent), rel=1e-14)
        assert blocks.parent is None or coherent < 0.5 * total  # white h: blocks average it out


def test_coherent_power_of_constant_and_white_h():
    """A constant h_n is all coherent; white h_n keeps 1 / block^2 of its power after averaging
    in blocks of block^2 pixels (the mask's edge blocks hold fewer pixels, so a little more)."""
    nside = 256
    mask = masks.survey_mask("deep", nside)
    blocks = predict.PixelBlocks(mask)
    total, coherent = blocks.coherent_power(np.full(mask.size, 0.3 - 0.4j))
    assert total == pytest.approx(0.25, rel=1e-13) and coherent == pytest.approx(0.25, rel=1e-13)
    rng = np.random.default_rng(5)
    white = rng.standard_normal(mask.size) + 1j * rng.standard_normal(mask.size)
    total, coherent = blocks.coherent_power(white)
    n_obs = np.count_nonzero(mask)
    assert total == pytest.approx(2.0, abs=5 * 2 / np.sqrt(n_obs))
    # expectation: 2 sum_b (sum_{i in b} w_i^2 / W_b) / sum w, from E[h_i h_j*] = 2 delta_ij
    w = mask[blocks.obs]
    expected = 2 * np.sum(
        np.bincount(blocks.parent, w**2)[blocks.used] / blocks.block_weight[blocks.used]
    )
    expected /= w.sum()
    n_blocks = np.count_nonzero(blocks.used)
    assert coherent == pytest.approx(expected, rel=5 / np.sqrt(n_blocks))
    assert 1.0 / predict.COHERENT_BLOCK**2 < expected / 2 < 1.2 / predict.COHERENT_BLOCK**2


@pytest.mark.parametrize("survey", ["wide", "deep"])
def test_angle_error_cl_prediction_from_the_maps_own_spectra(survey, study, paper_sky, theory):
    """A common angle error of 3 deg and a non-orthogonality of 1 deg, no rotation, Nside 512:
    dP = (u - 1) P with one number u, so dB = Im(u) E + (Re u - 1) B of the masked maps, and
    predict.signal_bb with the maps' own masked EE, BB, EB (local_cl) gives the leaked power and
    the whole residual (auto plus the cross part 2 Re<B, dB>, one realisation's <B, E>) alike;
    the coupling of full-sky spectra gives only their average (0.91-1.04 of the leaked power
    before). Pixel-centre prediction of randomly placed hits: the maps' window leaves the last
    bands up to 8 % high."""
    s = study[survey]
    sysm = Systematics(pol_angle_deg=3.0, nonortho_deg=1.0)
    sim = engine.simulate(paper_sky, paper_scan(survey), systematics=sysm, pixels=s["obs"])
    local = predict.local_cl(paper_sky, s["mask"], LMAX)
    cross, auto = spectra.residual_bb_parts(sim.qu, s["ref"].qu, s["mask"], LMAX)
    for leaked, simulated in ((True, auto), (False, auto + cross)):
        prediction = predict.Prediction(theory, s["couplings"], 7.0, local, leaked=leaked)
        pred = predict.residual_pseudo_bb(s["h"], s["mask"], prediction, sysm)
        ratio = spectra.bin_spectrum(pred, EDGES)[1] / spectra.bin_spectrum(simulated, EDGES)[1]
        ratio = spectra.bin_spectrum(pred, EDGES)[1] / spectra.bin_spectrum(simulated, EDGES)[1]
        assert np.all(np.abs(ratio - 1) < 0.1), (leaked, ratio)


@pytest.mark.parametrize(
    "survey, sysm", [("deep", PAPER_GAIN), ("wide", PAPER_POINTING), ("deep", PAPER_POINTING)]
)
def test_cl_prediction_with_the_interpolation_window_to_2_nside(survey, sysm, theory):
    """Random in-pixel hits read the maps by bilinear interpolation: with
    predict.interpolation_window (the value's window for T and P, the gradient's for pointing) the
    C_ell-level prediction follows the simulated leaked power within 10 % in every band of 32
    multipoles from 40 to 2 Nside (Nside 256, 14' beam; the value's window alone left deep
    pointing 19 % high); without a window the prediction overshoots the last band by 1.4x or
    more."""
    nside, lmax = 256, 512
    sky = make_sky(SkyConfig(nside=nside, lmax=3 * nside - 1, fwhm_arcmin=14.0, seed=1), theory)
    mask = masks.survey_mask(survey, nside)
    obs = mask > 0
    scan = paper_scan(survey)
    h, crossings = engine.scan_moments(scan, nside, pixels=obs)
    ref = engine.simulate(sky, scan, pixels=obs)
    sim = engine.simulate(sky, scan, systematics=sysm, pixels=obs)
    auto = spectra.residual_bb_parts(sim.qu, ref.qu, mask, lmax)[1]
    couplings = coupling.mask_coupling(mask, lmax, band=3 * nside - 1)
    local = predict.local_cl(sky, mask, lmax)
    prediction = predict.Prediction(theory, couplings, 14.0, local, leaked=True)
    edges = spectra.linear_bins(40, lmax, 32)
    sim_bands = spectra.bin_spectrum(auto, edges)[1]
    ratio = {}
    for window in (True, False):
        pred = predict.residual_pseudo_bb(
            h,
            mask,
            prediction,
            sysm,
            crossings=crossings,
            in_pixel="random",
            interpolated=window,
        )
        ratio[window] = spectra.bin_spectrum(pred, edges)[1] / sim_bands
    assert np.all(np.abs(ratio[True] - 1) < 0.10), ratio[True]
    assert ratio[False][-1] > 1.4


def test_the_prediction_counts_sky_above_lmax_that_the_mask_mixes_down(theory):
    """A polarisation-angle error on the deep mask, Nside 64, the spectra to lmax 128 and the sky
    to 191: the mean of 64 TOD skies against the theory prediction. With the coupling cut at lmax
    the top band read 0.61 of the simulation (the reviewer saw 0.94 at Nside 128); from the
    sky's band limit every band agrees within 5 % or 3 standard errors (measured 0.98-1.00)."""
    nside, lmax, band = 64, 128, 191
    mask = masks.survey_mask("deep", nside)
    obs = mask > 0
    sysm = Systematics(pol_angle_deg=1.0)
    scan = SyntheticScan(n_phi=4, range_rad=0.7, in_pixel="centre", seed=1)
    edges = spectra.linear_bins(40, lmax, 22)
    sims = []
    for seed in range(64):
        s = make_sky(SkyConfig(nside=nside, lmax=band, fwhm_arcmin=60.0, seed=seed), theory)
        ref = engine.simulate(s, scan, pixels=obs)
        sim = engine.simulate(s, scan, systematics=sysm, pixels=obs)
        sims.append(spectra.bin_spectrum(spectra.residual_bb_parts(sim.qu, ref.qu, mask, lmax)[1],
                                         edges)[1])  # fmt: skip
    mean = np.mean(sims, axis=0)
    se = np.std(sims, axis=0, ddof=1) / np.sqrt(len(sims))
    h, crossings = engine.scan_moments(scan, nside, pixels=obs)

    def predicted(coupling_band):
        c = coupling.mask_coupling(mask, lmax, band=coupling_band)
        prediction = predict.Prediction(theory, c, 60.0, leaked=True)
        pred = predict.residual_pseudo_bb(h, mask, prediction, sysm, crossings=crossings)
        return spectra.bin_spectrum(pred, edges)[1]

    wide = predicted(band)
    assert np.all(np.abs(wide - mean) < np.maximum(0.05 * mean, 3 * se)), wide / mean
    assert predicted(lmax)[-1] < 0.8 * mean[-1]
