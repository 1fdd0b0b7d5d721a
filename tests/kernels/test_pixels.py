import healpy as hp
import numpy as np
import pytest

from boresight.kernels import pixels


@pytest.mark.parametrize("nside", [1, 2, 8, 64])
def test_pixel_centres_match_healpy(nside):
    p = np.arange(12 * nside**2)
    half = np.full(p.size, 0.5)
    theta, phi = pixels.pixel_points(nside, p, half, half)
    t2, p2 = hp.pix2ang(nside, p)
    assert np.allclose(theta, t2, rtol=0, atol=1e-13)
    assert np.allclose(np.angle(np.exp(1j * (phi - p2))), 0, atol=1e-12)


@pytest.mark.parametrize("nside", [1, 4, 32])
def test_random_points_fall_in_their_pixel(nside):
    p = np.repeat(np.arange(12 * nside**2), 20)
    rng = np.random.default_rng(0)
    theta, phi = pixels.pixel_points(nside, p, rng.random(p.size), rng.random(p.size))
    assert np.array_equal(hp.ang2pix(nside, theta, phi), p)


def test_in_pixel_points_are_uniform_in_solid_angle():
    """Sub-pixel counts: every NEST child of a pixel (equal area) gets the same share.

    Uniform (u, v) -> uniform on the sphere because the HEALPix projection is equal-area; a
    non-equal-area map (e.g. uniform in theta, phi) fails this chi-square test by a wide margin.
    """
    nside, k = 8, 4  # children at nside * k
    n_per = 4000
    p = np.repeat(np.arange(12 * nside**2), n_per)
    rng = np.random.default_rng(1)
    theta, phi = pixels.pixel_points(nside, p, rng.random(p.size), rng.random(p.size))
    child = hp.ang2pix(nside * k, theta, phi, nest=True)
    counts = np.bincount(child, minlength=12 * (nside * k) ** 2)
    expected = n_per / k**2
    chi2 = np.sum((counts - expected) ** 2 / expected)
    dof = counts.size - 12 * nside**2
    # chi2 of dof degrees of freedom: mean dof, sd sqrt(2 dof); 5 sd is a 1e-6 false alarm.
    assert abs(chi2 - dof) < 5 * np.sqrt(2 * dof)


@pytest.mark.parametrize("nside", [1, 2, 16, 128])
def test_interpolation_matches_healpy(nside):
    rng = np.random.default_rng(nside)
    maps = rng.normal(size=(3, 12 * nside**2))
    theta = np.concatenate([np.arccos(rng.uniform(-1, 1, 3000)), [0.0, np.pi, 1e-9, np.pi - 1e-9]])
    phi = rng.uniform(0, 2 * np.pi, theta.size)
    got = pixels.interpolate_interleaved(np.ascontiguousarray(maps.T), nside, theta, phi)
    want = np.array([hp.get_interp_val(m, theta, phi) for m in maps])
    assert np.allclose(got, want, rtol=0, atol=1e-13)


@pytest.mark.parametrize("nside", [1, 2, 16, 512, 8192])
def test_ang2pix_matches_healpy(nside):
    rng = np.random.default_rng(nside)
    theta = np.concatenate(
        [
            np.arccos(rng.uniform(-1, 1, 200000)),
            [0.0, np.pi, 1e-12, np.pi - 1e-12, np.arccos(2 / 3), np.arccos(-2 / 3)],
            np.arccos(rng.uniform(0.985, 1.0, 20000)),
        ]
    )  # the polar-cap branch
    phi = np.concatenate(
        [
            rng.uniform(0, 2 * np.pi, 200000),
            [0.0, 1.0, 2 * np.pi - 1e-12, 3.0, 0.5, 6.0],
            rng.uniform(0, 2 * np.pi, 20000),
        ]
    )
    assert np.array_equal(pixels.ang2pix_array(nside, theta, phi), hp.ang2pix(nside, theta, phi))
