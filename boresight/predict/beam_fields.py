"""The detectors' beam terms: detector X's extra signal is a sum over its beam's azimuthal moments
k of spin-k fields F_k of the sky (T, E and B) times e^{-i k psi_X}, so the map gains terms
h_n G_n, n = 2 -+ k: the width's nabla^2 T and the ellipticity's eth-bar^2 P at h_2, the
ellipticity's eth^2 T at h_0 (which no rotation changes) and h_4, its eth^2 P at h_{-2} and h_6.
:data:`BEAM_N_MAX` covers every term of first order in the ellipticity."""

from __future__ import annotations

from typing import TYPE_CHECKING

import healpy as hp
import numpy as np

from .. import harmonics
from ..constants import ARCMIN
from ..instrument.beams import moment_filters, pair_beams
from ..spectra import masked_pol_alm
from .coefficients import drawn_pairs

if TYPE_CHECKING:
    from collections.abc import Sequence

    from ..cosmology import Spectra
    from ..coupling import Coupling
    from ..instrument.pairs import Instrument, PairParameters, Systematics
    from ..sky import Sky
    from .sky_spectra import FieldSpectra
    from .windows import HitSpread


BEAM_N_MAX = 6  #: the beams' terms reach h_6 at first order in the ellipticity (eth^2 P)


def beam_filters(
    systematics: Systematics,
    instrument: Instrument | None,
    rotations_deg: Sequence[float],
    fwhm_arcmin: float,
    lmax: int,
    *,
    n_max: int = BEAM_N_MAX,
) -> dict[int, np.ndarray]:
    """The filters of the detectors' beam terms h_n G_n of Y, -n_max <= n <= n_max.

    Detector X's extra signal is F_0 + sum_k 2 Re[F_k e^{-i k psi_X}]
    (:func:`boresight.instrument.beams.moment_filters`), so with psi_X = phi + c_X Y gains, from each
    detector, s_X g_X [h_2 F_0 + sum_k (h_{2-k} e^{-i k c_X} F_k + h_{2+k} e^{i k c_X} F_k*)],
    each h_n carrying its repeat's and pair's phase e^{i n (alpha + a)}, means over (repeat, pair)
    (docs/conventions.md). G_n is a spin-(2 - n) field for n <= 2, and for n > 2 the conjugate
    of a spin-(n - 2) field H_n; the filters give G_n's (or H_n's) harmonic coefficients as
    sum_c filter[c, l] a^c_lm over the sky's beam-smoothed T, E, B alm.

    Parameters
    ----------
    systematics : boresight.instrument.pairs.Systematics
    instrument : boresight.instrument.pairs.Instrument or None
    rotations_deg : sequence of float
    fwhm_arcmin : float
        The sky's beam.
    lmax, n_max : int

    Returns
    -------
    dict of int to numpy.ndarray
        n -> complex array of shape (3, lmax + 1); h_{-n} = conj(h_n).
    """
    instrument, alpha, par = drawn_pairs(systematics, instrument, rotations_deg)
    return pairs_beam_filters(
        par,
        instrument.pair_angles_rad,
        alpha,
        systematics.per_repeat(alpha.size),
        fwhm_arcmin=fwhm_arcmin,
        lmax=lmax,
        n_max=n_max,
    )


def pairs_beam_filters(
    par: PairParameters,
    pair_angles: np.ndarray,
    alpha: np.ndarray,
    dg_repeat: np.ndarray,
    *,
    fwhm_arcmin: float,
    lmax: int,
    n_max: int = BEAM_N_MAX,
) -> dict[int, np.ndarray]:
    """:func:`beam_filters` of pairs given by their parameters: the mean over the pairs and the
    repeats of each pair's filters. For one pair, its own (a focal plane's pairs each have their
    own moments, :mod:`boresight.predict.focalplane`).

    Parameters
    ----------
    par : boresight.instrument.pairs.PairParameters
        (M,) each.
    pair_angles : numpy.ndarray, shape (M,)
        The pairs' nominal angles [rad].
    alpha, dg_repeat : numpy.ndarray, shape (K,)
        The repeats' rotations [rad] and gain drifts.
    fwhm_arcmin : float
    lmax, n_max : int

    Returns
    -------
    dict of int to numpy.ndarray
        As :func:`beam_filters`.
    """
    nominal = fwhm_arcmin * ARCMIN
    smoothing = hp.gauss_beam(nominal, lmax=lmax, pol=True).T[:3]  # (T, E, B), (3, lmax + 1)
    kmax = n_max + 2
    ang = alpha[:, None] + pair_angles[None, :]  # (K, M)
    gain_b = 1 - (par.dg[None, :] + dg_repeat[:, None])
    angle_a, angle_b = par.angle_errors()
    offset = {"a": angle_a, "b": angle_b + np.pi / 2}  # c_X: the detector's angle from the assumed
    out = {n: np.zeros((3, lmax + 1), dtype=np.complex128) for n in range(-n_max, n_max + 1)}
    cache = {}
    for m, beam_pair in enumerate(pair_beams(par, nominal)):
        for detector, beam, sign, gain in zip("ab", beam_pair, (1, -1), (1.0, gain_b[:, m])):
            if beam not in cache:
                cache[beam] = moment_filters(beam, nominal, lmax, kmax)
            g = cache[beam]
            weight = sign * gain * np.ones(alpha.size)  # (K,)
            c = offset[detector][m]
            for k in range(kmax + 1):
                # F_k enters at h_{2-k}; F_k* at h_{2+k}, as H_n = conj(weight) F_k
                for n, phase in ((2 - k, 1j * (2 - k)), (2 + k, -1j * (2 + k)))[: 1 + (k > 0)]:
                    if abs(n) <= n_max:
                        out[n] += np.mean(weight * np.exp(phase * ang[:, m] - 1j * k * c)) * g[k]
    n = pair_angles.size
    return {key: f / n / np.where(smoothing > 0, smoothing, np.inf) for key, f in out.items()}


def beam_power(filt: np.ndarray, cl: np.ndarray) -> np.ndarray:
    """The power spectrum of a field whose coefficients are sum_c filt[c] a^c_lm.

    Parameters
    ----------
    filt : numpy.ndarray, shape (3, lmax + 1)
        On T, E, B; real or complex.
    cl : numpy.ndarray, shape (4, >= lmax + 1)
        TT, EE, BB, TE [muK^2].

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    tt, ee, bb, te = cl[:, : filt.shape[1]]
    t, e, b = filt
    return (
        np.abs(t) ** 2 * tt
        + np.abs(e) ** 2 * ee
        + np.abs(b) ** 2 * bb
        + 2 * np.real(t * np.conj(e)) * te
    )


def beam_field(sky, filt, spin, nthreads):
    """The spin-``spin`` field with coefficients sum_c filt[c] a^c_lm of the sky's T, E, B,
    (npix,) complex (for spin > 0, Q + i U of healpy's (E', B') = -(Re, Im) of the sum)."""
    n = min(filt.shape[1], sky.lmax + 1)
    padded = np.zeros((3, sky.lmax + 1), dtype=np.complex128)  # nothing beyond the filter's band
    padded[:, :n] = filt[:, :n]
    parts = [
        sum(harmonics.almxfl(sky.alm[c], getattr(padded[c], part)) for c in range(3))
        for part in ("real", "imag")
    ]
    if spin == 0:
        return harmonics.alm2map(parts[0], sky.nside, nthreads=nthreads) + 1j * harmonics.alm2map(
            parts[1], sky.nside, nthreads=nthreads
        )
    qu = harmonics.alm2map(-np.stack(parts), sky.nside, spin=spin, nthreads=nthreads)
    return qu[0] + 1j * qu[1]


def beam_spectra(
    theory: Spectra, band: int, fwhm_arcmin: float, field_cl: FieldSpectra | None = None
) -> np.ndarray:
    """The beam-smoothed TT, EE, BB, TE that the beam terms scale: the patch's through the
    apodized mask where ``field_cl`` has them (:func:`local_cl` with ``beams=True``), else the
    theory's.

    The sharp mask's pseudo-C_ell / <w^2> carries the mask's mixing of low-ell power into high
    ell, which the l^4 weight of nabla^2 T and eth^2 T turned into a 20x overshoot at ell > 600
    for a 30 arcmin beam at Nside 512; the theory alone misses the patch's sample variance
    (11 % in a band at Nside 256).

    Parameters
    ----------
    theory : boresight.cosmology.Spectra
    band : int
    fwhm_arcmin : float
    field_cl : FieldSpectra, optional

    Returns
    -------
    numpy.ndarray, shape (4, band + 1)
        [muK^2].
    """
    # healpy's TE window is sqrt(b_T b_E), so every column squared is the spectrum's window
    cl = theory.total(lmax=band) * hp.gauss_beam(fwhm_arcmin * ARCMIN, band, pol=True).T ** 2
    if field_cl is not None and field_cl.apodized is not None:
        n = min(band + 1, field_cl.apodized.shape[1])
        cl[:, :n] = field_cl.apodized[:, :n]
    return cl


def beam_h0_bb(
    coupling: Coupling,
    g0: np.ndarray,
    cl: np.ndarray,
    *,
    leaked: bool = False,
    spread: HitSpread | None = None,
    sky: Sky | None = None,
    mask: np.ndarray | None = None,
    analysis: str = "auto",
) -> np.ndarray:
    """Pseudo-C_BB of the beams' h_0 term, which no rotation changes.

    G_0 = sum_c g0[c] a^c is a spin-2 field: its E' and B' have the real filters -Re g0 and
    -Im g0 on (T, E, B) (a pure-E field rotated by the phase of g0; for an ellipticity,
    E' + i B' = -g0_T T to first order). Its leaked power is C^E'E', C^B'B'; the whole residual
    adds the cross terms 2 C^EE' and 2 C^BB' with the sky's own E and B (a smoothing of P).

    Parameters
    ----------
    coupling : boresight.coupling.Coupling
    g0 : numpy.ndarray, complex128, shape (3, band + 1)
        The h_0 filter of :func:`beam_filters`.
    cl : numpy.ndarray, shape (4, band + 1)
        TT, EE, BB, TE [muK^2] (:func:`beam_spectra`).
    leaked : bool
        The leaked power alone.
    spread : HitSpread, optional
        Hits spread over their pixels, the field read exactly at each (default: pixel centres).
    sky, mask : optional
        The simulated sky and the mask: G_0 is then made on the sphere and its leaked power is
        its own masked pseudo-C_ell (windowed by the hits' spread, plus their scatter), this
        realisation's E-to-B leakage included, rather than the coupling's average.
    analysis : str
        How the masked field becomes pseudo-alm (:func:`boresight.harmonics.map2alm`).

    Returns
    -------
    numpy.ndarray, shape (coupling.lmax + 1,)
        [muK^2].
    """
    lmax, band = coupling.lmax, coupling.band
    e_filt, b_filt = -g0.real, -g0.imag
    (cl_e, noise_e), (cl_b, noise_b) = (
        (beam_power(f, cl), 0.0) if spread is None else spread(beam_power(f, cl))
        for f in (e_filt, b_filt)
    )
    white = 0.5 * (noise_b + noise_e)  # the scatter's phase is random: half in each of E, B
    if sky is not None:
        field = beam_field(sky, g0, 2, 0)
        qu = np.array([field.real, field.imag])
        _e_alm, b_alm = masked_pol_alm(qu, mask, lmax, analysis=analysis)
        window = spread.pair[: lmax + 1] if spread is not None and spread.on else 1.0
        scatter = coupling.pseudo_bb(np.full(band + 1, white), np.full(band + 1, white))
        out = harmonics.alm2cl(b_alm) * window + scatter
        if leaked:
            return out
        cl_e, cl_b = np.zeros(band + 1), np.zeros(band + 1)  # the cross terms below only
    else:
        out = 0.0
        cl_e, cl_b = cl_e[: band + 1] + white, cl_b[: band + 1] + white
    if not leaked:  # <E E'> = f_T TE + f_E EE, <B B'> = f_B BB, averaged over the pixel's hits
        window = spread.pair if spread is not None and spread.on else 1.0
        cross_e = 2 * (e_filt[0] * cl[3] + e_filt[1] * cl[1]) * window
        cross_b = 2 * b_filt[2] * cl[2] * window
        cl_e, cl_b = cl_e + cross_e[: band + 1], cl_b + cross_b[: band + 1]
    return out + coupling.pseudo_bb(cl_b, cl_e)
