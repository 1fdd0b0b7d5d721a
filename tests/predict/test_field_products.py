"""The exact expected pseudo-C_ell of weights times the sky's fields, against independent routes:
Wigner's explicit sum for d^l, the mask coupling (NaMaster-checked), a direct Wigner-3j sum, and
the covariance of the sky propagated mode by mode through an exact Gauss-Legendre grid."""

import math

import ducc0
import healpy as hp
import numpy as np
import pytest

from boresight import coupling
from boresight.predict import field_products as fp

RNG_SEED = 20261202


def _explicit_d(j, mp, m, x):
    """Wigner's sum for d^j_{m' m}(beta) (Varshalovich 4.3.1 (2)), x = cos(beta)."""
    c, s = np.sqrt((1 + x) / 2), np.sqrt((1 - x) / 2)
    total = np.zeros_like(x)
    for k in range(0, 2 * j + 1):
        if j + m - k < 0 or mp - m + k < 0 or j - mp - k < 0:
            continue
        num = math.sqrt(
            math.factorial(j + mp)
            * math.factorial(j - mp)
            * math.factorial(j + m)
            * math.factorial(j - m)
        )
        den = (
            math.factorial(j + m - k)
            * math.factorial(k)
            * math.factorial(mp - m + k)
            * math.factorial(j - mp - k)
        )
        total += (
            (-1) ** (mp - m + k) * num / den * c ** (2 * j + m - mp - 2 * k) * s ** (mp - m + 2 * k)
        )
    return total


@pytest.mark.parametrize(
    "m, mp", [(0, 0), (1, 0), (2, 2), (2, -2), (-1, 3), (3, -1), (4, -4), (0, 2)]
)
def test_wigner_d_equals_wigners_explicit_sum(m, mp):
    x = np.cos(np.linspace(0.01, np.pi - 0.01, 7))
    d = fp.wigner_d(m, mp, 12, x)
    for j in range(13):
        want = _explicit_d(j, m, mp, x) if j >= max(abs(m), abs(mp)) else 0 * x
        # the recursion loses a few ulps per step from its start
        np.testing.assert_allclose(d[j], want, atol=1e-12)


def _sky_cl(band, seed=RNG_SEED):
    """A red TT, EE, BB, TE with |TE| < sqrt(TT EE) (4, band + 1)."""
    ell = np.arange(band + 1.0)
    tt = 1e3 / (ell + 2) ** 2
    ee = 30 / (ell + 3) ** 1.5
    bb = 0.4 * ee
    te = 0.5 * np.sqrt(tt * ee) * np.cos(ell)
    return np.array([tt, ee, bb, te])


def test_a_mask_times_p_is_the_mask_coupling():
    """g = w (spin 0), F = P: the expectation is the mask's coupling of EE and BB."""
    nside, lmax, band = 32, 40, 48
    theta, _ = hp.pix2ang(nside, np.arange(12 * nside**2))
    mask = (theta < 1.1).astype(float) * (1 + 0.3 * np.cos(3 * theta))
    cl = _sky_cl(band)
    got = fp.expected_pseudo_cl(
        [fp.Weight(0, mask + 0j, fp.polarisation(np.ones(band + 1)))], cl, lmax
    )
    want = coupling.mask_coupling(mask, lmax, band=band).pseudo_bb(cl[2], cl[1])
    want_ee = coupling.mask_coupling(mask, lmax, band=band).pseudo_bb(cl[1], cl[2])
    # both are exact quadratures of the same mask spectrum: rounding only
    np.testing.assert_allclose(got.bb, want, rtol=1e-10, atol=1e-12 * want.max())
    np.testing.assert_allclose(got.ee, want_ee, rtol=1e-10, atol=1e-12 * want_ee.max())


def _random_alm(lmax, rng, spin):
    """(2, nalm) random band-limited E, B of a weight (zero below |spin|)."""
    n = hp.Alm.getsize(lmax)
    alm = rng.normal(size=(2, n)) + 1j * rng.normal(size=(2, n))
    ell, m = hp.Alm.getlm(lmax)
    alm[:, m == 0] = alm[:, m == 0].real
    alm[:, ell < abs(spin)] = 0
    return alm / (1 + ell) ** 1.5


def _terms(band):
    """Every kind of leak term: the gain's h_2 T, pointing's h_1 grad and h_3 conj(grad), the
    h_4 P* term and the spin-0 P term."""
    ones = np.exp(-np.arange(band + 1) / 9.0)
    return [
        (2, fp.temperature(ones)),
        (1, fp.gradient(ones)),
        (3, fp.gradient(ones, conjugate=True)),
        (4, fp.polarisation(ones, conjugate=True)),
        (0, fp.polarisation(ones)),
    ]


def _harmonic_sum(alms, spins, fields, cl, lmax):
    """<C~^BB_L> as the sum over l1 l2 of the weights' and fields' spectra times 3j symbols
    (docs/conventions.md), with ducc0's Schulten-Gordon 3j."""
    band = fields[0].band
    lw = lmax + band
    w, v = fp.weight_cross_spectra(alms, spins, lw)
    c, d = fp.field_cross_spectra(fields, cl)
    out = np.zeros(lmax + 1)
    for big_l in range(2, lmax + 1):
        p = q = 0.0
        for l2 in range(band + 1):
            for i, (_s, f) in enumerate(zip(spins, fields)):
                t = f.spin
                if abs(t) > l2:  # the field has no such multipole
                    continue
                lo_a, three_a = ducc0.misc.wigner3j_int(l2, big_l, -t, 2)  # (l1 l2 L; -s -t 2)
                lo_b, three_b = ducc0.misc.wigner3j_int(l2, big_l, t, -2)  # (l1 l2 L; s t -2)
                for j, (_sp, fq) in enumerate(zip(spins, fields)):
                    if abs(fq.spin) > l2:
                        continue
                    lo_c, three_c = ducc0.misc.wigner3j_int(l2, big_l, -fq.spin, 2)
                    for l1 in range(max(lo_a, lo_c), min(lo_a + three_a.size, lo_c + three_c.size)):
                        if l1 > lw:
                            continue
                        norm = (2 * l1 + 1) * (2 * l2 + 1)
                        p += (
                            norm
                            * w[i, j, l1]
                            * c[i, j, l2]
                            * three_a[l1 - lo_a]
                            * three_c[l1 - lo_c]
                        )
                        if lo_b <= l1 < lo_b + three_b.size:
                            q += (
                                norm
                                * v[i, j, l1]
                                * d[i, j, l2]
                                * three_b[l1 - lo_b]
                                * three_c[l1 - lo_c]
                            )
        out[big_l] = (p - q).real / (8 * np.pi)
    return out


def test_the_quadrature_equals_a_direct_wigner_3j_sum():
    lmax, band = 10, 6
    rng = np.random.default_rng(RNG_SEED)
    terms = _terms(band)
    spins = [s for s, _ in terms]
    fields = [f for _, f in terms]
    alms = [_random_alm(lmax + band, rng, s) for s in spins]
    cl = _sky_cl(band)
    got = fp.expected_pseudo_cl_alm(alms, spins, fields, cl, lmax).bb
    want = _harmonic_sum(alms, spins, fields, cl, lmax)
    # two exact evaluations of one sum: rounding only
    np.testing.assert_allclose(got[2:], want[2:], rtol=1e-9)


def _gl_map(alm, spin, lmax, ntheta, nphi):
    """A spin-s field on a Gauss-Legendre grid from its (E, B) alm; negative spin: conjugate of
    the spin-|s| field; spin 0: Re from E, Im from B."""
    opts = dict(lmax=lmax, geometry="GL", ntheta=ntheta, nphi=nphi)
    if spin == 0:
        re, im = (ducc0.sht.experimental.synthesis_2d(alm=a[None], spin=0, **opts)[0] for a in alm)
        return re + 1j * im
    qu = ducc0.sht.experimental.synthesis_2d(alm=alm, spin=abs(spin), **opts)
    z = qu[0] + 1j * qu[1]
    return np.conj(z) if spin < 0 else z


def _sky_modes(band, cl):
    """Unit-variance basis of the sky's T, E, B alm (3, nalm) with covariance cl: one vector per
    real degree of freedom, TE correlated through a Cholesky factor per l."""
    n = hp.Alm.getsize(band)
    ell, m = hp.Alm.getlm(band)
    for idx in range(n):
        l_ = ell[idx]
        tt, ee, bb, te = cl[:, l_]
        if ee == 0:  # l < 2: T alone
            chol = np.array([[np.sqrt(tt), 0.0], [0.0, 0.0]])
        else:
            chol = np.linalg.cholesky(np.array([[tt, te], [te, ee]]))
        parts = (1.0,) if m[idx] == 0 else (np.sqrt(0.5), 1j * np.sqrt(0.5))
        for part in parts:
            for col in range(3):
                alm = np.zeros((3, n), dtype=np.complex128)
                if col < 2:
                    alm[0, idx], alm[1, idx] = chol[0, col] * part, chol[1, col] * part
                else:
                    alm[2, idx] = np.sqrt(bb) * part
                yield alm


def test_the_expectation_is_the_sky_covariance_propagated_mode_by_mode():
    """Independent of the 3j algebra and of the spin-sign conventions: each of the sky's modes
    is put on an exact Gauss-Legendre grid, through every field and weight, multiplied, summed
    and analysed to its B pseudo-spectrum; their sum is the expectation."""
    lmax, lw_band, band = 8, 6, 5
    rng = np.random.default_rng(RNG_SEED + 1)
    terms = _terms(band)
    spins = [s for s, _ in terms]
    fields = [f for _, f in terms]
    alms = [_random_alm(lw_band, rng, s) for s in spins]
    cl = _sky_cl(band)
    cl[1:, :2] = 0.0  # E and B start at l = 2
    degree = lw_band + band + lmax
    ntheta, nphi = degree + 2, 2 * degree + 2
    weights = [_gl_map(a, s, lw_band, ntheta, nphi) for a, s in zip(alms, spins)]
    want = np.zeros(lmax + 1)
    for sky in _sky_modes(band, cl):
        total = sum(
            g * _gl_map(f.alm(sky), f.spin, band, ntheta, nphi) for g, f in zip(weights, fields)
        )
        eb = ducc0.sht.experimental.analysis_2d(
            map=np.array([total.real, total.imag]), spin=2, lmax=lmax, geometry="GL"
        )
        want += hp.alm2cl(eb[1])
    lw = lmax + band
    padded = [_resize(a, lw_band, lw) for a in alms]
    got = fp.expected_pseudo_cl_alm(padded, spins, fields, cl, lmax).bb
    # both exact; the grid's quadrature is exact for the product's band limit
    np.testing.assert_allclose(got[2:], want[2:], rtol=1e-8)


def _resize(alm, lmax_in, lmax_out):
    """(2, nalm) alm zero-padded from lmax_in to lmax_out."""
    out = np.zeros((alm.shape[0], hp.Alm.getsize(lmax_out)), dtype=alm.dtype)
    ell, m = hp.Alm.getlm(lmax_in)
    out[:, hp.Alm.getidx(lmax_out, ell, m)] = alm
    return out


def test_the_kernels_give_a_weighted_sum_of_the_expectation():
    """bb_kernels' linear form in the weights' spectra equals sum_L weight_L <C~^BB_L> of the
    spectra themselves, for random weights of every kind of term and random coefficients'
    moments."""
    lmax, band = 12, 6
    rng = np.random.default_rng(RNG_SEED + 2)
    terms = _terms(band)
    spins = [s for s, _ in terms]
    fields = [f for _, f in terms]
    alms = [_random_alm(lmax + band, rng, s) for s in spins]
    c = rng.normal(size=len(spins)) + 1j * rng.normal(size=len(spins))
    second, pseudo = np.outer(c, np.conj(c)), np.outer(c, c)
    cl = _sky_cl(band)
    weight_l = rng.normal(size=lmax + 1)
    weight_l[:2] = 0.0
    bb = fp.expected_pseudo_cl_alm(alms, spins, fields, cl, lmax, second=second, pseudo=pseudo).bb
    kappa_w, kappa_v = fp.bb_kernels(spins, fields, cl, weight_l, second=second, pseudo=pseudo)
    w, v = fp.weight_cross_spectra(alms, spins, lmax + band)
    value = np.real(np.sum(kappa_w * w) - np.sum(kappa_v * v))
    # one quadrature summed two ways: rounding only
    assert value == pytest.approx(np.sum(weight_l * bb), rel=1e-10)


@pytest.mark.parametrize("field", ["temperature", "gradient", "conjugate gradient", "P", "P*"])
def test_the_derivatives_are_edth_and_its_conjugate(field):
    """d T is the gradient of fp.gradient (ducc0's DERIV1) and dbar T its conjugate; on any
    spin s, dbar d = edth-bar edth = -(l - s)(l + s + 1), the spin-weighted
    harmonics' identity, and d dbar = edth edth-bar = -(l + s)(l - s + 1), for conjugate fields
    too."""
    band = 40
    ell = np.arange(band + 1)
    window = np.exp(-ell / 30.0)
    fields = {
        "temperature": fp.temperature(window),
        "gradient": fp.gradient(window),
        "conjugate gradient": fp.gradient(window, conjugate=True),
        "P": fp.polarisation(window),
        "P*": fp.polarisation(window, conjugate=True),
    }
    f = fields[field]
    if field == "temperature":
        up, down = fp.derivative(f, raising=True), fp.derivative(f, raising=False)
        assert (up.spin, down.spin) == (1, -1)
        np.testing.assert_allclose(up.filters, fp.gradient(window).filters, rtol=1e-14)
        np.testing.assert_allclose(
            down.coefficients, fp.gradient(window, conjugate=True).coefficients, rtol=1e-14
        )
    s = f.spin
    down_up = fp.derivative(fp.derivative(f, raising=True), raising=False)
    up_down = fp.derivative(fp.derivative(f, raising=False), raising=True)
    assert down_up.spin == up_down.spin == s
    laplacian = -(ell - s) * (ell + s + 1.0)
    np.testing.assert_allclose(down_up.coefficients, laplacian * f.coefficients, atol=1e-12)
    np.testing.assert_allclose(
        up_down.coefficients, -(ell + s) * (ell - s + 1.0) * f.coefficients, atol=1e-12
    )
