"""The spectra of the sky's fields that a prediction scales: the beam-smoothed theory
(:func:`field_spectra`), or one sky's own inside a mask (:func:`local_cl`), which takes the
patch's sample variance out of a comparison with a simulation of that sky."""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import healpy as hp
import numpy as np

from ..constants import ARCMIN
from ..masks import apodize
from ..spectra import pseudo_spectra

if TYPE_CHECKING:
    from ..sky import Sky


def field_spectra(theory, lmax, fwhm_arcmin):
    """Beam-smoothed spectra of the sky.

    Parameters
    ----------
    theory : boresight.cosmology.Spectra
    lmax : int
    fwhm_arcmin : float

    Returns
    -------
    tt, ee, bb : numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    tt, ee, bb, _ = theory.total(lmax=lmax)
    beam = hp.gauss_beam(fwhm_arcmin * ARCMIN, lmax=lmax, pol=True)
    return tt * beam[:, 0] ** 2, ee * beam[:, 1] ** 2, bb * beam[:, 2] ** 2


class FieldSpectra(NamedTuple):
    """Beam-smoothed spectra of the fields a prediction scales [muK^2]: TT, EE + BB (the h_4 P*
    term) and EE, (lmax + 1,) each, as full-sky equivalents (pseudo-C_ell / <w^2>); the maps'
    own pseudo-C_ell EE, BB, EB through the mask, (3, lmax + 1) (the h_0 term,
    :func:`boresight.predict.signal_bb`); and, for the beam terms (:func:`boresight.predict.beam_spectra`), TT, EE, BB, TE through
    the apodized mask, (4, lmax + 1). ``read`` keeps, per window, the EE, BB, EB of the sky as the
    hits read it (windowed, then masked), made on first use by :func:`boresight.predict.residual_pseudo_bb`."""

    tt: np.ndarray
    pol: np.ndarray
    ee: np.ndarray
    masked: np.ndarray | None = None
    apodized: np.ndarray | None = None
    read: dict | None = None


BEAM_APODIZATION_DEG = 2.0  #: apodization of the mask for the beam terms' local spectra


def local_cl(
    sky: Sky,
    mask: np.ndarray,
    lmax: int,
    *,
    nthreads: int = 0,
    beams: bool = False,
    analysis: str = "auto",
) -> FieldSpectra:
    """Beam-smoothed TT, EE + BB and EE of one sky inside a mask: pseudo-C_ell / <w^2>.

    Feeding these to :func:`boresight.predict.systematic_cl` instead of the theory removes the patch's sample variance
    when a prediction is compared with a simulation of that sky.

    Parameters
    ----------
    sky : boresight.sky.Sky
    mask : numpy.ndarray, shape (npix,)
    lmax : int
    nthreads : int
    beams : bool
        Also TT, EE, BB, TE through the apodized mask, for beam systematics (one more analysis).
    analysis : str
        :func:`boresight.harmonics.map2alm`'s analysis, as the simulated maps'.

    Returns
    -------
    FieldSpectra
    """
    mask = np.asarray(mask, dtype=np.float64)
    pseudo = pseudo_spectra(sky.maps, mask, lmax, nthreads=nthreads, analysis=analysis)
    cl = pseudo / np.mean(mask**2)
    masked = pseudo[[1, 2, 4]]
    if not beams:
        return FieldSpectra(cl[0], cl[1] + cl[2], cl[1], masked, read={})
    smooth = mask * apodize((mask > 0).astype(np.float64), BEAM_APODIZATION_DEG)
    apodized = pseudo_spectra(sky.maps, smooth, lmax, nthreads=nthreads, analysis=analysis)[:4]
    apodized /= np.mean(smooth**2)
    return FieldSpectra(cl[0], cl[1] + cl[2], cl[1], masked, apodized, read={})
