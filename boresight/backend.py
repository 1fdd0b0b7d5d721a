"""The kernel backend contract: what the engine needs from ``tod_cpu`` (numba) and ``tod_gpu``
(CuPy), and the one place that picks a backend by name.

A backend is a module with the functions of :class:`KernelBackend`. The engine calls only these,
never asks which backend it has, and hands arrays back and forth through ``to_device`` /
``to_host``. Both backends draw the same counter-based random numbers, so their maps agree to
rounding (``tests/test_gpu.py``); ``tests/test_backend.py`` checks that both modules provide the
contract with the same parameters, without needing a GPU.
"""

from typing import Protocol, runtime_checkable

BACKENDS = ("cpu", "gpu")


@runtime_checkable
class KernelBackend(Protocol):
    """The hot loop's kernels. Arrays are numpy (cpu) or CuPy (gpu) arrays on the backend's
    device; angles in radians; a chunk holds ``P`` pixels, ``H`` hits, ``K`` rotations, ``M``
    pairs and ``F`` sky fields (I, Q, U and optionally a leak template)."""

    def generate_hits(self, seed, nside, pixels, offsets, range_rad, centre_rad, centred):
        """theta, phi, psi (H,) of every hit of a chunk of pixels; pixel k owns hits
        offsets[k]..offsets[k + 1] - 1 (offsets (P + 1,) int64)."""

    def offset_points(self, theta, phi, psi, rotations, pair_angles, rho, chi):
        """Where detector B of each (hit, rotation, pair) looks: theta_b, phi_b (H, K, M)."""

    def interpolate(self, stack, nside, theta, phi):
        """Bilinear interpolation of the interleaved (npix, F) stack at points -> (F, n)."""

    def accumulate(self, offsets, psi, values_a, values_b, rotations, pair_angles, dg, leak):
        """Normal-equation sums (P, 5) of hits grouped by pixel, from the fields at detector A
        (F, H) and B (F, H, K, M), or an empty (F, 0, K, M) when B looks where A does."""

    def accumulate_scatter(
        self, pixels, psi, values_a, values_b, rotations, pair_angles, dg, leak, out
    ):
        """Add the sums of hits in any order into ``out[pixels[h]]`` (npix, 5), in hit order."""

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
        dg,
        rho,
        chi,
        leak,
        pointing,
    ):
        """Normal-equation sums (P, 5) of a synthetic scan with an interpolated sky: the same
        numbers as generate_hits -> interpolate (-> offset_points) -> accumulate."""

    def moments(self, offsets, psi, rotations, n_max):
        """(P, n_max + 1) complex <exp(i n psi)> over each pixel's hits and rotations."""

    def to_device(self, array):
        """The array on the backend's device."""

    def to_host(self, array):
        """The array as numpy."""

    def zeros(self, shape):
        """A float64 array of zeros on the device."""


def get_backend(name):
    """The kernel module of a backend: 'cpu' (numba) or 'gpu' (CuPy)."""
    if name == "cpu":
        from . import tod_cpu

        return tod_cpu
    if name == "gpu":
        from . import tod_gpu

        return tod_gpu
    raise ValueError(f"backend must be one of {BACKENDS}, got {name!r}")
