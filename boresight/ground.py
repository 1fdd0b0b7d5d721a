"""Real ground scans: constant-elevation scans (CES) from a site, with a boresight schedule.

Each CES sweeps the azimuth between centre - throw / 2 and centre + throw / 2 at constant speed,
reversing at each end in ``turnaround_s`` at constant deceleration (overshooting by
speed * turnaround / 4), at fixed elevation and boresight angle. The Earth turns between and
during CESs. Each sample's direction is rotated from the horizon to the apparent equatorial frame
of date (CIRS, from the Earth Rotation Angle with UT1 = UTC + dut1), then to the schedule's frame,
ICRS by default (:mod:`boresight.frames`: aberration and precession-nutation, 0.15 deg in 2026).
Refraction and polar motion are left out (below 0.5 arcsec). A schedule may leave out the
samples of its turnarounds, as TOAST's map-making does by default; it keeps them by default.

The crossing angle psi of a sample is the orientation on the sky of the focal plane's "up" axis
(towards the zenith at zero boresight rotation), measured from e_theta towards e_phi of the
schedule's frame like the synthetic scans' psi, plus the boresight angle: in CIRS,
psi = pi - q + boresight, with q the parallactic angle (position angle of the zenith, east of
north).
"""

from __future__ import annotations

import csv
import json
import os
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numba
import numpy as np

from . import frames, validation
from .config import ConfigError, toml_text, tomllib
from .constants import DEG
from .frames import to_frame

if TYPE_CHECKING:
    from collections.abc import Iterator

    from .toast_schedule import ScanMotion


UNIX_EPOCH_JD = frames.UNIX_EPOCH_JD
#: what a schedule does with the samples of its turnarounds
TURNAROUNDS = ("include", "exclude")
#: Simons Observatory site, Cerro Toco, Atacama (deg, deg, m)
ATACAMA = (-22.958, -67.787, 5200.0)


@dataclass(frozen=True)
class Site:
    """An observatory position.

    Parameters
    ----------
    lat_deg : float
        Geodetic latitude [deg], in [-90, 90].
    lon_deg : float
        East longitude [deg].
    alt_m : float
        Altitude [m].
    name, telescope : str
        Labels kept from and written to TOAST schedules (no ``|`` or line breaks).
    """

    lat_deg: float = ATACAMA[0]
    lon_deg: float = ATACAMA[1]
    alt_m: float = ATACAMA[2]
    name: str = "site"
    telescope: str = "telescope"

    def __post_init__(self):
        validation.number("lat_deg", self.lat_deg, -90.0, 90.0)
        validation.number("lon_deg", self.lon_deg, -180.0, 360.0)
        validation.number("alt_m", self.alt_m, -500.0, 1e5)
        validation.label("site name", self.name)
        validation.label("telescope", self.telescope)


@dataclass(frozen=True)
class CES:
    """One constant-elevation scan; every field finite and within :data:`CES_LIMITS`.

    Parameters
    ----------
    start_unix : float
        Start [UTC seconds since 1970].
    duration_s : float
        Length [s], > 0.
    elevation_deg : float
        Elevation [deg], in (0, 90).
    az_centre_deg, az_throw_deg : float
        Centre and full width of the azimuth sweep [deg].
    speed_deg_s : float
        Azimuth speed of the mount [deg/s], > 0.
    boresight_deg : float
        Boresight rotation of this CES [deg].
    turnaround_s : float
        Time to reverse at each end, at constant deceleration [s].
    name : str
        Patch name (TOAST's), kept as metadata.
    scan_index, subscan_index : int
        TOAST's pass and sub-pass of the patch, kept as metadata.
    """

    start_unix: float
    duration_s: float
    elevation_deg: float
    az_centre_deg: float
    az_throw_deg: float
    speed_deg_s: float = 1.0
    boresight_deg: float = 0.0
    turnaround_s: float = 0.0  #: time to reverse at each end, at constant deceleration
    name: str = "ces"
    scan_index: int = 0
    subscan_index: int = 0

    def __post_init__(self):
        for name, (lo, hi) in CES_LIMITS.items():
            validation.number(f"CES {name}", getattr(self, name), lo, hi)
        validation.label("CES name", self.name)
        validation.integer("CES scan_index", self.scan_index, 0)
        validation.integer("CES subscan_index", self.subscan_index, 0)
        if not 0 < self.elevation_deg < 90:
            raise ValueError(f"CES elevation_deg = {self.elevation_deg} must lie in (0, 90)")
        if self.duration_s <= 0 or self.speed_deg_s <= 0:
            raise ValueError("CES duration_s and speed_deg_s must be > 0")


#: allowed range of every CES field: start between 1970 and 2100, speeds and times of real mounts
CES_LIMITS = {
    "start_unix": (0.0, 4.1e9),
    "duration_s": (0.0, 1e7),
    "elevation_deg": (0.0, 90.0),
    "az_centre_deg": (-720.0, 720.0),
    "az_throw_deg": (0.0, 360.0),
    "speed_deg_s": (0.0, 100.0),
    "boresight_deg": (-3600.0, 3600.0),
    "turnaround_s": (0.0, 3600.0),
}
#: the CES fields a schedule must give (the others have defaults)
CES_REQUIRED = ("start_unix", "duration_s", "elevation_deg", "az_centre_deg", "az_throw_deg")
#: the CES labels a schedule may give (TOAST's patch name, pass and sub-pass)
CES_METADATA = ("name", "scan_index", "subscan_index")


@dataclass(frozen=True)
class Schedule:
    """A site, a set of CESs and the sample rate.

    Parameters
    ----------
    ces : tuple of CES
    site : Site
    sample_rate_hz : float
    dut1_s : float
        UT1 - UTC [s], in [-1, 1].
    repeat_boresight_deg : tuple of float
        The CES set is observed once per angle [deg] (identical sky tracks).
    frame : {"icrs", "galactic", "cirs"}
        The sky frame of its pointing (:mod:`boresight.frames`).
    turnarounds : {"include", "exclude"}
        Keep or leave out the samples of the turnarounds (TOAST's map-making leaves them out).
    """

    ces: tuple
    site: Site = Site()
    sample_rate_hz: float = 20.0
    dut1_s: float = 0.0  #: UT1 - UTC [s]
    repeat_boresight_deg: tuple = (0.0,)  #: the CES set is observed once per angle [deg]
    frame: str = "icrs"
    turnarounds: str = "include"

    def __post_init__(self):
        frames.check_frame(self.frame)
        if self.turnarounds not in TURNAROUNDS:
            raise ValueError(f"turnarounds = {self.turnarounds!r}; allowed: {TURNAROUNDS}")
        if not self.ces or not all(isinstance(c, CES) for c in self.ces):
            raise ValueError("a schedule needs at least one CES")
        validation.number("sample_rate_hz", self.sample_rate_hz, 1e-3, 1e4)
        validation.number("dut1_s", self.dut1_s, -1.0, 1.0)
        rep = validation.numbers_array(
            "repeat_boresight_deg", self.repeat_boresight_deg, -3600.0, 3600.0
        )
        if rep.ndim != 1 or rep.size == 0:
            raise ValueError("repeat_boresight_deg needs at least one angle")
        object.__setattr__(self, "repeat_boresight_deg", tuple(float(a) for a in rep))

    @property
    def n_samples(self):
        per_set = sum(int(c.duration_s * self.sample_rate_hz) for c in self.ces)
        return per_set * len(self.repeat_boresight_deg)

    def repeated(self, boresight_deg):
        """This CES set observed once per boresight angle in the list (identical sky tracks)."""
        return replace(self, repeat_boresight_deg=tuple(boresight_deg))

    def single(self):
        """The CES set observed once, without the boresight repeats."""
        return replace(self, repeat_boresight_deg=(0.0,))

    def expanded(self):
        """The CESs in observing order, each boresight repeat as CESs of their own.

        Returns
        -------
        tuple of CES
            The CES set once per repeat angle, ``boresight_deg`` = its own + the repeat's.
        """
        return tuple(
            replace(c, boresight_deg=c.boresight_deg + rep)
            for rep in self.repeat_boresight_deg
            for c in self.ces
        )


class ScheduleError(ConfigError):
    """A schedule file that cannot be read, with the file, row and key in the message."""


def load_schedule(
    path: str,
    motion: ScanMotion | None = None,
    *,
    frame: str | None = None,
    turnarounds: str | None = None,
) -> Schedule:
    """Read a schedule file: boresight's TOML or CSV, or any TOAST schedule.

    TOML: optional [site], sample_rate_hz, dut1_s, repeat_boresight_deg and [[ces]] tables of CES
    fields. CSV: a header naming CES fields and one CES per row. Unknown keys or columns are errors.
    A TOAST schedule (text of any version, or ECSV; see :mod:`boresight.toast_schedule`) is
    recognised by its content, whatever its name.

    Parameters
    ----------
    path : str or os.PathLike
    motion : boresight.toast_schedule.ScanMotion, optional
        Scan rate, acceleration and sample rate of a TOAST schedule, which its file leaves out
        (default: ``SimGround``'s, at 20 Hz). boresight's own formats hold their own.
    frame, turnarounds : str, optional
        Replace the file's (:class:`Schedule`); a TOML schedule may give its own, the others
        take the defaults.

    Returns
    -------
    Schedule

    Raises
    ------
    ScheduleError
        Naming the file, the row (CSV line or [[ces]] number) and the key.
    """
    from . import toast_schedule

    path = str(path)
    if not os.path.isfile(path):
        raise ScheduleError(f"schedule not found (or not a file): {path}")
    if toast_schedule.is_toast_schedule(path):
        schedule = toast_schedule.read(path, motion or toast_schedule.ScanMotion())
    else:
        try:
            schedule = Schedule(_csv_rows(path)) if path.endswith(".csv") else _toml_schedule(path)
        except ScheduleError:
            raise
        except (ValueError, TypeError) as err:
            raise ScheduleError(f"schedule {path}: {err}") from None
    given = {k: v for k, v in (("frame", frame), ("turnarounds", turnarounds)) if v is not None}
    try:
        return replace(schedule, **given)
    except ValueError as err:
        raise ScheduleError(f"schedule {path}: {err}") from None


def is_schedule(path: str) -> bool:
    """Whether a file is a schedule (TOAST's, CSV, or TOML with [[ces]]) rather than a study.

    Parameters
    ----------
    path : str

    Returns
    -------
    bool
    """
    from . import toast_schedule

    if toast_schedule.is_toast_schedule(path) or str(path).endswith(".csv"):
        return True
    try:
        return "ces" in toml_text(path)
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError):
        return False


def _ces(fields, where):
    """A CES from a dict of fields, with ``where`` (file and row) in every error."""
    unknown = sorted(set(fields) - set(CES_LIMITS) - set(CES_METADATA))
    missing = [k for k in CES_REQUIRED if k not in fields]
    if unknown or missing:
        raise ScheduleError(
            f"{where}: unknown keys {unknown}, missing keys {missing}; CES keys: "
            f"{list(CES_LIMITS) + list(CES_METADATA)}"
        )
    try:
        return CES(**fields)
    except (ValueError, TypeError) as err:
        raise ScheduleError(f"{where}: {err}") from None


def _csv_rows(path):
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        rows = []
        for i, row in enumerate(reader, start=2):
            where = f"schedule {path}, line {i}"
            if None in row or None in row.values():
                raise ScheduleError(
                    f"{where}: the row has a different number of values than the header"
                )
            fields = {}
            for key, text in row.items():
                try:
                    fields[key] = (
                        text if key == "name" else (int if key in CES_METADATA else float)(text)
                    )
                except ValueError:
                    raise ScheduleError(f"{where}: {key} = {text!r} is not a number") from None
            rows.append(_ces(fields, where))
    if not rows:
        raise ScheduleError(f"schedule {path} has no CES rows")
    return tuple(rows)


SCHEDULE_KEYS = (
    "site",
    "ces",
    "sample_rate_hz",
    "dut1_s",
    "repeat_boresight_deg",
    "frame",
    "turnarounds",
)


def _toml_schedule(path):
    try:
        raw = toml_text(path)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise ScheduleError(f"schedule {path} is not valid TOML: {err}") from None
    unknown = sorted(set(raw) - set(SCHEDULE_KEYS))
    if unknown:
        raise ScheduleError(
            f"schedule {path}: unknown keys {unknown}; allowed: {list(SCHEDULE_KEYS)}"
        )
    site, ces = raw.get("site", {}), raw.get("ces", [])
    if not isinstance(site, dict) or not isinstance(ces, list):
        raise ScheduleError(f"schedule {path}: [site] must be a table and [[ces]] a list of tables")
    bad_site = sorted(set(site) - {"lat_deg", "lon_deg", "alt_m", "name", "telescope"})
    if bad_site:
        raise ScheduleError(f"schedule {path}: unknown [site] keys {bad_site}")
    if not all(isinstance(c, dict) for c in ces):
        raise ScheduleError(f"schedule {path}: every [[ces]] must be a table")
    repeat = raw.get("repeat_boresight_deg", [0.0])
    if not isinstance(repeat, list):
        raise ScheduleError(f"schedule {path}: repeat_boresight_deg must be a list of angles")
    return Schedule(
        tuple(_ces(c, f"schedule {path}, [[ces]] number {i + 1}") for i, c in enumerate(ces)),
        Site(**site),
        raw.get("sample_rate_hz", 20.0),
        raw.get("dut1_s", 0.0),
        tuple(repeat),
        raw.get("frame", "icrs"),
        raw.get("turnarounds", "include"),
    )


def schedule_format(path: str) -> str:
    """The format of a schedule file: "toast", "csv" or "toml"."""
    from . import toast_schedule

    if toast_schedule.is_toast_schedule(path):
        return "toast"
    return "csv" if str(path).endswith(".csv") else "toml"


def write_schedule(schedule: Schedule, path: str, fmt: str) -> None:
    """Write a schedule in one of the formats :func:`load_schedule` reads, atomically.

    Parameters
    ----------
    schedule : Schedule
    path : str
    fmt : {"toml", "csv", "toast"}
        TOML keeps everything; CSV holds the CESs only (the default site and sample rate), with
        the repeats as rows; TOAST as :func:`boresight.toast_schedule.write`.
    """
    from . import io, toast_schedule

    if fmt == "toast":
        toast_schedule.write(schedule, path)
        return
    keys = list(CES_LIMITS) + list(CES_METADATA)
    if fmt == "csv":
        rows = [{k: getattr(c, k) for k in keys} for c in schedule.expanded()]
        io.write_csv(path, rows, keys)
        return
    if fmt != "toml":
        raise ValueError(f"schedule format must be toml, csv or toast, got {fmt!r}")
    s = schedule.site

    def value(v):
        return json.dumps(v) if isinstance(v, str) else repr(v)

    lines = [
        f"sample_rate_hz = {schedule.sample_rate_hz!r}",
        f"dut1_s = {schedule.dut1_s!r}",
        f"repeat_boresight_deg = {list(schedule.repeat_boresight_deg)!r}",
        f"frame = {value(schedule.frame)}",
        f"turnarounds = {value(schedule.turnarounds)}",
        "",
        "[site]",
        *(f"{k} = {value(getattr(s, k))}" for k in ("lat_deg", "lon_deg", "alt_m", "name")),
        f"telescope = {value(s.telescope)}",
    ]
    for c in schedule.ces:
        lines += ["", "[[ces]]", *(f"{k} = {value(getattr(c, k))}" for k in keys)]
    io.write_text(path, "\n".join(lines) + "\n")


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


@numba.njit(cache=True)
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


@numba.njit(parallel=True, cache=True)
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


#: the scalars of a CES chunk: start [unix s], rate [Hz], azimuth centre, throw [rad], speed
#: [rad/s], turnaround [s], elevation [rad], UT1 Julian date of the Unix epoch, longitude, latitude,
#: boresight angle [rad]
N_CHUNK = 11


def chunk_arguments(schedule, chunk_samples=1 << 20):
    """Kernel arguments of every chunk of a schedule, in observing order: the CES set in time order,
    once per boresight repeat.

    A chunk holds at most ``chunk_samples`` samples and lies in one block of
    :data:`boresight.frames.CHUNK_SECONDS` of its CES (counted from the CES's start), over which
    the frame's rotation is one, evaluated at the block's middle: so the pointing does not depend
    on ``chunk_samples``.

    Parameters
    ----------
    schedule : Schedule
    chunk_samples : int

    Yields
    ------
    tuple
        (first sample, samples: int; the CES's scalars, (:data:`N_CHUNK`,) float64; the frame's
        terms at the chunk's middle, (frames.N_TERMS,) float64).
    """
    lat, lon = schedule.site.lat_deg * DEG, schedule.site.lon_deg * DEG
    jd_offset = UNIX_EPOCH_JD + schedule.dut1_s / 86400.0
    rate = schedule.sample_rate_hz
    block = max(1, int(frames.CHUNK_SECONDS * rate))
    for repeat in schedule.repeat_boresight_deg:
        for c in schedule.ces:
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
                    yield s, min(chunk_samples, end - s), chunk, t


def pointing(schedule: Schedule, chunk_samples: int = 1 << 20) -> Iterator[tuple]:
    """The pointing of a whole schedule, chunk by chunk, in the schedule's frame.

    Samples in the turnarounds are left out where the schedule says so.

    Parameters
    ----------
    schedule : Schedule
    chunk_samples : int

    Yields
    ------
    theta, phi, psi : numpy.ndarray, shape (<= chunk_samples,)
        Colatitude, longitude and crossing angle [rad] in ``schedule.frame``; the CES set in time
        order, once per boresight repeat.
    """
    for args in chunk_arguments(schedule, chunk_samples):
        theta, phi, psi, turning = _ces_pointing(*args)
        if schedule.turnarounds == "exclude":
            keep = ~turning
            theta, phi, psi = theta[keep], phi[keep], psi[keep]
        yield theta, phi, psi
