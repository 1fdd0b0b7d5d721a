"""The hot loop on the CPU: numba kernels for hits, pointing offsets, pair differences, moments.

Each kernel works on one chunk of pixels and runs in parallel over pixels (or hits); every random
number comes from :mod:`boresight.rng` keyed by (seed, pixel, hit), so results do not depend on the
chunking or the thread count. ``boresight.kernels.gpu`` implements the same kernels for CuPy.
"""

from __future__ import annotations

import numba
import numpy as np

from .._util.jit import njit
from .fields import hit_offsets, pair_fields, sums_with_zero_qu
from .pixels import face_point, interpolate_interleaved, ring2xyf
from .rng import (
    JITTER_SALT,
    STREAM_PSI,
    STREAM_U,
    STREAM_V,
    derived_key,
    normal_from_key,
    pixel_key,
    uniform_from_key,
)

__all__ = [
    "generate_hits",
    "offset_points",
    "interpolate",
    "accumulate",
    "accumulate_scatter",
    "accumulate_detectors",
    "pair_samples",
    "pair_differences",
    "bin_differences",
    "bin_detectors",
    "bin_scan",
    "moments",
    "to_host",
    "to_device",
    "zeros",
]


def interpolate(stack: np.ndarray, nside: int, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Bilinear HEALPix interpolation of an interleaved stack.

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.interpolate`.
    """
    return interpolate_interleaved(stack, nside, theta, phi)


_TWOPI = 2.0 * np.pi


@numba.njit(inline="always")
def _draw_hit(key, j, nside, ix, iy, face, range_rad, centre_rad, centred):
    """Position (theta, phi) and crossing angle psi [rad] of hit j of the pixel with this key."""
    psi = centre_rad + range_rad * (uniform_from_key(key, j, STREAM_PSI) - 0.5)
    if centred:
        u = v = 0.5
    else:
        u = uniform_from_key(key, j, STREAM_U)
        v = uniform_from_key(key, j, STREAM_V)
    theta, phi = face_point(nside, ix, iy, face, u, v)
    return theta, phi, psi


@njit(parallel=True)
def generate_hits(seed, nside, pixels, offsets, range_rad, centre_rad, centred):
    """Position and crossing angle of every hit of a chunk of pixels.

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.generate_hits`.
    """
    nhit = offsets[-1]
    theta = np.empty(nhit)
    phi = np.empty(nhit)
    psi = np.empty(nhit)
    for k in numba.prange(pixels.size):
        key = pixel_key(seed, pixels[k])
        ix, iy, face = ring2xyf(nside, pixels[k])
        for h in range(offsets[k], offsets[k + 1]):
            theta[h], phi[h], psi[h] = _draw_hit(
                key, h - offsets[k], nside, ix, iy, face, range_rad[k], centre_rad[k], centred
            )
    return theta, phi, psi


@numba.njit(inline="always")
def _fold(t, f):
    """(theta, phi) [rad] of a point moved past a pole folded back, phi in [0, 2 pi)."""
    if t < 0.0:
        t, f = -t, f + np.pi
    elif t > np.pi:
        t, f = 2.0 * np.pi - t, f + np.pi
    if f < 0.0 or f >= _TWOPI:  # f % 2 pi is f itself there, and costs a division
        f = f % _TWOPI
    return t, f


@njit(parallel=True)
def offset_points(theta, phi, psi, rotations, pair_angles, rho, chi):
    """Where detector B of each pair looks, for every (hit, rotation, pair).

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.offset_points`.

    B looks at theta + rho cos(beta), phi + rho sin(beta) / sin(theta), with beta = psi +
    rotation + pair angle + chi: (cos, sin) of beta come from those of psi (per hit) and of the
    rest (per rotation and pair) by the angle-addition formulas, one sin/cos pair per hit.
    """
    nh, nk, nm = theta.size, rotations.size, pair_angles.size
    tb = np.empty((nh, nk, nm))
    pb = np.empty((nh, nk, nm))
    rho_cos = np.empty((nk, nm))
    rho_sin = np.empty((nk, nm))
    for k in range(nk):
        for m in range(nm):
            rho_cos[k, m] = rho[m] * np.cos(rotations[k] + pair_angles[m] + chi[m])
            rho_sin[k, m] = rho[m] * np.sin(rotations[k] + pair_angles[m] + chi[m])
    for h in numba.prange(nh):
        cos_psi, sin_psi = np.cos(psi[h]), np.sin(psi[h])
        inv_sin_t = 1.0 / np.sin(theta[h])
        for k in range(nk):
            for m in range(nm):
                d_theta = cos_psi * rho_cos[k, m] - sin_psi * rho_sin[k, m]
                d_phi = (sin_psi * rho_cos[k, m] + cos_psi * rho_sin[k, m]) * inv_sin_t
                tb[h, k, m], pb[h, k, m] = _fold(theta[h] + d_theta, phi[h] + d_phi)
    return tb, pb


@numba.njit(inline="always")
def _detectors(c_a, s_a, c_b, s_b, g_b, field_a, field_b, leak, beam_a, beam_b):
    """(d_A, d_B) of one pair: detector A responds to (cos, sin) 2 x its angle (c_a, s_a),
    detector B to (c_b, s_b) of its angle less 90 deg with gain g_b, B sees field_b (pointing), the
    additive leak, and each detector's extra signal from its own beam; fields are (I, Q, U,
    template)."""
    i_a, q_a, u_a, t_a = field_a
    i_b, q_b, u_b, t_b = field_b
    d_a = i_a + q_a * c_a + u_a * s_a + beam_a + 0.5 * leak * t_a
    d_b = g_b * (i_b - q_b * c_b - u_b * s_b + beam_b) - 0.5 * leak * t_b
    return d_a, d_b


#: what a kernel bins (:func:`_hit_sums`): pair differences into the 2x2 (Q, U) system, each
#: detector's own samples into the 3x3 (I, Q, U) system (both of a pair's detectors or A's alone),
#: or pair differences into a 3x3 system whose first unknown is a free spin-0 field (map-domain
#: deprojection)
PAIRS, BOTH, A_ONLY, SPIN0 = 0, 1, 2, 3


@numba.njit(inline="always")
def _fields(values, i):
    """(I, Q, U, template) of point i of a (F, N) array (template 0 when F = 3)."""
    return values[0, i], values[1, i], values[2, i], values[3, i] if values.shape[0] > 3 else 0.0


@numba.njit(inline="always")
def _flat(values_b):
    """(F, H, K, M) values per (hit, rotation, pair) as (F, H K M)."""
    return values_b.reshape(
        (values_b.shape[0], values_b.shape[1] * values_b.shape[2] * values_b.shape[3])
    )


@numba.njit(inline="always")
def _pair_sample(h, k, m, c0, s0, field_a, values_b, beams, response, leak, jitter, jitter_key, j):
    """One hit's (c, s, d_A, d_B) at rotation k and pair m: c, s are cos, sin 2 x the angle the
    map-maker assumes, d_A and d_B the detectors' samples (:func:`_hit_sums`)."""
    nk, nm = response.shape[0], response.shape[1]
    r = response[k, m]
    c = c0 * r[0] - s0 * r[1]
    s = s0 * r[0] + c0 * r[1]
    g_b = r[6]
    if jitter[m] != 0.0:
        g_b -= jitter[m] * normal_from_key(jitter_key, (j * nk + k) * nm + m)
    i = (h * nk + k) * nm + m
    field_b = field_a if values_b.shape[1] == 0 else _fields(values_b, i)
    beam_a = beam_b = 0.0
    if beams.shape[1] > 0:
        beam_a, beam_b = beams[0, i], beams[1, i]
    d_a, d_b = _detectors(
        c0 * r[2] - s0 * r[3],
        s0 * r[2] + c0 * r[3],
        c0 * r[4] - s0 * r[5],
        s0 * r[4] + c0 * r[5],
        g_b,
        field_a,
        field_b,
        leak[m],
        beam_a,
        beam_b,
    )
    return c, s, d_a, d_b


@numba.njit(inline="always")
def _hit_sums(h, psi, values_a, values_b, beams, response, leak, jitter, jitter_key, j, mode):
    """The normal-equation terms of hit h over every rotation and pair, as nine numbers.

    ``mode`` :data:`PAIRS`: the pair difference d's sum c^2, c s, s^2, c d, s d (and four zeros).
    :data:`BOTH` or :data:`A_ONLY`: each detector's own sample d with weights w = (1, c, s) (A)
    or (1, -c, -s) (B, at 90 deg): sum w_0 w_0, w_0 w_1, w_0 w_2, w_1 w_1, w_1 w_2, w_2 w_2,
    w_0 d, w_1 d, w_2 d. :data:`SPIN0`: the same nine with d the pair difference and w =
    (1, c, s). c, s are cos, sin 2 x the angle the map-maker assumes.

    values_b (F, H K M) holds detector B's fields per (hit, rotation, pair), flattened, or has no
    columns when B looks where A does; beams (2, H K M) likewise A's and B's extra signal from
    their beams, or has no columns. ``response`` is :func:`boresight.instrument.pairs.response`; pairs
    with ``jitter`` > 0 draw a normal deviate for each (hit j of the pixel, rotation, pair) from
    ``jitter_key``."""
    nk, nm = response.shape[0], response.shape[1]
    field_a = _fields(values_a, h)
    c0 = np.cos(2.0 * psi[h])
    s0 = np.sin(2.0 * psi[h])
    t0 = t1 = t2 = t3 = t4 = t5 = t6 = t7 = t8 = 0.0
    for k in range(nk):
        for m in range(nm):
            c, s, d_a, d_b = _pair_sample(
                h, k, m, c0, s0, field_a, values_b, beams, response, leak, jitter, jitter_key, j
            )
            if mode == PAIRS:
                d = 0.5 * (d_a - d_b)
                t0 += c * c
                t1 += c * s
                t2 += s * s
                t3 += c * d
                t4 += s * d
                continue
            # detector A, and with BOTH detector B at (1, -c, -s): the I-Q and I-U terms cancel
            n, sum_c, sum_s, d, cd, sd = 1.0, c, s, d_a, c * d_a, s * d_a
            if mode == SPIN0:
                d = 0.5 * (d_a - d_b)
                cd, sd = c * d, s * d
            elif mode == BOTH:
                n, sum_c, sum_s, d, cd, sd = 2.0, 0.0, 0.0, d + d_b, cd - c * d_b, sd - s * d_b
            t0 += n
            t1 += sum_c
            t2 += sum_s
            t3 += n * c * c
            t4 += n * c * s
            t5 += n * s * s
            t6 += d
            t7 += cd
            t8 += sd
    return t0, t1, t2, t3, t4, t5, t6, t7, t8


@njit(parallel=True)
def accumulate(offsets, psi, values_a, values_b, beams, response, leak, jitter, seed, pixels):
    """Pair differences binned into each pixel's 2x2 least-squares system for (Q, U).

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.accumulate`.

    Parallel over pixels.
    """
    values_b, beams = _flat(values_b), _flat(beams)
    out = np.zeros((offsets.size - 1, 5))
    for p in numba.prange(offsets.size - 1):
        jitter_key = derived_key(pixel_key(seed, pixels[p]), JITTER_SALT)
        a11 = a12 = a22 = b1 = b2 = 0.0
        for h in range(offsets[p], offsets[p + 1]):
            t = _hit_sums(
                h,
                psi,
                values_a,
                values_b,
                beams,
                response,
                leak,
                jitter,
                jitter_key,
                h - offsets[p],
                PAIRS,
            )
            a11 += t[0]
            a12 += t[1]
            a22 += t[2]
            b1 += t[3]
            b2 += t[4]
        out[p, 0] = a11
        out[p, 1] = a12
        out[p, 2] = a22
        out[p, 3] = b1
        out[p, 4] = b2
    return out


@njit
def _scatter(
    pixels, psi, values_a, values_b, beams, response, leak, jitter, seed, first, mode, out
):
    """Hits in any order added into a full-sky accumulator (npix, 5 or 9) in hit order, as
    ``mode`` bins them (:func:`_hit_sums`). Serial, so no two hits race for a pixel. The jitter of
    sample h is keyed by (seed, its index in the stream, first + h), as a synthetic hit's by
    (seed, pixel, hit)."""
    values_b, beams = _flat(values_b), _flat(beams)
    draws = np.any(jitter != 0.0)
    for h in range(pixels.size):
        key = derived_key(pixel_key(seed, first + h), JITTER_SALT) if draws else np.uint64(0)
        t = _hit_sums(h, psi, values_a, values_b, beams, response, leak, jitter, key, 0, mode)
        p = pixels[h]
        for j in range(out.shape[1]):
            out[p, j] += t[j]


def accumulate_scatter(
    pixels, psi, values_a, values_b, beams, response, leak, jitter, seed, first, out
):
    """:meth:`accumulate` for hits in any order, added into a full-sky accumulator in hit order.

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.accumulate_scatter`.
    """
    _scatter(
        pixels, psi, values_a, values_b, beams, response, leak, jitter, seed, first, PAIRS, out
    )


def accumulate_detectors(
    pixels, psi, values_a, values_b, beams, response, leak, jitter, seed, first, out, *, mapmaker
):
    """Each detector's own samples (or the pair differences beside a free spin-0 field), hits in
    any order, added into a full-sky accumulator of the per-pixel 3x3 system: CPU only (not part
    of the backend contract).

    Parameters
    ----------
    pixels, psi, values_a, values_b, beams, response, leak, jitter, seed, first
        As in :meth:`boresight.backend.KernelBackend.accumulate_scatter`.
    out : float64 array, shape (npix, 9)
        Running sums (:func:`_hit_sums`, :func:`boresight.mapmaking.solve_iqu`), updated in place.
    mapmaker : {"detectors", "single", "pairs-spin0"}
        Both detectors of each pair, detector A alone (a single-detector instrument), or the
        pair differences with a free spin-0 field (:data:`boresight.mapmaking.MAPMAKERS`).
    """
    mode = {"detectors": BOTH, "single": A_ONLY, "pairs-spin0": SPIN0}[mapmaker]
    _scatter(pixels, psi, values_a, values_b, beams, response, leak, jitter, seed, first, mode, out)


@njit
def _kept_samples(psi, values_a, values_b, beams, response, leak, jitter, seed, first, both):
    """(c, s, d) of :func:`pair_differences` (``both`` False: d (M, H), the pair differences) or
    :func:`pair_samples` (``both`` True: d (2M, H), detector A's samples of every pair, then
    B's)."""
    values_b, beams = _flat(values_b), _flat(beams)
    nm, n = response.shape[1], psi.size
    c, s = np.empty((nm, n)), np.empty((nm, n))
    d = np.empty((2 * nm if both else nm, n))
    draws = np.any(jitter != 0.0)
    for h in range(n):
        key = derived_key(pixel_key(seed, first + h), JITTER_SALT) if draws else np.uint64(0)
        field_a = _fields(values_a, h)
        c0, s0 = np.cos(2.0 * psi[h]), np.sin(2.0 * psi[h])
        for m in range(nm):
            c[m, h], s[m, h], d_a, d_b = _pair_sample(
                h, 0, m, c0, s0, field_a, values_b, beams, response, leak, jitter, key, 0
            )
            if both:
                d[m, h], d[nm + m, h] = d_a, d_b
            else:
                d[m, h] = 0.5 * (d_a - d_b)
    return c, s, d


def pair_differences(psi, values_a, values_b, beams, response, leak, jitter, seed, first):
    """Each sample's pair difference and map-maker weights, per pair, for a filter to act on
    before binning (:func:`bin_differences`): the terms :func:`accumulate_scatter` sums, kept.

    Parameters
    ----------
    psi, values_a, values_b, beams, response, leak, jitter, seed, first
        As in :meth:`boresight.backend.KernelBackend.accumulate_scatter`, with one rotation
        (a sample stream's).

    Returns
    -------
    c, s, d : float64 arrays, shape (M, H)
        cos, sin 2 x the angle the map-maker assumes and the pair difference 0.5 (d_A - d_B) of
        each pair m at each sample h.
    """
    args = (psi, values_a, values_b, beams, response, leak, jitter, seed, first)
    return _kept_samples(*args, False)


def pair_samples(psi, values_a, values_b, beams, response, leak, jitter, seed, first):
    """:func:`pair_differences` with both detectors' samples in place of their difference, for
    the detectors' map-maker (:func:`bin_detectors`): the terms :func:`accumulate_detectors`
    sums, kept.

    Returns
    -------
    c, s : float64 arrays, shape (M, H)
        cos, sin 2 x the angle the map-maker assumes for detector A (B's is 90 deg from it).
    d : float64 array, shape (2M, H)
        Detector A's samples of every pair m at each sample h, then detector B's.
    """
    args = (psi, values_a, values_b, beams, response, leak, jitter, seed, first)
    return _kept_samples(*args, True)


@numba.njit(inline="always")
def _add_row(out, p, terms):
    """out[p, k] += terms[k] for every k: one hit's sums added to its pixel's row."""
    for k in range(len(terms)):
        out[p, k] += terms[k]


@njit
def bin_differences(pixels, c, s, d, out):
    """Pair differences (filtered or not) added into a full-sky (npix, 5) accumulator in sample
    order, summed over the pairs first as :func:`accumulate_scatter` does, so that unfiltered
    differences give its sums exactly.

    Parameters
    ----------
    pixels : int64 array, shape (H,)
    c, s, d : float64 arrays, shape (M, H)
        As :func:`pair_differences` gives them.
    out : float64 array, shape (npix, 5)
        Running sums c^2, c s, s^2, c d, s d, updated in place.
    """
    for h in range(pixels.size):
        t0 = t1 = t2 = t3 = t4 = 0.0
        for m in range(c.shape[0]):
            t0 += c[m, h] * c[m, h]
            t1 += c[m, h] * s[m, h]
            t2 += s[m, h] * s[m, h]
            t3 += c[m, h] * d[m, h]
            t4 += s[m, h] * d[m, h]
        _add_row(out, pixels[h], (t0, t1, t2, t3, t4))


@njit
def bin_detectors(pixels, c, s, d_a, d_b, out):
    """Both detectors' samples (filtered or not) added into a full-sky (npix, 9) accumulator of
    the per-pixel 3x3 system for (I, Q, U) in sample order, summed over the pairs first as
    :func:`accumulate_detectors` (``mapmaker="detectors"``) does: A with weights (1, c, s), B
    with (1, -c, -s), so that the I-Q and I-U terms cancel.

    Parameters
    ----------
    pixels : int64 array, shape (H,)
    c, s, d_a, d_b : float64 arrays, shape (M, H)
        As :func:`pair_samples` gives them, its d split in two.
    out : float64 array, shape (npix, 9)
        Running sums (:func:`boresight.mapmaking.solve_iqu`), updated in place.
    """
    for h in range(pixels.size):
        t0 = t3 = t4 = t5 = t6 = t7 = t8 = 0.0
        for m in range(c.shape[0]):
            cm, sm = c[m, h], s[m, h]
            t0 += 2.0
            t3 += 2.0 * cm * cm
            t4 += 2.0 * cm * sm
            t5 += 2.0 * sm * sm
            t6 += d_a[m, h] + d_b[m, h]
            t7 += cm * d_a[m, h] - cm * d_b[m, h]
            t8 += sm * d_a[m, h] - sm * d_b[m, h]
        _add_row(out, pixels[h], (t0, 0.0, 0.0, t3, t4, t5, t6, t7, t8))


def bin_scan(
    seed: int,
    nside: int,
    pixels: np.ndarray,
    n_phi: np.ndarray,
    range_rad: np.ndarray,
    centre_rad: np.ndarray,
    centred: bool,
    stack: np.ndarray,
    rotations: np.ndarray,
    pair_angles: np.ndarray,
    response: np.ndarray,
    rho: np.ndarray,
    chi: np.ndarray,
    leak: np.ndarray,
    jitter: np.ndarray,
    pointing: bool,
    zero_qu: bool,
) -> np.ndarray | tuple:
    """Normal-equation sums of a synthetic scan with an interpolated sky.

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.bin_scan`.

    The CPU is compute bound: a fused numba loop measured 5 % slower than these
    cache-sized stages, so bin_scan runs generate_hits -> interpolate (-> offset_points) ->
    accumulate. With ``zero_qu`` only accumulate runs again, over the fields with Q = U = 0:
    the numbers of a separate scan of the unpolarised sky, to the bit.
    """
    offsets = hit_offsets(n_phi)
    theta, phi, psi = generate_hits(seed, nside, pixels, offsets, range_rad, centre_rad, centred)

    def at(t, p):
        return interpolate(stack, nside, t, p)

    values_a, values_b = pair_fields(
        at,
        offset_points,
        stack.shape[1],
        theta,
        phi,
        psi,
        rotations,
        pair_angles,
        rho,
        chi,
        pointing,
    )
    no_beams = np.empty((2, 0, rotations.size, pair_angles.size))

    def sums(a, b):
        return accumulate(offsets, psi, a, b, no_beams, response, leak, jitter, seed, pixels)

    return sums_with_zero_qu(sums, values_a, values_b, zero_qu)


@njit(parallel=True)
def moments(offsets, psi, rotations, n_max):
    """Spin moments of each pixel's hits, every rotation included.

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.moments`.
    """
    out = np.zeros((offsets.size - 1, n_max + 1), dtype=np.complex128)
    for p in numba.prange(offsets.size - 1):
        count = (offsets[p + 1] - offsets[p]) * rotations.size
        for h in range(offsets[p], offsets[p + 1]):
            for k in range(rotations.size):
                ang = psi[h] + rotations[k]
                for n in range(n_max + 1):
                    out[p, n] += complex(np.cos(n * ang), np.sin(n * ang))
        if count > 0:
            for n in range(n_max + 1):
                out[p, n] /= count
    return out


def to_host(array: np.ndarray) -> np.ndarray:
    """An array as numpy.

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.to_host`.

    The CPU kernels already return numpy arrays.
    """
    return array


def to_device(array: np.ndarray) -> np.ndarray:
    """An array on the backend's device (the sky fields, uploaded once).

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.to_device`.

    On the CPU the array stays where it is.
    """
    return array


def zeros(shape: tuple) -> np.ndarray:
    """A zeroed float64 accumulator on the device.

    Parameters, shapes and units: :meth:`boresight.backend.KernelBackend.zeros`.

    Host memory.
    """
    return np.zeros(shape)
