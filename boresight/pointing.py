"""Pointing of real scans: the sky direction and crossing angle of every sample of a schedule.

The Earth turns between and during CESs. Each sample's direction is rotated from the horizon to
the apparent equatorial frame of date (CIRS, from the Earth Rotation Angle with UT1 = UTC + dut1),
then to the schedule's frame, ICRS by default (:mod:`boresight.frames`: aberration and
precession-nutation, 0.15 deg in 2026). Refraction and polar motion are left out (below 0.5
arcsec). A schedule may leave out the samples of its turnarounds, as TOAST's map-making does by
default; it keeps them by default.

The crossing angle psi of a sample is the orientation on the sky of the focal plane's "up" axis
(towards the zenith at zero boresight rotation), measured from e_theta towards e_phi of the
schedule's frame like the synthetic scans' psi, plus the boresight angle: in CIRS,
psi = pi - q + boresight, with q the parallactic angle (position angle of the zenith, east of
north). The fused numba kernels compute it per sample without a stored TOD.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numba
import numpy as np

from . import frames
from ._util.jit import njit
from .constants import DEG
from .frames import to_frame
from .instrument.hwp import chunk_angles

if TYPE_CHECKING:
    from collections.abc import Iterator

    from .instrument.focalplane import FocalPlane
    from .instrument.hwp import HWP
    from .schedule import Schedule

UNIX_EPOCH_JD = frames.UNIX_EPOCH_JD


@numba.njit(inline="always")
def earth_rotation_angle(jd_ut1):
    """Earth Rotation Angle (IERS 2003), not reduced to [0, 2 pi).

    Parameters
    ----------
    jd_ut1 : float
        UT1 Julian date.

    Returns
    -------
    float
        [rad].
    """
    return (
        2 * np.pi * ((jd_ut1 % 1.0) + 0.7790572732640 + 0.00273781191135448 * (jd_ut1 - 2451545.0))
    )


@numba.njit(inline="always")
def horizon_terms(az, se, ce, sl, cl):
    """The rotation from horizon to equatorial coordinates of one direction.

    Parameters
    ----------
    az : float
        Azimuth east of north [rad].
    se, ce : float
        sin and cos of the elevation.
    sl, cl : float
        sin and cos of the latitude.

    Returns
    -------
    sd, y, x : float
        sin(dec), cos(dec) sin(H) and cos(dec) cos(H), H the hour angle.
    """
    sa, ca = np.sin(az), np.cos(az)
    sd = min(1.0, max(-1.0, sl * se + cl * ce * ca))
    return sd, -sa * ce, cl * se - sl * ce * ca


@numba.njit(inline="always")
def _scan_offset(t, throw, speed, turnaround):
    """Azimuth offset from the CES centre [rad] at time t [s] (throw [rad], speed [rad/s]), and
    whether the mount is turning around (outside the throw, as TOAST's turnaround intervals)."""
    leg = throw / speed
    u = t % (2 * (leg + turnaround))
    if u < leg:
        return -0.5 * throw + speed * u, False
    u -= leg
    if u < turnaround:
        return 0.5 * throw + speed * u - speed * u * u / turnaround, True
    u -= turnaround
    if u < leg:
        return 0.5 * throw - speed * u, False
    u -= leg
    return -0.5 * throw - speed * u + speed * u * u / turnaround, True


@njit
def _scan_offsets(t, throw, speed, turnaround):
    out = np.empty(t.size)
    turning = np.empty(t.size, dtype=np.bool_)
    for i in range(t.size):
        out[i], turning[i] = _scan_offset(t[i], throw, speed, turnaround)
    return out, turning


def ces_samples(ces, schedule, start=0, stop=None):
    """Times and horizon pointing of samples of a CES.

    Parameters
    ----------
    ces : CES
    schedule : Schedule
        Its sample rate.
    start, stop : int
        Sample range (default: the whole CES).

    Returns
    -------
    t : numpy.ndarray
        [unix s].
    az, el : numpy.ndarray
        [rad].
    turning : numpy.ndarray of bool
        Whether the mount is turning around (TOAST's turnaround intervals).
    """
    n = int(ces.duration_s * schedule.sample_rate_hz)
    stop = n if stop is None else min(stop, n)
    t = np.arange(start, stop) / schedule.sample_rate_hz
    offset, turning = _scan_offsets(
        t, max(ces.az_throw_deg, 1e-12) * DEG, ces.speed_deg_s * DEG, ces.turnaround_s
    )
    az = ces.az_centre_deg * DEG + offset
    return ces.start_unix + t, az, np.full(t.size, ces.elevation_deg * DEG), turning


@numba.njit(inline="always")
def sample_pointing(k, chunk, terms):
    """One sample of a CES in the frame of ``terms``.

    Parameters
    ----------
    k : int
        The sample's index in its CES.
    chunk : numpy.ndarray, shape (N_CHUNK,)
        The CES's scalars (:func:`chunk_arguments`).
    terms : numpy.ndarray, shape (frames.N_TERMS,)
        The frame's rotation and velocities (:func:`boresight.frames.frame_terms`).

    Returns
    -------
    z, r, phi : float
        cos(theta), sin(theta) and longitude [rad] of the direction.
    c, s : float
        cos and sin of the crossing angle at boresight angle 0: the direction of the zenith,
        measured from e_theta towards e_phi.
    turning : bool
        Whether the mount is turning around.
    """
    t = k / chunk[1]
    offset, turning = _scan_offset(t, max(chunk[3], 1e-300), chunk[4], chunk[5])
    era = earth_rotation_angle((chunk[0] + t) / 86400.0 + chunk[7]) + chunk[8]
    sl, cl = np.sin(chunk[9]), np.cos(chunk[9])
    sd, y, x = horizon_terms(chunk[2] + offset, np.sin(chunk[6]), np.cos(chunk[6]), sl, cl)
    c_era, s_era = np.cos(era), np.sin(era)
    dx, dy = c_era * x + s_era * y, s_era * x - c_era * y  # CIRS: RA = local ERA - H
    zx, zy, zz = cl * c_era, cl * s_era, sl  # the site's zenith
    dot = zx * dx + zy * dy + zz * sd
    z, r, phi, c, s = to_frame(
        dx, dy, sd, zx - dot * dx, zy - dot * dy, zz - dot * sd, c_era, s_era, terms
    )
    return z, r, phi, c, s, turning


@njit(parallel=True)
def _ces_pointing(k0, n, chunk, terms):
    """theta, phi, psi [rad] and the turnaround flag of samples k0..k0+n-1 of a CES
    (:func:`sample_pointing`), psi with the CES's boresight angle."""
    theta = np.empty(n)
    phi = np.empty(n)
    psi = np.empty(n)
    turning = np.empty(n, dtype=np.bool_)
    boresight = chunk[10]
    for i in numba.prange(n):
        z, r, phi[i], c, s, turning[i] = sample_pointing(k0 + i, chunk, terms)
        theta[i] = np.arctan2(r, z)
        psi[i] = np.arctan2(s, c) + boresight
    return theta, phi, psi, turning


@numba.njit(inline="always")
def offset_sample(z, r, cp, sp, c, s, v):
    """A detector's direction and crossing angle from its boresight's.

    The detector sits at ``v`` in the focal plane (:meth:`boresight.instrument.focalplane.FocalPlane.vectors`:
    its direction and orientation in TOAST's boresight frame, whose x axis points away from the
    zenith, towards -(c, s)). The crossing angle is that of the focal plane's "up" axis carried to
    the detector, in boresight's convention (TOAST's psi + pi).

    Parameters
    ----------
    z, r : float
        cos(theta) and sin(theta) of the boresight.
    cp, sp : float
        cos and sin of its longitude.
    c, s : float
        cos and sin of the boresight's crossing angle, the boresight angle included.
    v : numpy.ndarray, shape (6,)

    Returns
    -------
    z, r, phi, c, s : float
        The same of the detector.
    """
    # the focal plane's axes in the boresight's (e_theta, e_phi): x = -(c, s), y = (s, -c)
    a, b = -v[0] * c + v[1] * s, -v[0] * s - v[1] * c
    nx = v[2] * r * cp + a * z * cp - b * sp
    ny = v[2] * r * sp + a * z * sp + b * cp
    nz = v[2] * z - a * r
    a, b = -v[3] * c + v[4] * s, -v[3] * s - v[4] * c
    ox = v[5] * r * cp + a * z * cp - b * sp
    oy = v[5] * r * sp + a * z * sp + b * cp
    oz = v[5] * z - a * r
    rn = max(np.sqrt(nx * nx + ny * ny), 1e-300)
    # the orientation against the detector's (e_theta, e_phi), turned by pi: a unit vector, as o
    # is a rotated unit vector perpendicular to n
    inv = 1.0 / rn
    c_det = rn * oz - nz * (ox * nx + oy * ny) * inv
    s_det = (ox * ny - oy * nx) * inv
    phi = np.arctan2(ny, nx)
    if phi < 0:
        phi += 2 * np.pi
    return nz, rn, phi, c_det, s_det


@njit(parallel=True)
def _ces_detector_pointing(k0, n, chunk, terms, vectors):
    """theta, phi, psi [rad] of each detector at ``vectors`` (m, 6), (m, n), and the turnaround
    flag (n,), of samples k0..k0+n-1 of a CES."""
    m = vectors.shape[0]
    theta = np.empty((m, n))
    phi = np.empty((m, n))
    psi = np.empty((m, n))
    turning = np.empty(n, dtype=np.bool_)
    cb, sb = np.cos(chunk[10]), np.sin(chunk[10])
    for i in numba.prange(n):
        z, r, ph, c, s, turning[i] = sample_pointing(k0 + i, chunk, terms)
        c, s = c * cb - s * sb, c * sb + s * cb
        cp, sp = np.cos(ph), np.sin(ph)
        for d in range(m):
            zd, rd, phi[d, i], cd, sd = offset_sample(z, r, cp, sp, c, s, vectors[d])
            theta[d, i] = np.arctan2(rd, zd)
            psi[d, i] = np.arctan2(sd, cd)
    return theta, phi, psi, turning


#: the scalars of a CES chunk: start [unix s], rate [Hz], azimuth centre, throw [rad], speed
#: [rad/s], turnaround [s], elevation [rad], UT1 Julian date of the Unix epoch, longitude, latitude,
#: boresight angle [rad]
N_CHUNK = 11


def ces_angle_deg(schedule: Schedule, repeat: int, index: int) -> float:
    """The boresight angle [deg] of CES ``index`` in boresight repeat ``repeat``
    (:func:`ces_chunks`' numbering)."""
    return schedule.ces[index].boresight_deg + schedule.repeat_boresight_deg[repeat]


def ces_chunks(schedule, chunk_samples=1 << 20, *, ces=None):
    """Every chunk of a schedule with its kernel arguments, in observing order: the CES set in time order,
    once per boresight repeat.

    A chunk holds at most ``chunk_samples`` samples and lies in one block of
    :data:`boresight.frames.CHUNK_SECONDS` of its CES (counted from the CES's start), over which
    the frame's rotation is one, evaluated at the block's middle: so the pointing does not depend
    on ``chunk_samples``.

    Parameters
    ----------
    schedule : Schedule
    chunk_samples : int
    ces : range, optional
        Only the CESs whose place in observing order (repeat x CESs in the set + index) lies in
        it (default: every one).

    Yields
    ------
    repeat, index : int
        The repeat of the CES set and the CES's place in it.
    arguments : tuple
        (first sample, samples: int; the CES's scalars, (:data:`N_CHUNK`,) float64; the frame's
        terms at the chunk's middle, (frames.N_TERMS,) float64).
    """
    lat, lon = schedule.site.lat_deg * DEG, schedule.site.lon_deg * DEG
    jd_offset = UNIX_EPOCH_JD + schedule.dut1_s / 86400.0
    rate = schedule.sample_rate_hz
    block = max(1, int(frames.CHUNK_SECONDS * rate))
    for r, repeat in enumerate(schedule.repeat_boresight_deg):
        for i, c in enumerate(schedule.ces):
            if ces is not None and r * len(schedule.ces) + i not in ces:
                continue
            n = int(c.duration_s * rate)
            chunk = np.array(
                [
                    c.start_unix,
                    rate,
                    c.az_centre_deg * DEG,
                    c.az_throw_deg * DEG,
                    c.speed_deg_s * DEG,
                    c.turnaround_s,
                    c.elevation_deg * DEG,
                    jd_offset,
                    lon,
                    lat,
                    (c.boresight_deg + repeat) * DEG,
                ],
                dtype=np.float64,
            )
            starts = np.arange(0, n, block)
            middles = c.start_unix + (starts + 0.5 * block) / rate
            terms = frames.frame_terms(middles, schedule.site.lat_deg, schedule.frame)
            for b, t in zip(starts, terms):
                end = min(b + block, n)
                for s in range(int(b), end, chunk_samples):
                    yield r, i, (s, min(chunk_samples, end - s), chunk, t)


def chunk_arguments(schedule, chunk_samples=1 << 20):
    """The kernel arguments of :func:`ces_chunks`, chunk by chunk."""
    for _, _, arguments in ces_chunks(schedule, chunk_samples):
        yield arguments


def pointing(
    schedule: Schedule, chunk_samples: int = 1 << 20, *, hwp: HWP | None = None
) -> Iterator[tuple]:
    """The pointing of a whole schedule, chunk by chunk, in the schedule's frame.

    Samples in the turnarounds are left out where the schedule says so.

    Parameters
    ----------
    schedule : Schedule
    chunk_samples : int
    hwp : boresight.instrument.hwp.HWP, optional
        Also yield its angle at each sample (a continuous or stepped HWP).

    Yields
    ------
    theta, phi, psi : numpy.ndarray, shape (<= chunk_samples,)
        Colatitude, longitude and crossing angle [rad] in ``schedule.frame``; the CES set in time
        order, once per boresight repeat.
    chi : numpy.ndarray, shape (<= chunk_samples,)
        With ``hwp``: the HWP's angle in the focal plane [rad] (:func:`boresight.instrument.hwp.chunk_angles`).
    """
    for repeat, index, args in ces_chunks(schedule, chunk_samples):
        out = _ces_pointing(*args)
        if hwp is not None:
            out = (
                *out[:3],
                chunk_angles(hwp, schedule, repeat, index, first=args[0], n=args[1]),
                out[3],
            )
        if schedule.turnarounds == "exclude":
            keep = ~out[-1]
            out = tuple(x[keep] for x in out)
        yield out[:-1]


def detector_pointing(
    schedule: Schedule,
    focalplane: FocalPlane,
    chunk_samples: int = 1 << 20,
    *,
    hwp: HWP | None = None,
) -> Iterator[tuple]:
    """The pointing of every pair of a focal plane over a whole schedule, chunk by chunk: the
    boresight's (:func:`pointing`) carried to each pair's place, the boresight angle turning the
    focal plane about the boresight as TOAST's ``PointingDetectorSimple`` does.

    Parameters
    ----------
    schedule : Schedule
    focalplane : boresight.instrument.focalplane.FocalPlane
    chunk_samples : int
        Detector-samples per chunk (at least one sample of every pair).
    hwp : boresight.instrument.hwp.HWP, optional
        Also yield its angle at each sample.

    Yields
    ------
    theta, phi, psi : numpy.ndarray, shape (n_pairs, <= chunk_samples / n_pairs)
        Each pair's colatitude, longitude and crossing angle [rad] in ``schedule.frame``.
    chi : numpy.ndarray, shape (<= chunk_samples / n_pairs,)
        With ``hwp``: the HWP's angle in the focal plane [rad].
    """
    vectors = focalplane.vectors()
    per_pair = max(1, chunk_samples // focalplane.n_pairs)
    for repeat, index, args in ces_chunks(schedule, per_pair):
        if not focalplane.centred:  # the boresight turns about another point: per CES
            vectors = focalplane.vectors(ces_angle_deg(schedule, repeat, index))
        theta, phi, psi, turning = _ces_detector_pointing(*args, vectors)
        out = (theta, phi, psi)
        if hwp is not None:
            out = (*out, chunk_angles(hwp, schedule, repeat, index, first=args[0], n=args[1]))
        if schedule.turnarounds == "exclude":
            keep = ~turning
            out = tuple(x[..., keep] for x in out)
        yield out
