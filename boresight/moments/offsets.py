"""Each sample's offset from its pixel's centre, and the moments weighted by them (the
second-order reading of a field across the pixel).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import healpy as hp
import numpy as np

from .._util import interrupts
from ..constants import N_MAX
from ..pointing import (
    detector_pointing,
    pointing,
)

if TYPE_CHECKING:
    from ..instrument.focalplane import FocalPlane
    from ..schedule import Schedule


def sample_offsets(theta: np.ndarray, phi: np.ndarray, nside: int) -> tuple:
    """Each sample's RING pixel and its offset delta [rad] from the pixel's centre in the tangent
    plane there, (n - c_p) . e_theta + i (n - c_p) . e_phi (:func:`centroid_moments`).

    Parameters
    ----------
    theta, phi : numpy.ndarray
        The samples' colatitude and longitude [rad].
    nside : int

    Returns
    -------
    pix : numpy.ndarray, int64
    delta : numpy.ndarray, complex128
    """
    pix = hp.ang2pix(nside, theta, phi)
    c_theta, c_phi = hp.pix2ang(nside, pix)
    d = hp.ang2vec(theta, phi) - hp.ang2vec(c_theta, c_phi)
    e_theta = np.array(
        [np.cos(c_theta) * np.cos(c_phi), np.cos(c_theta) * np.sin(c_phi), -np.sin(c_theta)]
    )
    e_phi = np.array([-np.sin(c_phi), np.cos(c_phi), np.zeros_like(c_phi)])
    return pix, np.einsum("ij,ji->i", d, e_theta) + 1j * np.einsum("ij,ji->i", d, e_phi)


def centroid_moments(
    schedule: Schedule,
    nside: int,
    n_max: int = N_MAX,
    chunk_samples: int = 1 << 20,
    *,
    focalplane: FocalPlane | None = None,
) -> np.ndarray:
    """The samples' offsets from their pixel centres, weighted as the h_n are.

    delta_j = (n_j - c_p) . e_theta + i (n_j - c_p) . e_phi is sample j's offset [rad] in the
    tangent plane at its pixel's centre c_p (the spin-1 quantity of
    :func:`boresight.harmonics.alm2map_gradient`'s frame), so that a field read at the sample is
    F(c_p) + Re(conj(delta_j) grad F) to first order. Real scans cross a pixel along a few lines,
    and where they cross depends on the crossing angle: these moments carry what that does to a
    leak (:func:`boresight.predict.expected_residual`'s ``offsets``).

    Parameters
    ----------
    schedule : boresight.schedule.Schedule
        With its boresight angles and repeats (:func:`boresight.pointing.pointing`).
    nside, n_max, chunk_samples : int
    focalplane : boresight.instrument.focalplane.FocalPlane, optional
        Each pair's own, on its own samples and crossing angles
        (:func:`boresight.pointing.detector_pointing`), one pair at a time: the ``offsets`` of
        :func:`boresight.predict.focalplane.expected_residual`.

    Returns
    -------
    numpy.ndarray, complex128, shape (2, n_max + 1, npix), or (pairs, 2, n_max + 1, npix)
        (1/N) sum_j exp(i n psi_j) delta_j and (1/N) sum_j exp(i n psi_j) conj(delta_j), n = 0..
        n_max (0 where N = 0).
    """
    if focalplane is None:
        return _centroids(pointing(schedule, chunk_samples), nside, n_max)
    return np.array(
        [
            _centroids(
                (
                    tuple(x[0] for x in chunk)
                    for chunk in detector_pointing(schedule, focalplane.subset([i]), chunk_samples)
                ),
                nside,
                n_max,
            )
            for i in range(focalplane.n_pairs)
        ]
    )


def _centroids(chunks, nside, n_max):
    """:func:`centroid_moments` of the (theta, phi, psi) chunks of one pointing."""
    npix = 12 * nside**2
    sums = np.zeros((2, n_max + 1, npix), dtype=np.complex128)
    hits = np.zeros(npix)
    for theta, phi, psi in chunks:
        interrupts.check()
        pix, delta = sample_offsets(theta, phi, nside)
        hits += np.bincount(pix, minlength=npix)
        turn, spin = np.exp(1j * psi), np.ones(psi.size, dtype=np.complex128)
        for n in range(n_max + 1):
            for k, value in enumerate((delta, np.conj(delta))):
                w = spin * value
                sums[k, n] += np.bincount(pix, w.real, npix) + 1j * np.bincount(pix, w.imag, npix)
            spin = spin * turn
    return np.where(hits > 0, sums / np.maximum(hits, 1), 0.0)
