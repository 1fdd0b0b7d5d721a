"""Sky evaluation at hit positions: bilinear HEALPix interpolation or exact band-limited synthesis.

"interp" interpolates the pixelised maps (what the paper did; the backend kernels read ``stack``);
"exact" evaluates the beam-smoothed
alm at each point with ducc0's synthesis_general (accuracy ``EXACT_EPSILON``), which keeps the
second-order pointing terms that interpolation smears.
"""

from functools import cached_property

import numpy as np

from . import harmonics

METHODS = ("interp", "exact")
EXACT_EPSILON = 1e-11  #: ducc0 relative accuracy of exact evaluation


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


class SkyFields:
    """The fields a TOD samples: I, Q, U and optionally a leak template.

    Parameters
    ----------
    sky : boresight.sky.Sky
    template : numpy.ndarray, shape (npix,), optional
        The leak's template map [muK].
    template_alm : numpy.ndarray, optional
        Its alm, for exact evaluation.

    Notes
    -----
    ``stack`` holds the fields interleaved, shape (npix, F), the layout the interpolation kernels
    read; ``exact`` evaluates the alm at points with ducc0.
    """

    def __init__(self, sky, template=None, template_alm=None):
        self.nside = sky.nside
        self.alm = sky.alm
        self.n_fields = 3 if template is None else 4
        self.template_alm = template_alm
        self._sky, self._template = sky, template

    @cached_property
    def stack(self):
        """(npix, n_fields) interleaved fields; without a template, the sky's own (built once)."""
        if self._template is None:
            return self._sky.interleaved
        stack = np.empty((self._sky.maps.shape[1], self.n_fields))
        stack[:, :3] = self._sky.maps.T
        stack[:, 3] = self._template
        return stack

    def exact(self, theta, phi, nthreads=0):
        """Band-limited fields at points: (n_fields, npoints) for flat arrays theta, phi [rad]."""
        out = np.empty((self.n_fields, theta.size))
        out[0] = harmonics.evaluate(
            self.alm[0], theta, phi, epsilon=EXACT_EPSILON, nthreads=nthreads
        )
        out[1:3] = harmonics.evaluate(
            self.alm[1:], theta, phi, spin=2, epsilon=EXACT_EPSILON, nthreads=nthreads
        )
        if self.n_fields > 3:
            out[3] = harmonics.evaluate(
                self.template_alm, theta, phi, epsilon=EXACT_EPSILON, nthreads=nthreads
            )
        return out
