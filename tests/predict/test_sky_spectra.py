"""The spectra a prediction scales: the theory through the beam, or one sky's own inside a mask,
which on the full sky are healpy's anafast of its maps."""

import healpy as hp
import numpy as np

from boresight import predict
from boresight.constants import ARCMIN


def test_field_spectra_are_the_theory_through_the_beam(theory):
    tt, ee, bb = predict.field_spectra(theory, 200, 30.0)
    beam = hp.gauss_beam(30.0 * ARCMIN, lmax=200, pol=True)
    total = theory.total(lmax=200)
    np.testing.assert_allclose(tt, total[0] * beam[:, 0] ** 2, rtol=1e-14)
    np.testing.assert_allclose(ee, total[1] * beam[:, 1] ** 2, rtol=1e-14)
    np.testing.assert_allclose(bb, total[2] * beam[:, 2] ** 2, rtol=1e-14)


def test_local_spectra_of_the_full_sky_are_anafasts(small_sky):
    lmax = 128
    local = predict.local_cl(small_sky, np.ones(12 * 64**2), lmax, beams=True)
    tt, ee, bb = hp.anafast(small_sky.maps, lmax=lmax, iter=3)[:3]
    np.testing.assert_allclose(local.tt[2:], tt[2:], rtol=1e-10)
    np.testing.assert_allclose(local.pol[2:], (ee + bb)[2:], rtol=1e-10)
    np.testing.assert_allclose(local.ee, local.masked[0], rtol=1e-12)  # no mask: <w^2> = 1
    assert local.apodized.shape == (4, lmax + 1)


def test_local_spectra_of_half_the_sky_are_full_sky_equivalents(small_sky):
    """Pseudo-C_ell / <w^2>: on half the sky, the mean over 50 <= ell <= 128 is the full sky's
    within its sample variance (without the division it would be half)."""
    full = predict.local_cl(small_sky, np.ones(12 * 64**2), 128)
    half_mask = (np.arange(12 * 64**2) < 6 * 64**2).astype(float)
    half = predict.local_cl(small_sky, half_mask, 128)
    ratio = np.mean(half.tt[50:] / full.tt[50:])
    assert 0.85 < ratio < 1.15, ratio
