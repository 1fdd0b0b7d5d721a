"""Pseudo-C_ell spectra of masked maps, residual B-mode spectra and binning.

Pseudo-alm are the masked maps' analysis by :func:`boresight.harmonics.map2alm` (``analysis``:
by default one pass with ring weights at lmax <= 2 Nside), beam not deconvolved; C_ell in muK^2
from ell = 0, in healpy's order TT, EE, BB, TE, EB, TB.
"""

from __future__ import annotations

import healpy as hp
import numpy as np

from . import harmonics

ORDER = ("tt", "ee", "bb", "te", "eb", "tb")


class Footprint:
    """A mask's observed pixels and their weights, built once per mask: the transforms of masked
    maps given on those pixels (:meth:`pol_alm`) never make a full-sky map.

    Parameters
    ----------
    mask : array_like, shape (npix,)
        Weights (RING); the pixels with weight != 0 are observed.

    Attributes
    ----------
    nside, npix : int
    pixels : numpy.ndarray, int64, shape (nobs,)
        The observed pixels, increasing.
    weights : numpy.ndarray, shape (nobs,)
        The mask there. The full-sky mask is not kept (0.4 GB at Nside 2048): :attr:`mask`
        makes it again.
    """

    def __init__(self, mask):
        mask = np.asarray(mask, dtype=np.float64)
        self.npix = mask.size
        self.nside = int(round(np.sqrt(self.npix / 12)))
        self.pixels = np.flatnonzero(mask)
        self.weights = mask[self.pixels]
        self._parents = {}

    @property
    def mask(self) -> np.ndarray:
        """The full-sky mask, float64 (npix,), made anew at each call."""
        out = np.zeros(self.npix)
        out[self.pixels] = self.weights
        return out

    def parents(self, block: int) -> np.ndarray:
        """Each observed pixel's NEST parent at Nside / block, made once per block size.

        Parameters
        ----------
        block : int
            A power of 2, <= Nside.

        Returns
        -------
        numpy.ndarray, int32, shape (nobs,)
            Kept for the next job on the footprint: in int32, 0.08 GB on the wide mask at Nside
            2048 (a parent index is below 12 (Nside / block)^2).
        """
        if block not in self._parents:
            parents = hp.ring2nest(self.nside, self.pixels) // (block * block)
            self._parents[block] = parents.astype(np.int32)
        return self._parents[block]

    def alm(self, values, lmax, spin=0, *, nthreads=0, analysis="auto", overwrite=False):
        """alm of the masked map that is ``values`` on the observed pixels.

        Parameters
        ----------
        values : array_like
            (nobs,) for spin 0; (2, nobs) Q, U for spin 2 [muK], finite.
        lmax, spin, nthreads : int
        analysis : str
            :func:`boresight.harmonics.map2alm`'s analysis (one of
            :data:`boresight.harmonics.ANALYSES`).
        overwrite : bool
            Mask a float64 ``values`` in place (the caller gives it up).

        Returns
        -------
        numpy.ndarray, complex128
            (nalm,) for spin 0; (2, nalm) (E, B) otherwise.
        """
        values = np.asarray(values, dtype=np.float64)
        if values.shape[-1] != self.pixels.size:
            raise ValueError(f"{values.shape[-1]} values for {self.pixels.size} observed pixels")
        # NaN propagates through min and max and fails both comparisons
        if values.size and not (-1e29 <= values.min() and values.max() <= 1e29):
            raise ValueError("maps contain NaN or UNSEEN values inside the mask")
        masked = np.multiply(values, self.weights, out=values if overwrite else None)
        return harmonics.map2alm_pixels(
            masked,
            self.pixels,
            self.nside,
            lmax,
            spin=spin,
            analysis=analysis,
            nthreads=nthreads,
        )


def as_footprint(mask: np.ndarray | Footprint) -> Footprint:
    """A mask's :class:`Footprint`: itself when it is one (built once and shared by many jobs).

    Parameters
    ----------
    mask : numpy.ndarray, shape (npix,), or Footprint

    Returns
    -------
    Footprint
    """
    return mask if isinstance(mask, Footprint) else Footprint(mask)


def masked_alm(
    maps: np.ndarray,
    mask: np.ndarray,
    lmax: int,
    *,
    nthreads: int = 0,
    analysis: str = "auto",
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
        As :meth:`Footprint.alm`.

    Returns
    -------
    numpy.ndarray, complex128, shape (3, nalm)
    """
    footprint, maps = _observed(maps, mask)
    alm = np.empty((3, harmonics.n_alm(lmax)), dtype=np.complex128)
    alm[0] = footprint.alm(maps[0], lmax, 0, nthreads=nthreads, analysis=analysis)
    alm[1:] = footprint.alm(maps[1:], lmax, 2, nthreads=nthreads, analysis=analysis)
    return alm


def masked_pol_alm(
    qu: np.ndarray,
    mask: np.ndarray,
    lmax: int,
    *,
    nthreads: int = 0,
    analysis: str = "auto",
) -> np.ndarray:
    """E, B alm (2, nalm) of masked Q, U maps ``qu`` (2, npix) [muK], finite inside the mask; the
    other parameters as :func:`masked_alm`.
    """
    footprint, qu = _observed(qu, mask)
    return footprint.alm(qu, lmax, 2, nthreads=nthreads, analysis=analysis, overwrite=True)


def _observed(maps, mask):
    """The mask's :class:`Footprint` and the maps (..., npix) on its pixels (a copy)."""
    maps = np.asarray(maps)
    footprint = as_footprint(mask)
    if maps.shape[-1] != footprint.npix:
        raise ValueError(f"maps have {maps.shape[-1]} pixels but the mask has {footprint.npix}")
    return footprint, maps[..., footprint.pixels].astype(np.float64, copy=False)


def pseudo_spectra(
    maps: np.ndarray,
    mask: np.ndarray,
    lmax: int,
    *,
    nthreads: int = 0,
    analysis: str = "auto",
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
    t, e, b = masked_alm(maps, mask, lmax, nthreads=nthreads, analysis=analysis)
    return np.array(
        [harmonics.alm2cl(x, y) for x, y in ((t, t), (e, e), (b, b), (t, e), (e, b), (t, b))]
    )


def residual_bb_parts(
    qu_sys: np.ndarray,
    qu_ref: np.ndarray,
    mask: np.ndarray,
    lmax: int,
    *,
    nthreads: int = 0,
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
    analysis : str
        As :func:`masked_alm`.

    Returns
    -------
    cross : numpy.ndarray, shape (lmax + 1,)
        2 Re<B, dB> [muK^2].
    auto : numpy.ndarray, shape (lmax + 1,)
        <dB, dB> [muK^2].
    """
    footprint, qu_ref = _observed(qu_ref, mask)
    b_ref = footprint.alm(qu_ref, lmax, 2, nthreads=nthreads, analysis=analysis)[1]
    d_qu = np.subtract(np.asarray(qu_sys)[:, footprint.pixels], qu_ref)
    return difference_bb_parts(
        d_qu,
        b_ref,
        footprint,
        lmax,
        nthreads=nthreads,
        analysis=analysis,
        overwrite=True,
    )


def difference_bb_parts(
    d_qu: np.ndarray,
    b_ref: np.ndarray,
    footprint: Footprint,
    lmax: int,
    *,
    nthreads: int = 0,
    analysis: str = "auto",
    overwrite: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`residual_bb_parts` from the difference map and the reference's B alm.

    Parameters
    ----------
    d_qu : array_like, shape (2, nobs)
        sys - ref [muK] on the footprint's pixels.
    b_ref : numpy.ndarray, complex128, shape (nalm,)
    footprint : Footprint
    lmax : int
    nthreads : int
    analysis : str
        As :func:`masked_alm`.
    overwrite : bool
        As :meth:`Footprint.alm`.

    Returns
    -------
    cross, auto : numpy.ndarray, shape (lmax + 1,)
    """
    d_b = footprint.alm(d_qu, lmax, 2, nthreads=nthreads, analysis=analysis, overwrite=overwrite)[1]
    return 2.0 * harmonics.alm2cl(b_ref, d_b), harmonics.alm2cl(d_b)


def residual_bb(
    qu_sys: np.ndarray,
    qu_ref: np.ndarray,
    mask: np.ndarray,
    lmax: int,
    *,
    nthreads: int = 0,
) -> np.ndarray:
    """C_BB(sys) - C_BB(ref) of masked Q, U maps: the sum of :func:`residual_bb_parts`.

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2] from ell = 0.
    """
    return sum(residual_bb_parts(qu_sys, qu_ref, mask, lmax, nthreads=nthreads))


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


def per_ell(values, edges, lmax: int, *, outside: float) -> np.ndarray:
    """Per-band ``values`` on every multipole of their band (edges[i] <= ell < edges[i + 1]),
    ``outside`` elsewhere: (lmax + 1,), the inverse of :func:`bin_spectrum` on a flat band."""
    out = np.full(lmax + 1, outside, dtype=float)
    for lo, hi, v in zip(edges[:-1], edges[1:], values):
        out[lo:hi] = v
    return out


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
