"""The hot loop on an NVIDIA GPU: CuPy RawKernels with the same algorithms as ``kernels.cpu``.

The CUDA source (gpu.cu, package data) ports boresight.kernels.rng, boresight.kernels.pixels
and boresight.kernels.cpu line by line
(same integer arithmetic for the counter-based random numbers), so CPU and GPU maps agree to the
rounding of sin/cos/acos (tests/test_gpu.py: <= 1e-12 relative). Synthetic scans with an
interpolated sky run as one fused kernel (bin_scan, 7e10 detector samples/s on an H100); the
staged kernels serve exact evaluation and real sample streams, which are sorted by pixel on the
GPU so that sums add in sample order (deterministic, as on the CPU). CuPy is chosen over JAX
because the kernels are per-pixel loops with 64-bit integer hashing, which raw CUDA expresses
directly. Spherical-harmonic transforms stay on ducc0 (CPU): bench/bench_sht.py measured s2fft
on the GPU 56 times slower. Install with `pip install boresight[gpu]` (CuPy for CUDA 12; use
cupy-cuda13x for CUDA 13).
"""

from __future__ import annotations

from importlib import resources

import numpy as np

try:
    import cupy as cp
except ImportError as err:  # pragma: no cover - exercised where CuPy is missing
    raise ImportError(
        "backend 'gpu' needs CuPy: pip install 'boresight[gpu]' (or cupy-cuda13x for CUDA 13)"
    ) from err

_THREADS = 256
#: the CUDA kernels, shipped as package data beside this module
SOURCE = (resources.files("boresight.kernels") / "gpu.cu").read_text()
_module = None


def _kernel(name):
    global _module
    if _module is None:
        try:
            if cp.cuda.runtime.getDeviceCount() < 1:
                raise RuntimeError
        except Exception as err:
            raise RuntimeError(
                "backend 'gpu': no CUDA GPU is visible (CuPy found no device)"
            ) from err
        _module = cp.RawModule(code=SOURCE, options=("--std=c++17",))
    return _module.get_function(name)


def _launch(name, n, args):
    if n > 0:
        _kernel(name)(((n + _THREADS - 1) // _THREADS,), (_THREADS,), args)


def _d(array, dtype=np.float64):
    return cp.ascontiguousarray(cp.asarray(array, dtype=dtype))


def to_device(array: np.ndarray) -> cp.ndarray:
    """An array on the backend's device (the sky fields, uploaded once).

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.to_device`.

    Copied to the GPU.
    """
    return _d(array)


def to_host(array: object) -> np.ndarray:
    """An array as numpy.

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.to_host`.
    """
    return cp.asnumpy(array) if isinstance(array, cp.ndarray) else array


def _scan_args(seed, nside, pixels, counts, range_rad, centre_rad, centred):
    """Kernel arguments of a chunk of a synthetic scan's pixels (counts: hit offsets or N_phi)."""
    return (
        _d(pixels, np.int64),
        _d(counts, np.int64),
        _d(range_rad),
        _d(centre_rad),
        np.int64(pixels.size),
        np.uint64(seed),
        np.int64(nside),
        np.int32(bool(centred)),
    )


def generate_hits(
    seed: int,
    nside: int,
    pixels: np.ndarray,
    offsets: np.ndarray,
    range_rad: np.ndarray,
    centre_rad: np.ndarray,
    centred: bool,
) -> tuple:
    """Position and crossing angle of every hit of a chunk of pixels.

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.generate_hits`.
    """
    offsets_d = _d(offsets, np.int64)
    nhit = int(offsets[-1])
    theta, phi, psi = (cp.empty(nhit) for _ in range(3))
    _launch(
        "generate_hits",
        pixels.size,
        _scan_args(seed, nside, pixels, offsets_d, range_rad, centre_rad, centred)
        + (theta, phi, psi),
    )
    return theta, phi, psi


def offset_points(
    theta: np.ndarray,
    phi: np.ndarray,
    psi: np.ndarray,
    rotations: np.ndarray,
    pair_angles: np.ndarray,
    rho: np.ndarray,
    chi: np.ndarray,
) -> tuple:
    """Where detector B of each pair looks, for every (hit, rotation, pair).

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.offset_points`.
    """
    nh, nk, nm = theta.size, rotations.size, pair_angles.size
    tb = cp.empty((nh, nk, nm))
    pb = cp.empty((nh, nk, nm))
    args = (_d(theta), _d(phi), _d(psi), np.int64(nh), np.int32(nk), np.int32(nm))
    _launch("offset_points", nh, args + _offsets(rotations, pair_angles, rho, chi) + (tb, pb))
    return tb, pb


def _offsets(rotations, pair_angles, rho, chi):
    """Device arrays (K, M) of rho cos and rho sin of rotation + pair angle + chi [rad]: detector
    B's offset before the hit's crossing angle turns it (angle addition, as in
    kernels.cpu.offset_points)."""
    beta = np.asarray(rotations)[:, None] + np.asarray(pair_angles)[None, :] + np.asarray(chi)
    rho = np.asarray(rho)
    return _d(rho * np.cos(beta)), _d(rho * np.sin(beta))


def interpolate(stack: object, nside: int, theta: np.ndarray, phi: np.ndarray) -> cp.ndarray:
    """Bilinear HEALPix interpolation of an interleaved stack.

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.interpolate`.
    """
    stack = stack if isinstance(stack, cp.ndarray) else _d(stack)
    theta, phi = _d(theta), _d(phi)
    out = cp.empty((stack.shape[1], theta.size))
    _launch(
        "interpolate",
        theta.size,
        (stack, np.int32(stack.shape[1]), np.int64(nside), theta, phi, np.int64(theta.size), out),
    )
    return out


def _physics(response, leak, jitter=None, beams=None):
    """Device arrays of the per-(rotation, pair) turns cos, sin 2(alpha + angle), dg and leak.

    The CUDA kernels model a constant gain per pair and the sky's beam: polarisation-angle errors,
    gain drift between repeats, gain jitter and detector beams are refused with a clear error
    (they run on the CPU).
    """
    if beams is not None and beams.shape[1] > 0:
        raise ValueError(
            "the GPU backend has no detector beams or added systematics (extra signals of A and "
            "B); they need backend = 'cpu'"
        )
    response = np.asarray(response)
    g_b = response[..., 6]
    ideal = (
        np.array_equal(response[..., 2:4], response[..., 0:2])
        and np.array_equal(response[..., 4:6], response[..., 0:2])
        and (g_b == g_b[:1]).all()
        and (jitter is None or not np.any(jitter))
    )
    if not ideal:
        raise ValueError(
            "the GPU backend simulates per-pair gain, pointing and leak only; polarisation-angle "
            "errors, gain drift (dg_repeat) and gain jitter need backend = 'cpu'"
        )
    return (
        np.int32(response.shape[0]),
        np.int32(response.shape[1]),
        _d(response[..., 0]),
        _d(response[..., 1]),
        _d(1.0 - g_b[0]),
        _d(leak),
    )


def _stored_values(values_a, values_b):
    """Device arrays and sizes (va, vb or null, nh, nf) of interpolated fields at hits."""
    va = _d(values_a)
    vb = _d(values_b) if values_b.shape[1] > 0 else np.uint64(0)
    return va, vb, np.int64(va.shape[1]), np.int32(va.shape[0])


def _accumulate(offsets, psi, target, values_a, values_b, physics, out):
    _launch(
        "accumulate",
        offsets.size - 1,
        (_d(offsets, np.int64), _d(psi), np.int64(offsets.size - 1), target)
        + _stored_values(values_a, values_b)
        + physics
        + (out,),
    )


def accumulate(
    offsets: object,
    psi: object,
    values_a: object,
    values_b: object,
    beams: np.ndarray,
    response: np.ndarray,
    leak: np.ndarray,
    jitter: np.ndarray,
    seed: int,
    pixels: np.ndarray,
) -> cp.ndarray:
    """Pair differences binned into each pixel's 2x2 least-squares system for (Q, U).

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.accumulate`.

    Without jitter, so ``seed`` and ``pixels`` are unused.
    """
    out = cp.zeros((offsets.size - 1, 5))
    args = (values_a, values_b, _physics(response, leak, jitter, beams), out)
    _accumulate(offsets, psi, np.uint64(0), *args)
    return out


def accumulate_scatter(
    pixels: object,
    psi: object,
    values_a: object,
    values_b: object,
    beams: np.ndarray,
    response: np.ndarray,
    leak: np.ndarray,
    jitter: np.ndarray,
    seed: int,
    first: int,
    out: cp.ndarray,
) -> None:
    """:meth:`accumulate` for hits in any order, added into a full-sky accumulator in hit order.

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.accumulate_scatter`.

    The hits are sorted by (pixel, position) on the GPU, so every pixel's sums are added
    in hit order, as on the CPU: deterministic, and equal to the CPU to rounding. Gain jitter is
    refused (:func:`_physics`), so ``seed`` and ``first`` are unused.
    """
    pixels = _d(pixels, np.int64)
    order = cp.argsort(pixels * pixels.size + cp.arange(pixels.size))
    target, counts = cp.unique(pixels[order], return_counts=True)
    offsets = cp.zeros(target.size + 1, dtype=cp.int64)
    cp.cumsum(counts, out=offsets[1:])
    values_b = _d(values_b)[:, order] if values_b.shape[1] > 0 else values_b
    args = (_d(values_a)[:, order], values_b, _physics(response, leak, jitter, beams), out)
    _accumulate(offsets, _d(psi)[order], target, *args)


def bin_scan(
    seed: int,
    nside: int,
    pixels: np.ndarray,
    n_phi: np.ndarray,
    range_rad: np.ndarray,
    centre_rad: np.ndarray,
    centred: bool,
    stack: cp.ndarray,
    rotations: np.ndarray,
    pair_angles: np.ndarray,
    response: np.ndarray,
    rho: np.ndarray,
    chi: np.ndarray,
    leak: np.ndarray,
    jitter: np.ndarray,
    pointing: bool,
    zero_qu: bool,
) -> cp.ndarray:
    """Normal-equation sums of a synthetic scan with an interpolated sky.

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.bin_scan`.

    One fused kernel: each thread draws its pixel's hits, interpolates the stack where both
    detectors of every pair look and sums in registers, without per-hit arrays.

    The same numbers as generate_hits -> interpolate (-> offset_points) -> accumulate.
    """
    out = cp.empty((2, pixels.size, 5) if zero_qu else (pixels.size, 5))
    physics = _physics(response, leak, jitter)
    _launch(
        "bin_scan",
        pixels.size,
        _scan_args(seed, nside, pixels, n_phi, range_rad, centre_rad, centred)
        + (stack, np.int32(stack.shape[1]))
        + physics[:5]
        + _offsets(rotations, pair_angles, rho, chi)
        + (physics[5], np.int32(bool(pointing)), np.int32(bool(zero_qu)), out),
    )
    return out


def moments(offsets: object, psi: object, rotations: np.ndarray, n_max: int) -> cp.ndarray:
    """Spin moments of each pixel's hits, every rotation included.

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.moments`.
    """
    npix = offsets.size - 1
    out = cp.empty((npix, n_max + 1), dtype=cp.complex128)
    _launch(
        "moments",
        npix,
        (
            _d(offsets, np.int64),
            _d(psi),
            np.int64(npix),
            _d(rotations),
            np.int32(rotations.size),
            np.int32(n_max),
            out,
        ),
    )
    return out


def zeros(shape: tuple) -> cp.ndarray:
    """A zeroed float64 accumulator on the device.

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.zeros`.

    GPU memory.
    """
    return cp.zeros(shape)
