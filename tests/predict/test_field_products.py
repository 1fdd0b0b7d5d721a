"""The exact expected pseudo-C_ell of weights times the sky's fields, against independent routes:
Wigner's explicit sum for d^l, the mask coupling (NaMaster-checked), a direct Wigner-3j sum, and
the covariance of the sky propagated mode by mode through an exact Gauss-Legendre grid."""

import math

import ducc0
import healpy as hp
import numpy as np
import pytest

from boresight import coupling, harmonics
from boresight.kernels import cpu
from boresight.predict import field_products as fp
from boresight.sky import SkyConfig, make_sky

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


def _read_at(sky, field, theta, phi):
    """A sky field's value at points, evaluated exactly (ducc0's synthesis_general)."""
    filters = np.zeros((3, sky.lmax + 1), dtype=np.complex128)
    n = min(field.filters.shape[1], sky.lmax + 1)
    filters[:, :n] = field.filters[:, :n]
    parts = [
        sum(harmonics.almxfl(sky.alm[c], getattr(filters[c], part)) for c in range(3))
        for part in ("real", "imag")
    ]
    if field.spin == 0:
        return harmonics.evaluate(parts[0], theta, phi) + 1j * harmonics.evaluate(
            parts[1], theta, phi
        )
    q, u = harmonics.evaluate(-np.stack(parts), theta, phi, spin=abs(field.spin))
    return q + 1j * u if field.spin > 0 else q - 1j * u


@pytest.mark.parametrize("spin", [0, 2])
def test_a_coordinate_step_is_its_taylor_series(spin):
    """T (spin 0) and P (spin 2) read where detector B looks, one step (rho cos beta, rho sin beta
    / sin theta) away in the coordinates (the engine's kernel, evaluated exactly), less their
    value at A: fp.coordinate_step to first order leaves a residual of order rho^2, to second
    order one of order rho^3 (doubling rho multiplies it by 8.00 at 2000 points, and at rho = 1e-3
    it is 1 % of the first order's); without its cot(theta) and 1 / sin^2(theta) terms, the
    covariant second order alone (a step along the great circle) still leaves one of order rho^2
    (doubling multiplies it by 4.1-4.4)."""
    sky = make_sky(SkyConfig(nside=32, lmax=64, fwhm_arcmin=450.0, seed=3))
    rng = np.random.default_rng(RNG_SEED)
    theta = np.arccos(rng.uniform(-0.9, 0.9, 2000))
    phi, beta = rng.uniform(0.0, 2 * np.pi, (2, 2000))
    window = np.ones(sky.lmax + 1)
    base = fp.temperature(window) if spin == 0 else fp.polarisation(window)
    step = fp.coordinate_step(base)
    cot, csc2 = 1 / np.tan(theta), 1 / np.sin(theta) ** 2
    value = {k: sum(t.scale * cot**t.cot * csc2**t.csc2 * _read_at(sky, t.field, theta, phi)
                    for t in terms) for k, terms in step.items()}  # fmt: skip
    plain = {k: sum(t.scale * _read_at(sky, t.field, theta, phi) for t in terms
                    if t.cot == t.csc2 == 0) for k, terms in step.items()}  # fmt: skip
    at_a = _read_at(sky, base, theta, phi)
    residual = {}
    for rho in (1e-3, 2e-3):
        delta = rho * np.exp(1j * beta)
        zero = np.zeros(1)
        tb, pb = cpu.offset_points(theta, phi, beta, zero, zero, np.array([rho]), zero)
        change = _read_at(sky, base, tb.ravel(), pb.ravel()) - at_a
        weights = {"conj": np.conj(delta), "delta": delta, "conj2": np.conj(delta) ** 2,
                   "delta2": delta**2, "abs2": np.abs(delta) ** 2}  # fmt: skip
        first = change - sum(weights[k] * value[k] for k in ("conj", "delta"))
        second = first - sum(weights[k] * value[k] for k in ("conj2", "delta2", "abs2"))
        covariant = first - sum(weights[k] * plain[k] for k in ("conj2", "delta2", "abs2"))
        residual[rho] = [np.mean(np.abs(r)) for r in (first, second, covariant)]
    growth = np.array(residual[2e-3]) / np.array(residual[1e-3])
    assert 3.5 < growth[0] < 4.5 and 7.5 < growth[1] < 8.5 and growth[2] < 5.0, growth
    assert residual[1e-3][1] < 0.05 * residual[1e-3][0], residual
