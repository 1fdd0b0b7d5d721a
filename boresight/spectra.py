"""Pseudo-C_ell spectra of masked maps, residual B-mode spectra and binning.

Spectra are anafast-equivalent (ducc0 transforms with 3 Jacobi iterations, beam not deconvolved),
C_ell in muK^2 from ell = 0, in healpy's order TT, EE, BB, TE, EB, TB.
"""

import numpy as np

from . import harmonics

ORDER = ("tt", "ee", "bb", "te", "eb", "tb")


def masked_alm(maps, mask, lmax, nthreads=0):
    """(T, E, B) alm (3, nalm) of I, Q, U maps (3, npix) multiplied by ``mask``."""
    maps = np.asarray(maps, dtype=np.float64)
    _check(maps, mask)
    alm = np.empty((3, harmonics.n_alm(lmax)), dtype=np.complex128)
    alm[0] = harmonics.map2alm(maps[0] * mask, lmax, nthreads=nthreads)
    alm[1:] = harmonics.map2alm(maps[1:] * mask, lmax, spin=2, nthreads=nthreads)
    return alm


def masked_pol_alm(qu, mask, lmax, nthreads=0):
    """(E, B) alm (2, nalm) of Q, U maps (2, npix) multiplied by ``mask``."""
    qu = np.asarray(qu, dtype=np.float64)
    _check(qu, mask)
    return harmonics.map2alm(qu * mask, lmax, spin=2, nthreads=nthreads)


def _check(maps, mask):
    if maps.shape[-1] != np.shape(mask)[-1]:
        raise ValueError(f"maps have {maps.shape[-1]} pixels but the mask has {np.shape(mask)[-1]}")
    observed = np.asarray(mask) != 0
    # one pass each, no copies; NaN propagates through min and max and fails both comparisons
    lo = np.min(maps, where=observed, initial=np.inf)
    hi = np.max(maps, where=observed, initial=-np.inf)
    if not (-1e29 <= lo and hi <= 1e29) and observed.any():
        raise ValueError("maps contain NaN or UNSEEN values inside the mask")


def pseudo_spectra(maps, mask, lmax, nthreads=0):
    """TT, EE, BB, TE, EB, TB pseudo-C_ell (6, lmax+1) of masked I, Q, U maps [muK^2]."""
    t, e, b = masked_alm(maps, mask, lmax, nthreads)
    return np.array(
        [harmonics.alm2cl(x, y) for x, y in ((t, t), (e, e), (b, b), (t, e), (e, b), (t, b))]
    )


def residual_bb_parts(qu_sys, qu_ref, mask, lmax, nthreads=0, b_ref=None):
    """(cross, auto) parts of C_BB(sys) - C_BB(ref): 2 Re<B, dB> and <dB, dB>, each (lmax+1,).

    B = B(ref) and dB = B(sys - ref): the transform of the small difference map keeps its full
    relative precision, unlike subtracting two spectra. The cross part has zero mean when the
    systematic is uncorrelated with the polarisation; the auto part is what leakage adds on average.
    ``b_ref``: the B alm of the masked reference, when already computed.
    """
    if b_ref is None:
        b_ref = masked_pol_alm(qu_ref, mask, lmax, nthreads)[1]
    return difference_bb_parts(np.subtract(qu_sys, qu_ref), b_ref, mask, lmax, nthreads)


def difference_bb_parts(d_qu, b_ref, mask, lmax, nthreads=0):
    """(cross, auto) of residual_bb_parts from the difference map d_qu = sys - ref (2, npix) and
    the B alm of the masked reference."""
    d_b = masked_pol_alm(d_qu, mask, lmax, nthreads)[1]
    return 2.0 * harmonics.alm2cl(b_ref, d_b), harmonics.alm2cl(d_b)


def residual_bb(qu_sys, qu_ref, mask, lmax, nthreads=0):
    """C_BB(sys) - C_BB(ref) [muK^2] of masked Q, U maps (see residual_bb_parts)."""
    return sum(residual_bb_parts(qu_sys, qu_ref, mask, lmax, nthreads))


def linear_bins(lmin, lmax, width):
    """Band edges [lo, hi) of width ``width`` from lmin up to lmax (inclusive)."""
    edges = np.arange(lmin, lmax + 2, width)
    if edges[-1] != lmax + 1:
        edges = np.append(edges, lmax + 1)
    return edges


def log_bins(lmin, lmax, n_bins):
    """About ``n_bins`` logarithmically spaced integer band edges from lmin to lmax + 1."""
    edges = np.unique(np.round(np.geomspace(lmin, lmax + 1, n_bins + 1)).astype(int))
    return edges


def bin_spectrum(cl, edges):
    """Band means of cl over [edges[i], edges[i+1]); returns (centres, means)."""
    cl = np.asarray(cl)
    lo, hi = edges[:-1], edges[1:]
    if hi[-1] > cl.shape[-1]:
        raise ValueError(f"bin edge {hi[-1]} beyond the spectrum's lmax {cl.shape[-1] - 1}")
    means = np.array([cl[..., a:b].mean(axis=-1) for a, b in zip(lo, hi)]).T
    return 0.5 * (lo + hi - 1), means


def cl2dl(cl):
    """D_ell = ell (ell + 1) C_ell / 2 pi."""
    ell = np.arange(np.shape(cl)[-1])
    return cl * ell * (ell + 1) / (2 * np.pi)
