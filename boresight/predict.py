"""Analytic prediction of the spurious polarisation from the spin moments h_n (paper eqs. 5-10).

A sample j of pair m in rotation repeat k has the assumed angle phi_j = psi_j + alpha_k + a_m.
Its pair difference departs from the ideal Re[P* e^{2 i phi}] by (docs/conventions.md)::

  dd = 1/2 dg_km T + 1/2 l_m S - 1/2 rho_m Re[G e^{-i beta}] + Re[P* e^{2 i phi} gamma_km]

with dg_km = dg_m + dg_repeat_k, beta = phi + chi_m, G = dT/dtheta + i dT/dphi / sin(theta) and
gamma_km = (e^{2i(delta - eps/2)} + (1 - dg_km) e^{2i(delta + eps/2)}) / 2 - 1 (angle errors
delta, eps). The least-squares map-maker turns Y = 2 <e^{2 i phi} dd> into
dP = (Y - H_4 Y*) / (1 - ``|H_4|^2``) with H_4 = m_4 h_4, and to first order in rho::

  Y = t_2 h_2 T + s_2 h_2 S + g_1 h_1 G + g_3 h_3 G* + p_0 P + p_4 h_4 P*

where h_n = <exp(i n psi)> over one repeat's crossings of a pixel and every coefficient is a mean
over (k, m) (:func:`coefficients`): t_2 = <dg e^{2i(alpha+a)}>, s_2 = <l e^{2i(alpha+a)}>,
g_1 = -1/2 <rho e^{i(alpha+a-chi)}>, g_3 = -1/2 <rho e^{i(3(alpha+a)+chi)}>, p_0 = <conj gamma>,
p_4 = <gamma e^{4i(alpha+a)}>, m_4 = <e^{4i(alpha+a)}>. For the paper's pairs at (0, 45) deg and
no repeat these are the paper's eq. 5-9 (its eq. 6 is the complex conjugate of these forms: its
h_n and gradient use the opposite orientation; amplitudes are identical). Gain, leak and angle
terms are exact for pixel-centre hits; pointing is first order in rho.

Power spectra: each term c h_n F contributes C^EE = C^BB = ``|c|^2`` / 2 * [coh_n C^FF_l +
(``<|h_n|^2>`` - coh_n) Omega_pix sigma_F^2]: a coherent part from h_n smoothed over blocks of
pixels (what Wallis et al. 2017 write as ``<|h_n|^2>`` C^FF) and a white part from the
pixel-to-pixel scatter of h_n. The h_0 term rotates and rescales the sky's own polarisation, u P
with u = 1 + p_0. Gain jitter of rms sigma adds white noise of variance
``<sigma^2>`` T^2 / N_samples per pixel. Masked pseudo-C_ell follow through M^{BB,BB} and
M^{BB,EE} (paper eq. 10). The C_ell level needs m_4 = 0 (pairs whose 4 x angles cancel, e.g.
(0, 45) deg or any "uniform" focal plane of 2 or more pairs, or a repeat that cancels h_4); the
map level has no such limit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import healpy as hp
import numba
import numpy as np

from . import harmonics
from .constants import ARCMIN, DEG
from .instrument import Instrument
from .threads import numba_threads

if TYPE_CHECKING:
    from collections.abc import Sequence

    from .cosmology import Spectra
    from .coupling import Coupling
    from .instrument import Systematics
    from .sky import Sky


N_MAX = 4  #: highest spin moment the predictions use
COHERENT_BLOCK = 8  #: h_n is smoothed over (COHERENT_BLOCK)^2 pixels for the coherent part
M4_TOLERANCE = 1e-9  #: ``|m_4|`` below which the map-maker's h_4 coupling vanishes


@dataclass(frozen=True)
class Coefficients:
    """The coefficients of every term of the spurious polarisation (module docstring).

    Parameters
    ----------
    t2, s2, g1, g3, p0, p4 : complex
        Of h_2 T, h_2 S, h_1 G [rad], h_3 G* [rad], P and h_4 P*.
    m4 : complex
        The map-maker's <e^{4i(alpha + a)}> over (repeat, pair).
    jitter_var : float
        ``<sigma^2>`` of the gain jitter over pairs.
    n_samples : int
        Samples per crossing: repeats x pairs.
    """

    t2: complex
    s2: complex
    g1: complex
    g3: complex
    p0: complex
    p4: complex
    m4: complex
    jitter_var: float
    n_samples: int


def coefficients(
    systematics: Systematics,
    instrument: Instrument | None = None,
    rotations_deg: Sequence[float] = (0.0,),
) -> Coefficients:
    """The coefficients of the spurious polarisation of an instrument's systematics.

    Parameters
    ----------
    systematics : boresight.instrument.Systematics
    instrument : boresight.instrument.Instrument, optional
        Default: the paper's pairs at (0, 45) deg.
    rotations_deg : sequence of float
        The boresight rotation of each repeat [deg]; (0,) for a scan whose h_n already include
        its rotations (a real schedule).

    Returns
    -------
    Coefficients
    """
    instrument = Instrument() if instrument is None else instrument
    alpha = np.asarray(rotations_deg, dtype=np.float64) * DEG
    par = systematics.per_pair(instrument.n_pairs)
    ang = alpha[:, None] + instrument.pair_angles_rad[None, :]
    dg = par.dg[None, :] + systematics.per_repeat(alpha.size)[:, None]
    off = par.pol_angle[None, :]
    half = 0.5 * par.nonortho[None, :]
    gamma = 0.5 * (np.exp(2j * (off - half)) + (1 - dg) * np.exp(2j * (off + half))) - 1
    e2 = np.exp(2j * ang)
    return Coefficients(
        t2=complex(np.mean(dg * e2)),
        s2=complex(np.mean(par.leak * e2)),
        g1=complex(-0.5 * np.mean(par.rho * np.exp(1j * (ang - par.chi)))),
        g3=complex(-0.5 * np.mean(par.rho * np.exp(1j * (3 * ang + par.chi)))),
        p0=complex(np.mean(np.conj(gamma))),
        p4=complex(np.mean(gamma * e2**2)),
        m4=complex(np.mean(e2**2)),
        jitter_var=float(np.mean(par.dg_jitter**2)),
        n_samples=int(ang.size),
    )


def supports(instrument: Instrument | None, rotations_deg: Sequence[float] = (0.0,)) -> bool:
    """Whether the C_ell-level prediction covers an instrument and repeats: m_4 = 0.

    Parameters
    ----------
    instrument : boresight.instrument.Instrument or None
        None stands for the paper's pairs.
    rotations_deg : sequence of float

    Returns
    -------
    bool
    """
    from .instrument import Systematics

    return abs(coefficients(Systematics(), instrument, rotations_deg).m4) < M4_TOLERANCE


def _check_supported(coefs):
    if abs(coefs.m4) >= M4_TOLERANCE:
        raise ValueError(
            "the C_ell-level prediction needs pair angles whose 4 x angles cancel over the pairs "
            f"and repeats (m_4 = {coefs.m4:.3g}); use the map-level delta_p"
        )


def delta_p(
    sky: Sky,
    h: np.ndarray,
    systematics: Systematics,
    instrument: Instrument | None = None,
    template: np.ndarray | None = None,
    nthreads: int = 0,
    rotations_deg: Sequence[float] = (0.0,),
) -> np.ndarray:
    """Predicted spurious polarisation P = Q + i U from h_n and the sky, map-maker included.

    Gain, leak and angle terms are exact for pixel-centre hits; pointing is first order in rho.
    Gain jitter, a random term, has zero mean and is left out.

    Parameters
    ----------
    sky : boresight.sky.Sky
    h : numpy.ndarray, complex128, shape (>= 5, npix)
        h_n maps of one repeat's hits (:func:`boresight.engine.scan_moments` of
        ``scan.one_repeat()``), or of a real schedule with its rotations.
    systematics : boresight.instrument.Systematics
    instrument : boresight.instrument.Instrument, optional
        Default: the paper's pairs.
    template : numpy.ndarray, shape (npix,), optional
        The leak's template [muK] (default: the sky's I).
    nthreads : int
    rotations_deg : sequence of float
        The repeats' boresight rotations [deg].

    Returns
    -------
    numpy.ndarray, complex128, shape (npix,)
        [muK].
    """
    if h.shape[0] < 5 or h.shape[1] != sky.maps.shape[1]:
        raise ValueError(f"h must have shape (>= 5, {sky.maps.shape[1]}), got {h.shape}")
    c = coefficients(systematics, instrument, rotations_deg)
    t = sky.maps[0]
    s, grad = np.empty(0), np.empty((2, 0))  # an empty field switches its term off
    if systematics.has_leak:
        s = t if template is None else np.asarray(template, dtype=np.float64)
    if systematics.has_pointing:
        grad = harmonics.alm2map_gradient(sky.alm[0], sky.nside, nthreads)
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
            np.array([c.t2, c.s2, c.g1, c.g3, c.p0, c.p4, c.m4]),
            out,
        )
    return out


@numba.njit(parallel=True, cache=True)
def _delta_p(h, t, q, u, s, grad_theta, grad_phi, c, out):
    """dP of every pixel: the leak term if s is not empty, pointing if grad is not empty; c holds
    (t2, s2, g1, g3, p0, p4, m4)."""
    for i in numba.prange(t.size):
        p = complex(q[i], u[i])
        y = c[0] * h[2, i] * t[i] + c[4] * p + c[5] * h[4, i] * p.conjugate()
        if s.size:
            y += c[1] * h[2, i] * s[i]
        if grad_theta.size:
            g = complex(grad_theta[i], grad_phi[i])
            y += c[2] * h[1, i] * g + c[3] * h[3, i] * g.conjugate()
        h4 = c[6] * h[4, i]
        det = 1.0 - (h4.real**2 + h4.imag**2)
        if h4 == 0:
            out[i] = y
        elif det > 1e-12:
            out[i] = (y - h4 * y.conjugate()) / det
        else:  # one angle only: the simulation flags the pixel invalid
            out[i] = 0.0


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


def leak_terms(coefs, systematics, cl_tt, cl_pol, template_cl=None):
    """The terms c h_n F of the spurious P whose spectra add (all but the h_0 term).

    Parameters
    ----------
    coefs : Coefficients
    systematics : boresight.instrument.Systematics
        Which terms are on (leak, pointing).
    cl_tt, cl_pol : numpy.ndarray, shape (lmax + 1,)
        Spectra of T and of P (EE + BB) [muK^2].
    template_cl : numpy.ndarray, optional
        Spectrum of the leak's template (default: TT).

    Returns
    -------
    list of (int, complex, numpy.ndarray)
        (n, coefficient c, C^FF of the field F).
    """
    ell = np.arange(cl_tt.size)
    terms = [(2, coefs.t2, cl_tt), (4, coefs.p4, cl_pol)]
    if systematics.has_leak:
        terms.append((2, coefs.s2, cl_tt if template_cl is None else template_cl[: cl_tt.size]))
    if systematics.has_pointing:
        grad = ell * (ell + 1) * cl_tt
        terms += [(1, coefs.g1, grad), (3, coefs.g3, grad)]
    return terms


class FieldSpectra(NamedTuple):
    """Beam-smoothed spectra of the fields a prediction scales, (lmax + 1,) [muK^2] each: TT,
    EE + BB (the h_4 P* term) and EE (the h_0 term)."""

    tt: np.ndarray
    pol: np.ndarray
    ee: np.ndarray


def local_cl(sky: Sky, mask: np.ndarray, lmax: int, nthreads: int = 0) -> FieldSpectra:
    """Beam-smoothed TT, EE + BB and EE of one sky inside a mask: pseudo-C_ell / <w^2>.

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
    FieldSpectra
    """
    from .spectra import pseudo_spectra

    cl = pseudo_spectra(sky.maps, mask, lmax, nthreads) / np.mean(np.asarray(mask) ** 2)
    return FieldSpectra(cl[0], cl[1] + cl[2], cl[1])


def systematic_cl(
    h: np.ndarray,
    mask: np.ndarray,
    systematics: Systematics,
    spectra: Spectra,
    lmax: int,
    fwhm_arcmin: float,
    instrument: Instrument | None = None,
    template_cl: np.ndarray | None = None,
    field_cl: FieldSpectra | None = None,
    rotations_deg: Sequence[float] = (0.0,),
    crossings: np.ndarray | None = None,
) -> np.ndarray:
    """Full-sky spurious C^EE = C^BB predicted from h_n over a mask (all terms but h_0).

    Parameters
    ----------
    h : numpy.ndarray, complex128, shape (>= 5, npix)
        h_n of one repeat (as in :func:`delta_p`).
    mask : numpy.ndarray, shape (npix,)
    systematics : boresight.instrument.Systematics
    spectra : boresight.cosmology.Spectra
    lmax : int
    fwhm_arcmin : float
    instrument : boresight.instrument.Instrument, optional
    template_cl : numpy.ndarray, optional
        Spectrum of the leak's template.
    field_cl : FieldSpectra, optional
        Beam-smoothed spectra to use instead of the theory (:func:`local_cl`).
    rotations_deg : sequence of float
        The repeats' boresight rotations [deg].
    crossings : numpy.ndarray, shape (npix,), optional
        Crossings per pixel in one repeat; needed with gain jitter.

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2], 0 at ell < 2.

    Raises
    ------
    ValueError
        m_4 != 0 (:func:`supports`), or jitter without ``crossings``.
    """
    coefs = coefficients(systematics, instrument, rotations_deg)
    _check_supported(coefs)
    cl_tt, cl_ee, cl_bb = field_spectra(spectra, lmax, fwhm_arcmin)
    cl_pol = cl_ee + cl_bb
    if field_cl is not None:
        cl_tt, cl_pol = field_cl.tt[: lmax + 1], field_cl.pol[: lmax + 1]
    omega_pix = 4 * np.pi / h.shape[1]
    ell = np.arange(lmax + 1)
    out = np.zeros(lmax + 1)
    blocks = PixelBlocks(mask)
    for n, c, cl_ff in leak_terms(coefs, systematics, cl_tt, cl_pol, template_cl):
        if c == 0:
            continue
        total, coherent = blocks.coherent_power(h[n])
        variance = np.sum((2 * ell + 1) / (4 * np.pi) * cl_ff)
        white = (total - coherent) * omega_pix * variance
        out += 0.5 * abs(c) ** 2 * (coherent * cl_ff + white)
    if coefs.jitter_var > 0:
        if crossings is None:
            raise ValueError("the gain jitter's prediction needs the crossings per pixel")
        w2 = blocks.weight**2
        inverse_samples = np.sum(w2 / (crossings[blocks.obs] * coefs.n_samples)) / np.sum(w2)
        variance_t = np.sum((2 * ell + 1) / (4 * np.pi) * cl_tt)
        out += 0.5 * omega_pix * coefs.jitter_var * variance_t * inverse_samples
    out[:2] = 0.0
    return out


def signal_bb(
    coupling: Coupling,
    coefs: Coefficients,
    cl_ee: np.ndarray,
    cl_bb: np.ndarray,
    leaked: bool = False,
) -> np.ndarray:
    """Pseudo-C_BB change of the h_0 term, which turns the sky's P into u P with u = 1 + p_0.

    E' + i B' = u (E + i B), so C^B'B' - C^BB = Im(u)^2 C^EE + (Re(u)^2 - 1) C^BB, and E likewise.
    Its leaked power alone, of dB = Im(u) E + (Re(u) - 1) B, has (Re(u) - 1)^2 in place of
    Re(u)^2 - 1: the rest is the cross term 2 (Re(u) - 1) C^BB, a rescaling of the sky's own B.

    Parameters
    ----------
    coupling : boresight.coupling.Coupling
    coefs : Coefficients
    cl_ee, cl_bb : numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    leaked : bool
        The leaked power <dB, dB> only.

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    u = 1 + coefs.p0
    re2, im2 = (u.real - 1) ** 2 if leaked else u.real**2 - 1, u.imag**2
    return re2 * coupling.pseudo_bb(cl_bb, cl_ee) + im2 * coupling.pseudo_bb(cl_ee, cl_bb)


def residual_pseudo_bb(
    h: np.ndarray,
    mask: np.ndarray,
    coupling: Coupling,
    systematics: Systematics,
    spectra: Spectra,
    fwhm_arcmin: float,
    instrument: Instrument | None = None,
    template_cl: np.ndarray | None = None,
    field_cl: FieldSpectra | None = None,
    rotations_deg: Sequence[float] = (0.0,),
    crossings: np.ndarray | None = None,
    leaked: bool = False,
) -> np.ndarray:
    """Predicted masked residual C_BB(sys) - C_BB(no sys) (paper eq. 10).

    The leaked power M^{BB,BB} C^BB_sys + M^{BB,EE} C^EE_sys plus the h_0 term's change of the
    cosmological signal (:func:`signal_bb`; for the paper's gain (1 - (dg_1 + dg_2)/4)^2 - 1).

    Parameters
    ----------
    h, mask, systematics, spectra, fwhm_arcmin, instrument, template_cl, field_cl
        As in :func:`systematic_cl`.
    coupling : boresight.coupling.Coupling
        The mask's coupling matrices; their lmax is the prediction's.
    rotations_deg, crossings
        As in :func:`systematic_cl`.
    leaked : bool
        Predict the leaked power <dB, dB> alone, without the h_0 term's rescaling of the sky's own
        B (:func:`signal_bb`).

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    lmax = coupling.lmax
    cl_sys = systematic_cl(
        h,
        mask,
        systematics,
        spectra,
        lmax,
        fwhm_arcmin,
        instrument,
        template_cl,
        field_cl,
        rotations_deg,
        crossings,
    )
    _, cl_ee, cl_bb = field_spectra(spectra, lmax, fwhm_arcmin)
    if field_cl is not None:  # the patch's E; its masked B would carry the mask's E-to-B leak
        cl_ee = field_cl.ee[: lmax + 1]
    coefs = coefficients(systematics, instrument, rotations_deg)
    signal = signal_bb(coupling, coefs, cl_ee, cl_bb, leaked)
    return coupling.pseudo_bb(cl_sys, cl_sys) + signal


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
