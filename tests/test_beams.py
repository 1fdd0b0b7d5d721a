"""Beam width and ellipticity (issue 14): ducc0's totalconvolve against healpy's Gaussian beam, a
second-order Taylor expansion of the sky, and the analytic h_n prediction."""

import healpy as hp
import numpy as np
import pytest

from boresight import (
    beams,
    config,
    coupling,
    engine,
    harmonics,
    masks,
    predict,
    sky,
    spectra,
)
from boresight.constants import ARCMIN, DEG
from boresight.instrument import Systematics
from boresight.scan import SyntheticScan, paper_scan

CENTRED = SyntheticScan(n_phi=4, range_rad=0.7, in_pixel="centre", seed=3)


def _ell_m(lmax, k):
    return hp.Alm.getidx(lmax, np.arange(k, lmax + 1), k)


def test_a_circular_beam_is_healpys_gaussian_beam():
    """T: healpy.blm_gauss to the profile's curvature (sigma^2 ~ 5e-5); E, B: healpy's polarised
    coefficients times -sqrt(2) (its convention answers -(Q cos 2psi + U sin 2psi) / sqrt(2)),
    to the polarised window's exp(2 sigma^2) factor."""
    lmax, fwhm = 200, 1.0 * DEG
    ours = beams.beam_alm(beams.Beam(fwhm), lmax, 4)
    ref = hp.blm_gauss(fwhm, lmax, pol=True)
    np.testing.assert_allclose(ours[0, _ell_m(lmax, 0)], ref[0, : lmax + 1], atol=3e-4 * 0.0798)
    idx = _ell_m(lmax, 2)
    ratio = ours[1:, idx] / ref[1:, hp.Alm.getidx(lmax, np.arange(2, lmax + 1), 2)]
    np.testing.assert_allclose(ratio, -np.sqrt(2), rtol=3e-4)
    for k in (1, 3, 4):
        assert np.abs(ours[:, _ell_m(lmax, k)]).max() < 1e-14


@pytest.fixture(scope="module")
def smooth_field():
    """A band-limited T (ell <= 30), its alm and, at 40 points, its covariant Hessian in the
    (e_theta, e_phi) frame by central differences of exact evaluation."""
    lmax = 64
    rng = np.random.default_rng(3)
    n = harmonics.n_alm(lmax)
    ell = harmonics.ell_of_alm(lmax)
    alm = rng.normal(size=n) + 1j * rng.normal(size=n)
    alm[: lmax + 1] = alm[: lmax + 1].real
    alm[(ell > 30) | (ell < 2)] = 0
    th, ph = rng.uniform(0.5, 2.6, 40), rng.uniform(0, 2 * np.pi, 40)
    psi = rng.uniform(-np.pi, np.pi, 40)

    def t(dt, dp):
        return harmonics.evaluate(alm, th + dt, (ph + dp) % (2 * np.pi), epsilon=1e-13)

    h = 1e-3
    t0 = t(0, 0)
    d_t = (t(h, 0) - t(-h, 0)) / (2 * h)
    d_p = (t(0, h) - t(0, -h)) / (2 * h)
    d_tt = (t(h, 0) - 2 * t0 + t(-h, 0)) / h**2
    d_pp = (t(0, h) - 2 * t0 + t(0, -h)) / h**2
    d_tp = (t(h, h) - t(h, -h) - t(-h, h) + t(-h, -h)) / (4 * h * h)
    s, c = np.sin(th), np.cos(th)
    hessian = (d_tt, d_pp / s**2 + c / s * d_t, (d_tp - c / s * d_p) / s)
    return dict(alm=alm, lmax=lmax, theta=th, phi=ph, psi=psi, hessian=hessian)


def _convolved(field, beam, nominal):
    """totalconvolve of T alone with (beam - nominal beam) at the field's points."""
    import ducc0

    diff = beams.beam_alm(beam, field["lmax"], 8) - beams.beam_alm(nominal, field["lmax"], 8)
    diff, kmax = beams.truncate(diff[:1], field["lmax"], 8)
    conv = ducc0.totalconvolve.Interpolator(
        field["alm"][None], diff, False, field["lmax"], kmax, epsilon=1e-12, nthreads=1
    )
    ptg = np.stack([field["theta"], field["phi"], field["psi"]], axis=1)
    return conv.interpol(ptg)[0]


def _expansion(field, sigma, e, angle):
    """1/2 sigma^2 e^2 nabla^2 T + sigma^2 e [cos 2b (T_tt - T_pp) + 2 sin 2b T_tp], b = psi +
    angle: the second-order Taylor expansion of an elliptical beam less the circular one."""
    tt, pp, tp = field["hessian"]
    b = field["psi"] + angle
    return 0.5 * sigma**2 * e**2 * (tt + pp) + sigma**2 * e * (
        np.cos(2 * b) * (tt - pp) + 2 * np.sin(2 * b) * tp
    )


def test_totalconvolve_agrees_with_the_second_order_expansion(smooth_field):
    """The major axis lies at ``angle`` from the polarisation axis, in the sense of chi; the
    remainder is the fourth-order k = 2 term sigma^4 e l^4, so it halves with the ellipticity."""
    fwhm = 0.3 * DEG
    sigma = fwhm / beams.FWHM_PER_SIGMA
    nominal = beams.Beam(fwhm)
    misfit = []
    for e in (0.2, 0.1):
        conv = _convolved(smooth_field, beams.Beam(fwhm, e, 0.5), nominal)
        diff = conv - _expansion(smooth_field, sigma, e, 0.5)
        assert np.linalg.norm(diff) < 5e-3 * np.linalg.norm(conv)
        misfit.append(np.linalg.norm(diff))
    assert misfit[0] / misfit[1] == pytest.approx(2.0, rel=0.1)
    wrong_sense = _expansion(smooth_field, sigma, 0.2, -0.5)
    conv = _convolved(smooth_field, beams.Beam(fwhm, 0.2, 0.5), nominal)
    assert np.linalg.norm(conv - wrong_sense) > 0.5 * np.linalg.norm(conv)


def test_windows_are_nabla2_and_eth2_at_small_beams():
    """w0 -> -1/2 (sigma_X^2 (1 + e^2) - sigma^2) l (l + 1), w2 -> -sigma_X^2 e sqrt((l+2)!/(l-2)!)
    at l sigma << 1 (the harmonic forms of 1/2 a nabla^2 T and sigma^2 e eth^2 T)."""
    lmax, fwhm, e = 60, 0.2 * DEG, 0.1
    sigma = fwhm / beams.FWHM_PER_SIGMA
    w0, w2 = beams.windows(beams.Beam(1.02 * fwhm, e), fwhm, lmax)
    ell = np.arange(lmax + 1.0)
    b = np.exp(-0.5 * ell * (ell + 1) * sigma**2)
    a = (1.02 * sigma) ** 2 * (1 + e**2) - sigma**2
    np.testing.assert_allclose(w0[2:], -0.5 * a * ell[2:] * (ell[2:] + 1) * b[2:], rtol=2e-2)
    eth2 = np.sqrt((ell - 1) * ell * (ell + 1) * (ell + 2))
    np.testing.assert_allclose(w2[2:], -((1.02 * sigma) ** 2) * e * eth2[2:] * b[2:], rtol=2e-2)


def _residual(sky_, scan, systematics, **kw):
    ref = engine.simulate(sky_, scan, **kw)
    m = engine.simulate(sky_, scan, systematics=systematics, **kw)
    return (m.q - ref.q) + 1j * (m.u - ref.u)


def _predicted(sky_, scan, systematics):
    h, _ = engine.scan_moments(scan.one_repeat(), sky_.nside)
    return predict.delta_p(
        sky_, h, systematics, rotations_deg=scan.rotations_deg
    ) - predict.delta_p(sky_, h, Systematics(), rotations_deg=scan.rotations_deg)


@pytest.mark.parametrize(
    "systematics, tolerance",
    [
        (Systematics(dfwhm_b_arcmin=1.0), 1e-7),  # exact: the beam's k = 0 window
        (Systematics(dfwhm_a_arcmin=-0.5, dfwhm_b_arcmin=(0.4, 1.0)), 1e-7),
        (Systematics(ellipticity_b=0.05, ellipticity_angle_b_deg=20.0), 2e-2),  # + k = 4
        (Systematics(ellipticity_a=0.05, ellipticity_b=0.05), 1e-3),  # k = 4 of A and B cancel
    ],
)
def test_engine_beams_equal_the_analytic_map(small_sky_unpolarised, systematics, tolerance):
    dp = _residual(small_sky_unpolarised, CENTRED, systematics)
    pred = _predicted(small_sky_unpolarised, CENTRED, systematics)
    assert np.linalg.norm(dp - pred) < tolerance * np.linalg.norm(dp)


def test_the_beams_smoothing_of_p_is_a_percent_of_the_map(small_sky):
    """The prediction leaves out the beams' smoothing of P and the ellipticity's k = 4 moment:
    together 1.9 % of the residual here."""
    sysm = Systematics(dfwhm_b_arcmin=1.0, ellipticity_b=0.05)
    dp = _residual(small_sky, CENTRED, sysm)
    pred = _predicted(small_sky, CENTRED, sysm)
    assert np.linalg.norm(dp - pred) < 0.025 * np.linalg.norm(dp)


def test_width_cancels_at_90_and_ellipticity_survives_90_and_180(small_sky_unpolarised):
    """Width couples through h_2 (like gain): a 0/90 repeat removes it. Ellipticity's h_0 part
    co-rotates with the detector: 0/90 and 0/180 leave it unchanged (to its k = 4 part, e^2)."""
    width = Systematics(dfwhm_b_arcmin=1.0)
    base = np.linalg.norm(_residual(small_sky_unpolarised, CENTRED, width))
    at_90 = SyntheticScan(**{**CENTRED.__dict__, "rotations_deg": (0.0, 90.0)})
    assert np.linalg.norm(_residual(small_sky_unpolarised, at_90, width)) < 1e-8 * base
    ellipse = Systematics(ellipticity_a=0.03, ellipticity_b=0.03)
    unrotated = _residual(small_sky_unpolarised, CENTRED, ellipse)
    for angle in (90.0, 180.0):
        scan = SyntheticScan(**{**CENTRED.__dict__, "rotations_deg": (0.0, angle)})
        rotated = _residual(small_sky_unpolarised, scan, ellipse)
        assert np.linalg.norm(rotated - unrotated) < 2e-3 * np.linalg.norm(unrotated)


@pytest.mark.parametrize(
    "survey, sysm",
    [("deep", Systematics(dfwhm_b_arcmin=0.5)), ("wide", Systematics(ellipticity_b=0.03))],
)
def test_beam_cl_prediction_within_10_percent(survey, sysm, theory):
    """Nside 256, the paper's scans (random in-pixel hits): the C_ell-level prediction of the
    leaked power, with the hits' spread over their pixels (predict.hit_spread_window), against
    the simulation in every band 40 <= ell <= 256. (Both systematics on both masks at Nside 512:
    bench/bench_beams.py.)"""
    nside, lmax = 256, 300
    the_sky = sky.make_sky(sky.SkyConfig(nside=nside, lmax=3 * nside - 1, fwhm_arcmin=14.0), theory)
    mask = masks.survey_mask(survey, nside)
    obs = mask > 0
    scan = paper_scan(survey)
    ref = engine.simulate(the_sky, scan, pixels=obs)
    h, crossings = engine.scan_moments(scan.one_repeat(), nside, pixels=obs)
    couplings = coupling.coupling_matrices(mask, lmax)
    local = predict.local_cl(the_sky, mask, lmax, beams=True)
    edges = spectra.linear_bins(40, 256, 36)
    sim = engine.simulate(the_sky, scan, systematics=sysm, pixels=obs)
    auto = spectra.residual_bb_parts(sim.qu, ref.qu, mask, lmax)[1]
    pred = predict.residual_pseudo_bb(
        h,
        mask,
        couplings,
        sysm,
        theory,
        14.0,
        field_cl=local,
        crossings=crossings,
        leaked=True,
        in_pixel="random",
    )
    ratio = spectra.bin_spectrum(pred, edges)[1] / spectra.bin_spectrum(auto, edges)[1]
    assert np.all(np.abs(ratio - 1) < 0.10), ratio


@pytest.mark.parametrize(
    "table, match",
    [
        ({"dfwhm_b_arcmin": -20.0}, "FWHM"),
        ({"ellipticity_b": 1.0}, "ellipticity_b"),
        ({"ellipticity_a": -0.1}, "ellipticity_a"),
        ({"ellipticity_b": float("nan")}, "ellipticity_b"),
        ({"dfwhm_a_arcmin": float("nan")}, "dfwhm_a_arcmin"),
        ({"ellipticity_b": {"mean": 0.01, "rms": 0.5}}, "ellipticity_b"),
    ],
)
def test_bad_beams_are_config_errors(table, match):
    raw = {"sky": {"nside": 16, "lmax": 40, "fwhm_arcmin": 10.0}, "systematics": table}
    with pytest.raises(config.ConfigError, match=match):
        config.parse_study(raw)


def test_beams_without_a_sky_beam_are_a_config_error():
    raw = {
        "sky": {"nside": 16, "lmax": 40, "fwhm_arcmin": 0.0},
        "systematics": {"ellipticity_b": 0.1},
    }
    with pytest.raises(config.ConfigError, match="fwhm_arcmin > 0"):
        config.parse_study(raw)


def test_gpu_refuses_beams():
    pytest.importorskip("cupy")
    from boresight import tod_gpu

    with pytest.raises(ValueError, match="backend = 'cpu'"):
        tod_gpu._physics(np.zeros((1, 2, 7)), np.zeros(2), None, np.zeros((2, 3, 1, 2)))


def test_beams_need_a_sky_beam(small_sky):
    with pytest.raises(ValueError, match="fwhm_arcmin > 0"):
        beams.BeamConvolver(small_sky.alm, 0.0)
    assert beams.Beam(10 * ARCMIN).ellipticity == 0.0


def test_beam_maps_do_not_depend_on_chunks_or_threads(small_sky):
    sysm = Systematics(dfwhm_b_arcmin=0.8, ellipticity_a=0.04, rho_arcmin=0.5)
    scan = SyntheticScan(n_phi=3, range_rad=0.7, seed=2, rotations_deg=(0.0, 60.0))
    one = engine.simulate(small_sky, scan, systematics=sysm, nthreads=1, chunk_pixels=997)
    two = engine.simulate(small_sky, scan, systematics=sysm, nthreads=2)
    np.testing.assert_array_equal(one.q, two.q)
    np.testing.assert_array_equal(one.u, two.u)


def test_beam_terms_are_where_systematic_cl_reads_them_exactly(theory):
    """With leak and pointing on too, leak_terms puts the beams' terms at predict.BEAM_TERMS (the
    h_2 term with W, and h_4 D4), which systematic_cl spreads as fields read exactly at hits."""
    sysm = Systematics(dg=0.01, leak=0.01, rho_arcmin=0.3, ellipticity_b=0.02, dfwhm_b_arcmin=0.2)
    lmax = 60
    coefs = predict.coefficients(sysm)
    beam = predict.beam_filters(sysm, None, (0.0,), 30.0, lmax)
    tt, ee, bb = predict.field_spectra(theory, lmax, 30.0)
    terms = predict.leak_terms(coefs, sysm, tt, ee + bb, beam=beam)
    assert [t[0] for t in terms] == [2, 4, 2, 1, 3, 4]
    first, last = (terms[i] for i in predict.BEAM_TERMS)
    np.testing.assert_allclose(first[2], np.abs(coefs.t2 + beam.w2) ** 2 * tt)
    np.testing.assert_allclose(last[2], np.abs(beam.e4) ** 2 * tt)
