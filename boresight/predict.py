"""Analytic prediction of the spurious polarisation from the spin moments h_n (paper eqs. 5-10).

For the paper's Q pair (0 deg) and U pair (45 deg), naive map-making gives
P_hat = (1/N) sum_j exp(2 i psi_j) (d_1 + i d_2), and to first order (docs/conventions.md)::

  gain:     dP = 1/2 h_2 (dg_1 + i dg_2) T  - (dg_1 + dg_2)/4 P  - (dg_1 - dg_2)/4 h_4 P*   (exact)
  leak:     dP = 1/2 h_2 (l_1 + i l_2) S                                                    (exact)
  pointing: dP = -1/4 h_1 G c_1 - 1/4 h_3 G* c_3,   G = dT/dtheta + i dT/dphi / sin(theta),
            c_1 = rho_1 e^{-i chi_1} + rho_2 e^{-i(chi_2 - pi/4)},
            c_3 = rho_1 e^{+i chi_1} + rho_2 e^{+i(chi_2 + 3 pi/4)}                         (O(rho))

with h_n = <exp(i n psi)> over a pixel's crossings. The paper's eq. 6 is the complex conjugate of
these forms (its h_n and gradient use the opposite orientation); amplitudes are identical.

Power spectra: each term c h_n F contributes C^EE = C^BB = ``|c|^2`` / 2 * [coh_n C^FF_l +
(``<|h_n|^2>`` - coh_n) Omega_pix sigma_F^2]: a coherent part from h_n smoothed over blocks of
pixels (what Wallis et al. 2017 write as ``<|h_n|^2>`` C^FF) and a white part from the
pixel-to-pixel scatter of h_n. Masked pseudo-C_ell follow through M^{BB,BB} and M^{BB,EE}
(paper eq. 10).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import healpy as hp
import numba
import numpy as np

from . import harmonics
from .constants import ARCMIN
from .threads import numba_threads

if TYPE_CHECKING:
    from collections.abc import Sequence

    from .cosmology import Spectra
    from .coupling import Coupling
    from .instrument import Instrument, Systematics
    from .sky import Sky


N_MAX = 4  #: highest spin moment the predictions use
COHERENT_BLOCK = 8  #: h_n is smoothed over (COHERENT_BLOCK)^2 pixels for the coherent part


def supports(instrument):
    """Whether the analytic prediction covers an instrument: the paper's pairs at (0, 45) deg.

    Parameters
    ----------
    instrument : boresight.instrument.Instrument or None
        None stands for the paper's pairs.

    Returns
    -------
    bool
    """
    return instrument is None or tuple(instrument.pair_angles_deg) == (0.0, 45.0)


def _qu_pairs(instrument):
    if not supports(instrument):
        raise ValueError(
            "the analytic prediction needs the paper's pairs at (0, 45) deg, got "
            f"{instrument.pair_angles_deg}"
        )


def pointing_coefficients(rho, chi):
    """The complex coefficients of the pointing leak (module docstring).

    Parameters
    ----------
    rho, chi : numpy.ndarray, shape (2,)
        Per-pair offset and direction [rad] of the Q and U pairs.

    Returns
    -------
    c_1, c_3 : complex
        [rad]: dP = -1/4 h_1 G c_1 - 1/4 h_3 G* c_3.
    """
    c1 = rho[0] * np.exp(-1j * chi[0]) + rho[1] * np.exp(-1j * (chi[1] - np.pi / 4))
    c3 = rho[0] * np.exp(1j * chi[0]) + rho[1] * np.exp(1j * (chi[1] + 3 * np.pi / 4))
    return c1, c3


def delta_p(
    sky: Sky,
    h: np.ndarray,
    systematics: Systematics,
    instrument: Instrument | None = None,
    template: np.ndarray | None = None,
    nthreads: int = 0,
) -> np.ndarray:
    """Predicted spurious polarisation P = Q + i U from h_n and the sky.

    Gain and leak terms are exact for pixel-centre hits; pointing is first order in rho.

    Parameters
    ----------
    sky : boresight.sky.Sky
    h : numpy.ndarray, complex128, shape (>= 5, npix)
        h_n maps (:func:`boresight.engine.scan_moments`).
    systematics : boresight.instrument.Systematics
    instrument : boresight.instrument.Instrument, optional
        Must be the paper's Q/U pairs (None: assumed).
    template : numpy.ndarray, shape (npix,), optional
        The leak's template [muK] (default: the sky's I).
    nthreads : int

    Returns
    -------
    numpy.ndarray, complex128, shape (npix,)
        [muK].
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
    """A mask's observed pixels grouped in blocks of block^2 pixels (NEST parents at nside / block),
    built once per mask and used for every h_n.

    Parameters
    ----------
    mask : numpy.ndarray, shape (npix,)
    block : int
        Side of a block in pixels.
    """

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
        """``<|h_n|^2>`` over the mask and its coherent part.

        Parameters
        ----------
        hn : numpy.ndarray, complex128, shape (npix,)

        Returns
        -------
        total : float
            Mask-weighted mean of ``|h_n|^2``.
        coherent : float
            The same of h_n averaged in blocks (equal to total when Nside < block).
        """
        wo, ho = self.weight, hn[self.obs]
        total = np.sum(wo * np.abs(ho) ** 2) / wo.sum()
        if self.parent is None:
            return total, total
        mean_re = np.bincount(self.parent, weights=wo * ho.real)[self.used]
        mean_im = np.bincount(self.parent, weights=wo * ho.imag)[self.used]
        coherent = np.sum((mean_re**2 + mean_im**2) / self.block_weight[self.used]) / wo.sum()
        return total, coherent


def field_spectra(spectra, lmax, fwhm_arcmin):
    """Beam-smoothed spectra of the sky.

    Parameters
    ----------
    spectra : boresight.cosmology.Spectra
    lmax : int
    fwhm_arcmin : float

    Returns
    -------
    tt, ee, bb : numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    tt, ee, bb, _ = spectra.total(lmax=lmax)
    beam = hp.gauss_beam(fwhm_arcmin * ARCMIN, lmax=lmax, pol=True)
    return tt * beam[:, 0] ** 2, ee * beam[:, 1] ** 2, bb * beam[:, 2] ** 2


def leak_terms(systematics, cl_tt, cl_pol, template_cl=None):
    """The terms c h_n F of the spurious P for the Q/U pair layout.

    Parameters
    ----------
    systematics : boresight.instrument.Systematics
    cl_tt, cl_pol : numpy.ndarray, shape (lmax + 1,)
        Spectra of T and of P (EE + BB) [muK^2].
    template_cl : numpy.ndarray, optional
        Spectrum of the leak's template (default: TT).

    Returns
    -------
    list of (int, complex, numpy.ndarray)
        (n, coefficient c, C^FF of the field F).
    """
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


def local_cl(
    sky: Sky, mask: np.ndarray, lmax: int, nthreads: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Beam-smoothed (TT, EE + BB) of one sky inside a mask: pseudo-C_ell / <w^2>.

    Feeding these to :func:`systematic_cl` instead of the theory removes the patch's sample variance
    when a prediction is compared with a simulation of that sky.

    Parameters
    ----------
    sky : boresight.sky.Sky
    mask : numpy.ndarray, shape (npix,)
    lmax : int
    nthreads : int

    Returns
    -------
    tt, pol : numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    from .spectra import pseudo_spectra

    cl = pseudo_spectra(sky.maps, mask, lmax, nthreads) / np.mean(np.asarray(mask) ** 2)
    return cl[0], cl[1] + cl[2]


def systematic_cl(
    h: np.ndarray,
    mask: np.ndarray,
    systematics: Systematics,
    spectra: Spectra,
    lmax: int,
    fwhm_arcmin: float,
    instrument: Instrument | None = None,
    template_cl: np.ndarray | None = None,
    field_cl: tuple | None = None,
) -> np.ndarray:
    """Full-sky spurious C^EE = C^BB predicted from h_n over a mask.

    Parameters
    ----------
    h : numpy.ndarray, complex128, shape (>= 5, npix)
    mask : numpy.ndarray, shape (npix,)
    systematics : boresight.instrument.Systematics
    spectra : boresight.cosmology.Spectra
    lmax : int
    fwhm_arcmin : float
    instrument : boresight.instrument.Instrument, optional
    template_cl : numpy.ndarray, optional
        Spectrum of the leak's template.
    field_cl : tuple of numpy.ndarray, optional
        Beam-smoothed (TT, EE + BB) to use instead of the theory (:func:`local_cl`).

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2], 0 at ell < 2.
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
    h: np.ndarray,
    mask: np.ndarray,
    coupling: Coupling,
    systematics: Systematics,
    spectra: Spectra,
    fwhm_arcmin: float,
    instrument: Instrument | None = None,
    template_cl: np.ndarray | None = None,
    field_cl: tuple | None = None,
) -> np.ndarray:
    """Predicted masked residual C_BB(sys) - C_BB(no sys) (paper eq. 10).

    Adds the common rescaling of the cosmological signal, (1 - (dg_1 + dg_2)/4)^2 - 1, to the leaked
    power M^{BB,BB} C^BB_sys + M^{BB,EE} C^EE_sys.

    Parameters
    ----------
    h, mask, systematics, spectra, fwhm_arcmin, instrument, template_cl, field_cl
        As in :func:`systematic_cl`.
    coupling : boresight.coupling.Coupling
        The mask's coupling matrices; their lmax is the prediction's.

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    lmax = coupling.lmax
    cl_sys = systematic_cl(
        h, mask, systematics, spectra, lmax, fwhm_arcmin, instrument, template_cl, field_cl
    )
    dg = systematics.per_pair(2)[0]
    _, cl_ee, cl_bb = field_spectra(spectra, lmax, fwhm_arcmin)
    scale = (1 - (dg[0] + dg[1]) / 4) ** 2 - 1
    return coupling.pseudo_bb(cl_sys, cl_sys) + scale * coupling.pseudo_bb(cl_bb, cl_ee)


def rotation_suppression(n: int, rotations_deg: Sequence[float]) -> float:
    """``|h_n|^2`` after / before repeating every hit at each angle alpha_k:
    ``|<exp(i n alpha_k)>|^2``.

    For the schedule (0, alpha) this is cos^2(n alpha / 2).

    Parameters
    ----------
    n : int
    rotations_deg : sequence of float

    Returns
    -------
    float
    """
    alpha = np.radians(np.asarray(rotations_deg, dtype=np.float64))
    return float(np.abs(np.mean(np.exp(1j * n * alpha))) ** 2)


def pixel_window(nside: int, lmax: int) -> np.ndarray:
    """Window of a map that averages hits over its pixels: the window of a disc of the pixel's area,
    2 J_1(x) / x with x = ell sqrt(4 / npix) (healpy.pixwin needs a download).

    Parameters
    ----------
    nside, lmax : int

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
    """
    from scipy.special import j1

    x = np.arange(lmax + 1) * np.sqrt(4.0 / (12 * nside**2))
    return np.where(x > 0, 2 * j1(x) / np.where(x > 0, x, 1), 1.0)


def reference_bb(
    coupling: Coupling,
    spectra: Spectra,
    fwhm_arcmin: float,
    nside: int,
    r: float = 0.0,
    a_lens: float = 0.0,
) -> np.ndarray:
    """Pseudo-C_BB of the cosmological B-mode alone (E = 0), with beam and pixel window.

    Parameters
    ----------
    coupling : boresight.coupling.Coupling
    spectra : boresight.cosmology.Spectra
    fwhm_arcmin : float
    nside : int
    r, a_lens : float

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
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


def tensor_template(
    coupling: Coupling, spectra: Spectra, fwhm_arcmin: float, nside: int
) -> np.ndarray:
    """Pseudo-C_BB of tensors at r = 1 through the mask: the template of :func:`delta_r`.

    Parameters
    ----------
    coupling, spectra, fwhm_arcmin, nside
        As in :func:`reference_bb`.

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    return reference_bb(coupling, spectra, fwhm_arcmin, nside, r=1.0)


def delta_r(
    residual: np.ndarray, template: np.ndarray, lmin: int = R_RANGE[0], lmax: int = R_RANGE[1]
) -> float:
    """The tensor-to-scalar ratio a residual pseudo-C_BB would fake: the least-squares amplitude of
    the template over lmin <= ell <= lmax.

    Parameters
    ----------
    residual, template : numpy.ndarray
        Pseudo-C_BB [muK^2] from ell = 0.
    lmin, lmax : int

    Returns
    -------
    float
    """
    lmax = min(lmax, residual.size - 1, template.size - 1)
    if lmin >= lmax:
        raise ValueError(f"empty multipole range [{lmin}, {lmax}] for delta_r")
    s = slice(lmin, lmax + 1)
    return float(np.sum(residual[s] * template[s]) / np.sum(template[s] ** 2))
