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
    """Reconstructed maps, RING, full sky.

    Parameters
    ----------
    q, u : numpy.ndarray, float64, shape (npix,)
        [muK], healpy.UNSEEN where invalid.
    hits : numpy.ndarray, int64, shape (npix,)
        Hits x rotations per pixel.
    rcond : numpy.ndarray, float64, shape (npix,)
        Reciprocal condition number of each pixel's 2x2 system, 0 where unobserved.
    """

    q: np.ndarray
    u: np.ndarray
    hits: np.ndarray
    rcond: np.ndarray

    @property
    def nside(self):
        return hp.npix2nside(self.q.size)

    @property
    def valid(self):
        """Boolean map of pixels with a well-conditioned solution."""
        return self.q != hp.UNSEEN

    @property
    def qu(self):
        """(2, npix) array of Q, U with invalid pixels set to 0 (for transforms under a mask)."""
        return self.qu_at(slice(None))

    def qu_at(self, pixels):
        """Q, U at some pixels, invalid ones set to 0.

        Parameters
        ----------
        pixels : numpy.ndarray of int, shape (n,), or slice
            RING indices.

        Returns
        -------
        numpy.ndarray, shape (2, n)
        """
        qu = np.array([self.q[pixels], self.u[pixels]])
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
