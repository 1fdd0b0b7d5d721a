"""What TOD template deprojection leaves of a leak of T: the template's error, predicted.

A pair difference d = g X leaks a field X read from T (T itself for a gain; its gradient for a
pointing offset; its second derivatives for a width or an ellipticity). Deprojection
(:class:`boresight.mitigation.Deprojection`) fits the same field x of a template map t to d per
block, c = <x d> / <x x>, and keeps d - c x. Write the TOD's field X = B T and the template's
x = B_t T + n (the sky's beam B, the template's own beam B_t and noise n, per ell) and e = X - x
its error. Then c = g (1 - kappa) with kappa = -<x e> / <x x>, and what is left is

    d - c x = g (e + kappa x),

the leak of the field e + kappa x: today's prediction with C_ell^TT replaced by

    C_ell^res = C_ell^ee + 2 kappa C_ell^ex + kappa^2 C_ell^xx,
    C^ee = (B - B_t)^2 C^TT + N,  C^ex = (B - B_t) B_t C^TT - N,  C^xx = B_t^2 C^TT + N,

and kappa from the fields' variances over the sky, each ell weighted by (2 ell + 1) / (4 pi)
(ell (ell + 1))^k for a field of k derivatives. A template read from the sky itself (B_t = B,
N = 0) leaves nothing; a noisy template of the sky's beam leaves (1 - kappa)^2 N + kappa^2 B^2
C^TT, its noise less the fit's share of it, plus the share of the sky the noise pulls off the
fit. Checked against the mean of TOD skies deprojected with noisy template maps
(``tests/predict/test_template_error.py``). What drifts within a block is not in it.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import healpy as hp
import numpy as np

from ..constants import ARCMIN
from ..cosmology import Spectra


class TemplateError(NamedTuple):
    """The spectra of the fields [muK^2 per ell, as the TOD reads them], (lmax + 1,) each, and
    the fit's share ``kappa``."""

    error: np.ndarray
    cross: np.ndarray
    template: np.ndarray
    kappa: float

    @property
    def residual(self) -> np.ndarray:
        """C_ell^res = C^ee + 2 kappa C^ex + kappa^2 C^xx: the field the leak is left with."""
        return self.error + 2.0 * self.kappa * self.cross + self.kappa**2 * self.template


def template_error(
    tt: np.ndarray,
    *,
    lmax: int,
    fwhm_arcmin: float,
    template_fwhm_arcmin: float | None = None,
    noise_cl: np.ndarray | float = 0.0,
    derivatives: int = 0,
) -> TemplateError:
    """The error of a template map against the sky the TOD reads, and the fit's share of it.

    Parameters
    ----------
    tt : numpy.ndarray
        The sky's C_ell^TT before its beam [muK^2], to at least ``lmax``.
    lmax : int
        The band limit of both fields (the template map is read to it).
    fwhm_arcmin : float
        The sky's beam.
    template_fwhm_arcmin : float, optional
        The template's beam (default the sky's).
    noise_cl : numpy.ndarray or float
        The template's noise spectrum N_ell [muK^2] as read to ``lmax``, or a white level (a map
        of white noise sigma per pixel reads as sigma^2 4 pi / npix).
    derivatives : int
        0 for the T template (gain), 1 for the gradient's (pointing), 2 for the second
        derivatives' (width, ellipticity): the fit weights each ell by (ell (ell + 1))^k.

    Returns
    -------
    TemplateError
    """
    if lmax < 2 or tt.size < lmax + 1:
        raise ValueError(f"template_error: lmax {lmax} needs C_ell^TT to it (has {tt.size - 1})")
    if derivatives not in (0, 1, 2):
        raise ValueError(f"derivatives = {derivatives!r}: 0, 1 or 2")
    ell = np.arange(lmax + 1)
    beam = hp.gauss_beam(fwhm_arcmin * ARCMIN, lmax=lmax)
    own = (
        beam
        if template_fwhm_arcmin is None
        else hp.gauss_beam(template_fwhm_arcmin * ARCMIN, lmax=lmax)
    )
    cl = np.array(tt[: lmax + 1], dtype=float)
    cl[:2] = 0.0
    noise = np.broadcast_to(np.asarray(noise_cl, dtype=float), (lmax + 1,)).copy()
    noise[:2] = 0.0
    error = (beam - own) ** 2 * cl + noise
    cross = (beam - own) * own * cl - noise
    template = own**2 * cl + noise
    weight = (2 * ell + 1) / (4 * np.pi) * (ell * (ell + 1.0)) ** derivatives
    kappa = -float(np.sum(weight * cross) / np.sum(weight * template))
    return TemplateError(error, cross, template, kappa)


def deprojected_theory(theory: Spectra, left: TemplateError, *, fwhm_arcmin: float) -> Spectra:
    """The theory a prediction of the deprojected leak reads: C_ell^TT the residual field's
    (:attr:`TemplateError.residual`, the sky's beam divided out, since a
    :class:`boresight.predict.Prediction` applies it), P unchanged (no T template fits a leak
    of P).

    Parameters
    ----------
    theory : boresight.cosmology.Spectra
    left : TemplateError
    fwhm_arcmin : float
        The sky's beam, the prediction's.

    Returns
    -------
    boresight.cosmology.Spectra
    """
    lmax = left.error.size - 1
    beam2 = hp.gauss_beam(fwhm_arcmin * ARCMIN, lmax=lmax) ** 2
    tt = np.zeros_like(theory.tt)
    n = min(lmax, theory.lmax) + 1
    tt[:n] = left.residual[:n] / beam2[:n]
    return dataclasses.replace(theory, tt=tt, tt_tensor=np.zeros_like(theory.tt_tensor))
