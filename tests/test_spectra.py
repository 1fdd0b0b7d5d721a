import healpy as hp
import numpy as np
import pytest
from helpers import rel_max

from boresight import harmonics, masks, spectra


@pytest.mark.parametrize(
    "analysis, lmax, anafast",
    [("jacobi", 150, dict(iter=3)), ("ring_weights", 128, dict(iter=0, use_weights=True))],
)
def test_pseudo_spectra_match_anafast(small_sky, analysis, lmax, anafast):
    mask = masks.survey_mask("wide", 64)
    got = spectra.pseudo_spectra(small_sky.maps, mask, lmax, analysis=analysis)
    want = hp.anafast(small_sky.maps * mask, lmax=lmax, **anafast)
    for g, w in zip(got, want):
        assert np.max(np.abs(g - w)[2:]) <= 1e-8 * np.max(np.abs(w[2:]))


def test_residual_keeps_precision_of_tiny_differences(small_sky):
    """A 1e-7 relative perturbation: the difference-map route equals the exact bilinear form.

    (qu + dqu) - qu recovers dqu to float64 eps / 1e-7 ~ 2e-9 relative, which bounds the route;
    subtracting two pseudo-spectra loses far more.
    """
    mask = masks.survey_mask("deep", 64)
    qu = small_sky.maps[1:]
    rng = np.random.default_rng(0)
    dqu = 1e-7 * np.std(qu) * rng.normal(size=qu.shape)
    res = spectra.residual_bb(qu + dqu, qu, mask, 150)
    b = spectra.masked_pol_alm(qu, mask, 150)[1]
    db = spectra.masked_pol_alm(dqu, mask, 150)[1]
    from boresight.harmonics import alm2cl

    exact = 2 * alm2cl(b, db) + alm2cl(db)
    err = rel_max(res[2:], exact[2:])
    assert err < 1e-8
    zero_t = np.zeros_like(qu[:1])
    naive = (
        spectra.pseudo_spectra(np.concatenate([zero_t, qu + dqu]), mask, 150)[2]
        - spectra.pseudo_spectra(np.concatenate([zero_t, qu]), mask, 150)[2]
    )
    # Here the linear cross term dominates, so the naive route is "only" ~30x worse; for residuals
    # cancelled by rotation (auto term ~ 1e-14 of the signal) it resolves nothing.
    assert rel_max(naive[2:], exact[2:]) > 10 * err


def test_unseen_inside_mask_is_rejected(small_sky):
    maps = small_sky.maps.copy()
    maps[1, 0] = hp.UNSEEN
    with pytest.raises(ValueError, match="UNSEEN"):
        spectra.pseudo_spectra(maps, np.ones(maps.shape[1]), 50)


def test_binning():
    edges = spectra.linear_bins(2, 11, 4)
    assert list(edges) == [2, 6, 10, 12]
    centres, means = spectra.bin_spectrum(np.arange(12.0), edges)
    assert np.allclose(means, [3.5, 7.5, 10.5]) and np.allclose(centres, [3.5, 7.5, 10.5])
    assert spectra.log_bins(2, 1000, 10)[0] == 2
    assert np.isclose(spectra.cl2dl(np.ones(3))[2], 6 / (2 * np.pi))


def _gauss_legendre_case(nside, lmax, mask_of, order=4):
    """A band-limited spin-2 field times a mask that is a polynomial of degree 2 ``order`` in
    cos(theta): its exact pseudo-alm (a Gauss-Legendre quadrature, ducc0 analysis_2d), its
    HEALPix samples and the worst relative error of a route's EE and BB bands."""
    import ducc0

    band_limit = lmax - 2 * order
    ell = hp.Alm.getlm(band_limit)[0]
    rng = np.random.default_rng(3)
    amp = np.sqrt(np.where(ell >= 2, 1.0 / (ell + 10.0) ** 2, 0.0) / 2)
    alm = (rng.standard_normal((2, ell.size)) + 1j * rng.standard_normal((2, ell.size))) * amp
    alm[:, : band_limit + 1] = alm[:, : band_limit + 1].real * np.sqrt(2)
    ntheta = lmax + 2
    grid = ducc0.sht.synthesis_2d(
        alm=alm, lmax=band_limit, spin=2, ntheta=ntheta, nphi=2 * lmax + 4, geometry="GL"
    )
    grid *= mask_of(np.arccos(-np.polynomial.legendre.leggauss(ntheta)[0]))[None, :, None]
    exact = ducc0.sht.analysis_2d(map=grid, lmax=lmax, spin=2, geometry="GL")
    theta, _ = hp.pix2ang(nside, np.arange(12 * nside**2))
    qu = harmonics.alm2map(alm, nside, spin=2) * mask_of(theta)
    edges = spectra.log_bins(20, lmax, 14)

    def worst(analysis):
        route = harmonics.map2alm(qu, lmax, spin=2, analysis=analysis)
        return max(
            np.max(
                np.abs(
                    spectra.bin_spectrum(harmonics.alm2cl(route[i]), edges)[1]
                    / spectra.bin_spectrum(harmonics.alm2cl(exact[i]), edges)[1]
                    - 1
                )
            )
            for i in (0, 1)
        )

    return qu, worst


def _north_cap(theta):
    return ((1 + np.cos(theta)) / 2) ** 4


def _band(theta):
    return np.sin(theta) ** 8


def test_masked_spectra_match_exact_gauss_legendre_quadrature():
    """An independent route for the pseudo-C_ell: a band-limited field times a band-limited mask
    is integrated exactly on a Gauss-Legendre grid. At Nside 64, lmax 2 Nside (measured):
    - a mask that reaches the north pole: Jacobi iterations 5.9e-7, one pass with ring weights
      5.9e-4 (the polar rings are too short), iterations=0 without weights ~1e-3; "auto" sees the
      pole and iterates;
    - a band away from the poles: ring weights 2.6e-6, and "auto" takes them;
    - lmax 3 Nside - 1, above what the ring weights integrate: LSQR 2.6e-5, Jacobi 8.6e-5."""
    qu, worst = _gauss_legendre_case(64, 128, _north_cap)
    assert harmonics.resolve_analysis("auto", qu, 128) == "jacobi"
    assert worst("auto") < 1e-5
    assert worst("ring_weights") > 1e-4
    assert worst("jacobi") < 1e-5
    qu, worst = _gauss_legendre_case(64, 128, _band)
    assert harmonics.resolve_analysis("ring_weights", qu, 128) == "ring_weights"
    assert worst("ring_weights") < 1e-5
    qu, worst = _gauss_legendre_case(64, 191, _band)
    assert harmonics.resolve_analysis("auto", qu, 191) == "lsqr"
    assert worst("auto") < 5e-5 < worst("jacobi")


def test_footprint_refuses_values_it_cannot_mask():
    """Values of another length than the observed pixels, or NaN among them, are errors; NaN off
    the mask is never read."""
    mask = masks.survey_mask("deep", 16)
    footprint = spectra.Footprint(mask)
    with pytest.raises(ValueError, match="observed pixels"):
        footprint.alm(np.zeros((2, footprint.pixels.size + 1)), 32, 2)
    bad = np.zeros((2, footprint.pixels.size))
    bad[1, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        footprint.alm(bad, 32, 2)
    qu = np.where(mask > 0, 1.0, np.nan) * np.ones((2, 1))
    assert np.all(np.isfinite(spectra.masked_pol_alm(qu, mask, 32)))


def test_a_footprint_keeps_its_pixels_not_the_full_sky_mask():
    """A Footprint holds the observed pixels and their weights only (the full-sky mask is 0.4 GB
    at Nside 2048); its mask is made again, equal to the one it was built from."""
    mask = masks.apodize(masks.survey_mask("deep", 32), 5.0)
    footprint = spectra.Footprint(mask)
    held = [v for v in vars(footprint).values() if isinstance(v, np.ndarray)]
    assert held and all(v.size < mask.size for v in held)
    np.testing.assert_array_equal(footprint.mask, mask)
    assert footprint.npix == mask.size and footprint.nside == 32
    with pytest.raises(ValueError, match="maps have 10 pixels but the mask has 12288"):
        spectra.masked_alm(np.zeros((3, 10)), footprint, 8)


def test_per_ell_is_the_inverse_of_binning_a_flat_band():
    """Per-band values spread on their multipoles bin back to themselves; outside the bands the
    fill."""
    from boresight.spectra import bin_spectrum, per_ell

    edges = np.array([30, 64, 96, 129])
    values = np.array([0.6, 0.85, 0.9])
    spread = per_ell(values, edges, 140, outside=1.0)
    np.testing.assert_allclose(bin_spectrum(spread, edges)[1], values, rtol=1e-15)
    assert np.all(spread[:30] == 1.0) and np.all(spread[129:] == 1.0)
