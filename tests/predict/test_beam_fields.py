"""The beams' terms of the C_ell-level prediction against simulation."""

import numpy as np
import pytest

from boresight import coupling, engine, masks, predict, spectra
from boresight.instrument.pairs import Systematics
from boresight.scan import paper_scan
from boresight.sky import SkyConfig, make_sky


@pytest.mark.parametrize(
    "survey, sysm",
    [("deep", Systematics(dfwhm_b_arcmin=0.5)), ("wide", Systematics(ellipticity_b=0.03))],
)
@pytest.mark.slow
def test_beam_cl_prediction_within_10_percent(survey, sysm, theory):
    """Nside 256, the paper's scans (random in-pixel hits): the C_ell-level prediction of the
    leaked power, with the hits' spread over their pixels (predict.hit_spread_window), against
    the simulation in every band 40 <= ell <= 256. (Both systematics on both masks at Nside 512:
    bench/bench_beams.py.)"""
    nside, lmax = 256, 300
    sky = make_sky(SkyConfig(nside=nside, lmax=3 * nside - 1, fwhm_arcmin=14.0), theory)
    mask = masks.survey_mask(survey, nside)
    obs = mask > 0
    scan = paper_scan(survey)
    ref = engine.simulate(sky, scan, pixels=obs)
    h, crossings = engine.scan_moments(scan.one_repeat(), nside, pixels=obs)
    couplings = coupling.mask_coupling(mask, lmax, band=3 * nside - 1)
    local = predict.local_cl(sky, mask, lmax, beams=True)
    edges = spectra.linear_bins(40, 256, 36)
    sim = engine.simulate(sky, scan, systematics=sysm, pixels=obs)
    auto = spectra.residual_bb_parts(sim.qu, ref.qu, mask, lmax)[1]
    prediction = predict.Prediction(theory, couplings, 14.0, field_cl=local, leaked=True)
    pred = predict.residual_pseudo_bb(
        h, mask, prediction, sysm, crossings=crossings, in_pixel="random"
    )
    ratio = spectra.bin_spectrum(pred, edges)[1] / spectra.bin_spectrum(auto, edges)[1]
    assert np.all(np.abs(ratio - 1) < 0.10), ratio


def test_beam_terms_are_read_exactly_and_pairs_keep_their_power(theory):
    """With leak and pointing on too, the beams' terms are flagged as read exactly at the hits
    and the others not. A pair h_n G_n + h_-n G_-n splits 2 (P(G_n) + P(G_-n)) between E and B
    (|a + b|^2 + |a - b|^2 = 2 |a|^2 + 2 |b|^2): the pairing moves power, never makes it."""
    sysm = Systematics(dg=0.01, leak=0.01, rho_arcmin=0.3, ellipticity_b=0.02, dfwhm_b_arcmin=0.2)
    lmax = 60
    coefs = predict.coefficients(sysm)
    beam = predict.beam_filters(sysm, None, (0.0,), 30.0, lmax)
    cl = predict.beam_spectra(theory, lmax, 30.0)
    tt, ee, bb = predict.field_spectra(theory, lmax, 30.0)
    terms = predict.leak_terms(coefs, sysm, tt, ee + bb, beam=beam, beam_cl=cl)
    assert [(t.n, t.exact) for t in terms][:5] == [
        (2, True),
        (4, False),
        (2, False),
        (1, False),
        (3, False),
    ]
    assert {t.n for t in terms[5:]} == {
        4,
        6,
    }  # odd moments vanish for Gaussian beams and all(t.exact for t in terms[5:])
    for term in terms[5:]:
        n = term.n
        alone = predict.beam_power(beam[n], cl) + predict.beam_power(beam[-n], cl)
        np.testing.assert_allclose(term.cl_e + term.cl_b, 2 * alone, rtol=1e-12, atol=1e-30)
    g2 = beam[2] + np.array([coefs.t2, 0, 0])[:, None]
    both = predict.beam_power(g2, cl) + predict.beam_power(beam[-2], cl)
    np.testing.assert_allclose(terms[0].cl_e + terms[0].cl_b, 2 * both, rtol=1e-12)
