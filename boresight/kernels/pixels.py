"""HEALPix RING-scheme geometry as numba kernels for the hot loop.

Ports of the few routines of Healpix C++ ``healpix_base.cc`` (Gorski et al. 2005) that the TOD
kernels need per hit: pixel -> face coordinates, face coordinates -> (theta, phi), and the 4-pixel
bilinear interpolation weights (``get_interpol``, what ``healpy.get_interp_weights`` returns).
The tests check every one against healpy.

In-pixel positions: the HEALPix projection from a base face's (x, y) square to the sphere is
equal-area (the Jacobian d(z, phi)/d(x, y) is constant on each face), so a point uniform in (x, y)
inside a pixel's sub-square is uniform in solid angle inside the pixel.
"""

import numba
import numpy as np

from .._util.jit import njit

_JRLL = np.array([2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4], dtype=np.int64)
_JPLL = np.array([1, 3, 5, 7, 0, 2, 4, 6, 1, 3, 5, 7], dtype=np.int64)
_HALFPI = 0.5 * np.pi
_TWOPI = 2.0 * np.pi


@numba.njit(inline="always")
def _isqrt(v):
    r = np.int64(np.sqrt(v + 0.5))
    if r * r > v:
        r -= 1
    elif (r + 1) * (r + 1) <= v:
        r += 1
    return r


@numba.njit(inline="always")
def ring2xyf(nside, pix):
    """Face coordinates of a RING pixel (Healpix C++ ring2xyf).

    Parameters
    ----------
    nside, pix : int

    Returns
    -------
    ix, iy, face : int
        0 <= ix, iy < nside; face in 0..11.
    """
    ncap = 2 * nside * (nside - 1)
    npix = 12 * nside * nside
    nl2 = 2 * nside
    if pix < ncap:
        iring = (1 + _isqrt(1 + 2 * pix)) >> 1
        iphi = (pix + 1) - 2 * iring * (iring - 1)
        kshift = 0
        nr = iring
        face = (iphi - 1) // nr
    elif pix < npix - ncap:
        ip = pix - ncap
        tmp = ip // (4 * nside)
        iring = tmp + nside
        iphi = ip - tmp * 4 * nside + 1
        kshift = (iring + nside) & 1
        nr = nside
        ire = tmp + 1
        irm = nl2 + 1 - tmp
        ifm = (iphi - (ire >> 1) + nside - 1) // nside
        ifp = (iphi - (irm >> 1) + nside - 1) // nside
        if ifp == ifm:
            face = ifp | 4
        elif ifp < ifm:
            face = ifp
        else:
            face = ifm + 8
    else:
        ip = npix - pix
        iring = (1 + _isqrt(2 * ip - 1)) >> 1
        iphi = 4 * iring + 1 - (ip - 2 * iring * (iring - 1))
        kshift = 0
        nr = iring
        iring = 2 * nl2 - iring
        face = 8 + (iphi - 1) // nr
    irt = iring - ((2 + (face >> 2)) * nside) + 1
    ipt = 2 * iphi - _JPLL[face] * nr - kshift - 1
    if ipt >= nl2:
        ipt -= 8 * nside
    return (ipt - irt) >> 1, (-ipt - irt) >> 1, face


@numba.njit(inline="always")
def xyf2ang(x, y, face):
    """Angles of continuous face coordinates.

    Parameters
    ----------
    x, y : float
        In [0, 1] across the base face.
    face : int

    Returns
    -------
    theta, phi : float
        [rad].
    """
    jr = _JRLL[face] - x - y
    if jr < 1.0:
        nr = jr
        tmp = nr * nr / 3.0
        theta = 2.0 * np.arcsin(min(1.0, np.sqrt(tmp / 2.0)))  # z = 1 - tmp, accurate near pole
    elif jr > 3.0:
        nr = 4.0 - jr
        tmp = nr * nr / 3.0
        theta = np.pi - 2.0 * np.arcsin(min(1.0, np.sqrt(tmp / 2.0)))
    else:
        nr = 1.0
        theta = np.arccos((2.0 - jr) * 2.0 / 3.0)
    tmp = _JPLL[face] * nr + x - y
    if tmp < 0:
        tmp += 8.0
    if tmp >= 8:
        tmp -= 8.0
    phi = 0.0 if nr < 1e-15 else (0.5 * _HALFPI * tmp) / nr
    return theta, phi


@numba.njit(inline="always")
def pixel_point(nside, pix, u, v):
    """A point at a fractional position inside a RING pixel.

    (0.5, 0.5) is the pixel centre; uniform (u, v) gives points uniform in solid angle.

    Parameters
    ----------
    nside, pix : int
    u, v : float
        In [0, 1).

    Returns
    -------
    theta, phi : float
        [rad].
    """
    ix, iy, face = ring2xyf(nside, pix)
    return face_point(nside, ix, iy, face, u, v)


@numba.njit(inline="always")
def face_point(nside, ix, iy, face, u, v):
    """:func:`pixel_point` of a pixel given as face coordinates.

    Parameters
    ----------
    nside, ix, iy, face : int
    u, v : float

    Returns
    -------
    theta, phi : float
        [rad].
    """
    return xyf2ang((ix + u) / nside, (iy + v) / nside, face)


@numba.njit(inline="always")
def _ring_layout(nside, ring):
    """Ring number (1..4 nside - 1) -> (first pixel, pixels in ring, shifted)."""
    npix = 12 * nside * nside
    northring = 4 * nside - ring if ring > 2 * nside else ring
    if northring < nside:
        ringpix = 4 * northring
        shifted = True
        startpix = 2 * northring * (northring - 1)
    else:
        ringpix = 4 * nside
        shifted = ((northring - nside) & 1) == 0
        startpix = 2 * nside * (nside - 1) + (northring - nside) * ringpix
    if northring != ring:
        startpix = npix - startpix - ringpix
    return startpix, ringpix, shifted


@njit
def ring_colatitudes(nside):
    """Colatitude of every ring, as Healpix C++ ``get_ring_info2``.

    Parameters
    ----------
    nside : int

    Returns
    -------
    numpy.ndarray, shape (4 nside,)
        [rad]; entry r is ring r (1..4 nside - 1), entry 0 is unused. The interpolation reads
        it instead of two inverse cosines per point.
    """
    npix = 12 * nside * nside
    out = np.zeros(4 * nside)
    for ring in range(1, 4 * nside):
        northring = 4 * nside - ring if ring > 2 * nside else ring
        if northring < nside:
            tmp = northring * northring * (4.0 / npix)
            theta = np.arctan2(np.sqrt(tmp * (2.0 - tmp)), 1.0 - tmp)
        else:
            theta = np.arccos((2 * nside - northring) * (8.0 * nside / npix))
        out[ring] = np.pi - theta if northring != ring else theta
    return out


@numba.njit(inline="always")
def _ring_neighbours(nside, ring, phi, colatitudes):
    startpix, ringpix, shifted = _ring_layout(nside, ring)
    dphi = _TWOPI / ringpix
    tmp = phi / dphi - 0.5 * shifted
    i1 = np.int64(tmp) - 1 if tmp < 0 else np.int64(tmp)
    w1 = (phi - (i1 + 0.5 * shifted) * dphi) / dphi
    i2 = i1 + 1
    if i1 < 0:
        i1 += ringpix
    if i2 >= ringpix:
        i2 -= ringpix
    return startpix + i1, startpix + i2, 1.0 - w1, w1, colatitudes[ring]


@numba.njit(inline="always")
def interp_weights(nside, theta, phi, colatitudes):
    """Bilinear interpolation pixels and weights, as healpy.get_interp_weights.

    Parameters
    ----------
    nside : int
    theta, phi : float
        theta in [0, pi], phi in [0, 2 pi) [rad].
    colatitudes : numpy.ndarray, shape (4 nside,)
        :func:`ring_colatitudes` of nside.

    Returns
    -------
    p0, p1, p2, p3 : int
        RING pixels.
    w0, w1, w2, w3 : float
        Weights summing to 1.
    """
    npix = 12 * nside * nside
    z = np.cos(theta)
    az = abs(z)
    if az <= 2.0 / 3.0:
        ir1 = np.int64(nside * (2.0 - 1.5 * z))
    else:
        ir = np.int64(nside * np.sqrt(3.0 * (1.0 - az)))
        ir1 = ir if z > 0 else 4 * nside - ir - 1
    ir2 = ir1 + 1
    p0 = p1 = p2 = p3 = 0
    w0 = w1 = w2 = w3 = 0.0
    theta1 = theta2 = 0.0
    if ir1 > 0:
        p0, p1, w0, w1, theta1 = _ring_neighbours(nside, ir1, phi, colatitudes)
    if ir2 < 4 * nside:
        p2, p3, w2, w3, theta2 = _ring_neighbours(nside, ir2, phi, colatitudes)
    if ir1 == 0:
        wtheta = theta / theta2
        w2 *= wtheta
        w3 *= wtheta
        fac = (1.0 - wtheta) * 0.25
        w0 = fac
        w1 = fac
        w2 += fac
        w3 += fac
        p0 = (p2 + 2) & 3
        p1 = (p3 + 2) & 3
    elif ir2 == 4 * nside:
        wtheta = (theta - theta1) / (np.pi - theta1)
        w0 *= 1.0 - wtheta
        w1 *= 1.0 - wtheta
        fac = wtheta * 0.25
        w0 += fac
        w1 += fac
        w2 = fac
        w3 = fac
        p2 = ((p0 + 2) & 3) + npix - 4
        p3 = ((p1 + 2) & 3) + npix - 4
    else:
        wtheta = (theta - theta1) / (theta2 - theta1)
        w0 *= 1.0 - wtheta
        w1 *= 1.0 - wtheta
        w2 *= wtheta
        w3 *= wtheta
    return p0, p1, p2, p3, w0, w1, w2, w3


@numba.njit(inline="always")
def ang2pix(nside, theta, phi):
    """RING pixel of a direction, as healpy.ang2pix (Healpix C++ loc2pix).

    Parameters
    ----------
    nside : int
    theta, phi : float
        [rad].

    Returns
    -------
    int
    """
    return zphi2pix(nside, np.cos(theta), np.sin(theta), phi)


@numba.njit(inline="always")
def zphi2pix(nside, z, sin_theta, phi):
    """RING pixel from z = cos(theta), sin(theta) (used near the poles) and phi.

    Parameters
    ----------
    nside : int
    z, sin_theta, phi : float

    Returns
    -------
    int
    """
    za = abs(z)
    tt = (phi / _HALFPI) % 4.0
    if za <= 2.0 / 3.0:
        nl4 = 4 * nside
        temp1 = nside * (0.5 + tt)
        temp2 = nside * z * 0.75
        jp = np.int64(temp1 - temp2)
        jm = np.int64(temp1 + temp2)
        ir = nside + 1 + jp - jm
        kshift = 1 - (ir & 1)
        ip = ((jp + jm - nside + kshift + 1 + 2 * nl4) >> 1) % nl4
        return 2 * nside * (nside - 1) + (ir - 1) * nl4 + ip
    tp = tt - np.int64(tt)
    if za < 0.99:
        tmp = nside * np.sqrt(3.0 * (1.0 - za))
    else:
        tmp = nside * sin_theta / np.sqrt((1.0 + za) / 3.0)
    jp = np.int64(tp * tmp)
    jm = np.int64((1.0 - tp) * tmp)
    ir = jp + jm + 1
    ip = np.int64(tt * ir)
    if z > 0:
        return 2 * ir * (ir - 1) + ip
    return 12 * nside * nside - 2 * ir * (ir + 1) + ip


@njit(parallel=True)
def ang2pix_array(nside, theta, phi):
    """Vectorised :func:`ang2pix`.

    Parameters
    ----------
    nside : int
    theta, phi : numpy.ndarray, shape (n,)
        [rad], checked by the callers at the boundary.

    Returns
    -------
    numpy.ndarray, int64, shape (n,)
    """
    out = np.empty(theta.size, dtype=np.int64)
    for k in numba.prange(theta.size):
        out[k] = ang2pix(nside, theta[k], phi[k])
    return out


@njit(parallel=True)
def pixel_points(nside, pixels, u, v):
    """Vectorised :func:`pixel_point`.

    Parameters
    ----------
    nside : int
    pixels : numpy.ndarray of int, shape (n,)
    u, v : numpy.ndarray, shape (n,)

    Returns
    -------
    theta, phi : numpy.ndarray, shape (n,)
        [rad].
    """
    theta = np.empty(pixels.size)
    phi = np.empty(pixels.size)
    for k in numba.prange(pixels.size):
        theta[k], phi[k] = pixel_point(nside, pixels[k], u[k], v[k])
    return theta, phi


@njit(parallel=True)
def interpolate_interleaved(maps, nside, theta, phi):
    """Bilinear interpolation of an interleaved stack at many points.

    Interleaving puts a pixel's fields in one cache line: one memory access per neighbour.

    Parameters
    ----------
    maps : numpy.ndarray, shape (npix, F)
    nside : int
    theta, phi : numpy.ndarray, shape (n,)
        [rad].

    Returns
    -------
    numpy.ndarray, shape (F, n)
    """
    out = np.empty((maps.shape[1], theta.size))
    colatitudes = ring_colatitudes(nside)
    for k in numba.prange(theta.size):
        interpolate_point(maps, nside, theta[k], phi[k], colatitudes, out, k)
    return out


@numba.njit(inline="always")
def interpolate_point(maps, nside, theta, phi, colatitudes, out, column):
    """Bilinear interpolation of an interleaved stack at one point, into a column of ``out``.

    No array views in the hot loop.

    Parameters
    ----------
    maps : numpy.ndarray, shape (npix, F)
    nside : int
    theta, phi : float
        [rad].
    colatitudes : numpy.ndarray, shape (4 nside,)
        :func:`ring_colatitudes` of nside.
    out : numpy.ndarray, shape (F, n)
        Written in place at out[:, column].
    column : int
    """
    p0, p1, p2, p3, w0, w1, w2, w3 = interp_weights(nside, theta, phi, colatitudes)
    for f in range(maps.shape[1]):
        out[f, column] = w0 * maps[p0, f] + w1 * maps[p1, f] + w2 * maps[p2, f] + w3 * maps[p3, f]
