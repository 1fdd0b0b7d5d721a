"""What TOD template deprojection leaves of a leak of T: the closed form against numpy's own
regression of Gaussian fields on the sphere, and against the mean of TOD skies deprojected with
noisy template maps through the engine."""

import healpy as hp
import numpy as np
import pytest
from helpers import EXAMPLES

from boresight import spectra
from boresight.constants import ARCMIN
from boresight.cosmology import load_spectra
from boresight.instrument.pairs import Systematics
from boresight.jobs.template_check import template_error_check
from boresight.predict.template_error import template_error
from boresight.schedule import load_schedule


def test_a_template_of_the_sky_itself_leaves_nothing_and_noise_leaves_its_own_less_the_fit():
    tt = load_spectra().tt
    exact = template_error(tt, lmax=64, fwhm_arcmin=60.0)
    assert exact.kappa == 0.0 and not np.any(exact.residual)
    noisy = template_error(tt, lmax=64, fwhm_arcmin=60.0, noise_cl=1e-4)
    beam = hp.gauss_beam(60.0 * ARCMIN, lmax=64)
    ell = np.arange(65)
    weight = (2 * ell + 1)[2:]
    sky = beam[2:] ** 2 * tt[2:65]
    kappa = np.sum(weight * 1e-4) / np.sum(weight * (sky + 1e-4))
    assert noisy.kappa == pytest.approx(kappa, rel=1e-12)
    want = (1 - kappa) ** 2 * 1e-4 + kappa**2 * sky
    np.testing.assert_allclose(noisy.residual[2:], want, rtol=1e-12)
    with pytest.raises(ValueError, match="derivatives"):
        template_error(tt, lmax=64, fwhm_arcmin=60.0, derivatives=3)
    with pytest.raises(ValueError, match="lmax 64 needs"):
        template_error(tt[:50], lmax=64, fwhm_arcmin=60.0)


@pytest.mark.parametrize("derivatives", [0, 1])
def test_the_fit_and_what_it_leaves_are_numpys_regression_of_gaussian_fields(derivatives):
    """Full-sky Gaussian fields (a flat C_ell, so that the sky's variance spreads over many
    modes): the TOD's field X = B T, a template x = B_t T + n of another beam and white noise;
    numpy's least squares of X on x over the pixels (of their gradients' components, k = 1)
    gives c = 1 - kappa, and the spectrum of X - c x is C_ell^res, over 4 draws: kappa to 1 %
    (measured 0.1 %, kappa -0.11 and -0.16: the wider template's beam) and C^res to 4 % in bands
    of 16 (measured 2.4 %)."""
    nside, lmax = 64, 128
    tt = np.full(lmax + 1, 1.0)
    noise = 0.3 * 4 * np.pi / (12 * nside**2)
    fwhm, own = 60.0, 75.0
    left = template_error(
        tt,
        lmax=lmax,
        fwhm_arcmin=fwhm,
        template_fwhm_arcmin=own,
        noise_cl=noise,
        derivatives=derivatives,
    )
    beam, template_beam = (hp.gauss_beam(f * ARCMIN, lmax=lmax) for f in (fwhm, own))
    rng = np.random.default_rng(11)
    kappas, spectra_left = [], []
    for _ in range(4):
        np.random.seed(rng.integers(2**31))
        t_alm = hp.synalm(tt, lmax=lmax)
        n_alm = hp.synalm(np.full(lmax + 1, noise), lmax=lmax)
        x_alm = hp.almxfl(t_alm, template_beam) + n_alm
        big_x_alm = hp.almxfl(t_alm, beam)
        if derivatives == 0:
            d = hp.alm2map(big_x_alm, nside)[:, None]
            x = hp.alm2map(x_alm, nside)[:, None]
        else:
            d = np.stack(hp.alm2map_der1(big_x_alm, nside)[1:], axis=1)
            x = np.stack(hp.alm2map_der1(x_alm, nside)[1:], axis=1)
        # one coefficient for every component: the leak d = X (or its gradient), fitted by x
        c = np.linalg.lstsq(x.reshape(-1, 1), d.reshape(-1), rcond=None)[0][0]
        kappas.append(1.0 - c)
        spectra_left.append(hp.alm2cl(big_x_alm - c * x_alm))
    assert np.mean(kappas) == pytest.approx(left.kappa, rel=0.01)
    edges = np.arange(2, lmax + 2, 16)
    got = spectra.bin_spectrum(np.mean(spectra_left, axis=0), edges)[1]
    want = spectra.bin_spectrum(left.residual, edges)[1]
    np.testing.assert_allclose(got, want, rtol=0.04)


SYSTEMATICS = {
    "gain": (Systematics(dg=0.01), ("gain",)),
    "pointing": (Systematics(rho_arcmin=1.0, chi_deg=30.0), ("pointing",)),
}


@pytest.mark.slow
@pytest.mark.parametrize(
    "name, noise, template_fwhm",
    [
        ("gain", 0.05, None),
        ("gain", 0.5, None),
        ("pointing", 0.05, None),
        ("pointing", 0.5, None),
        ("pointing", 0.05, 75.0),
    ],
)
def test_the_deprojected_leak_is_predicted_within_10_percent(name, noise, template_fwhm):
    """The deep example's CES set at Nside 64, T-only skies of FWHM 60 arcmin, a gain or a
    pointing offset deprojected (its own templates, fitted per CES) with a template map that is
    the sky plus white noise (5 % and 50 % of the sky's rms: kappa about 0.003 and 0.2) or the sky
    at a 75 arcmin beam plus noise: the mean of 16 TOD skies' leak pseudo-C_BB left by
    deprojection against the exact expectation of the schedule's h_n with C_ell^TT replaced by
    the residual field's (:func:`template_error`), within 10 % in every band of 20 from 40 to
    2 nside. Measured (2026-12-07), prediction over the mean, bands 40-59 / 60-79 / 80-99 /
    100-119 / 120-128, each mean to 2-4 %: gain 1.02 / 1.06 / 1.01 / 1.02 / 0.96 (5 %) and
    1.01 / 1.07 / 1.02 / 1.03 / 0.98 (50 %); pointing 0.98 / 0.95 / 0.95 / 0.94 / 0.92 and
    1.02 / 1.01 / 1.04 / 1.01 / 0.99; a pointing template at a 75 arcmin beam 1.01 / 0.95 /
    0.94 / 0.99 / 0.97 (bench/bench_template_error.py prints them all). The gain's template at a
    75 arcmin beam, not held here: 0.87 / 1.08 / 1.09 / 1.09 / 1.04.)"""
    systematic, names = SYSTEMATICS[name]
    schedule = load_schedule(str(EXAMPLES / "schedule_deep_sat.toml")).single()
    check = template_error_check(
        schedule,
        systematic,
        names,
        nside=64,
        noise=noise,
        n_skies=16,
        template_fwhm_arcmin=template_fwhm,
    )
    assert np.all(check.error < 0.05 * check.mean), check.error / check.mean  # resolves 10 %
    np.testing.assert_allclose(check.predicted, check.mean, rtol=0.1)
