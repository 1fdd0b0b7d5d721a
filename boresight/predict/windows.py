"""The windows of fields read at hits spread over their pixels: exactly (the pair window of two hits
of one pixel) or by bilinear interpolation of the pixel-centre maps (the engine's "interp"), and
the in-pixel scatter they leave as white noise; and the pixel window of the reference curves."""

from __future__ import annotations

from functools import lru_cache

import healpy as hp
import numba
import numpy as np

from .._util.jit import njit
from ..kernels.cpu import generate_hits

SPREAD_PIXELS = 1 << 16  #: pixels whose hit pairs sample the window of hits spread over pixels


@lru_cache(maxsize=8)
def hit_spread_window(nside: int, band: int) -> np.ndarray:
    """w_l^2 = <P_l(cos gamma)> over two hits of one pixel, drawn as the engine draws them
    (uniform in the pixel's face coordinates): the window, squared, of a field averaged over its
    pixel's hits, and 1 - w_l^2 the share of C_l that scatters from hit to hit within a pixel.

    A quadrature over ``SPREAD_PIXELS`` pixels of the whole sphere (the HEALPix pixel shapes
    included), with a fixed seed.

    Parameters
    ----------
    nside, band : int

    Returns
    -------
    numpy.ndarray, shape (band + 1,)
    """

    npix = 12 * nside**2
    pixels = np.unique(np.linspace(0, npix - 1, min(npix, SPREAD_PIXELS)).astype(np.int64))
    offsets = 2 * np.arange(pixels.size + 1, dtype=np.int64)
    zeros = np.zeros(pixels.size)
    theta, phi, _ = generate_hits(0, nside, pixels, offsets, zeros, zeros, False)
    vec = np.array(hp.ang2vec(theta, phi))
    x = np.clip(np.sum(vec[0::2] * vec[1::2], axis=1), -1.0, 1.0)
    return _legendre_means(x, np.ones_like(x), band)


LEGENDRE_BLOCKS = 64  #: fixed blocks of the Legendre sums, added in order: no thread dependence


def _legendre_means(x, weight, band):
    """sum(weight P_l(x)) / n for l = 0..band, n the size of x's last axis (Legendre recurrence).

    Parameters
    ----------
    x, weight : numpy.ndarray, same shape
        Cosines of angles and their weights.
    band : int

    Returns
    -------
    numpy.ndarray, shape (band + 1,)
    """
    flat_x = np.ascontiguousarray(x, dtype=np.float64).ravel()
    flat_w = np.ascontiguousarray(weight, dtype=np.float64).ravel()
    partial = np.zeros((LEGENDRE_BLOCKS, band + 1))
    _legendre_sums(flat_x, flat_w, partial)
    return partial.sum(axis=0) / x.shape[-1]


@njit(parallel=True)
def _legendre_sums(x, weight, out):
    """out[k, l] = sum of weight P_l(x) over block k of x (the blocks fixed by out's rows); the
    recurrence runs over ell for a whole block at once, so the inner loop is SIMD."""
    blocks, band = out.shape[0], out.shape[1] - 1
    for k in numba.prange(blocks):
        lo, hi = k * x.size // blocks, (k + 1) * x.size // blocks
        xs, ws = x[lo:hi], weight[lo:hi]
        p_prev, p = np.ones(hi - lo), xs.copy()
        out[k, 0] = ws.sum()
        for ell in range(1, band + 1):
            a, b = (2 * ell + 1) / (ell + 1), ell / (ell + 1)
            acc = 0.0
            for i in range(hi - lo):
                acc += ws[i] * p[i]
                nxt = a * xs[i] * p[i] - b * p_prev[i]
                p_prev[i] = p[i]
                p[i] = nxt
            out[k, ell] = acc


@lru_cache(maxsize=8)
def interpolation_window(
    nside: int, band: int, gradient: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """The windows of a field read by bilinear interpolation of its pixel-centre values
    (healpy.get_interp_weights, the engine's "interp" evaluation) at hits spread over the pixel.

    With f(x) = sum_c w_c(x) F(n_c) over the four neighbours c of x: ``point`` =
    <sum_cc' w_c(x) w_c'(x) P_l(n_c . n_c')> (the variance of f at a hit, per unit C_l) and
    ``pair`` = the same for two hits x, y of one pixel (the variance of the pixel's mean over
    many hits). With ``gradient``, the same for the gradient of the interpolated surface (what a
    pointing offset reads: f(x + rho) - f(x)), with grad w_c . grad w_c' in place of w_c w_c'
    and divided by l (l + 1), the gradient's own factor. A quadrature over ``SPREAD_PIXELS`` / 4
    pixels with the engine's hit draws; gradients by central differences of 1e-6 rad along
    e_theta and e_phi (hits whose neighbours change within that step are left out).

    Parameters
    ----------
    nside, band : int
    gradient : bool

    Returns
    -------
    pair, point : numpy.ndarray, shape (band + 1,)
    """

    npix = 12 * nside**2
    pixels = np.unique(np.linspace(0, npix - 1, min(npix, SPREAD_PIXELS // 4)).astype(np.int64))
    offsets = 2 * np.arange(pixels.size + 1, dtype=np.int64)
    zeros = np.zeros(pixels.size)
    theta, phi, _ = generate_hits(0, nside, pixels, offsets, zeros, zeros, False)
    neighbours, weights = hp.get_interp_weights(nside, theta, phi)  # (4, 2 n)
    keep = np.ones(theta.size, dtype=bool)
    if gradient:
        step, parts = 1e-6, []
        for d_theta, d_phi in ((step, 0.0), (0.0, step / np.sin(theta))):
            up, w_up = hp.get_interp_weights(nside, theta + d_theta, phi + d_phi)
            down, w_down = hp.get_interp_weights(nside, theta - d_theta, phi - d_phi)
            keep &= np.all(up == neighbours, axis=0) & np.all(down == neighbours, axis=0)
            parts.append((w_up - w_down) / (2 * step))
        weights = np.stack(parts)  # (2, 4, 2 n): d w_c / d e_theta, d w_c / d e_phi
    else:
        weights = weights[None]
    both = keep[0::2] & keep[1::2]
    vec = np.array(hp.pix2vec(nside, neighbours.ravel())).reshape(3, 4, -1)
    x_vec, y_vec = vec[:, :, 0::2][..., both], vec[:, :, 1::2][..., both]
    x_w, y_w = weights[:, :, 0::2][..., both], weights[:, :, 1::2][..., both]
    ell = np.arange(band + 1)
    norm = np.maximum(ell * (ell + 1), 1) if gradient else np.ones(band + 1)
    out = {}
    for key, (a, b, w_a, w_b) in {
        "pair": (x_vec, y_vec, x_w, y_w),
        "point": (x_vec, x_vec, x_w, x_w),
    }.items():
        x = np.clip(np.einsum("icn,idn->cdn", a, b), -1.0, 1.0)
        w = np.einsum("icn,idn->cdn", w_a, w_b)
        out[key] = _legendre_means(x, w, band) / norm
    if gradient:
        out["pair"][0] = out["point"][0] = 1.0  # the monopole has no gradient
    return out["pair"], out["point"]


def mean_inverse_hits(in_pixel, footprint, crossings):
    """<1 / N_hits> over the observed pixels, weighted by the mask squared, where hits spread
    over their pixels (``in_pixel`` "random" with ``crossings`` (npix,)); else None."""
    if in_pixel != "random" or crossings is None:
        return None
    w2 = footprint.weights**2
    return np.sum(w2 / crossings[footprint.pixels]) / np.sum(w2)


class HitSpread:
    """What hits spread at random over their pixels do to a field F's term: its coherent part is
    F averaged over the pixel's hits (C^FF times the pair window), and each hit's departure from
    that average adds white noise of variance sigma_in^2 / N_hits per pixel, sigma_in^2 =
    sum_l (2l + 1) / 4 pi C^FF (point - pair). A field read exactly at the hit has point = 1 and
    pair = w_l^2 (:func:`hit_spread_window`); one interpolated from pixel centres has
    :func:`interpolation_window`. Nothing for pixel-centre hits."""

    def __init__(self, in_pixel, nside, band, inverse_hits, interpolated=False, gradient=False):
        if in_pixel not in ("centre", "random"):
            raise ValueError(f"in_pixel must be 'centre' or 'random', got {in_pixel!r}")
        self.on = in_pixel == "random"
        if self.on:
            if inverse_hits is None:
                raise ValueError("hits spread over their pixels need the crossings per pixel")
            if interpolated:
                self.pair, self.point = interpolation_window(nside, band, gradient)
            else:
                self.pair, self.point = hit_spread_window(nside, band), 1.0
            self.noise = 4 * np.pi / (12 * nside**2) * inverse_hits
            self.ell = np.arange(band + 1)

    def __call__(self, cl_ff):
        """(C^FF of the pixel-averaged field, the white power of the in-pixel scatter)."""
        if not self.on:
            return cl_ff, 0.0
        scatter = np.sum((2 * self.ell + 1) / (4 * np.pi) * cl_ff * (self.point - self.pair))
        return cl_ff * self.pair, self.noise * scatter


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
