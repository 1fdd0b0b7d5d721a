"""The samples' offsets from their pixel's centre and the moments weighted by them."""

import numpy as np
from helpers import night_schedule

from boresight import moments, pointing
from boresight.instrument import focalplane


def test_centroid_moments_are_each_samples_place_in_its_pixel():
    """The offsets of the samples from their pixel centres, weighted by exp(i n psi), against
    the small-angle offsets (theta - theta_c, sin theta_c (phi - phi_c)) binned by hand: equal
    to second order in the pixel size, and no larger than a pixel."""
    import healpy as hp

    nside = 16
    schedule = night_schedule(rate=1.0, n=2)
    got = moments.centroid_moments(schedule, nside, n_max=2)
    theta, phi, psi = (np.concatenate(x) for x in zip(*pointing.pointing(schedule)))
    pix = hp.ang2pix(nside, theta, phi)
    c_theta, c_phi = hp.pix2ang(nside, pix)
    wrapped = (phi - c_phi + np.pi) % (2 * np.pi) - np.pi
    delta = (theta - c_theta) + 1j * np.sin(c_theta) * wrapped
    hits = np.bincount(pix, minlength=12 * nside**2)
    seen = hits > 0
    size = hp.nside2resol(nside)
    for n in range(3):
        for k, value in enumerate((delta, np.conj(delta))):
            w = np.exp(1j * n * psi) * value
            want = np.bincount(pix, w.real, hits.size) + 1j * np.bincount(pix, w.imag, hits.size)
            want = want[seen] / hits[seen]
            np.testing.assert_allclose(got[k, n, seen], want, rtol=0, atol=size**2)
    assert np.abs(got[0, 0]).max() < size
    assert np.abs(got[0, 0]).max() > 0.05 * size  # the centroids are off the centres
    assert np.all(got[:, :, ~seen] == 0)


def test_a_focal_planes_centroid_moments_are_each_pairs_own():
    """With a focal plane, pair i's offsets are its own samples' (detector_pointing), binned by
    hand as above, weighted by the crossing angle of its h_n in characterise_focalplane; pairs on
    the axis have the boresight's, to rounding."""
    import healpy as hp

    nside, n_max = 16, 2
    schedule = night_schedule(rate=1.0, n=2)
    hexagon = focalplane.hexagon(7, 10.0)
    got = moments.centroid_moments(schedule, nside, n_max=n_max, focalplane=hexagon)
    stats = moments.characterise_focalplane(schedule, hexagon, nside, per_pair=True)
    chunks = list(pointing.detector_pointing(schedule, hexagon))
    size = hp.nside2resol(nside)
    for i in (0, 4):  # the centre and a corner 5 deg off the axis
        theta, phi, psi = (np.concatenate([c[k][i] for c in chunks]) for k in range(3))
        pix = hp.ang2pix(nside, theta, phi)
        hits = np.bincount(pix, minlength=12 * nside**2)
        seen = hits > 0
        c_theta, c_phi = hp.pix2ang(nside, pix)
        wrapped = (phi - c_phi + np.pi) % (2 * np.pi) - np.pi
        delta = (theta - c_theta) + 1j * np.sin(c_theta) * wrapped

        def binned(w, pix=pix, hits=hits, seen=seen):
            out = np.bincount(pix, w.real, hits.size) + 1j * np.bincount(pix, w.imag, hits.size)
            return out[seen] / hits[seen]

        for n in range(n_max + 1):
            spin = np.exp(1j * n * psi)
            np.testing.assert_allclose(binned(spin), stats.pair_h[i, n, seen], rtol=0, atol=1e-12)
            for k, value in enumerate((delta, np.conj(delta))):
                np.testing.assert_allclose(got[i, k, n, seen], binned(spin * value), atol=size**2)
        assert np.abs(got[i, 0, 0]).max() > 0.05 * size
    assert not np.allclose(got[0], got[4])  # a pair off the axis crosses its pixels elsewhere
    on_axis = focalplane.on_axis((0.0, 45.0))
    alone = moments.centroid_moments(schedule, nside, n_max=n_max)
    for pair in moments.centroid_moments(schedule, nside, n_max=n_max, focalplane=on_axis):
        np.testing.assert_allclose(pair, alone, rtol=0, atol=1e-15)
