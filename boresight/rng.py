"""Counter-based random numbers keyed by (seed, pixel, hit, stream).

Every random draw of a hit is a pure function of its key, so a simulation gives the same numbers
whatever the chunking, thread count, backend or number of workers. The generator is a chain of
SplitMix64 finalisers (Steele, Lea & Flood 2014), each a bijection on 64-bit integers:

    h = mix(mix(mix(seed ^ SEED_SALT) ^ pixel) ^ (hit * N_STREAMS + stream))

and a uniform double in [0, 1) is the top 53 bits of h. The GPU backend uses the same arithmetic.
"""

import numba
import numpy as np

N_STREAMS = 4  #: independent draws per hit: crossing angle, in-pixel u, in-pixel v, spare
STREAM_PSI, STREAM_U, STREAM_V = 0, 1, 2
SEED_SALT = np.uint64(0x9E3779B97F4A7C15)
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


@numba.njit(parallel=True, cache=True)
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
