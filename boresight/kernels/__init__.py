"""The hot loop's kernels, one backend module each, and what they share.

* :mod:`~boresight.kernels.contract`: what the engine needs from a backend
  (:class:`~boresight.kernels.contract.KernelBackend`) and :func:`get_backend`, the one place that
  picks one by name;
* :mod:`~boresight.kernels.cpu`: the numba kernels; :mod:`~boresight.kernels.gpu` and ``gpu.cu``:
  the same algorithms for CuPy;
* :mod:`~boresight.kernels.pixels`: HEALPix geometry (pixel of a point, points in a pixel,
  bilinear interpolation) as numba functions;
* :mod:`~boresight.kernels.rng`: counter-based random numbers keyed by (seed, pixel, hit,
  stream);
* :mod:`~boresight.kernels.fields`: the glue both backends share (hit offsets, the fields at both
  detectors, the Q = U = 0 sums).
"""

from .contract import BACKENDS, KernelBackend, get_backend

__all__ = ["BACKENDS", "KernelBackend", "get_backend"]
