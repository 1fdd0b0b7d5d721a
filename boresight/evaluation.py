"""Sky evaluation at hit positions: bilinear HEALPix interpolation or exact band-limited synthesis.

"interp" interpolates the pixelised maps (what the paper did; the backend kernels read ``stack``);
"exact" evaluates the beam-smoothed
alm at each point with ducc0's synthesis_general (accuracy ``EXACT_EPSILON``), which keeps the
second-order pointing terms that interpolation smears. The engine also reads "pixel": each
map's value in the sample's own pixel, as TOAST's ``ScanHealpixMap`` scans a map (with it an
ideal instrument's maps return the input maps to rounding on any samples).
"""

from functools import cached_property

import numpy as np

from . import harmonics

METHODS = ("interp", "exact")
#: what the engine's TOD reads besides: the map's value in the sample's pixel
ENGINE_METHODS = METHODS + ("pixel",)
EXACT_EPSILON = 1e-11  #: ducc0 relative accuracy of exact evaluation


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

    def in_pixel(self, pixels):
        """The fields' map values in some pixels: (n_fields, npoints) for RING indices (n,)."""
        return np.ascontiguousarray(self.stack[pixels].T)

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
