"""The kernel backend contract: what the engine needs from ``kernels.cpu`` (numba) and ``kernels.gpu``
(CuPy), and the one place that picks a backend by name.

A backend is a module with the functions of :class:`KernelBackend`. The engine calls only these,
never asks which backend it has, and hands arrays back and forth through ``to_device`` /
``to_host``. Both backends draw the same counter-based random numbers, so their maps agree to
rounding (``tests/test_gpu.py``); ``tests/kernels/test_contract.py`` checks that both modules provide the
contract with the same parameters, without needing a GPU.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

BACKENDS = ("cpu", "gpu")


@runtime_checkable
class KernelBackend(Protocol):
    """The hot loop's kernels. Arrays are numpy (cpu) or CuPy (gpu) arrays on the backend's
    device; angles in radians; a chunk holds ``P`` pixels, ``H`` hits, ``K`` rotations, ``M``
    pairs and ``F`` sky fields (I, Q, U and optionally a leak template)."""

    def generate_hits(self, seed, nside, pixels, offsets, range_rad, centre_rad, centred):
        """Position and crossing angle of every hit of a chunk of pixels.

        Parameters
        ----------
        seed : int
        nside : int
        pixels : int64 array, shape (P,)
            RING indices.
        offsets : int64 array, shape (P + 1,)
            Pixel k owns hits offsets[k]..offsets[k + 1] - 1 (the hit number in its random key).
        range_rad, centre_rad : float64 array, shape (P,)
        centred : bool
            Hits at pixel centres instead of uniform positions.

        Returns
        -------
        theta, phi, psi : float64 array, shape (H,)
            [rad].
        """

    def offset_points(self, theta, phi, psi, rotations, pair_angles, rho, chi):
        """Where detector B of each pair looks, for every (hit, rotation, pair).

        Parameters
        ----------
        theta, phi, psi : float64 array, shape (H,)
            Hits [rad].
        rotations, pair_angles : float64 array, shapes (K,), (M,)
            [rad].
        rho, chi : float64 array, shape (M,)
            Pointing offset and its direction per pair [rad].

        Returns
        -------
        theta_b, phi_b : float64 array, shape (H, K, M)
            [rad]; points past a pole folded back.
        """

    def interpolate(self, stack, nside, theta, phi):
        """Bilinear HEALPix interpolation of an interleaved stack.

        Parameters
        ----------
        stack : float64 array, shape (npix, F)
        nside : int
        theta, phi : float64 array, shape (n,)
            [rad].

        Returns
        -------
        float64 array, shape (F, n)
        """

    def accumulate(
        self, offsets, psi, values_a, values_b, beams, response, leak, jitter, seed, pixels
    ):
        """Pair differences binned into each pixel's 2x2 least-squares system for (Q, U).

        Parameters
        ----------
        offsets : int64 array, shape (P + 1,)
        psi : float64 array, shape (H,)
        values_a : float64 array, shape (F, H)
            Fields I, Q, U[, leak template] where detector A looks [muK].
        values_b : float64 array, shape (F, H, K, M) or (F, 0, K, M)
            The same where detector B looks; empty when B looks where A does.
        beams : float64 array, shape (2, H, K, M) or (2, 0, K, M)
            Detector A's and B's extra signal from their own beams [muK]
            (:class:`boresight.instrument.beams.BeamConvolver`); empty when both beams are the sky's.
        response : float64 array, shape (K, M, 7)
            Assumed and true polarisation angles and detector B's gain per (rotation, pair)
            (:func:`boresight.instrument.pairs.response`).
        leak, jitter : float64 array, shape (M,)
            Additive leak and rms of the per-sample gain jitter.
        seed : int
            Key of the jitter draws, with the pixel and hit.
        pixels : int64 array, shape (P,)
            RING index of each pixel.

        Returns
        -------
        float64 array, shape (P, 5)
            sum c^2, sum c s, sum s^2, sum c d, sum s d with c, s = cos, sin 2a.
        """

    def accumulate_scatter(
        self, pixels, psi, values_a, values_b, beams, response, leak, jitter, seed, first, out
    ):
        """:meth:`accumulate` for hits in any order, added into a full-sky accumulator in hit order.

        Parameters
        ----------
        pixels : int64 array, shape (H,)
            RING pixel of each hit.
        psi, values_a, values_b, beams, response, leak, jitter
            As in :meth:`accumulate`.
        seed : int
            Key of the jitter draws, with the sample's index in its stream.
        first : int
            The stream index of the first hit (the samples of earlier chunks).
        out : float64 array, shape (npix, 5)
            Running sums, updated in place.
        """

    def bin_scan(
        self,
        seed,
        nside,
        pixels,
        n_phi,
        range_rad,
        centre_rad,
        centred,
        stack,
        rotations,
        pair_angles,
        response,
        rho,
        chi,
        leak,
        jitter,
        pointing,
        zero_qu,
    ):
        """Normal-equation sums of a synthetic scan with an interpolated sky.

        The same numbers as generate_hits -> interpolate (-> offset_points) -> accumulate.

        Parameters
        ----------
        seed, nside, pixels, range_rad, centre_rad, centred
            As in :meth:`generate_hits`.
        n_phi : int64 array, shape (P,)
            Hits per pixel.
        stack : array, shape (npix, F)
            The interleaved sky fields on the device (:meth:`to_device`).
        rotations, pair_angles : float64 array, shapes (K,), (M,)
            Boresight rotations and nominal pair angles [rad] (detector B's pointing).
        response, leak, jitter
            As in :meth:`accumulate`.
        rho, chi : float64 array, shape (M,)
            As in :meth:`offset_points`.
        pointing : bool
            Whether detector B looks elsewhere.
        zero_qu : bool
            Also the sums of the same hits over the sky with Q = U = 0 (its I and the leak's
            template kept): the paper's zero-polarisation check, without a second pass.

        Returns
        -------
        float64 array, shape (P, 5), or with ``zero_qu`` a pair of them (a tuple or a (2, P, 5)
        array): the sky's, then Q = U = 0's
        """

    def moments(self, offsets, psi, rotations, n_max):
        """Spin moments of each pixel's hits, every rotation included.

        Parameters
        ----------
        offsets : int64 array, shape (P + 1,)
        psi : float64 array, shape (H,)
        rotations : float64 array, shape (K,)
            [rad].
        n_max : int

        Returns
        -------
        complex128 array, shape (P, n_max + 1)
            <exp(i n (psi + alpha_k))>.
        """

    def to_device(self, array):
        """An array on the backend's device (the sky fields, uploaded once).

        Parameters
        ----------
        array : numpy.ndarray

        Returns
        -------
        array
        """

    def to_host(self, array):
        """An array as numpy.

        Parameters
        ----------
        array : array

        Returns
        -------
        numpy.ndarray
        """

    def zeros(self, shape):
        """A zeroed float64 accumulator on the device.

        Parameters
        ----------
        shape : tuple of int

        Returns
        -------
        array
        """


def get_backend(name: str) -> KernelBackend:
    """The kernel module of a backend.

    Parameters
    ----------
    name : {"cpu", "gpu"}

    Returns
    -------
    module
        ``kernels.cpu`` (numba) or ``kernels.gpu`` (CuPy), each a :class:`KernelBackend`.
    """
    if name == "cpu":
        from . import cpu

        return cpu
    if name == "gpu":
        from . import gpu

        return gpu
    raise ValueError(f"backend must be one of {BACKENDS}, got {name!r}")
