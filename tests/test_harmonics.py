"""Spherical-harmonic transforms through ducc0 against healpy's: ring weights, the one-pass
analysis of the survey masks, alm2cl and almxfl, and transforms on observed pixels only."""

import healpy as hp
import numpy as np
import pytest

from boresight import harmonics, masks


@pytest.mark.parametrize("footprint", ["full sky", "deep", "nothing"])
def test_ring_weights_are_healpys(footprint):
    """One pass with ring weights is healpy.map2alm(use_weights=True, iter=0) (its own reading of
    the same weight files, over every ring), spin 0 and 2: also where boresight transforms only
    the rings a mask touches (the deep mask's 27 %), and for empty maps."""
    nside, lmax = 32, 64
    rng = np.random.default_rng(5)
    weight = {"full sky": 1.0, "deep": masks.survey_mask("deep", nside), "nothing": 0.0}
    maps = rng.standard_normal((3, 12 * nside**2)) * weight[footprint]
    want = hp.map2alm(maps, lmax=lmax, iter=0, use_weights=True, pol=True)
    if footprint == "nothing":
        assert not np.any(harmonics.map2alm(maps[1:], lmax, spin=2, analysis="ring_weights"))
        return
    got_t = harmonics.map2alm(maps[0], lmax, spin=0, analysis="ring_weights")
    got_eb = harmonics.map2alm(maps[1:], lmax, spin=2, analysis="ring_weights")
    np.testing.assert_allclose(got_t, want[0], rtol=0, atol=1e-12 * np.abs(want[0]).max())
    np.testing.assert_allclose(got_eb, want[1:], rtol=0, atol=1e-12 * np.abs(want[1:]).max())


def test_auto_analysis_of_the_survey_masks_is_one_pass():
    """The paper's masks stay clear of the poles, so their spectra take one transform at
    lmax <= 2 Nside, and LSQR above; a bad name is refused."""
    for survey in ("deep", "wide"):
        mask = masks.survey_mask(survey, 64)
        assert harmonics.resolve_analysis("auto", mask, 128) == "ring_weights"
        assert harmonics.resolve_analysis("auto", mask, 129) == "lsqr"
    with pytest.raises(ValueError, match="analysis"):
        harmonics.resolve_analysis("fast", mask, 128)


def test_alm2cl_and_almxfl_are_healpys():
    """The per-m loops (no (nalm,) index array) give healpy's alm2cl to rounding and its almxfl
    exactly."""
    lmax = 300
    rng = np.random.default_rng(11)
    re, im = rng.standard_normal((2, 2, harmonics.n_alm(lmax)))
    a, b = re + 1j * im
    a[: lmax + 1], b[: lmax + 1] = a[: lmax + 1].real, b[: lmax + 1].real
    for got, want in (
        (harmonics.alm2cl(a, b), hp.alm2cl(a, b)),
        (harmonics.alm2cl(a), hp.alm2cl(a)),
    ):
        # rounding of sums of terms of either sign: relative to the spectrum's scale
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-14 * np.abs(want).max())
    fl = rng.random(lmax + 1)
    np.testing.assert_array_equal(harmonics.almxfl(a, fl), hp.almxfl(a, fl))
    stacked = harmonics.almxfl(np.array([a, b]), fl)
    np.testing.assert_array_equal(stacked[1], hp.almxfl(b, fl))


def test_every_cross_spectrum_at_once_is_healpys_alm2cl():
    """harmonics.alm_cross_spectra of 5 alm of real fields: every pair's healpy.alm2cl to 1e-14
    relative, in full and to a lower band limit."""
    rng = np.random.default_rng(3)
    lmax = 40
    _, m = hp.Alm.getlm(lmax)
    alms = rng.normal(size=(5, m.size)) + 1j * rng.normal(size=(5, m.size))
    alms[:, m == 0] = alms[:, m == 0].real
    want = np.array([[hp.alm2cl(a, b) for b in alms] for a in alms])
    np.testing.assert_allclose(
        harmonics.alm_cross_spectra(alms), want, rtol=0, atol=1e-14 * np.abs(want).max()
    )
    np.testing.assert_allclose(
        harmonics.alm_cross_spectra(alms, 20),
        want[..., :21],
        rtol=0,
        atol=1e-14 * np.abs(want).max(),
    )


@pytest.mark.parametrize("case", ["deep", "north cap", "above 2 nside", "zeros"])
def test_transform_on_observed_pixels_is_the_full_sky_ones(case):
    """map2alm_pixels (the rings that hold data packed into one array, no full-sky map) gives
    map2alm's alm of the full-sky map to the last bit: one pass on the deep mask, with a pixel
    that holds 0; the Jacobi iterations "auto" takes for a cap at the pole; LSQR above 2 Nside;
    and maps that are zero on every observed pixel."""
    nside = 32
    lmax = 95 if case == "above 2 nside" else 64
    theta, _ = hp.pix2ang(nside, np.arange(12 * nside**2))
    mask = (theta < 0.6).astype(float) if case == "north cap" else masks.survey_mask("deep", nside)
    pixels = np.flatnonzero(mask)
    rng = np.random.default_rng(9)
    values = rng.standard_normal((2, pixels.size)) * mask[pixels] * (case != "zeros")
    values[:, pixels.size // 2] = 0.0
    maps = np.zeros((2, mask.size))
    maps[:, pixels] = values
    analysis = {"north cap": "jacobi", "above 2 nside": "lsqr"}.get(case, "ring_weights")
    assert harmonics.resolve_analysis("auto", maps, lmax) == analysis
    want = harmonics.map2alm(maps, lmax, spin=2)
    got = harmonics.map2alm_pixels(values, pixels, nside, lmax, spin=2)
    np.testing.assert_array_equal(got, want)
    got_t = harmonics.map2alm_pixels(values[0], pixels, nside, lmax)
    np.testing.assert_array_equal(got_t, harmonics.map2alm(maps[0], lmax))
    assert np.any(want) == (case != "zeros")


def test_synthesis_on_observed_pixels_is_the_full_sky_maps():
    """alm2map_pixels synthesises only the rings that hold the pixels, packed; each value is the
    full-sky map's to rounding, 2e-14 of the map's largest value (measured), spin 0 and 2, a
    mask's pixels and a scattered few. ducc0 sums a ring whose mirror ring is also synthesised in
    another order."""
    nside, lmax = 32, 80
    rng = np.random.default_rng(4)
    alm = rng.standard_normal((2, harmonics.n_alm(lmax))) + 0j
    few = np.unique(rng.integers(0, 12 * nside**2, 40))
    for pixels in (np.flatnonzero(masks.survey_mask("wide", nside)), few):
        for spin, coefficients in ((2, alm), (0, alm[0])):
            got = harmonics.alm2map_pixels(coefficients, pixels, nside, spin=spin)
            want = harmonics.alm2map(coefficients, nside, spin=spin)[..., pixels]
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-13 * np.abs(want).max())
