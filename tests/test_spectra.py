import healpy as hp
import numpy as np
import pytest
from conftest import rel_max

from boresight import coupling, harmonics, masks, spectra


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


def test_coupling_matches_direct_wigner_sum():
    """ducc0's matrices against the textbook sum over ducc0.misc.wigner3j_int (another routine)."""
    from ducc0.misc import wigner3j_int

    mask = masks.survey_mask("deep", 16)
    lmax = 24
    couplings = coupling.mask_coupling(mask, lmax)
    w = coupling.mask_spectrum(mask, 2 * lmax)
    for l1, l2 in [(2, 2), (5, 9), (17, 3), (24, 24)]:
        for s, mats in ((0, (couplings.tt,)), (2, (couplings.even, couplings.odd))):
            lmin, w3 = wigner3j_int(l1, l2, s, -s)
            big_l = lmin + np.arange(w3.size)
            keep = big_l <= 2 * lmax
            big_l, w3 = big_l[keep], w3[keep]
            base = (2 * l2 + 1) / (4 * np.pi) * (2 * big_l + 1) * w[big_l] * w3**2
            parity = (-1.0) ** (l1 + l2 + big_l)
            wants = (
                [base.sum()]
                if s == 0
                else [(base * (1 + parity) / 2).sum(), (base * (1 - parity) / 2).sum()]
            )
            for m, want in zip(mats, wants):
                assert np.isclose(m[l1, l2], want, rtol=1e-12, atol=1e-18)


@pytest.mark.parametrize("survey, band", [("deep", 128), ("wide", 128), ("deep", 191)])
def test_real_space_coupling_is_the_wigner_3j_matrices(survey, band):
    """pseudo_bb (a product of correlation functions, Gauss-Legendre quadrature) against the
    matrices of ducc0's Wigner-3j routine: E only (the E-to-B part), B only, and both; also from
    full-sky spectra to a band above lmax (the rectangular matrices).

    Measured: <= 4e-11 relative at every l, <= 1.3e-14 of the spectrum's peak."""
    lmax = 128
    couplings = coupling.mask_coupling(masks.survey_mask(survey, 64), lmax, band=band)
    ell = np.arange(band + 1)
    wiggle = np.random.default_rng(1).uniform(0.5, 1.5, band + 1)
    cl_ee, cl_bb, zero = wiggle / (ell + 5.0) ** 2, 0.3 / (ell + 3.0) ** 2.5, np.zeros(band + 1)
    if band > lmax:  # the band above lmax is counted
        cut = couplings.pseudo_bb(cl_bb[: lmax + 1], cl_ee[: lmax + 1])
        assert np.all(couplings.pseudo_bb(cl_bb, cl_ee)[lmax - 10 :] > 1.05 * cut[lmax - 10 :])
    for bb, ee in ((zero, cl_ee), (cl_bb, zero), (cl_bb, cl_ee)):
        got, want = couplings.pseudo_bb(bb, ee), couplings.even @ bb + couplings.odd @ ee
        assert np.all(got[:2] == 0.0)
        assert np.max(np.abs(got[2:] / want[2:] - 1)) < 1e-10
        assert np.max(np.abs(got - want)) < 5e-14 * np.max(want)
    tiny = coupling.mask_coupling(masks.survey_mask(survey, 64), 1)  # no l >= 2 to couple
    assert np.array_equal(tiny.pseudo_bb(np.ones(2), np.ones(2)), np.zeros(2))


def test_coupling_predicts_monte_carlo_pseudo_cl():
    """<pseudo C_l> over 200 Gaussian skies of known C_l equals M C_l (E-only input: EE and BB,
    through the real-space coupling; TT through its matrix).

    Each band mean has a Monte-Carlo error of ~1/sqrt(200 x modes): bounds are ~4 sigma.
    """
    nside, lmax = 32, 64
    mask = masks.survey_mask("wide", nside)
    couplings = coupling.mask_coupling(mask, lmax)
    ell = np.arange(lmax + 1)
    cl = np.where(ell >= 2, 1.0 / (ell + 10.0) ** 2, 0.0)
    zero = np.zeros_like(cl)
    acc = np.zeros((3, lmax + 1))
    n_sim = 200
    for i in range(n_sim):
        np.random.seed(i)
        maps = hp.synfast([cl, cl, zero, zero], nside, lmax=lmax, new=True)
        ps = spectra.pseudo_spectra(maps, mask, lmax)
        acc += ps[:3] / n_sim
    edges = spectra.linear_bins(4, lmax - 4, 10)
    for got, want in (
        (acc[0], couplings.tt @ cl),
        (acc[1], couplings.pseudo_bb(cl, zero)),  # pseudo-C_EE, by the E <-> B symmetry
        (acc[2], couplings.pseudo_bb(zero, cl)),
    ):
        _, g = spectra.bin_spectrum(got, edges)
        _, w = spectra.bin_spectrum(want, edges)
        assert np.all(np.abs(g / w - 1) < 0.06), g / w


def test_coupling_matches_namaster_when_installed():
    nmt = pytest.importorskip("pymaster")
    nside, lmax = 32, 60
    mask = masks.survey_mask("wide", nside)
    couplings = coupling.mask_coupling(mask, lmax)
    b = nmt.NmtBin.from_lmax_linear(lmax, 1)
    f0 = nmt.NmtField(mask, None, spin=0, lmax=lmax)
    f2 = nmt.NmtField(mask, None, spin=2, lmax=lmax)
    w00 = nmt.NmtWorkspace.from_fields(f0, f0, b)
    w22 = nmt.NmtWorkspace.from_fields(f2, f2, b)
    m00 = w00.get_coupling_matrix()
    m22 = w22.get_coupling_matrix().reshape(lmax + 1, 4, lmax + 1, 4)
    assert rel_max(couplings.tt[2:, 2:], m00[2:, 2:]) < 1e-4
    assert rel_max(couplings.even[2:, 2:], m22[2:, 0, 2:, 0]) < 1e-4
    assert rel_max(couplings.odd[2:, 2:], m22[2:, 0, 2:, 3]) < 1e-4


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
