"""Naive map-making: per-pixel least squares for Q and U from the binned pair differences.

Each pixel's normal matrix [[sum c^2, sum c s], [sum c s, sum s^2]] (c, s = cos, sin 2a) is solved
for (Q, U). Its reciprocal condition number rcond = lambda_min / lambda_max is kept; pixels with no
hits or rcond < ``rcond_min`` are flagged invalid and set to healpy.UNSEEN, never filled.
"""

from __future__ import annotations

from dataclasses import dataclass

import healpy as hp
import numpy as np

RCOND_MIN = 1e-6  #: below this the 2x2 system is treated as singular (one polarisation angle)


@dataclass(frozen=True)
class Maps:
    """Reconstructed maps, RING, held on the observed pixels; full-sky maps on access.

    Parameters
    ----------
    nside : int
    pixels : numpy.ndarray, int64, shape (n,)
        RING indices of the observed pixels, increasing.
    q_obs, u_obs : numpy.ndarray, float64, shape (n,)
        [muK] on those pixels, healpy.UNSEEN where invalid.
    hits_obs : numpy.ndarray, int64, shape (n,)
        Hits x rotations.
    rcond_obs : numpy.ndarray, float64, shape (n,)
        Reciprocal condition number of each pixel's 2x2 system.

    Notes
    -----
    :attr:`q`, :attr:`u`, :attr:`hits`, :attr:`rcond` and :attr:`valid` are full-sky (npix,) maps
    made on each access (UNSEEN, 0 or False off the observed pixels); the residual jobs use
    :meth:`qu_at` on the observed pixels and never make them (0.4 GB each at Nside 2048).
    """

    nside: int
    pixels: np.ndarray
    q_obs: np.ndarray
    u_obs: np.ndarray
    hits_obs: np.ndarray
    rcond_obs: np.ndarray

    def _on_sky(self, values, fill):
        out = np.full(12 * self.nside**2, fill, dtype=values.dtype)
        out[self.pixels] = values
        return out

    @property
    def q(self):
        """(npix,) [muK], UNSEEN where invalid."""
        return self._on_sky(self.q_obs, hp.UNSEEN)

    @property
    def u(self):
        """(npix,) [muK], UNSEEN where invalid."""
        return self._on_sky(self.u_obs, hp.UNSEEN)

    @property
    def hits(self):
        """(npix,) int64, hits x rotations per pixel."""
        return self._on_sky(self.hits_obs, 0)

    @property
    def rcond(self):
        """(npix,) reciprocal condition numbers, 0 where unobserved."""
        return self._on_sky(self.rcond_obs, 0.0)

    @property
    def valid(self):
        """Boolean map of pixels with a well-conditioned solution."""
        return self._on_sky(self.q_obs != hp.UNSEEN, False)

    @property
    def qu(self):
        """(2, npix) array of Q, U with invalid pixels set to 0 (for transforms under a mask)."""
        qu = np.zeros((2, 12 * self.nside**2))
        qu[:, self.pixels] = self.qu_at(self.pixels)
        return qu

    def qu_at(self, pixels):
        """Q, U at some pixels, 0 where invalid or unobserved.

        Parameters
        ----------
        pixels : numpy.ndarray of int, shape (n,)
            RING indices; the observed ones themselves cost no search.

        Returns
        -------
        numpy.ndarray, shape (2, n)
        """
        pixels = np.asarray(pixels)
        if np.array_equal(pixels, self.pixels):
            qu = np.array([self.q_obs, self.u_obs])
        else:
            qu = np.zeros((2, pixels.size))
            if self.pixels.size:
                at = np.minimum(np.searchsorted(self.pixels, pixels), self.pixels.size - 1)
                seen = self.pixels[at] == pixels
                qu[:, seen] = self.q_obs[at[seen]], self.u_obs[at[seen]]
        np.copyto(qu, 0.0, where=qu[0] == hp.UNSEEN)
        return qu


def solve(normal: np.ndarray, rcond_min: float = RCOND_MIN) -> tuple:
    """Solve each pixel's 2x2 least-squares system for (Q, U).

    Parameters
    ----------
    normal : numpy.ndarray or cupy.ndarray, shape (n, 5)
        sum c^2, sum c s, sum s^2, sum c d, sum s d per pixel (c, s = cos, sin 2a).
    rcond_min : float
        Pixels below this reciprocal condition number are invalid.

    Returns
    -------
    q, u : array, shape (n,)
        [muK], UNSEEN where invalid.
    rcond : array, shape (n,)
    """
    a11, a12, a22, b1, b2 = normal.T
    half_trace = 0.5 * (a11 + a22)
    spread = np.sqrt((0.5 * (a11 - a22)) ** 2 + a12**2)
    lam_max = half_trace + spread
    with np.errstate(divide="ignore", invalid="ignore"):
        rcond = np.where(lam_max > 0, (half_trace - spread) / lam_max, 0.0)
        det = a11 * a22 - a12**2
        q = (a22 * b1 - a12 * b2) / det
        u = (a11 * b2 - a12 * b1) / det
    ok = rcond >= rcond_min
    return np.where(ok, q, hp.UNSEEN), np.where(ok, u, hp.UNSEEN), np.maximum(rcond, 0.0)
