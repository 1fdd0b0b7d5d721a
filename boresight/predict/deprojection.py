"""The noise price of map-domain deprojection, from the h_n.

The pairs' map-maker solves each pixel's (Q, U) from its pair differences d_j = Q cos 2phi_j +
U sin 2phi_j + noise; ``mapmaker="pairs-spin0"`` (:data:`boresight.mapmaking.MAPMAKERS`) solves
a free spin-0 field a beside them, d_j = a + Q cos 2phi_j + U sin 2phi_j + noise, which takes the
leak of a gain or beam-width mismatch common to the pairs whatever the angles (s4cmb's IGQU for
gains, Wallis et al. 2016). With white noise of variance sigma^2 per pair-sample and N
pair-samples in the pixel, the (Q, U) information matrix is, in the moments h_n = <e^{i n phi}>
of the pixel's pair-samples (every pair's angle a_m included: h_n = <e^{i n a}> h_n of the
boresight for pairs sharing the samples)::

  pairs:        N / (2 sigma^2) [(1 +- |h_4|)]                         (eigenvalues)
  pairs-spin0:  N / (2 sigma^2) [(1 - |h_2|^2 +- |h_4 - h_2^2|)]

the second the Schur complement of the spin-0 field. Deprojection is free where h_2 = 0 (a
rotation that nulls h_2 nulls its price too) and diverges as the angles collapse. The variance
of Q + U grows by :func:`noise_inflation`; for the paper's pairs at 0 and 45 deg it is
``(1 - |h_2|^2 / 2) / (1 - |h_2|^2)`` in the boresight's h_2.
"""

from __future__ import annotations

import numpy as np


def information(h2: np.ndarray, h4: np.ndarray, *, deproject: bool) -> tuple:
    """The (Q, U) information matrix's eigenvalues per pair-sample, in units of 1 / sigma^2.

    Parameters
    ----------
    h2, h4 : numpy.ndarray, complex
        The pixel's pair-samples' moments <e^{2 i phi}>, <e^{4 i phi}> in the map-maker's angle.
    deproject : bool
        With a free spin-0 field beside (Q, U).

    Returns
    -------
    low, high : numpy.ndarray
        Shaped as h2.
    """
    h2, h4 = np.asarray(h2), np.asarray(h4)
    if deproject:
        mean, spread = 1.0 - np.abs(h2) ** 2, np.abs(h4 - h2**2)
    else:
        mean, spread = np.ones(np.shape(h4)), np.abs(h4)
    return 0.5 * (mean - spread), 0.5 * (mean + spread)


def qu_variance(h2: np.ndarray, h4: np.ndarray, hits: np.ndarray, *, deproject: bool):
    """var(Q) + var(U) per pixel in units of sigma^2, the trace of the inverse information.

    Parameters
    ----------
    h2, h4 : numpy.ndarray, complex
    hits : numpy.ndarray
        Pair-samples per pixel.
    deproject : bool

    Returns
    -------
    numpy.ndarray
        inf where the system is singular.
    """
    low, high = information(h2, h4, deproject=deproject)
    with np.errstate(divide="ignore"):
        return np.where(low > 0, (1.0 / low + 1.0 / high) / np.asarray(hits, float), np.inf)


def noise_inflation(h2: np.ndarray, h4: np.ndarray) -> np.ndarray:
    """How much a free spin-0 field raises each pixel's var(Q) + var(U):
    ``(1 - |h_2|^2) (1 - |h_4|^2) / ((1 - |h_2|^2)^2 - |h_4 - h_2^2|^2)``.

    Parameters
    ----------
    h2, h4 : numpy.ndarray, complex

    Returns
    -------
    numpy.ndarray
        >= 1; inf where the deprojected system is singular.
    """
    low, high = information(h2, h4, deproject=True)
    plain = 1.0 - np.abs(np.asarray(h4)) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = 0.25 * plain * (1.0 / low + 1.0 / high)
    return np.where(low > 0, ratio, np.inf)


def noise_factor(
    h2: np.ndarray, h4: np.ndarray, hits: np.ndarray, weights: np.ndarray | None = None
) -> float:
    """How much a free spin-0 field raises a white noise's pseudo-spectrum, N_ell^EE + N_ell^BB:
    white noise of pixel variances v_p, masked by weights w_p, has the flat pseudo-spectrum
    Omega_pix / (4 pi) sum_p w_p^2 v_p (with the mask's mean w^2 to undo), so the factor is
    sum_p w_p^2 v_p' / sum_p w_p^2 v_p with v and v' :func:`qu_variance` without and with the
    field; a survey's N_ell and its sigma(r) take it as a shorter observing time
    (:func:`boresight.noise.sigma_r`'s ``time_fraction`` = 1 / factor).

    Parameters
    ----------
    h2, h4 : numpy.ndarray, complex
        The pixels' pair-sample moments.
    hits : numpy.ndarray
        Pair-samples per pixel.
    weights : numpy.ndarray, optional
        The mask's weights on those pixels (default 1).

    Returns
    -------
    float
        >= 1; inf where a weighted pixel's deprojected system is singular.
    """
    w2 = np.ones(np.shape(hits)) if weights is None else np.asarray(weights, float) ** 2
    used = np.atleast_1d(w2 > 0)
    plain = np.atleast_1d(qu_variance(h2, h4, hits, deproject=False))[used]
    free = np.atleast_1d(qu_variance(h2, h4, hits, deproject=True))[used]
    if not used.any() or not np.all(np.isfinite(plain)):
        raise ValueError("noise_factor: every weighted pixel must solve Q and U without the field")
    w2 = np.atleast_1d(w2)[used]
    return float(np.sum(w2 * free) / np.sum(w2 * plain))
