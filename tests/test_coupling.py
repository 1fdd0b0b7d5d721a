"""The mask's coupling matrices against the direct Wigner-3j sum, Monte Carlo pseudo-C_ell and
NaMaster when installed."""

import healpy as hp
import numpy as np
import pytest
from helpers import rel_max

from boresight import coupling, masks, spectra


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


@pytest.mark.slow
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
