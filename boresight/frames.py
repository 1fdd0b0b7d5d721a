"""Sky frames of real-scan pointing: ICRS (the field's equatorial frame) and Galactic.

The pointing kernels (:mod:`boresight.pointing`, :mod:`boresight.moments`) turn azimuth and
elevation into a direction in the Celestial Intermediate Reference System (CIRS) of the sample's
date, with the Earth Rotation Angle. The frame of every output is ICRS, the frame TOAST's
J2000, SO's maps and Planck's equatorial maps are in, or Galactic where a user asks. Between
the two lie, per sample:

* diurnal aberration, from the site's velocity about the Earth's axis (at most 0.3 arcsec);
* the bias-precession-nutation rotation CIRS -> GCRS (IAU 2006/2000A, ``erfa.c2i06a``), about
  0.15 deg of RA in 2026, and for Galactic the constant ICRS -> Galactic rotation (astropy's);
* annual aberration, from the Earth's barycentric velocity (``erfa.epv00``, at most 20.5 arcsec).

The rotation and the Earth's velocity change slowly: :func:`frame_terms` evaluates them once per
chunk of at most :data:`CHUNK_SECONDS`, at the chunk's middle, and the kernels apply them to every
sample with :func:`to_frame`. Aberration is first order in v / c (a 2e-8 rad = 4 mas remainder).
Light deflection by the Sun (4 mas at 90 deg from it) and polar motion (< 0.5 arcsec) are left
out. The result is astropy's AltAz -> ICRS to 0.5 arcsec (``tests/test_pointing.py``).

The crossing angle moves with the frame: the focal plane's "up" direction at the sample is
rotated with the direction and measured against the new frame's (e_theta, e_phi) there.
"""

from __future__ import annotations

import warnings
from functools import lru_cache

import erfa
import numba
import numpy as np

#: the frames a schedule's pointing can be given in: ICRS, Galactic, or the apparent equatorial
#: frame of date (CIRS, topocentric: no aberration, no precession-nutation; what telescopes point in)
FRAMES = ("icrs", "galactic", "cirs")
#: longest stretch of samples that shares one rotation and Earth velocity [s]: precession,
#: nutation and the turn of the Earth's velocity then move a direction by < 0.005 arcsec
CHUNK_SECONDS = 1800.0
UNIX_EPOCH_JD = 2440587.5
#: the Earth's rotation rate [rad/s] and equatorial radius [m] (diurnal aberration)
EARTH_OMEGA = 7.292115e-5
EARTH_RADIUS_M = 6378137.0
SPEED_OF_LIGHT_M_S = 299792458.0
#: terms of a chunk: the rotation CIRS -> frame (row-major 3 x 3), the Earth's barycentric
#: velocity / c in the frame (3), the site's equatorial speed / c (1)
N_TERMS = 13


def check_frame(frame: str) -> str:
    """A frame name, checked.

    Parameters
    ----------
    frame : str

    Returns
    -------
    str

    Raises
    ------
    ValueError
        Not one of :data:`FRAMES`.
    """
    if frame not in FRAMES:
        raise ValueError(f"frame = {frame!r}; allowed: {FRAMES}")
    return frame


@lru_cache(maxsize=1)
def icrs_to_galactic() -> np.ndarray:
    """The rotation from ICRS to Galactic coordinates (astropy's), (3, 3): v_gal = R v_icrs."""
    from astropy import units as u
    from astropy.coordinates import ICRS, Galactic

    axes = ICRS(ra=[0.0, 90.0, 0.0] * u.deg, dec=[0.0, 0.0, 90.0] * u.deg).transform_to(Galactic())
    image = axes.cartesian  # the images of the ICRS x, y and z axes
    return np.array([image.x.value, image.y.value, image.z.value])  # [component, axis]


def _tt(jd_utc):
    """TT Julian dates (two parts) of UTC Julian dates (leap seconds from erfa's table)."""
    with warnings.catch_warnings():  # erfa calls dates past its table's last update "dubious"
        warnings.simplefilter("ignore", erfa.ErfaWarning)
        tai1, tai2 = erfa.utctai(np.floor(jd_utc), jd_utc - np.floor(jd_utc))
        return erfa.taitt(tai1, tai2)


def frame_terms(t_unix: np.ndarray, lat_deg: float, frame: str = "icrs") -> np.ndarray:
    """The terms :func:`to_frame` needs at each of a set of times.

    Parameters
    ----------
    t_unix : numpy.ndarray, shape (n,)
        UTC [s since 1970], one per chunk of samples.
    lat_deg : float
        The site's latitude [deg] (its speed about the Earth's axis).
    frame : {"icrs", "galactic", "cirs"}

    Returns
    -------
    numpy.ndarray, float64, shape (n, N_TERMS)
        Per time: the rotation CIRS -> frame row by row, the Earth's barycentric velocity / c in
        the frame, and the site's speed / c.
    """
    check_frame(frame)
    t_unix = np.atleast_1d(np.asarray(t_unix, dtype=np.float64))
    out = np.zeros((t_unix.size, N_TERMS))
    if frame == "cirs":
        out[:, [0, 4, 8]] = 1.0
        return out
    tt1, tt2 = _tt(UNIX_EPOCH_JD + t_unix / 86400.0)
    rotation = np.swapaxes(erfa.c2i06a(tt1, tt2), -1, -2)  # GCRS <- CIRS (c2i's transpose)
    _, barycentric = erfa.epv00(tt1, tt2)  # TDB ~ TT: 1.7 ms apart
    beta = barycentric["v"] / erfa.DC  # [AU/day] / [AU/day]
    if frame == "galactic":
        galactic = icrs_to_galactic()
        rotation = galactic @ rotation
        beta = beta @ galactic.T
    site = EARTH_OMEGA * EARTH_RADIUS_M * np.cos(np.radians(lat_deg)) / SPEED_OF_LIGHT_M_S
    out[:, :9] = rotation.reshape(-1, 9)
    out[:, 9:12] = beta
    out[:, 12] = site
    return out


@numba.njit(inline="always")
def to_frame(dx, dy, dz, ux, uy, uz, cos_era, sin_era, terms):
    """One sample from CIRS to the frame of ``terms`` (:func:`frame_terms`).

    Parameters
    ----------
    dx, dy, dz : float
        The apparent direction in CIRS (a unit vector).
    ux, uy, uz : float
        A tangent vector at it (the focal plane's "up"), any length > 0.
    cos_era, sin_era : float
        Of the local Earth rotation angle (the site's east is (-sin, cos, 0) in CIRS).
    terms : numpy.ndarray, shape (N_TERMS,)

    Returns
    -------
    z, r, phi : float
        cos(theta), sin(theta) and longitude in [0, 2 pi) of the direction in the frame.
    c, s : float
        cos and sin of the tangent vector's angle from e_theta towards e_phi there.
    """
    m = terms
    k = terms[12]
    # the aberration's velocity in the frame: the Earth's, plus the site's east times its speed
    bx = m[9] + k * (-m[0] * sin_era + m[1] * cos_era)
    by = m[10] + k * (-m[3] * sin_era + m[4] * cos_era)
    bz = m[11] + k * (-m[6] * sin_era + m[7] * cos_era)
    x = m[0] * dx + m[1] * dy + m[2] * dz
    y = m[3] * dx + m[4] * dy + m[5] * dz
    w = m[6] * dx + m[7] * dy + m[8] * dz
    vx = m[0] * ux + m[1] * uy + m[2] * uz
    vy = m[3] * ux + m[4] * uy + m[5] * uz
    vz = m[6] * ux + m[7] * uy + m[8] * uz
    # apparent -> natural direction: p = p' - beta + (p' . beta) p' (first order in v / c)
    dot = x * bx + y * by + w * bz
    x, y, w = x - bx + dot * x, y - by + dot * y, w - bz + dot * w
    norm = np.sqrt(x * x + y * y + w * w)
    x, y, w = x / norm, y / norm, w / norm
    r = np.sqrt(x * x + y * y)
    if r > 0:
        cp, sp = x / r, y / r
    else:
        cp, sp = 1.0, 0.0
    c = (w * cp) * vx + (w * sp) * vy - r * vz  # . e_theta = (cos t cos p, cos t sin p, -sin t)
    s = -sp * vx + cp * vy  # . e_phi = (-sin p, cos p, 0)
    length = np.sqrt(c * c + s * s)
    if length > 0:
        c, s = c / length, s / length
    else:
        c, s = 1.0, 0.0
    return w, r, np.arctan2(y, x) % (2 * np.pi), c, s
