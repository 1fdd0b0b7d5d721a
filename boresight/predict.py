"""Analytic prediction of the spurious polarisation from the spin moments h_n (paper eqs. 5-10).

For the paper's Q pair (0 deg) and U pair (45 deg), naive map-making gives
P_hat = (1/N) sum_j exp(2 i psi_j) (d_1 + i d_2), and to first order (docs/conventions.md):

  gain:     dP = 1/2 h_2 (dg_1 + i dg_2) T  - (dg_1 + dg_2)/4 P  - (dg_1 - dg_2)/4 h_4 P*   (exact)
  leak:     dP = 1/2 h_2 (l_1 + i l_2) S                                                    (exact)
  pointing: dP = -1/4 h_1 G c_1 - 1/4 h_3 G* c_3,   G = dT/dtheta + i dT/dphi / sin(theta),
            c_1 = rho_1 e^{-i chi_1} + rho_2 e^{-i(chi_2 - pi/4)},
            c_3 = rho_1 e^{+i chi_1} + rho_2 e^{+i(chi_2 + 3 pi/4)}                         (O(rho))

with h_n = <exp(i n psi)> over a pixel's crossings. The paper's eq. 6 is the complex conjugate of
these forms (its h_n and gradient use the opposite orientation); amplitudes are identical.

Power spectra: each term c h_n F contributes C^EE = C^BB = |c|^2 / 2 * [coh_n C^FF_l +
(<|h_n|^2> - coh_n) Omega_pix sigma_F^2]: a coherent part from h_n smoothed over blocks of pixels
(what Wallis et al. 2017 write as <|h_n|^2> C^FF) and a white part from the pixel-to-pixel scatter
of h_n. Masked pseudo-C_ell follow through M^{BB,BB} and M^{BB,EE} (paper eq. 10).
"""

import healpy as hp
import numba
import numpy as np

from . import harmonics
from .constants import ARCMIN
from .threads import numba_threads

N_MAX = 4  #: highest spin moment the predictions use
COHERENT_BLOCK = 8  #: h_n is smoothed over (COHERENT_BLOCK)^2 pixels for the coherent part


def supports(instrument):
    """Whether the analytic prediction covers this instrument: the paper's pairs at (0, 45) deg."""
    return instrument is None or tuple(instrument.pair_angles_deg) == (0.0, 45.0)


def _qu_pairs(instrument):
    if not supports(instrument):
        raise ValueError(
            "the analytic prediction needs the paper's pairs at (0, 45) deg, got "
            f"{instrument.pair_angles_deg}"
        )


def pointing_coefficients(rho, chi):
    """(c_1, c_3) of the pointing leak from per-pair rho, chi [rad] of the Q and U pairs."""
    c1 = rho[0] * np.exp(-1j * chi[0]) + rho[1] * np.exp(-1j * (chi[1] - np.pi / 4))
    c3 = rho[0] * np.exp(1j * chi[0]) + rho[1] * np.exp(1j * (chi[1] + 3 * np.pi / 4))
    return c1, c3


def delta_p(sky, h, systematics, instrument=None, template=None, nthreads=0):
    """Predicted spurious P = Q + i U map (complex, npix) from h (>= 5, npix) and the sky.

    Gain and leak terms are exact for pixel-centre hits; pointing is first order in rho.
    """
    _qu_pairs(instrument)
    if h.shape[0] < 5 or h.shape[1] != sky.maps.shape[1]:
        raise ValueError(f"h must have shape (>= 5, {sky.maps.shape[1]}), got {h.shape}")
    dg, rho, chi, leak = systematics.per_pair(2)
    t = sky.maps[0]
    s, grad = np.empty(0), np.empty((2, 0))  # an empty field switches its term off
    if systematics.has_leak:
        s = t if template is None else np.asarray(template, dtype=np.float64)
    c1 = c3 = 0j
    if systematics.has_pointing:
        grad = harmonics.alm2map_gradient(sky.alm[0], sky.nside, nthreads)
        c1, c3 = pointing_coefficients(rho, chi)
    out = np.empty(t.size, dtype=np.complex128)
    with numba_threads(nthreads):
        _delta_p(
            h,
            t,
            sky.maps[1],
            sky.maps[2],
            s,
            grad[0],
            grad[1],
            0.5 * (dg[0] + 1j * dg[1]),
            (dg[0] + dg[1]) / 4,
            (dg[0] - dg[1]) / 4,
            0.5 * (leak[0] + 1j * leak[1]),
            c1,
            c3,
            out,
        )
    return out


@numba.njit(parallel=True, cache=True)
def _delta_p(h, t, q, u, s, grad_theta, grad_phi, a2, common, a4, leak2, c1, c3, out):
    """The gain, leak (if s is not empty) and pointing (if grad is not empty) terms of delta_p."""
    for i in numba.prange(t.size):
        p = complex(q[i], u[i])
        v = a2 * h[2, i] * t[i] - common * p - a4 * h[4, i] * p.conjugate()
        if s.size:
            v += leak2 * h[2, i] * s[i]
        if grad_theta.size:
            g = complex(grad_theta[i], grad_phi[i])
            v -= 0.25 * (h[1, i] * g * c1 + h[3, i] * g.conjugate() * c3)
        out[i] = v


class PixelBlocks:
    """A mask's observed pixels and their blocks of block^2 pixels (the NEST parents at
    nside / block), built once per mask and used for every h_n."""

    def __init__(self, mask, block=COHERENT_BLOCK):
        nside = hp.npix2nside(np.size(mask))
        w = np.asarray(mask, dtype=np.float64)
        self.obs = np.flatnonzero(w)
        self.weight = w[self.obs]
        self.parent = hp.ring2nest(nside, self.obs) // (block * block) if nside >= block else None
        if self.parent is not None:
            self.block_weight = np.bincount(self.parent, weights=self.weight)
            self.used = self.block_weight > 0

    def coherent_power(self, hn):
        """(<|h_n|^2>, coherent part) over the mask: the coherent part averages h_n in blocks."""
        wo, ho = self.weight, hn[self.obs]
        total = np.sum(wo * np.abs(ho) ** 2) / wo.sum()
        if self.parent is None:
            return total, total
        mean_re = np.bincount(self.parent, weights=wo * ho.real)[self.used]
        mean_im = np.bincount(self.parent, weights=wo * ho.imag)[self.used]
        coherent = np.sum((mean_re**2 + mean_im**2) / self.block_weight[self.used]) / wo.sum()
        return total, coherent


def field_spectra(spectra, lmax, fwhm_arcmin):
    """Beam-smoothed TT, EE, BB [muK^2] of a Spectra object for ell <= lmax."""
    tt, ee, bb, _ = spectra.total(lmax=lmax)
    beam = hp.gauss_beam(fwhm_arcmin * ARCMIN, lmax=lmax, pol=True)
    return tt * beam[:, 0] ** 2, ee * beam[:, 1] ** 2, bb * beam[:, 2] ** 2


def leak_terms(systematics, cl_tt, cl_pol, template_cl=None):
    """The (n, coefficient, C^FF) terms of the spurious P for the Q/U pair layout."""
    dg, rho, chi, leak = systematics.per_pair(2)
    ell = np.arange(cl_tt.size)
    terms = [(2, 0.5 * (dg[0] + 1j * dg[1]), cl_tt), (4, (dg[0] - dg[1]) / 4, cl_pol)]
    if systematics.has_leak:
        terms.append(
            (
                2,
                0.5 * (leak[0] + 1j * leak[1]),
                cl_tt if template_cl is None else template_cl[: cl_tt.size],
            )
        )
    if systematics.has_pointing:
        c1, c3 = pointing_coefficients(rho, chi)
        grad = ell * (ell + 1) * cl_tt
        terms += [(1, -0.25 * c1, grad), (3, -0.25 * c3, grad)]
    return terms


def local_cl(sky, mask, lmax, nthreads=0):
    """Beam-smoothed (TT, EE + BB) of one sky realisation inside the mask: pseudo-C_ell / <w^2>.

    Feeding these to :func:`systematic_cl` instead of the theory spectra removes the sample
    variance of the patch when a prediction is compared with a simulation of that sky.
    """
    from .spectra import pseudo_spectra

    cl = pseudo_spectra(sky.maps, mask, lmax, nthreads) / np.mean(np.asarray(mask) ** 2)
    return cl[0], cl[1] + cl[2]


def systematic_cl(
    h,
    mask,
    systematics,
    spectra,
    lmax,
    fwhm_arcmin,
    instrument=None,
    template_cl=None,
    field_cl=None,
):
    """Full-sky spurious C^EE = C^BB [muK^2] (lmax+1,) predicted from h_n over the mask.

    field_cl: optional beam-smoothed (TT, EE + BB) to use instead of the theory (see local_cl).
    """
    _qu_pairs(instrument)
    cl_tt, cl_ee, cl_bb = field_spectra(spectra, lmax, fwhm_arcmin)
    cl_pol = cl_ee + cl_bb
    if field_cl is not None:
        cl_tt, cl_pol = (np.asarray(c)[: lmax + 1] for c in field_cl)
    omega_pix = 4 * np.pi / h.shape[1]
    ell = np.arange(lmax + 1)
    out = np.zeros(lmax + 1)
    blocks = PixelBlocks(mask)
    for n, c, cl_ff in leak_terms(systematics, cl_tt, cl_pol, template_cl):
        if c == 0:
            continue
        total, coherent = blocks.coherent_power(h[n])
        variance = np.sum((2 * ell + 1) / (4 * np.pi) * cl_ff)
        white = (total - coherent) * omega_pix * variance
        out += 0.5 * abs(c) ** 2 * (coherent * cl_ff + white)
    out[:2] = 0.0
    return out


def residual_pseudo_bb(
    h,
    mask,
    coupling,
    systematics,
    spectra,
    fwhm_arcmin,
    instrument=None,
    template_cl=None,
    field_cl=None,
):
    """Predicted masked residual C_BB(sys) - C_BB(no sys) [muK^2] (paper eq. 10).

    Adds the common rescaling of the cosmological signal, (1 - (dg_1 + dg_2)/4)^2 - 1, to the
    leaked power M^{BB,BB} C^BB_sys + M^{BB,EE} C^EE_sys.
    """
    lmax = coupling.lmax
    cl_sys = systematic_cl(
        h, mask, systematics, spectra, lmax, fwhm_arcmin, instrument, template_cl, field_cl
    )
    dg = systematics.per_pair(2)[0]
    _, cl_ee, cl_bb = field_spectra(spectra, lmax, fwhm_arcmin)
    scale = (1 - (dg[0] + dg[1]) / 4) ** 2 - 1
    return coupling.pseudo_bb(cl_sys, cl_sys) + scale * coupling.pseudo_bb(cl_bb, cl_ee)


def rotation_suppression(n, rotations_deg):
    """|h_n|^2 after / before repeating every hit at each angle alpha_k: |<exp(i n alpha_k)>|^2.

    For the schedule (0, alpha) this is cos^2(n alpha / 2).
    """
    alpha = np.radians(np.asarray(rotations_deg, dtype=np.float64))
    return float(np.abs(np.mean(np.exp(1j * n * alpha))) ** 2)


def pixel_window(nside, lmax):
    """Pixel window of a map that averages hits over its pixels, as the window of a disc of the
    pixel's area, 2 J_1(x) / x with x = ell sqrt(4 / npix) (healpy.pixwin needs a download)."""
    from scipy.special import j1

    x = np.arange(lmax + 1) * np.sqrt(4.0 / (12 * nside**2))
    return np.where(x > 0, 2 * j1(x) / np.where(x > 0, x, 1), 1.0)


def reference_bb(coupling, spectra, fwhm_arcmin, nside, r=0.0, a_lens=0.0):
    """Pseudo-C_ell BB of the cosmological B-mode alone (E = 0), with beam and pixel window."""
    lmax = coupling.lmax
    beam = hp.gauss_beam(fwhm_arcmin * ARCMIN, lmax=lmax, pol=True)[:, 2]
    pixwin = pixel_window(nside, lmax)
    cl = spectra.bb(r=r, a_lens=a_lens)[: lmax + 1] * (beam * pixwin) ** 2
    return coupling.even @ cl


# The bias on the tensor-to-scalar ratio r that a residual B-mode spectrum implies.
#
# Estimator: the least-squares amplitude of the tensor template over a multipole range,
#     delta_r = sum_l R_l T_l / sum_l T_l^2,   lmin <= l <= lmax,
# with R_l the residual pseudo-C_BB and T_l the pseudo-C_BB of tensors at r = 1 through the same
# mask, beam and pixel window (reference_bb). Uniform weights: for the deep survey's
# 30 <= l <= 300 the template's shape dominates the weights that cosmic variance would give.

R_RANGE = (30, 300)  #: the deep survey's primordial range


def tensor_template(coupling, spectra, fwhm_arcmin, nside):
    """Pseudo-C_BB [muK^2] of tensors at r = 1 through the mask's coupling matrix."""
    return reference_bb(coupling, spectra, fwhm_arcmin, nside, r=1.0)


def delta_r(residual, template, lmin=R_RANGE[0], lmax=R_RANGE[1]):
    """Tensor-to-scalar ratio a residual pseudo-C_BB would fake (least-squares amplitude)."""
    lmax = min(lmax, residual.size - 1, template.size - 1)
    if lmin >= lmax:
        raise ValueError(f"empty multipole range [{lmin}, {lmax}] for delta_r")
    s = slice(lmin, lmax + 1)
    return float(np.sum(residual[s] * template[s]) / np.sum(template[s] ** 2))
