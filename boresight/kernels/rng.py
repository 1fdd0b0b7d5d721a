"""Counter-based random numbers keyed by (seed, pixel, hit, stream).

Every random draw of a hit is a pure function of its key, so a simulation gives the same numbers
whatever the chunking, thread count, backend or number of workers. The generator is a chain of
SplitMix64 finalisers (Steele, Lea & Flood 2014), each a bijection on 64-bit integers:

    h = mix(mix(mix(seed ^ SEED_SALT) ^ pixel) ^ (hit * N_STREAMS + stream))

and a uniform double in [0, 1) is the top 53 bits of h. The GPU backend uses the same arithmetic.
Draws that are not per hit (per-sample gain jitter, per-pair systematic parameters) take a key
derived from the pixel's, ``mix(key ^ salt)``, and count their own draws; a normal deviate is the
Box-Muller transform of two uniforms of one count.
"""

import numba
import numpy as np

from .._util.jit import njit

N_STREAMS = 4  #: independent draws per hit: crossing angle, in-pixel u, in-pixel v, spare
STREAM_PSI, STREAM_U, STREAM_V = 0, 1, 2
SEED_SALT = np.uint64(0x9E3779B97F4A7C15)
JITTER_SALT = np.uint64(0xD1B54A32D192ED03)  #: per-sample gain jitter
PAIR_SALT = np.uint64(0xAEF17502108EF2D9)  #: per-pair systematic parameters
REPEAT_SALT = np.uint64(0x8CB92BA72F3D8DD7)  #: per-repeat gain drift
HWP_SALT = np.uint64(0xF1357AEA2E62A9C5)  #: per-sample jitter of a HWP's angle
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_TWO_M53 = 2.0**-53


@numba.njit(inline="always")
def mix64(z):
    """SplitMix64 finaliser: a bijective 64-bit mixing function.

    Parameters
    ----------
    z : numpy.uint64

    Returns
    -------
    numpy.uint64
    """
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@numba.njit(inline="always")
def pixel_key(seed, pixel):
    """The per-pixel part of the key chain: mix(mix(seed ^ SEED_SALT) ^ pixel).

    Parameters
    ----------
    seed, pixel : int
        >= 0.

    Returns
    -------
    numpy.uint64
    """
    return mix64(mix64(np.uint64(seed) ^ SEED_SALT) ^ np.uint64(pixel))


@numba.njit(inline="always")
def uniform_from_key(key, hit, stream):
    """A uniform double from a pixel's key and (hit, stream).

    Parameters
    ----------
    key : numpy.uint64
        :func:`pixel_key`.
    hit, stream : int
        >= 0.

    Returns
    -------
    float
        In [0, 1).
    """
    h = mix64(key ^ (np.uint64(hit) * np.uint64(N_STREAMS) + np.uint64(stream)))
    return np.float64(h >> _S11) * _TWO_M53


@numba.njit(inline="always")
def uniform(seed, pixel, hit, stream):
    """A uniform double for the key (seed, pixel, hit, stream).

    Parameters
    ----------
    seed, pixel, hit, stream : int
        >= 0.

    Returns
    -------
    float
        In [0, 1).
    """
    return uniform_from_key(pixel_key(seed, pixel), hit, stream)


@njit(parallel=True)
def uniform_array(seed, pixels, hits, stream):
    """Vectorised :func:`uniform`.

    Parameters
    ----------
    seed : int
    pixels, hits : numpy.ndarray of int, shape (n,)
    stream : int

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    out = np.empty(pixels.size)
    for k in numba.prange(pixels.size):
        out[k] = uniform(seed, pixels[k], hits[k], stream)
    return out


@numba.njit(inline="always")
def derived_key(key, salt):
    """A key for another family of draws of the same pixel: mix(key ^ salt).

    Parameters
    ----------
    key, salt : numpy.uint64

    Returns
    -------
    numpy.uint64
    """
    return mix64(key ^ salt)


@numba.njit(inline="always")
def normal_from_key(key, count):
    """A standard normal deviate: Box-Muller of the uniforms (count, 0) and (count, 1) of a key.

    Parameters
    ----------
    key : numpy.uint64
    count : int
        >= 0.

    Returns
    -------
    float
    """
    u1 = 1.0 - uniform_from_key(key, count, 0)  # in (0, 1]: the log is finite
    u2 = uniform_from_key(key, count, 1)
    return np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)


@njit
def normal_array(seed, pixel, salt, n, first=0):
    """n standard normal deviates of the key (seed, pixel) and a salt, counts first .. first +
    n - 1 (a stream's draws, whatever its chunks).

    Parameters
    ----------
    seed, pixel : int
        >= 0.
    salt : numpy.uint64
    n : int
    first : int
        The first count.

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    key = derived_key(pixel_key(seed, pixel), salt)
    out = np.empty(n)
    for i in range(n):
        out[i] = normal_from_key(key, first + i)
    return out
