"""Beam width and ellipticity: ducc0's totalconvolve against healpy's Gaussian beam, a
second-order Taylor expansion of the sky, and the analytic h_n prediction."""

import healpy as hp
import numpy as np
import pytest

from boresight import config, engine, harmonics, predict
from boresight.constants import ARCMIN, DEG
from boresight.instrument import beams
from boresight.instrument.pairs import Systematics
from boresight.scan import SyntheticScan

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
    ell = hp.Alm.getlm(lmax)[0]
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


def test_moment_filters_are_the_expansions_at_small_beams():
    """At l sigma << 1 the filters of beams.moment_filters are the harmonic forms of the
    second-order expansion: on T, F_0 = 1/2 a nabla^2 T (a = sigma_X^2 (1 + e^2) - sigma^2) and
    2 F_2 = sigma_X^2 e eth^2 T; on P, a spin-0 -1/2 sigma^2 e eth-bar^2 P and a spin-4
    -1/4 sigma^2 e eth^2 P, both turned by the major axis's angle: (E, B) filters
    (Re, Im) e^{-2i angle} and e^{-2i angle} (1, i)."""
    lmax, fwhm, e = 60, 0.2 * DEG, 0.1
    sigma = fwhm / beams.FWHM_PER_SIGMA
    ell = np.arange(lmax + 1.0)
    b = np.exp(-0.5 * ell * (ell + 1) * sigma**2)
    a = (1.02 * sigma) ** 2 * (1 + e**2) - sigma**2
    g = beams.moment_filters(beams.Beam(1.02 * fwhm, e), fwhm, lmax, 4)
    np.testing.assert_allclose(g[0, 0, 2:], -0.5 * a * ell[2:] * (ell[2:] + 1) * b[2:], rtol=2e-2)
    eth2 = np.sqrt((ell - 1) * ell * (ell + 1) * (ell + 2))
    np.testing.assert_allclose(
        2 * g[2, 0, 2:], (1.02 * sigma) ** 2 * e * eth2[2:] * b[2:], rtol=2e-2
    )
    spin4 = np.sqrt(np.maximum((ell - 3) * (ell - 2) * (ell + 3) * (ell + 4), 0))
    for angle in (0.0, 0.3, np.pi / 4):
        g = beams.moment_filters(beams.Beam(fwhm, e, angle), fwhm, lmax, 4)
        turn = sigma**2 * e * b * np.exp(-2j * angle)
        np.testing.assert_allclose(
            g[0, 1, 2:], -0.5 * (turn * eth2).real[2:], rtol=1e-3, atol=1e-12
        )
        np.testing.assert_allclose(
            g[0, 2, 2:], -0.5 * (turn * eth2).imag[2:], rtol=1e-3, atol=1e-12
        )
        np.testing.assert_allclose(g[4, 1, 4:], -0.25 * (turn * spin4)[4:], rtol=1e-3)
        np.testing.assert_allclose(g[4, 2, 4:], -0.25j * (turn * spin4)[4:], rtol=1e-3)


def test_moment_fields_are_the_convolution(small_sky):
    """The spin-k fields of beams.moment_filters, synthesised by ducc0 at arbitrary points, sum
    to ducc0 totalconvolve's signal of (beam - nominal beam) for T, E and B skies and any
    orientation of the ellipse."""
    import ducc0

    rng = np.random.default_rng(5)
    th, ph, psi = rng.uniform(0.3, 2.8, 30), rng.uniform(0, 2 * np.pi, 30), rng.uniform(-3, 3, 30)
    lmax, nominal = small_sky.lmax, small_sky.fwhm_arcmin * ARCMIN
    sky_alm = beams.unsmoothed_alm(small_sky.alm, nominal)
    for beam in (beams.Beam(1.1 * nominal), beams.Beam(nominal, 0.2, 0.5)):
        ref = beams.BeamConvolver(small_sky.alm, nominal, 1).extra(beam, th, ph, psi)
        g = beams.moment_filters(beam, nominal, lmax, 12)
        out = np.zeros(th.size)
        for k in range(g.shape[0]):
            coef = [
                sum(hp.almxfl(sky_alm[c], getattr(g[k, c], p)) for c in range(3))
                for p in ("real", "imag")
            ]
            if k == 0:
                out += harmonics.evaluate(coef[0], th, ph, epsilon=1e-12)
                continue
            qu = ducc0.sht.experimental.synthesis_general(
                alm=-np.stack(coef),
                spin=k,
                lmax=lmax,
                loc=np.stack([th, ph], axis=1),
                epsilon=1e-12,
            )
            out += 2 * np.real((qu[0] + 1j * qu[1]) * np.exp(-1j * k * psi))
        assert np.max(np.abs(out - ref)) < 1e-8 * np.max(np.abs(ref))


def _residual(sky_, scan, systematics, **kw):
    ref = engine.simulate(sky_, scan, **kw)
    m = engine.simulate(sky_, scan, systematics=systematics, **kw)
    return (m.q - ref.q) + 1j * (m.u - ref.u)


def _predicted(sky_, scan, systematics, n_max=predict.BEAM_N_MAX):
    h, _ = engine.scan_moments(scan.one_repeat(), sky_.nside, n_max)
    return predict.delta_p(
        sky_, h, systematics, rotations_deg=scan.rotations_deg
    ) - predict.delta_p(sky_, h, Systematics(), rotations_deg=scan.rotations_deg)


@pytest.mark.parametrize(
    "systematics",
    [
        Systematics(dfwhm_b_arcmin=1.0),
        Systematics(dfwhm_a_arcmin=-0.5, dfwhm_b_arcmin=(0.4, 1.0)),
        Systematics(ellipticity_b=0.05, ellipticity_angle_b_deg=20.0),
        Systematics(ellipticity_a=0.05, ellipticity_b=0.05, dg=0.01, pol_angle_deg=0.5),
    ],
)
def test_engine_beams_equal_the_analytic_map(small_sky, systematics):
    """Pixel-centre hits, polarised sky: with h_n to n = 8 the map-level prediction's beam terms
    (every moment of beams.moment_filters to k = 10, T and P) are the engine's maps to 5e-6
    (widths: 1e-9; the rest is the k > 10 moments, ~ e^5); the default BEAM_N_MAX = 6 (all terms
    of first order in e) leaves 1.5e-4 at e = 0.05 and the old T-only terms (h_4 and below) 1 %."""
    dp = _residual(small_sky, CENTRED, systematics)
    error = {n: np.linalg.norm(dp - _predicted(small_sky, CENTRED, systematics, n)) for n in (4, 8)}
    assert error[8] < 5e-6 * np.linalg.norm(dp)
    if systematics.ellipticity_b and not systematics.ellipticity_a:  # (equal A and B cancel)
        assert error[4] > 1e-3 * np.linalg.norm(dp)  # the P and higher-moment terms matter


def test_default_beam_moments_leave_second_order_terms(small_sky):
    sysm = Systematics(dfwhm_b_arcmin=1.0, ellipticity_b=0.05)
    dp = _residual(small_sky, CENTRED, sysm)
    assert np.linalg.norm(dp - _predicted(small_sky, CENTRED, sysm)) < 3e-4 * np.linalg.norm(dp)


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
    from boresight.kernels import gpu

    with pytest.raises(ValueError, match="backend = 'cpu'"):
        gpu._physics(np.zeros((1, 2, 7)), np.zeros(2), None, np.zeros((2, 3, 1, 2)))


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
