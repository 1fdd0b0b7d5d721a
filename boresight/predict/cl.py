"""The C_ell-level prediction: each term c h_n F of the spurious P contributes C^EE = C^BB =
``|c|^2`` / 2 [coh_n C^FF + (``<|h_n|^2>`` - coh_n) Omega_pix sigma_F^2] (a coherent part from h_n
averaged over blocks of pixels, a white part from its pixel-to-pixel scatter), the h_0 term
rescales the sky's own polarisation, and the mask's coupling (paper eq. 10) makes the residual
pseudo-C_BB. It needs m_4 = 0 (pairs whose 4 x angles cancel); the map level has no such limit."""

from __future__ import annotations

from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, NamedTuple

import healpy as hp
import numba
import numpy as np

from .. import harmonics
from .._util import interrupts
from .._util.jit import njit
from ..instrument.added import refuse as refuse_added
from ..spectra import Footprint, as_footprint
from .beam_fields import BEAM_N_MAX, beam_filters, beam_h0_bb, beam_power, beam_spectra
from .coefficients import (
    check_supported,
    coefficients,
    expected_coefficients,
    expected_power,
    jitter_variance,
)
from .sky_spectra import FieldSpectra, field_spectra
from .windows import HitSpread, mean_inverse_hits

if TYPE_CHECKING:
    from collections.abc import Sequence

    from ..cosmology import Spectra
    from ..coupling import Coupling
    from ..instrument.pairs import Instrument, Systematics
    from ..sky import Sky
    from .coefficients import Coefficients, ExpectedPower


COHERENT_BLOCK = 8  #: h_n is smoothed over (COHERENT_BLOCK)^2 pixels for the coherent part


class PixelBlocks:
    """A mask's observed pixels grouped in blocks of block^2 pixels (NEST parents at nside / block),
    built once per mask and used for every h_n.

    Parameters
    ----------
    mask : numpy.ndarray, shape (npix,), or boresight.spectra.Footprint
        The mask, or its footprint (whose pixels and weights the blocks then share).
    block : int
        Side of a block in pixels.
    """

    def __init__(self, mask, block=COHERENT_BLOCK):
        footprint = as_footprint(mask)
        nside = footprint.nside
        self.obs, self.weight = footprint.pixels, footprint.weights
        self.parent = footprint.parents(block) if nside >= block else None
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
        wo = self.weight
        parent = self.parent if self.parent is not None else np.zeros(0, dtype=np.int32)
        nblock = 0 if self.parent is None else self.block_weight.size
        power, sum_re, sum_im = _block_sums(hn, self.obs, wo, parent, nblock)
        total = np.sum(power) / wo.sum()
        if self.parent is None:
            return total, total
        mean_re, mean_im = sum_re[self.used], sum_im[self.used]
        coherent = np.sum((mean_re**2 + mean_im**2) / self.block_weight[self.used]) / wo.sum()
        return total, coherent


@njit(parallel=True)
def _block_sums(hn, obs, weight, parent, nblock):
    """w |h|^2 at each observed pixel, and the sums of w h over each block (none when nblock is
    0) in pixel order, as numpy's bincount adds them: the same sums whatever the thread count."""
    power = np.empty(obs.size)
    for i in numba.prange(obs.size):
        h = hn[obs[i]]
        power[i] = weight[i] * (h.real * h.real + h.imag * h.imag)
    sum_re, sum_im = np.zeros(nblock), np.zeros(nblock)
    if nblock > 0:
        for i in range(obs.size):
            h = hn[obs[i]]
            sum_re[parent[i]] += weight[i] * h.real
            sum_im[parent[i]] += weight[i] * h.imag
    return power, sum_re, sum_im


class Term(NamedTuple):
    """One term c h_n F of the spurious P (with, for a pair of beam terms, its partner
    c' h_{-n} F'): its moment n (h_{-n} = conj h_n), coefficient c, the spectra [muK^2] whose
    halves its E and B modes take (equal but for such a pair), and whether the engine reads its
    field exactly at the hits (the beams' fields) rather than by interpolation of the sky's maps."""

    n: int
    c: complex
    cl_e: np.ndarray
    cl_b: np.ndarray
    exact: bool = False


def leak_terms(
    coefs,
    systematics,
    cl_tt,
    cl_pol,
    *,
    template_cl=None,
    beam=None,
    beam_cl=None,
    t2_mean=None,
):
    """The terms c h_n F of the spurious P whose spectra add (all but the h_0 terms).

    Parameters
    ----------
    coefs : Coefficients
    systematics : boresight.instrument.pairs.Systematics
        Which terms are on (leak, pointing).
    cl_tt, cl_pol : numpy.ndarray, shape (lmax + 1,)
        Spectra of T and of P (EE + BB) [muK^2].
    template_cl : numpy.ndarray, optional
        Spectrum of the leak's template (default: TT).
    beam : dict of int to numpy.ndarray, optional
        The beam terms' filters (:func:`beam_filters`): G_2 joins the gain's h_2 T term, every
        other n but 0 is a term of its own.
    beam_cl : numpy.ndarray, shape (4, >= lmax + 1), optional
        The TT, EE, BB, TE those terms scale (:func:`beam_spectra`); required with ``beam``.
    t2_mean : complex, optional
        E t2 when ``coefs`` holds expected powers (:func:`expected_coefficients`): the h_2 term is
        then E``|t2 T + G_2|^2`` = ``|coefs.t2|^2`` TT + 2 Re(E t2 conj(g_T)) TT
        + 2 Re(E t2 conj(g_E)) TE + ``|G_2|^2``.

    Returns
    -------
    list of Term
        With ``beam``, the first (h_2: gain and G_2) and those after the others carry the beams.
    """
    refuse_added(systematics, "the C_ell level (its spectra assume a field finer than h_n)")
    ell = np.arange(cl_tt.size)
    terms = [Term(2, coefs.t2, cl_tt, cl_tt), Term(4, coefs.p4, cl_pol, cl_pol)]
    if systematics.has_leak:
        template = cl_tt if template_cl is None else np.zeros(cl_tt.size)
        if template_cl is not None:  # zero beyond the template's own band limit
            n = min(cl_tt.size, template_cl.size)
            template[:n] = template_cl[:n]
        terms.append(Term(2, coefs.s2, template, template))
    if systematics.has_pointing:
        grad = ell * (ell + 1) * cl_tt
        terms += [Term(1, coefs.g1, grad, grad), Term(3, coefs.g3, grad, grad)]
    if beam is not None:
        terms[0] = Term(2, 1.0, *_gain_and_beam(coefs, beam, beam_cl, t2_mean), exact=True)
        for n, filt in beam.items():
            if n in (0, 2, -2) or (n < 0 and -n in beam):
                continue  # h_0 is beam_h0_bb's; a negative n with a partner goes with it
            partner = np.conj(beam.get(-n, np.zeros_like(filt))) * (-1) ** n
            if not (np.any(filt) or np.any(partner)):
                continue
            cl_e, cl_b = (beam_power(filt + sign * partner, beam_cl) for sign in (1, -1))
            terms.append(Term(n, 1.0, cl_e, cl_b, exact=True))
    return terms


def _gain_and_beam(coefs, beam, beam_cl, t2_mean):
    """E and B spectra of the h_2 terms with the beams: t2 T + G_2 and its partner G_{-2}, whose
    B modes subtract (docs/conventions.md); with ``t2_mean``, averaged over the gain's draws."""
    g2 = beam[2]
    partner = np.conj(beam.get(-2, np.zeros_like(g2)))
    out = []
    for v in (g2 + partner, g2 - partner):
        if t2_mean is None:
            out.append(beam_power(v + np.array([coefs.t2, 0, 0])[:, None], beam_cl))
            continue
        tt, te = beam_cl[0], beam_cl[3]
        cross = (
            2 * np.real(t2_mean * np.conj(v[0])) * tt + 2 * np.real(t2_mean * np.conj(v[1])) * te
        )
        out.append(abs(coefs.t2) ** 2 * tt + cross + beam_power(v, beam_cl))
    return out


def systematic_cl(
    h: np.ndarray,
    mask: np.ndarray | Footprint,
    systematics: Systematics,
    theory: Spectra,
    lmax: int,
    *,
    fwhm_arcmin: float,
    instrument: Instrument | None = None,
    template_cl: np.ndarray | None = None,
    field_cl: FieldSpectra | None = None,
    rotations_deg: Sequence[float] = (0.0,),
    crossings: np.ndarray | None = None,
    in_pixel: str = "centre",
    expected: bool = False,
    interpolated: bool = False,
) -> np.ndarray:
    """Full-sky spurious C^EE and C^BB predicted from h_n over a mask (all terms but h_0).

    Every term shares its power equally between E and B but the beams' pairs of terms h_n G_n
    and h_{-n} G_{-n}, whose B modes partly cancel (docs/conventions.md).

    Parameters
    ----------
    h : numpy.ndarray, complex128, shape (>= 5, npix)
        h_n of one repeat (as in :func:`delta_p`); the beams' terms use the moments it holds, to
        :data:`BEAM_N_MAX`.
    mask : numpy.ndarray, shape (npix,), or boresight.spectra.Footprint
    systematics : boresight.instrument.pairs.Systematics
    theory : boresight.cosmology.Spectra
        Lensed LCDM and tensor spectra [muK^2].
    lmax : int
        The sky's band limit: every field's power to it enters, also that a mask later mixes
        below a lower lmax of the pseudo-spectra (a :class:`boresight.coupling.Coupling`'s band).
    fwhm_arcmin : float
    instrument : boresight.instrument.pairs.Instrument, optional
    template_cl : numpy.ndarray, optional
        Spectrum of the leak's template.
    field_cl : FieldSpectra, optional
        Beam-smoothed spectra to use instead of the theory (:func:`local_cl`) where they reach.
    rotations_deg : sequence of float
        The repeats' boresight rotations [deg].
    crossings : numpy.ndarray, shape (npix,), optional
        Crossings per pixel in one repeat; needed with gain jitter or random in-pixel hits.
    in_pixel : {"centre", "random"}
        Where the scan's hits fall in their pixels (``SyntheticScan.in_pixel``): "random" adds
        the pixel window and the in-pixel scatter of every field (:class:`HitSpread`).
    expected : bool
        The average over the per-pair draws of {mean, rms} parameters (:func:`expected_power`)
        instead of the drawn focal plane.
    interpolated : bool
        With random in-pixel hits: the sky's fields are read by bilinear interpolation of the
        maps (the engine's ``evaluation="interp"``), so the terms of T, P, the leak's template and
        the pointing take :func:`interpolation_window`; the beams' terms are read exactly.

    Returns
    -------
    numpy.ndarray, shape (2, lmax + 1)
        C^EE, C^BB [muK^2], 0 at ell < 2.

    Raises
    ------
    ValueError
        m_4 != 0 (:func:`supports`), or jitter or random hits without ``crossings``.
    """
    coefs = coefficients(systematics, instrument, rotations_deg)
    check_supported(coefs)
    t2_mean = None
    if expected:
        power = expected_power(systematics, instrument, rotations_deg)
        coefs, t2_mean = expected_coefficients(coefs, power), power.t2_mean
    nside = hp.npix2nside(h.shape[1])
    band = lmax  # the fields' variance and spectra to the sky's band limit
    cl_tt, cl_pol = _field_cl(theory, band, fwhm_arcmin, field_cl)
    omega_pix = 4 * np.pi / h.shape[1]
    ell = np.arange(band + 1)
    out = np.zeros((2, lmax + 1))
    footprint = as_footprint(mask)
    blocks = PixelBlocks(footprint)
    beam = beam_cl = None
    if systematics.has_beams:  # the patch's spectra through the apodized mask: beam_spectra
        n_max = min(BEAM_N_MAX, h.shape[0] - 1)
        beam = beam_filters(systematics, instrument, rotations_deg, fwhm_arcmin, band, n_max=n_max)
        beam_cl = beam_spectra(theory, band, fwhm_arcmin, field_cl)
    inverse_hits = mean_inverse_hits(in_pixel, footprint, crossings)
    exact = HitSpread(in_pixel, nside, band, inverse_hits)
    value = HitSpread(in_pixel, nside, band, inverse_hits, interpolated)
    slope = value  # replaced for the pointing terms below
    if systematics.has_pointing:
        slope = HitSpread(in_pixel, nside, band, inverse_hits, interpolated, gradient=True)
    terms = leak_terms(
        coefs,
        systematics,
        cl_tt,
        cl_pol,
        template_cl=template_cl,
        beam=beam,
        beam_cl=beam_cl,
        t2_mean=t2_mean,
    )
    for n, c, cl_e, cl_b, read_exactly in terms:
        if c == 0:
            continue
        total, coherent = blocks.coherent_power(h[abs(n)])
        spread = exact if read_exactly else slope if n in (1, 3) else value  # 1, 3: pointing
        (cl_e, noise_e), (cl_b, noise_b) = spread(cl_e), spread(cl_b)
        variance = np.sum((2 * ell + 1) / (4 * np.pi) * (cl_e + cl_b)) / 2
        white = (total - coherent) * omega_pix * variance + (noise_e + noise_b) / 2
        for row, cl in enumerate((cl_e, cl_b)):
            out[row] += 0.5 * abs(c) ** 2 * (coherent * cl[: lmax + 1] + white)
    jitter_var = jitter_variance(systematics, coefs, expected)
    if jitter_var > 0:
        if crossings is None:
            raise ValueError(
                "the gain jitter's prediction needs the scan's crossings per pixel (crossings=)"
            )
        w2 = blocks.weight**2
        inverse_samples = np.sum(w2 / (crossings[blocks.obs] * coefs.n_samples)) / np.sum(w2)
        point = value.point if value.on else 1.0  # T's variance where the hits read it
        variance_t = np.sum((2 * ell + 1) / (4 * np.pi) * cl_tt * point)
        out += 0.5 * omega_pix * jitter_var * variance_t * inverse_samples
    out[:, :2] = 0.0
    return out


def _field_cl(theory, band, fwhm_arcmin, field_cl):
    """TT and EE + BB to ``band``: the patch's own (``field_cl``) where it has them, else the
    theory's."""
    cl_tt, cl_ee, cl_bb = field_spectra(theory, band, fwhm_arcmin)
    cl_pol = cl_ee + cl_bb
    if field_cl is not None:
        n = min(band + 1, field_cl.tt.size)
        cl_tt[:n], cl_pol[:n] = field_cl.tt[:n], field_cl.pol[:n]
    return cl_tt, cl_pol


def signal_bb(
    coupling: Coupling,
    coefs: Coefficients,
    cl_ee: np.ndarray,
    cl_bb: np.ndarray,
    *,
    leaked: bool = False,
    expected: ExpectedPower | None = None,
    masked: np.ndarray | None = None,
) -> np.ndarray:
    """Pseudo-C_BB change of the h_0 term, which turns the sky's P into u P with u = 1 + p_0.

    E' + i B' = u (E + i B), so dB = Im(u) E + (Re(u) - 1) B. Its leaked power <dB, dB> is
    (Re u - 1)^2 BB + Im(u)^2 EE + 2 (Re u - 1) Im(u) EB; the whole change adds the cross terms
    2 (Re u - 1) BB + 2 Im(u) EB. For full-sky spectra (EB = 0) that is Im(u)^2 C^EE +
    (Re(u)^2 - 1) C^BB through the mask's coupling. As u is one number for the whole map, the
    maps' own masked pseudo-spectra (``masked``) give it exactly, the mask's E-to-B leakage of
    this very sky included.

    Parameters
    ----------
    coupling : boresight.coupling.Coupling
    coefs : Coefficients
    cl_ee, cl_bb : numpy.ndarray, shape (lmax + 1,)
        Full-sky spectra [muK^2], used without ``masked``.
    leaked : bool
        The leaked power <dB, dB> only.
    expected : ExpectedPower, optional
        Use its averages of p_0's powers over the per-pair draws instead of coefs'.
    masked : numpy.ndarray, shape (3, lmax + 1), optional
        The maps' pseudo-C_ell EE, BB, EB through the mask [muK^2].

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    if expected is None:
        w = coefs.p0
        re, im, re2, im2, reim = w.real, w.imag, w.real**2, w.imag**2, w.real * w.imag
    else:
        e = expected
        re, im, re2, im2, reim = e.re_p0, e.im_p0, e.re_p0_2, e.im_p0_2, e.re_im_p0
    if masked is None:
        ee, bb = coupling.pseudo_bb(cl_ee, cl_bb), coupling.pseudo_bb(cl_bb, cl_ee)
        eb = np.zeros_like(ee)
    else:
        ee, bb, eb = masked[:, : coupling.lmax + 1]
    out = re2 * bb + im2 * ee + 2 * reim * eb
    if not leaked:
        out = out + 2 * re * bb + 2 * im * eb
    return out


@dataclass(frozen=True)
class Prediction:
    """What the h_n prediction of a residual needs besides the scan and the systematics.

    Parameters
    ----------
    theory : boresight.cosmology.Spectra
        Lensed LCDM and tensor spectra [muK^2].
    couplings : boresight.coupling.Coupling
        The mask's coupling at the prediction's lmax, from the sky's band limit (its ``band``).
    fwhm_arcmin : float
        The sky's Gaussian beam [arcmin].
    field_cl : FieldSpectra or concurrent.futures.Future, optional
        Spectra [muK^2] of the sky inside the mask (:func:`local_cl`), which removes the patch's
        sample variance from the comparison; default: the theory.
    leaked : bool
        Predict the leaked power <dB, dB> alone, without the h_0 term's rescaling of the sky's own
        B (:func:`signal_bb`), rather than the whole residual.
    map_checks : int, optional
        How many jobs will read :meth:`gradient`: it is let go after the last of them (the
        caller's copy only is left); default: kept until :meth:`release`.
    """

    theory: Spectra
    couplings: Coupling
    fwhm_arcmin: float
    field_cl: FieldSpectra | Future | None = None
    leaked: bool = False
    map_checks: int | None = None
    _held: dict = field(default_factory=dict, repr=False, compare=False)

    def resolved_field_cl(self) -> FieldSpectra | None:
        """:attr:`field_cl`, waited for where it is still being computed."""
        if isinstance(self.field_cl, Future):
            return interrupts.result(self.field_cl)
        return self.field_cl

    def gradient(self, sky: Sky, pixels: np.ndarray, nthreads: int = 0) -> np.ndarray:
        """The sky's dT/dtheta, dT/dphi / sin(theta) at ``pixels``, (2, n), kept for the next
        job's map-level prediction on the same sky and pixels (the jobs of one mask share both)
        until :attr:`map_checks` jobs have read it.
        """
        held = self._held.get("gradient")
        if held is None or held[0] is not sky or held[1] is not pixels:
            grad = harmonics.alm2map_gradient(sky.alm[0], sky.nside, nthreads, pixels)
            held = self._held["gradient"] = (sky, pixels, grad)
        self._held["reads"] = self._held.get("reads", 0) + 1
        if self._held["reads"] == self.map_checks:
            self.release()
        return held[2]

    @property
    def last_map_check(self) -> bool:
        """Whether the next read of :meth:`gradient` lets it go (:attr:`map_checks`)."""
        return self._held.get("reads", 0) + 1 == self.map_checks

    def release(self):
        """Drop what :meth:`gradient` keeps (0.3 GB on the wide mask at Nside 2048) once no
        other job will check its map."""
        self._held.clear()


def residual_pseudo_bb(
    h: np.ndarray,
    mask: np.ndarray | Footprint,
    prediction: Prediction,
    systematics: Systematics,
    *,
    instrument: Instrument | None = None,
    template_cl: np.ndarray | None = None,
    rotations_deg: Sequence[float] = (0.0,),
    crossings: np.ndarray | None = None,
    in_pixel: str = "centre",
    expected: bool = False,
    interpolated: bool = False,
    sky: Sky | None = None,
    analysis: str = "auto",
) -> np.ndarray:
    """Predicted masked residual C_BB(sys) - C_BB(no sys) (paper eq. 10).

    The leaked power M^{BB,BB} C^BB_sys + M^{BB,EE} C^EE_sys plus the h_0 term's change of the
    cosmological signal (:func:`signal_bb`; for the paper's gain (1 - (dg_1 + dg_2)/4)^2 - 1),
    plus the beams' h_0 field (:func:`beam_h0_bb`; its cross term with an angle error's
    rotation of E is left out). With the prediction's ``field_cl`` the h_0 term of u uses the
    maps' own masked spectra (:func:`signal_bb`).

    Parameters
    ----------
    h, mask, systematics, instrument, template_cl
        As in :func:`systematic_cl`; ``mask`` may be its :class:`boresight.spectra.Footprint`.
    prediction : Prediction
        The theory, the mask's coupling (its lmax is the prediction's, its band the sky's band
        limit, to which the fields' power enters: what the mask mixes down from above lmax
        included), the sky's beam, its spectra inside the mask and whether to predict the leaked
        power alone.
    rotations_deg, crossings, in_pixel, expected, interpolated
        As in :func:`systematic_cl`.
    sky : boresight.sky.Sky, optional
        The simulated sky: the beams' h_0 field is then made on the sphere and masked
        (:func:`beam_h0_bb`), so its leaked power is this realisation's.
    analysis : str
        How that masked field becomes pseudo-alm (:func:`boresight.harmonics.map2alm`).

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    coupling, theory, fwhm_arcmin = (
        prediction.couplings,
        prediction.theory,
        prediction.fwhm_arcmin,
    )
    field_cl, leaked = prediction.resolved_field_cl(), prediction.leaked
    lmax, band = coupling.lmax, coupling.band
    mask = as_footprint(mask)  # the observed pixels, once for every use below
    inverse_hits = mean_inverse_hits(in_pixel, mask, crossings)
    cl_sys = systematic_cl(
        h,
        mask,
        systematics,
        theory,
        band,
        fwhm_arcmin=fwhm_arcmin,
        instrument=instrument,
        template_cl=template_cl,
        field_cl=field_cl,
        rotations_deg=rotations_deg,
        crossings=crossings,
        in_pixel=in_pixel,
        expected=expected,
        interpolated=interpolated,
    )
    nside = hp.npix2nside(h.shape[1])
    _, cl_ee, cl_bb = field_spectra(theory, band, fwhm_arcmin)
    if field_cl is not None:  # the patch's E; its masked B would carry the mask's E-to-B leak
        n = min(band + 1, field_cl.ee.size)
        cl_ee[:n] = field_cl.ee[:n]
    masked = None if field_cl is None else field_cl.masked
    if masked is not None and masked.shape[1] < lmax + 1:
        raise ValueError(f"field_cl holds the maps' spectra to {masked.shape[1] - 1} < lmax {lmax}")
    if in_pixel == "random":  # the maps' P as the hits read it: windowed, plus in-pixel scatter
        spread = HitSpread(in_pixel, nside, band, inverse_hits, interpolated)
        (cl_ee, noise_e), (cl_bb, noise_b) = spread(cl_ee), spread(cl_bb)
        white = 0.5 * (noise_e + noise_b)
        cl_ee, cl_bb = cl_ee + white, cl_bb + white
        if masked is not None:
            scatter = coupling.pseudo_bb(np.full(band + 1, white), np.full(band + 1, white))
            if sky is not None:  # the maps as the hits read them, masked: window, then mask
                read = {} if field_cl.read is None else field_cl.read
                key = (interpolated, lmax, analysis)
                if key not in read:
                    read[key] = _windowed_masked(sky, np.sqrt(spread.pair), mask, lmax, analysis)
                masked = read[key]
            else:
                masked = masked[:, : lmax + 1] * spread.pair[: lmax + 1]
            masked = masked + [
                scatter,
                scatter,
                np.zeros_like(scatter),
            ]
    coefs = coefficients(systematics, instrument, rotations_deg)
    power = expected_power(systematics, instrument, rotations_deg) if expected else None
    signal = signal_bb(coupling, coefs, cl_ee, cl_bb, leaked=leaked, expected=power, masked=masked)
    if systematics.has_beams:
        g0 = beam_filters(systematics, instrument, rotations_deg, fwhm_arcmin, band, n_max=0)[0]
        beam_cl = beam_spectra(theory, band, fwhm_arcmin, field_cl)
        spread = HitSpread(in_pixel, nside, band, inverse_hits)
        h0 = beam_h0_bb(
            coupling,
            g0,
            beam_cl,
            leaked=leaked,
            spread=spread,
            sky=sky,
            mask=mask,
            analysis=analysis,
        )
        signal = signal + h0
    return coupling.pseudo_bb(cl_sys[1], cl_sys[0]) + signal


def _windowed_masked(sky, window, mask, lmax, analysis):
    """EE, BB, EB pseudo-C_ell (3, lmax + 1) of the sky's Q, U smoothed by ``window`` (per ell),
    then masked: the mask's E-to-B leakage of the maps the hits read."""
    n = min(window.size, sky.lmax + 1)
    alm = harmonics.almxfl(sky.alm[1:], np.pad(window[:n], (0, sky.lmax + 1 - n)))
    footprint = as_footprint(mask)  # the maps on the observed pixels only
    qu = harmonics.alm2map_pixels(alm, footprint.pixels, sky.nside, spin=2)
    del alm  # not beside the analysis's own (0.24 GB each at lmax 4000)
    e, b = footprint.alm(qu, lmax, 2, analysis=analysis, overwrite=True)
    return np.array([harmonics.alm2cl(e), harmonics.alm2cl(b), harmonics.alm2cl(e, b)])
