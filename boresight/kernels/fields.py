"""What both kernel backends share around their kernels: where each pixel's hits lie in a chunk,
the sky fields at both detectors of every pair, and the sums of the same hits with the sky's
Q = U = 0 (the paper's check that a residual comes from the polarised sky)."""

from __future__ import annotations

import numpy as np


def hit_offsets(n_phi: np.ndarray) -> np.ndarray:
    """Where each pixel's hits start in a chunk's hit arrays.

    Parameters
    ----------
    n_phi : array_like of int, shape (P,)

    Returns
    -------
    numpy.ndarray, int64, shape (P + 1,)
        Pixel k owns hits offsets[k]..offsets[k + 1] - 1.
    """
    offsets = np.zeros(np.size(n_phi) + 1, dtype=np.int64)
    np.cumsum(n_phi, out=offsets[1:])
    return offsets


def pair_fields(
    at, offset_points, n_fields, theta, phi, psi, rotations, pair_angles, rho, chi, pointing
):
    """The sky fields where detectors A and B of every pair look.

    Parameters
    ----------
    at : callable
        at(theta, phi) -> (F, n): interpolation on the backend's device, or exact evaluation.
    offset_points : callable
        The backend's kernel for detector B's pointing.
    n_fields : int
    theta, phi, psi : array, shape (H,)
        Hits [rad].
    rotations, pair_angles, rho, chi : array
        [rad], shapes (K,), (M,), (M,), (M,).
    pointing : bool
        Whether detector B looks elsewhere.

    Returns
    -------
    values_a : array, shape (F, H)
    values_b : array, shape (F, H, K, M), or (F, 0, K, M) without a pointing offset
    """
    values_a = at(theta, phi)
    if not pointing:
        return values_a, np.empty((n_fields, 0, rotations.size, pair_angles.size))
    tb, pb = offset_points(theta, phi, psi, rotations, pair_angles, rho, chi)
    return values_a, at(tb.ravel(), pb.ravel()).reshape((n_fields,) + tb.shape)


def without_qu(values):
    """Fields at points with Q and U zero: what the sky without polarisation
    (:meth:`boresight.sky.Sky.without_polarisation`) gives there, for its I and the leak's
    template are this sky's. The paper's Q = U = 0 check reads them from the same hits.

    Parameters
    ----------
    values : array, shape (F, ...)
        I, Q, U (and the template) at points, numpy or CuPy.

    Returns
    -------
    array
        A copy, rows 1 and 2 zero.
    """
    out = values.copy()
    out[1:3] = 0.0
    return out


def sums_with_zero_qu(sums, values_a, values_b, zero_qu):
    """``sums(values_a, values_b)``, and with ``zero_qu`` also those of the fields with Q = U = 0
    (:func:`without_qu`) from the same hits.

    Parameters
    ----------
    sums : callable
        sums(values_a, values_b) -> normal-equation sums (P, 5), the backend's accumulate.
    values_a, values_b : array
        The fields at both detectors (:func:`pair_fields`).
    zero_qu : bool

    Returns
    -------
    array, shape (P, 5), or a pair of them with ``zero_qu`` (the sky's, Q = U = 0's)
    """
    if not zero_qu:
        return sums(values_a, values_b)
    return sums(values_a, values_b), sums(without_qu(values_a), without_qu(values_b))
