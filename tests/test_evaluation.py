"""The sky at each hit: exact band-limited evaluation against bilinear interpolation, and the
gradient against finite differences."""

import healpy as hp
import numpy as np
from helpers import rel_max

from boresight import engine, harmonics
from boresight.constants import ARCMIN
from boresight.scan import SyntheticScan


def test_exact_and_interpolated_agree_to_interpolation_error(small_sky):
    """Bilinear interpolation of a beam-smoothed map errs by ~ (pixel/beam)^2 / 8 of the signal.

    Nside 128 (27 arcmin pixels) with a 60 arcmin beam: the relative rms error is below 10 per
    cent; halving the pixel size must shrink it about fourfold (second-order scheme).
    """
    from boresight import sky as skymod

    scan = SyntheticScan(n_phi=2, range_rad=0.3, seed=5)
    errs = []
    for nside in (128, 256):
        s = skymod.make_sky(skymod.SkyConfig(nside=nside, lmax=191, fwhm_arcmin=60.0, seed=7))
        a = engine.simulate(s, scan)
        b = engine.simulate(s, scan, evaluation="exact")
        errs.append(np.std(a.q - b.q) / np.std(b.q))
    assert errs[0] < 0.1
    assert 3.0 < errs[0] / errs[1] < 4.5


def test_gradient_matches_finite_difference(small_sky_unpolarised):
    """G = (dT/dtheta, dT/dphi / sin theta) of ducc0 against central differences of exact T."""
    s = small_sky_unpolarised
    g = harmonics.alm2map_gradient(s.alm[0], s.nside)
    pix = np.arange(2000, 40000, 37)
    theta, phi = hp.pix2ang(s.nside, pix)
    eps = 0.5 * ARCMIN

    def t(th, ph):
        return harmonics.evaluate(s.alm[0], th, ph)

    d_theta = (t(theta + eps, phi) - t(theta - eps, phi)) / (2 * eps)
    d_phi = (t(theta, phi + eps) - t(theta, phi - eps)) / (2 * eps * np.sin(theta))
    # Central differences err by ~ eps^2 / 6 relative to the beam scale squared: ~ 1e-4.
    assert rel_max(g[0][pix], d_theta) < 3e-4
    assert rel_max(g[1][pix], d_phi) < 3e-4
    # on some pixels only (their rings, packed): the full-sky values to rounding
    on = harmonics.alm2map_gradient(s.alm[0], s.nside, pixels=pix)
    np.testing.assert_allclose(on, g[:, pix], rtol=0, atol=1e-13 * np.abs(g).max())
