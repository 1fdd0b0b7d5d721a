"""What every focal-plane prediction shares: the map-maker's 2x2 solve, the hit-weighted means over
pairs, the pixels' geometry and a field read across the pixel, each against an independent route."""

import healpy as hp
import numpy as np

from boresight.predict import field_products
from boresight.predict.pair_fields import (
    derivative_maps,
    hit_mean,
    pixel_geometry,
    solve_pairs,
    taylor,
)


def test_the_solve_inverts_the_map_makers_2x2_system():
    """The map-maker's 2x2 system gives Y = dP + H_4 dP*: the solve returns that dP, and 0 where
    the system is singular (``|H_4|`` = 1)."""
    rng = np.random.default_rng(1)
    dp = rng.normal(size=50) + 1j * rng.normal(size=50)
    h4 = 0.9 * rng.uniform(size=50) * np.exp(2j * np.pi * rng.uniform(size=50))
    y = dp + h4 * np.conj(dp)
    np.testing.assert_allclose(solve_pairs(y, h4), dp, rtol=1e-12, atol=1e-12)
    assert solve_pairs(np.array([1.0 + 1j]), np.array([1.0 + 0j]))[0] == 0


def test_the_hit_mean_is_the_share_weighted_sum_over_pairs():
    rng = np.random.default_rng(2)
    shares = rng.normal(size=3) + 1j * rng.normal(size=3)
    weights = rng.uniform(size=(3, 7))
    h = rng.normal(size=(3, 7)) + 1j * rng.normal(size=(3, 7))
    by_hand = sum(shares[i] * weights[i] * h[i] for i in range(3))
    np.testing.assert_allclose(hit_mean(shares, weights, h), by_hand, rtol=1e-14)


def test_the_pixels_geometry_is_cot_and_csc2_at_their_centres():
    nside = 8
    theta = hp.pix2ang(nside, np.arange(12 * nside**2))[0]
    factor = pixel_geometry(nside)
    field = field_products.SkyField(0, np.ones((3, 2)))
    np.testing.assert_allclose(
        factor(field_products.StepTerm(1.0, 1, 0, field)), 1 / np.tan(theta), rtol=1e-12
    )
    np.testing.assert_allclose(
        factor(field_products.StepTerm(1.0, 2, 1, field)),
        np.tan(theta) ** -2 * np.sin(theta) ** -2,
        rtol=1e-12,
    )


def test_a_fields_derivative_maps_are_healpys_gradient(small_sky):
    """T read at delta = delta_theta + i delta_phi is T + (conj(delta) d T + delta dbar T) / 2, so
    d T = dT/dtheta + i dT/dphi / sin(theta) and dbar T its conjugate: against healpy's own
    first derivatives of the same alm (alm2map_der1)."""
    sky = small_sky
    filters = np.zeros((3, sky.lmax + 1))
    filters[0] = 1.0
    field = field_products.SkyField(0, filters)
    up, down = derivative_maps(sky, field, 0)
    _, d_theta, d_phi = hp.alm2map_der1(sky.alm[0], sky.nside, lmax=sky.lmax)
    scale = np.abs(d_theta).max()
    np.testing.assert_allclose(up, d_theta + 1j * d_phi, rtol=0, atol=1e-6 * scale)
    np.testing.assert_allclose(down, np.conj(up), rtol=0, atol=1e-12 * scale)
    terms = taylor(field)
    assert {k: v[0] for k, v in terms.items()} == {
        None: 1.0, "conj": 0.5, "delta": 0.5, "conj2": 0.125, "delta2": 0.125, "abs2": 0.25
    }  # fmt: skip
