"""Pseudo-C_ell spectra of masked maps, residual B-mode spectra and binning.

Pseudo-alm are the masked maps' analysis by :func:`boresight.harmonics.map2alm` (``analysis``:
by default one pass with ring weights at lmax <= 2 Nside), beam not deconvolved; C_ell in muK^2
from ell = 0, in healpy's order TT, EE, BB, TE, EB, TB.
"""

from __future__ import annotations

import numpy as np

from . import harmonics

ORDER = ("tt", "ee", "bb", "te", "eb", "tb")


def masked_alm(
    maps: np.ndarray, mask: np.ndarray, lmax: int, nthreads: int = 0, analysis: str = "auto"
) -> np.ndarray:
    """T, E, B alm of masked I, Q, U maps.

    Parameters
    ----------
    maps : array_like, shape (3, npix)
        I, Q, U [muK], RING, finite inside the mask.
    mask : numpy.ndarray, shape (npix,)
    lmax : int
    nthreads : int
    analysis : str
        :func:`boresight.harmonics.map2alm`'s analysis (one of
        :data:`boresight.harmonics.ANALYSES`).

    Returns
    -------
    numpy.ndarray, complex128, shape (3, nalm)
    """
    maps = np.asarray(maps, dtype=np.float64)
    _check(maps, mask)
    alm = np.empty((3, harmonics.n_alm(lmax)), dtype=np.complex128)
    alm[0] = harmonics.map2alm(maps[0] * mask, lmax, 0, analysis, nthreads=nthreads)
    alm[1:] = harmonics.map2alm(maps[1:] * mask, lmax, 2, analysis, nthreads=nthreads)
    return alm


def masked_pol_alm(
    qu: np.ndarray,
    mask: np.ndarray,
    lmax: int,
    nthreads: int = 0,
    analysis: str = "auto",
    overwrite: bool = False,
) -> np.ndarray:
    """E, B alm (2, nalm) of masked Q, U maps ``qu`` (2, npix) [muK], finite inside the mask; the
    other parameters as :func:`masked_alm`. ``overwrite``: mask a float64 ``qu`` in place (no
    full-sky copy; the caller gives ``qu`` up).
    """
    qu = np.asarray(qu, dtype=np.float64)
    _check(qu, mask)
    masked = np.multiply(qu, mask, out=qu if overwrite else None)
    return harmonics.map2alm(masked, lmax, 2, analysis, nthreads=nthreads)


def _check(maps, mask):
    if maps.shape[-1] != np.shape(mask)[-1]:
        raise ValueError(f"maps have {maps.shape[-1]} pixels but the mask has {np.shape(mask)[-1]}")
    observed = np.asarray(mask) != 0
    # one pass each, no copies; NaN propagates through min and max and fails both comparisons
    lo = np.min(maps, where=observed, initial=np.inf)
    hi = np.max(maps, where=observed, initial=-np.inf)
    if not (-1e29 <= lo and hi <= 1e29) and observed.any():
        raise ValueError("maps contain NaN or UNSEEN values inside the mask")


def pseudo_spectra(
    maps: np.ndarray, mask: np.ndarray, lmax: int, nthreads: int = 0, analysis: str = "auto"
) -> np.ndarray:
    """Pseudo-C_ell of masked maps, beam not deconvolved.

    Parameters
    ----------
    maps : array_like, shape (3, npix)
        I, Q, U [muK].
    mask : numpy.ndarray, shape (npix,)
    lmax : int
    nthreads : int
    analysis : str
        As :func:`masked_alm`.

    Returns
    -------
    numpy.ndarray, shape (6, lmax + 1)
        TT, EE, BB, TE, EB, TB [muK^2] from ell = 0 (healpy's order, :data:`ORDER`).
    """
    t, e, b = masked_alm(maps, mask, lmax, nthreads, analysis)
    return np.array(
        [harmonics.alm2cl(x, y) for x, y in ((t, t), (e, e), (b, b), (t, e), (e, b), (t, b))]
    )


def residual_bb_parts(
    qu_sys: np.ndarray,
    qu_ref: np.ndarray,
    mask: np.ndarray,
    lmax: int,
    nthreads: int = 0,
    b_ref: np.ndarray | None = None,
    analysis: str = "auto",
) -> tuple[np.ndarray, np.ndarray]:
    """The two parts of C_BB(sys) - C_BB(ref) of masked maps.

    B = B(ref) and dB = B(sys - ref): transforming the small difference map keeps its full relative
    precision, unlike subtracting two spectra. The cross part has zero mean when the systematic is
    uncorrelated with the polarisation; the auto part is what leakage adds on average.

    Parameters
    ----------
    qu_sys, qu_ref : array_like, shape (2, npix)
        Q, U [muK] with and without the systematic.
    mask : numpy.ndarray, shape (npix,)
    lmax : int
    nthreads : int
    b_ref : numpy.ndarray, shape (nalm,), optional
        The B alm of the masked reference, when already computed.
    analysis : str
        As :func:`masked_alm`.

    Returns
    -------
    cross : numpy.ndarray, shape (lmax + 1,)
        2 Re<B, dB> [muK^2].
    auto : numpy.ndarray, shape (lmax + 1,)
        <dB, dB> [muK^2].
    """
    if b_ref is None:
        b_ref = masked_pol_alm(qu_ref, mask, lmax, nthreads, analysis)[1]
    d_qu = np.subtract(qu_sys, qu_ref)
    return difference_bb_parts(d_qu, b_ref, mask, lmax, nthreads, analysis)


def difference_bb_parts(
    d_qu: np.ndarray,
    b_ref: np.ndarray,
    mask: np.ndarray,
    lmax: int,
    nthreads: int = 0,
    analysis: str = "auto",
    overwrite: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`residual_bb_parts` from the difference map and the reference's B alm.

    Parameters
    ----------
    d_qu : array_like, shape (2, npix)
        sys - ref [muK].
    b_ref : numpy.ndarray, complex128, shape (nalm,)
    mask : numpy.ndarray, shape (npix,)
    lmax : int
    nthreads : int
    analysis : str
        As :func:`masked_alm`.
    overwrite : bool
        As :func:`masked_pol_alm`.

    Returns
    -------
    cross, auto : numpy.ndarray, shape (lmax + 1,)
    """
    d_b = masked_pol_alm(d_qu, mask, lmax, nthreads, analysis, overwrite)[1]
    return 2.0 * harmonics.alm2cl(b_ref, d_b), harmonics.alm2cl(d_b)


def residual_bb(
    qu_sys: np.ndarray, qu_ref: np.ndarray, mask: np.ndarray, lmax: int, nthreads: int = 0
) -> np.ndarray:
    """C_BB(sys) - C_BB(ref) of masked Q, U maps: the sum of :func:`residual_bb_parts`.

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2] from ell = 0.
    """
    return sum(residual_bb_parts(qu_sys, qu_ref, mask, lmax, nthreads))


def linear_bins(lmin: int, lmax: int, width: int) -> np.ndarray:
    """Band edges of a fixed width.

    Parameters
    ----------
    lmin, lmax : int
        First and last multipole (inclusive).
    width : int

    Returns
    -------
    numpy.ndarray of int
        Edges [lo, hi) ending at lmax + 1.
    """
    edges = np.arange(lmin, lmax + 2, width)
    if edges[-1] != lmax + 1:
        edges = np.append(edges, lmax + 1)
    return edges


def log_bins(lmin: int, lmax: int, n_bins: int) -> np.ndarray:
    """Logarithmically spaced integer band edges.

    Parameters
    ----------
    lmin, lmax : int
        First and last multipole (inclusive).
    n_bins : int
        About this many bands (duplicate edges at low ell merge).

    Returns
    -------
    numpy.ndarray of int
        Edges [lo, hi) from lmin to lmax + 1.
    """
    edges = np.unique(np.round(np.geomspace(lmin, lmax + 1, n_bins + 1)).astype(int))
    return edges


def bin_spectrum(cl: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Band means of a spectrum.

    Parameters
    ----------
    cl : array_like, shape (..., lmax + 1)
    edges : array_like of int
        Band i is edges[i] <= ell < edges[i + 1].

    Returns
    -------
    centres : numpy.ndarray, shape (nbands,)
        (lo + hi - 1) / 2.
    means : numpy.ndarray, shape (nbands,) or (..., nbands) transposed as (nbands, ...)
    """
    cl = np.asarray(cl)
    lo, hi = edges[:-1], edges[1:]
    if hi[-1] > cl.shape[-1]:
        raise ValueError(f"bin edge {hi[-1]} beyond the spectrum's lmax {cl.shape[-1] - 1}")
    means = np.array([cl[..., a:b].mean(axis=-1) for a, b in zip(lo, hi)]).T
    return 0.5 * (lo + hi - 1), means


def cl2dl(cl: np.ndarray) -> np.ndarray:
    """D_ell = ell (ell + 1) C_ell / 2 pi.

    Parameters
    ----------
    cl : array_like, shape (..., lmax + 1)
        From ell = 0.

    Returns
    -------
    numpy.ndarray, same shape
    """
    ell = np.arange(np.shape(cl)[-1])
    return cl * ell * (ell + 1) / (2 * np.pi)
