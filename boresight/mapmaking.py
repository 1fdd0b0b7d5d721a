"""Naive map-making: per-pixel least squares for (Q, U) from pair differences, or for (I, Q, U)
from each detector's own samples.

Pair differences: each pixel's normal matrix [[sum c^2, sum c s], [sum c s, sum s^2]] (c, s =
cos, sin 2a) is solved for (Q, U) (:func:`solve`). Detectors: the 3x3 matrix sum w w^T with
w = (1, c, s) is solved for (I, Q, U) (:func:`solve_iqu`), as TOAST's and sotodlib's binned
map-makers do; a HWP telescope needs no pairs for it. When both detectors of every pair share
their samples, the I-Q and I-U terms cancel and the 3x3 solution's Q, U are the pair difference's
(``tests/test_mapmaking.py``).

The reciprocal condition number rcond = lambda_min / lambda_max is kept (of the 3x3 matrix as it
stands, as TOAST's ``CovarianceAndHits``: at most 1/2 for both detectors of a pair, whose I terms
count twice); pixels with no hits or rcond < ``rcond_min`` are flagged invalid and set to
healpy.UNSEEN, never filled.
"""

from __future__ import annotations

from dataclasses import dataclass

import healpy as hp
import numpy as np

RCOND_MIN = 1e-6  #: below this the 2x2 system is treated as singular (one polarisation angle)
#: how a stream's samples become maps: pair differences -> (Q, U); each detector's own samples
#: -> (I, Q, U), both of every pair's detectors or detector A alone (a single-detector instrument);
#: pair differences -> (a, Q, U) with a free spin-0 field a per pixel common to the pairs, which
#: takes a gain or beam-width mismatch's leak of T whatever the angles (map-domain deprojection;
#: its noise price is :func:`boresight.predict.deprojection.noise_inflation`)
MAPMAKERS = ("pairs", "detectors", "single", "pairs-spin0")


def check_mapmaker(mapmaker: str) -> None:
    """Refuse a map-maker not in :data:`MAPMAKERS`, in one clear error."""
    if mapmaker not in MAPMAKERS:
        raise ValueError(f"mapmaker must be one of {MAPMAKERS}, got {mapmaker!r}")


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
        Reciprocal condition number of each pixel's 2x2 (or 3x3) system.
    i_obs : numpy.ndarray, float64, shape (n,), optional
        [muK] on those pixels from the detectors' own samples (:func:`solve_iqu`), UNSEEN where
        invalid; None for pair differences, which do not see I.

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
    i_obs: np.ndarray | None = None

    def _on_sky(self, values, fill):
        out = np.full(12 * self.nside**2, fill, dtype=values.dtype)
        out[self.pixels] = values
        return out

    @property
    def i(self):
        """(npix,) [muK], UNSEEN where invalid; None for pair differences."""
        return None if self.i_obs is None else self._on_sky(self.i_obs, hp.UNSEEN)

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

    def take_qu(self, pixels):
        """:meth:`qu_at` for a caller that lets these maps go: where ``pixels`` are the observed
        ones and Q, U are the rows of one (2, n) array (the engine's), that array itself, its
        invalid pixels set to 0 in place; else a copy. At the Nside-2048 peak a copy waited in
        the transforms' queue beside its maps (0.3 GB each).

        Parameters
        ----------
        pixels : numpy.ndarray of int, shape (n,)

        Returns
        -------
        numpy.ndarray, shape (2, n)
        """
        qu = self.q_obs.base
        own = (
            qu is not None
            and qu.shape == (2, self.pixels.size)
            and qu.dtype == np.float64
            and qu.flags.c_contiguous
            and self.q_obs.ctypes.data == qu.ctypes.data
            and self.u_obs.ctypes.data == qu[1].ctypes.data
            and np.array_equal(pixels, self.pixels)
        )
        if not own:
            return self.qu_at(pixels)
        np.copyto(qu, 0.0, where=qu[0] == hp.UNSEEN)
        return qu

    def i_at(self, pixels):
        """I at some pixels, 0 where invalid or unobserved (:meth:`qu_at`'s rule).

        Parameters
        ----------
        pixels : numpy.ndarray of int, shape (n,)

        Returns
        -------
        numpy.ndarray, shape (n,)

        Raises
        ------
        ValueError
            For maps of pair differences, which do not see I.
        """
        if self.i_obs is None:
            raise ValueError("these maps are of pair differences, which do not see I")
        return self._at((self.i_obs,), pixels)[0]

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
        return self._at((self.q_obs, self.u_obs), pixels)

    def _at(self, rows, pixels):
        """Maps on the observed pixels (a tuple of k (n,) arrays) read at ``pixels``, 0 where
        invalid (Q UNSEEN) or unobserved: (k, len(pixels))."""
        pixels = np.asarray(pixels)
        valid = self.q_obs != hp.UNSEEN
        if np.array_equal(pixels, self.pixels):
            out = np.array(rows)
            np.copyto(out, 0.0, where=~valid)
            return out
        out = np.zeros((len(rows), pixels.size))
        if self.pixels.size:
            at = np.minimum(np.searchsorted(self.pixels, pixels), self.pixels.size - 1)
            seen = (self.pixels[at] == pixels) & valid[at]
            for k, row in enumerate(rows):
                out[k, seen] = row[at[seen]]
        return out


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


def solve_iqu(normal: np.ndarray, rcond_min: float = RCOND_MIN) -> tuple:
    """Solve each pixel's 3x3 least-squares system for (I, Q, U).

    Parameters
    ----------
    normal : numpy.ndarray, shape (n, 9)
        sum w_0 w_0, w_0 w_1, w_0 w_2, w_1 w_1, w_1 w_2, w_2 w_2, w_0 d, w_1 d, w_2 d per pixel,
        with w = (1, c, s) the detector sample's weights (c, s = cos, sin 2a).
    rcond_min : float
        Pixels below this reciprocal condition number are invalid.

    Returns
    -------
    i, q, u : numpy.ndarray, shape (n,)
        [muK], UNSEEN where invalid.
    rcond : numpy.ndarray, shape (n,)
    """
    upper = np.triu_indices(3)
    matrix = np.zeros((normal.shape[0], 3, 3))
    matrix[:, upper[0], upper[1]] = normal[:, :6]
    matrix[:, upper[1], upper[0]] = normal[:, :6]
    eig = np.linalg.eigvalsh(matrix)
    with np.errstate(divide="ignore", invalid="ignore"):
        rcond = np.where(eig[:, 2] > 0, eig[:, 0] / eig[:, 2], 0.0)
    ok = rcond >= rcond_min
    iqu = np.full((normal.shape[0], 3), hp.UNSEEN)
    iqu[ok] = np.linalg.solve(matrix[ok], normal[ok, 6:, None])[..., 0]
    return iqu[:, 0], iqu[:, 1], iqu[:, 2], np.maximum(rcond, 0.0)
