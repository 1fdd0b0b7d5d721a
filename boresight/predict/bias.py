"""The bias on the tensor-to-scalar ratio r that a residual pseudo-C_BB implies, and the reference
curves it is read against: the cosmological B-mode alone through the mask, beam and pixel
window."""

from __future__ import annotations

from typing import TYPE_CHECKING

import healpy as hp
import numpy as np

from ..constants import ARCMIN
from .windows import pixel_window

if TYPE_CHECKING:
    from ..cosmology import Spectra
    from ..coupling import Coupling


def reference_bb(
    coupling: Coupling,
    theory: Spectra,
    fwhm_arcmin: float,
    nside: int,
    *,
    r: float = 0.0,
    a_lens: float = 0.0,
) -> np.ndarray:
    """Pseudo-C_BB of the cosmological B-mode alone (E = 0), with beam and pixel window.

    Parameters
    ----------
    coupling : boresight.coupling.Coupling
    theory : boresight.cosmology.Spectra
    fwhm_arcmin : float
    nside : int
    r, a_lens : float

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    band = coupling.band  # the sky's B above the spectra's lmax, which the mask mixes down
    beam = hp.gauss_beam(fwhm_arcmin * ARCMIN, lmax=band, pol=True)[:, 2]
    pixwin = pixel_window(nside, band)
    cl = theory.bb(r=r, a_lens=a_lens)[: band + 1] * (beam * pixwin) ** 2
    return coupling.pseudo_bb(cl, np.zeros_like(cl))


R_RANGE = (30, 300)  #: the deep survey's primordial range


def tensor_template(
    coupling: Coupling, theory: Spectra, fwhm_arcmin: float, nside: int
) -> np.ndarray:
    """Pseudo-C_BB of tensors at r = 1 through the mask: the template of :func:`delta_r`.

    Parameters
    ----------
    coupling, theory, fwhm_arcmin, nside
        As in :func:`reference_bb`.

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    return reference_bb(coupling, theory, fwhm_arcmin, nside, r=1.0)


def delta_r_weights(template: np.ndarray, lmax: int) -> np.ndarray:
    """w (lmax + 1,) with :func:`delta_r` = sum_ell w_ell C_ell over :data:`R_RANGE` (to lmax):
    the template over its squared norm there, 0 elsewhere."""
    out = np.zeros(lmax + 1)
    lo, hi = R_RANGE[0], min(R_RANGE[1], lmax)
    out[lo : hi + 1] = template[lo : hi + 1] / np.sum(template[lo : hi + 1] ** 2)
    return out


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
    norm = np.sum(template[s] ** 2)
    if not (np.isfinite(norm) and norm > 0):
        raise ValueError(f"delta_r: the template is zero (or not finite) over [{lmin}, {lmax}]")
    return float(np.sum(residual[s] * template[s]) / norm)
